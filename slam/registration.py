"""Classical point-cloud registration (paper section VII-A baseline).

A registration estimates the motion ``m = (dx, dy, dth)`` of the current vehicle
frame expressed in the previous one (m, m, rad): a point seen at ``x`` in the current
frame is at ``R(dth) x + [dx, dy]`` in the previous frame.

- :class:`Registration`: the protocol, ``.estimate(prev_points, points, prior=None)``.
- :class:`ICPRegistration`: point-to-point ICP (nearest neighbours by cKDTree,
  outlier rejection, closed-form weighted 2-D Procrustes per iteration), initial
  guess from a constant-velocity prior (the last estimate).
- :class:`OdometryRegistration`: the true motion plus Gaussian noise (an "oracle"
  baseline for tests and ablations).

The CNN registration lives in ``slam.cnn_registration`` and follows the same protocol.
"""

from __future__ import annotations

import math
from typing import Protocol, runtime_checkable

import numpy as np
from scipy.spatial import cKDTree

from rhs_env.validation import check_int, check_range

__all__ = [
    "Registration",
    "ICPRegistration",
    "OdometryRegistration",
    "apply_motion",
    "compose",
    "points_in_frame",
    "relative_motion",
]


@runtime_checkable
class Registration(Protocol):
    """Estimate ``(dx, dy, dth)`` of the current frame in the previous frame."""

    def estimate(
        self, prev_points: np.ndarray, points: np.ndarray, prior: np.ndarray | None = None
    ) -> np.ndarray:  # pragma: no cover - protocol
        ...


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
    return np.array([x + c * dx - s * dy, y + s * dx + c * dy, (th + dth + math.pi) % (2 * math.pi) - math.pi])


