"""SLAM and point-cloud metrics (SPEC section 9). SI units: m, rad.

- :func:`position_rmse`: ``sqrt(mean_t |p_hat_t - p_t|^2)`` over the run, no
  alignment (the map frame is the start pose).
- :func:`heading_rmse`: ``sqrt(mean_t wrap(th_hat_t - th_t)^2)``.
- :func:`map_metrics`: one-to-one matching of estimated to true landmarks by the
  Hungarian algorithm (``scipy.optimize.linear_sum_assignment``) on the Euclidean
  distance; pairs farther than the gate are not matches. RMSE over matches,
  ``missed`` = true landmarks without a match, ``spurious`` = estimated landmarks
  without a match.
- :func:`point_cloud_metrics`: per cycle, every true scatterer in view is matched to
  its nearest point within a gate (detection); detection rate, RMSE over detected
  scatterers, and false points per cycle (points with no true scatterer within the
  gate).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

__all__ = [
    "position_rmse",
    "heading_rmse",
    "position_errors",
    "map_metrics",
    "point_cloud_cycle",
    "point_cloud_metrics",
]


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def position_errors(est: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Per-cycle position error ``|p_hat - p|`` (T,) (m); inputs (T, >=2)."""
    est = np.asarray(est, dtype=float)
    true = np.asarray(true, dtype=float)
    if est.shape[0] != true.shape[0]:
        raise ValueError(f"est and true must have the same length, got {est.shape[0]} and {true.shape[0]}")
    return np.linalg.norm(est[:, :2] - true[:, :2], axis=1)


def position_rmse(est: np.ndarray, true: np.ndarray) -> float:
    """Position RMSE (m) over the run, no alignment; NaN for an empty run."""
    e = position_errors(est, true)
    return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")


def heading_rmse(est: np.ndarray, true: np.ndarray) -> float:
    """Heading RMSE (rad) with wrapped differences; inputs (T, 3) poses or (T,) angles."""
    est = np.asarray(est, dtype=float)
    true = np.asarray(true, dtype=float)
    a = est[:, 2] if est.ndim == 2 else est
    b = true[:, 2] if true.ndim == 2 else true
    if a.shape != b.shape:
        raise ValueError(f"est and true must have the same length, got {a.shape} and {b.shape}")
    d = _wrap(a - b)
    return float(np.sqrt(np.mean(d**2))) if d.size else float("nan")


def map_metrics(est: np.ndarray, true: np.ndarray, gate: float = 2.0) -> dict:
    """Hungarian map matching within ``gate`` (m).

    Returns ``dict(rmse, matched, missed, spurious, pairs)``: ``rmse`` over matched
    pairs (NaN when none), ``pairs`` (matched, 2) int array of (est index, true index).
    """
    if not gate > 0:
        raise ValueError(f"gate must be in (0, inf), got {gate!r}")
    est = np.asarray(est, dtype=float).reshape(-1, 2)
    true = np.asarray(true, dtype=float).reshape(-1, 2)
    ne, nt = len(est), len(true)
    if ne == 0 or nt == 0:
        return dict(rmse=float("nan"), matched=0, missed=nt, spurious=ne, pairs=np.zeros((0, 2), dtype=int))
    d = np.linalg.norm(est[:, None, :] - true[None, :, :], axis=2)
    big = gate * 1e3 + d.max() * 10 + 1.0
    cost = np.where(d <= gate, d, big)
    r, c = linear_sum_assignment(cost)
    ok = d[r, c] <= gate
    r, c = r[ok], c[ok]
    m = int(ok.sum())
    rmse = float(np.sqrt(np.mean(d[r, c] ** 2))) if m else float("nan")
    return dict(rmse=rmse, matched=m, missed=nt - m, spurious=ne - m, pairs=np.stack([r, c], axis=1))


def point_cloud_cycle(true_xy: np.ndarray, points: np.ndarray, gate: float = 1.0) -> dict:
    """One cycle: ``dict(n_true, detected, sq_err_sum, false_points)``.

    ``true_xy`` (K, 2) scatterers in view, ``points`` (N, >=2) detected points, both in
    the same frame (m). A scatterer is detected when its nearest point is within
    ``gate``; a point is false when no scatterer is within ``gate`` of it.
    """
    if not gate > 0:
        raise ValueError(f"gate must be in (0, inf), got {gate!r}")
    t = np.asarray(true_xy, dtype=float).reshape(-1, 2)
    p = np.asarray(points, dtype=float)
    p = p.reshape(-1, p.shape[-1] if p.ndim == 2 else 2)[:, :2] if p.size else np.zeros((0, 2))
    if len(p) == 0:
        return dict(n_true=len(t), detected=0, sq_err_sum=0.0, false_points=0)
    if len(t) == 0:
        return dict(n_true=0, detected=0, sq_err_sum=0.0, false_points=len(p))
    d, _ = cKDTree(p).query(t, k=1)
    det = d <= gate
    dp, _ = cKDTree(t).query(p, k=1)
    return dict(
        n_true=len(t),
        detected=int(det.sum()),
        sq_err_sum=float(np.sum(d[det] ** 2)),
        false_points=int(np.sum(dp > gate)),
    )


def point_cloud_metrics(
    true_per_cycle: Sequence[np.ndarray], points_per_cycle: Sequence[np.ndarray], gate: float = 1.0
) -> dict:
    """Aggregate over cycles: ``dict(detection_rate, rmse, false_points_per_cycle, cycles)``.

    detection_rate = detected / scatterers in view (NaN if none), rmse over detected
    scatterers (m, NaN if none), false_points_per_cycle = mean false points per cycle.
    """
    if len(true_per_cycle) != len(points_per_cycle):
        raise ValueError("true_per_cycle and points_per_cycle must have the same length")
    n_true = det = fp = 0
    sq = 0.0
    for t, p in zip(true_per_cycle, points_per_cycle):
        r = point_cloud_cycle(t, p, gate)
        n_true += r["n_true"]
        det += r["detected"]
        fp += r["false_points"]
        sq += r["sq_err_sum"]
    n = len(true_per_cycle)
    return dict(
        detection_rate=det / n_true if n_true else float("nan"),
        rmse=math.sqrt(sq / det) if det else float("nan"),
        false_points_per_cycle=fp / n if n else float("nan"),
        cycles=n,
    )
