"""Angles and 2-D rigid frames: the one place they are written.

Conventions: a pose is ``(x, y, heading)`` (m, m, rad), heading counter-clockwise
from +x; a motion ``(dx, dy, dth)`` is the next pose expressed in the frame of the
previous one. ``R(th) = [[cos th, -sin th], [sin th, cos th]]``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["apply_motion", "circular_mean", "compose", "points_in_frame", "relative_motion", "rotation", "wrap_angle"]


def wrap_angle(a):
    """Angles (rad) wrapped to ``[-pi, pi)``: ``(a + pi) mod 2 pi - pi``; a scalar stays a numpy scalar."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def circular_mean(angles: np.ndarray, weights: np.ndarray | None = None) -> float:
    """Weighted mean on the circle: ``atan2(sum w sin a, sum w cos a)`` (rad)."""
    a = np.asarray(angles, dtype=float)
    w = np.ones_like(a) if weights is None else np.asarray(weights, dtype=float)
    return float(np.arctan2(np.sum(w * np.sin(a)), np.sum(w * np.cos(a))))


def rotation(theta: np.ndarray) -> np.ndarray:
    """Rotation matrices ``R(theta)``, shape ``theta.shape + (2, 2)``."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def apply_motion(xy: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """Map current-frame points (N, 2) into the previous frame: ``R(dth) x + t``."""
    dx, dy, dth = np.asarray(motion, dtype=float).reshape(3)
    c, s = math.cos(dth), math.sin(dth)
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    return np.stack([c * xy[:, 0] - s * xy[:, 1] + dx, s * xy[:, 0] + c * xy[:, 1] + dy], axis=1)


def points_in_frame(xy: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Points (N, 2) expressed in the frame of ``pose`` (3,): ``R(th)^T (x - [px, py])``.

    The inverse of :func:`apply_motion`; with a motion ``(dx, dy, dth)`` it moves
    points of the previous vehicle frame into the current one.
    """
    px, py, th = np.asarray(pose, dtype=float).reshape(3)
    c, s = math.cos(th), math.sin(th)
    d = np.asarray(xy, dtype=float).reshape(-1, 2) - (px, py)
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)


def compose(pose: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """``pose (+) motion``: ``[x, y] += R(th) [dx, dy]``, ``th += dth`` (wrapped); inverse of :func:`relative_motion`."""
    x, y, th = np.asarray(pose, dtype=float).reshape(3)
    dx, dy, dth = np.asarray(motion, dtype=float).reshape(3)
    c, s = math.cos(th), math.sin(th)
    return np.array([x + c * dx - s * dy, y + s * dx + c * dy, float(wrap_angle(th + dth))])


def relative_motion(pose_prev: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Motion of ``pose`` expressed in the frame of ``pose_prev`` (both (3,) map frame).

    ``[dx, dy] = R(th_prev)^T ([x, y] - [x_prev, y_prev])``, ``dth = wrap(th - th_prev)``.
    """
    a = np.asarray(pose_prev, dtype=float)
    b = np.asarray(pose, dtype=float)
    c, s = math.cos(a[2]), math.sin(a[2])
    d = b[:2] - a[:2]
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], float(wrap_angle(b[2] - a[2]))])