def relative_motion(pose_prev: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Motion of ``pose`` expressed in the frame of ``pose_prev`` (both (3,) map frame).

    ``[dx, dy] = R(th_prev)^T ([x, y] - [x_prev, y_prev])``, ``dth = wrap(th - th_prev)``.
    """
    a = np.asarray(pose_prev, dtype=float)
    b = np.asarray(pose, dtype=float)
    c, s = math.cos(a[2]), math.sin(a[2])
    d = b[:2] - a[:2]
    dth = (b[2] - a[2] + math.pi) % (2 * math.pi) - math.pi
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], dth])


def _procrustes_2d(src: np.ndarray, dst: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least-squares rigid transform with ``dst ~ R(th) src + t``.

    Closed form in 2-D: with centroids ``mu_s, mu_d`` and centred points ``a, b``,
    ``th = atan2(sum w (a_x b_y - a_y b_x), sum w (a_x b_x + a_y b_y))``,
    ``t = mu_d - R(th) mu_s``. Returns ``(tx, ty, th)``.
    """
    ws = w / w.sum()
    mu_s = ws @ src
    mu_d = ws @ dst
    a = src - mu_s
    b = dst - mu_d
    sxy = np.sum(ws * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    sxx = np.sum(ws * (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    th = math.atan2(sxy, sxx)
    c, s = math.cos(th), math.sin(th)
    t = mu_d - np.array([c * mu_s[0] - s * mu_s[1], s * mu_s[0] + c * mu_s[1]])
    return np.array([t[0], t[1], th])


class ICPRegistration:
    """Point-to-point ICP in the plane.

    Each iteration: move the current cloud with the running estimate, find each
    point's nearest neighbour in the previous cloud (cKDTree), keep pairs closer than
    ``max(min_gate_m, outlier_factor * median distance)`` and below ``max_gate_m``,
    and solve the weighted Procrustes problem (weights = sqrt of the product of the
    amplitudes when ``amplitude_weights``). Stops when the update is below
    ``tol_m`` / ``tol_rad`` or after ``max_iterations``.

    Initial guess: ``prior`` if given, else the last estimate (constant-velocity
    model), else zero. With fewer than ``min_pairs`` pairs the initial guess is
    returned. ``last_pairs`` / ``last_rmse`` report the final fit.

    Heading search: ICP converges only within a few degrees of the truth, while a
    highway lane change turns the vehicle by up to ~10 deg within one 0.2 s cycle
    and the Doppler prior carries no yaw. ICP is therefore also started from the
    guess turned by ``yaw_search_steps`` offsets spanning +-``yaw_search_rad``;
    the fit with the most points within ``min_gate_m`` of a previous point wins
    (ties: the lower RMS distance). ``yaw_search_rad=0`` disables it.
    """

    def __init__(
        self,
        max_iterations: int = 30,
        max_gate_m: float = 3.0,
        min_gate_m: float = 0.5,
        outlier_factor: float = 3.0,
        tol_m: float = 1e-6,
        tol_rad: float = 1e-7,
        min_pairs: int = 3,
        amplitude_weights: bool = False,
        constant_velocity: bool = True,
        yaw_search_rad: float = 0.2,
        yaw_search_steps: int = 8,
    ) -> None:
        check_int("max_iterations", max_iterations, 1, 10_000)
        check_range("yaw_search_rad", yaw_search_rad, 0.0, math.pi)
        check_int("yaw_search_steps", yaw_search_steps, 0, 360)
        self.yaw_offsets = (
            np.linspace(-yaw_search_rad, yaw_search_rad, yaw_search_steps + 1)
            if yaw_search_rad > 0 and yaw_search_steps > 0
            else np.zeros(0)
        )
        check_range("max_gate_m", max_gate_m, 0.0, None, low_open=True)
        check_range("min_gate_m", min_gate_m, 0.0, None, low_open=True)
        check_range("outlier_factor", outlier_factor, 0.0, None, low_open=True)
        check_range("tol_m", tol_m, 0.0, None)
        check_range("tol_rad", tol_rad, 0.0, None)
        check_int("min_pairs", min_pairs, 2, None)
        self.max_iterations = int(max_iterations)
        self.max_gate_m = float(max_gate_m)
        self.min_gate_m = float(min_gate_m)
        self.outlier_factor = float(outlier_factor)
        self.tol_m = float(tol_m)
        self.tol_rad = float(tol_rad)
        self.min_pairs = int(min_pairs)
        self.amplitude_weights = bool(amplitude_weights)
        self.constant_velocity = bool(constant_velocity)
        self.reset()

    def reset(self) -> None:
        """Forget the constant-velocity prior."""
        self.last_estimate: np.ndarray | None = None
        self.last_pairs = 0
        self.last_rmse = float("nan")

    def estimate(
        self, prev_points: np.ndarray, points: np.ndarray, prior: np.ndarray | None = None
    ) -> np.ndarray:
        """Motion ``(dx, dy, dth)`` of the current frame in the previous frame."""
        if prior is not None:
            guess = np.asarray(prior, dtype=float).reshape(3).copy()
        elif self.constant_velocity and self.last_estimate is not None:
            guess = self.last_estimate.copy()
        else:
            guess = np.zeros(3)
        prev = np.asarray(prev_points, dtype=float)
        cur = np.asarray(points, dtype=float)
        self.last_pairs = 0
        self.last_rmse = float("nan")
        if prev.ndim != 2 or cur.ndim != 2 or len(prev) < self.min_pairs or len(cur) < self.min_pairs:
            self.last_estimate = guess
            return guess.copy()
        tree = cKDTree(prev[:, :2])
        src = cur[:, :2]
        if self.amplitude_weights and prev.shape[1] >= 4 and cur.shape[1] >= 4:
            amp_p = np.maximum(prev[:, 3], 1e-12)
            amp_c = np.maximum(cur[:, 3], 1e-12)
        else:
            amp_p = amp_c = None
        best = None
        for offset in np.concatenate([[0.0], self.yaw_offsets[self.yaw_offsets != 0.0]]):
            start = guess + np.array([0.0, 0.0, offset])
            est, pairs, rmse = self._fit(tree, src, prev, start, amp_p, amp_c)
            if pairs:
                d, _ = tree.query(apply_motion(src, est), k=1, distance_upper_bound=self.max_gate_m)
                score = (int(np.sum(d <= self.min_gate_m)), -rmse)
                if best is None or score > best[0]:
                    best = (score, est, pairs, rmse)
        if best is None:
            est, self.last_pairs, self.last_rmse = guess.copy(), 0, float("nan")
        else:
            _, est, self.last_pairs, self.last_rmse = best
        est[2] = (est[2] + math.pi) % (2 * math.pi) - math.pi
        self.last_estimate = est.copy()
        return est

    def _fit(self, tree, src, prev, guess, amp_p, amp_c) -> tuple[np.ndarray, int, float]:
        """ICP iterations from ``guess``; returns (estimate, pairs, RMS distance of the final fit)."""
        last_pairs, last_rmse = 0, float("nan")
        est = guess.copy()
        for _ in range(self.max_iterations):
            moved = apply_motion(src, est)
            d, j = tree.query(moved, k=1, distance_upper_bound=self.max_gate_m)
            ok = np.isfinite(d)
            if ok.sum() < self.min_pairs:
                break
            gate = max(self.min_gate_m, self.outlier_factor * float(np.median(d[ok])))
            ok &= d <= gate
            if ok.sum() < self.min_pairs:
                break
            w = np.ones(ok.sum()) if amp_p is None else np.sqrt(amp_c[ok] * amp_p[j[ok]])
            new = _procrustes_2d(src[ok], prev[j[ok], :2], w)
            step = np.abs(new - est)
            est = new
            last_pairs = int(ok.sum())
            if step[0] < self.tol_m and step[1] < self.tol_m and step[2] < self.tol_rad:
                break
        if last_pairs:
            d, _ = tree.query(apply_motion(src, est), k=1, distance_upper_bound=self.max_gate_m)
            ok = np.isfinite(d)
            last_rmse = float(np.sqrt(np.mean(d[ok] ** 2))) if ok.any() else float("nan")
        return est, last_pairs, last_rmse


class OdometryRegistration:
    """Oracle registration: the true motion plus Gaussian noise.

    Call :meth:`set_true_motion` before :meth:`estimate` (``run_scenario`` does);
    the clouds are ignored. Noise stds: ``trans_std_m`` per axis (m), ``rot_std_rad``
    (rad), and ``trans_frac`` times the travelled distance (m/m).
    """

    def __init__(
        self,
        rng=None,
        trans_std_m: float = 0.0,
        rot_std_rad: float = 0.0,
        trans_frac: float = 0.0,
    ) -> None:
        check_range("trans_std_m", trans_std_m, 0.0, None)
        check_range("rot_std_rad", rot_std_rad, 0.0, math.pi)
        check_range("trans_frac", trans_frac, 0.0, 1.0)
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.trans_std_m = float(trans_std_m)
        self.rot_std_rad = float(rot_std_rad)
        self.trans_frac = float(trans_frac)
        self._truth: np.ndarray | None = None

    def set_true_motion(self, motion: np.ndarray) -> None:
        """The true ``(dx, dy, dth)`` for the next :meth:`estimate` call."""
        self._truth = np.asarray(motion, dtype=float).reshape(3).copy()

    def estimate(
        self, prev_points: np.ndarray, points: np.ndarray, prior: np.ndarray | None = None
    ) -> np.ndarray:
        """True motion + noise; the prior (or zero) when no truth was given."""
        if self._truth is None:
            return np.zeros(3) if prior is None else np.asarray(prior, dtype=float).reshape(3).copy()
        m = self._truth.copy()
        s_t = math.hypot(self.trans_std_m, self.trans_frac * math.hypot(m[0], m[1]))
        if s_t > 0:
            m[:2] += s_t * self.rng.standard_normal(2)
        if self.rot_std_rad > 0:
            m[2] += self.rot_std_rad * self.rng.standard_normal()
        return m
