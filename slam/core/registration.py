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

The CNN registration lives in ``slam.core.cnn_registration`` and follows the same protocol.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from scipy.spatial import cKDTree

from rhs_common.geometry import (
    apply_motion,
    compose,
    points_in_frame,
    relative_motion,
    wrap_angle,
)
from rhs_common.jit import KernelTable
from rhs_common.validation import (
    build,
    check_choice,
    check_int,
    check_range,
    check_types,
)

__all__ = [
    "Registration",
    "ICPConfig",
    "ICPRegistration",
    "make_registration",
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


def _median(x: np.ndarray) -> float:
    """``float(np.median(x))`` of a non-empty 1-D array without NaN, as np.median computes it.

    np.median partitions around the middle and averages the middle element (odd size)
    or the two middle ones (``(a + b) / 2``, even size): the same arithmetic here,
    without its generic axis / NaN handling (a third of an ICP iteration's time).
    """
    n = x.size
    h = n // 2
    if n % 2:
        return float(np.partition(x, h)[h])
    p = np.partition(x, (h - 1, h))
    return float((p[h - 1] + p[h]) / 2)


@dataclass(frozen=True)
class ICPConfig:
    """Settings of :class:`ICPRegistration` (see its docstring for their roles).

    ``max_iterations`` [1, 10000]; gates ``max_gate_m`` / ``min_gate_m`` (m, > 0);
    ``outlier_factor`` (> 0) times the median pair distance; stop tolerances ``tol_m``
    (m) / ``tol_rad`` (rad); ``min_pairs`` [2, 10^6]; ``amplitude_weights``;
    ``constant_velocity`` (start from the last estimate without a prior); heading search
    over ``yaw_search_steps`` [0, 360] offsets within +-``yaw_search_rad`` [0, pi].
    """

    max_iterations: int = 30
    max_gate_m: float = 3.0
    min_gate_m: float = 0.5
    outlier_factor: float = 3.0
    tol_m: float = 1e-6
    tol_rad: float = 1e-7
    min_pairs: int = 3
    amplitude_weights: bool = False
    constant_velocity: bool = True
    yaw_search_rad: float = 0.2
    yaw_search_steps: int = 8

    def __post_init__(self) -> None:
        check_types(self)
        check_int("max_iterations", self.max_iterations, 1, 10_000)
        check_range("yaw_search_rad", self.yaw_search_rad, 0.0, math.pi)
        check_int("yaw_search_steps", self.yaw_search_steps, 0, 360)
        check_range("max_gate_m", self.max_gate_m, 0.0, 1e3, low_open=True)
        check_range("min_gate_m", self.min_gate_m, 0.0, 1e3, low_open=True)
        check_range("outlier_factor", self.outlier_factor, 0.0, 1e3, low_open=True)
        check_range("tol_m", self.tol_m, 0.0, 1.0)
        check_range("tol_rad", self.tol_rad, 0.0, 1.0)
        check_int("min_pairs", self.min_pairs, 2, 1_000_000)


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

    def __init__(self, config: ICPConfig | None = None, **fields: Any) -> None:
        """``config`` (defaults when None), with any :class:`ICPConfig` field overridden by keyword."""
        cfg = build(ICPConfig, {**asdict(config or ICPConfig()), **fields}, "icp")
        self.config = cfg
        self.yaw_offsets = (
            np.linspace(-cfg.yaw_search_rad, cfg.yaw_search_rad, cfg.yaw_search_steps + 1)
            if cfg.yaw_search_rad > 0 and cfg.yaw_search_steps > 0
            else np.zeros(0)
        )
        self.max_iterations = cfg.max_iterations
        self.max_gate_m = cfg.max_gate_m
        self.min_gate_m = cfg.min_gate_m
        self.outlier_factor = cfg.outlier_factor
        self.tol_m = cfg.tol_m
        self.tol_rad = cfg.tol_rad
        self.min_pairs = cfg.min_pairs
        self.amplitude_weights = cfg.amplitude_weights
        self.constant_velocity = cfg.constant_velocity
        self.kernels = "numba"  # set from the SLAM config by the pipeline
        self.reset()

    @property
    def kernels(self) -> str:
        """The heading search's implementation: "numba" compiled with brute-force nearest neighbours
        (:func:`slam.core.kernels.icp_search`, the clouds hold tens of points), "numpy" cKDTree and numpy (the
        reference); setting it chooses the search (:data:`_STAGES`)."""
        return str(self._impl.kernels)

    @kernels.setter
    def kernels(self, kernels: str) -> None:
        self._impl = _STAGES.choose(kernels)  # the compiled or the numpy heading search

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
        src = cur[:, :2]
        if self.amplitude_weights and prev.shape[1] >= 4 and cur.shape[1] >= 4:
            amp_p = np.maximum(prev[:, 3], 1e-12)
            amp_c = np.maximum(cur[:, 3], 1e-12)
        else:
            amp_p = amp_c = None
        offsets = np.concatenate([[0.0], self.yaw_offsets[self.yaw_offsets != 0.0]])
        est, self.last_pairs, self.last_rmse = self._impl.search(self, src, prev, guess, offsets, amp_p, amp_c)
        est[2] = wrap_angle(est[2])
        self.last_estimate = est.copy()
        return est

    def _search_numpy(self, src, prev, guess, offsets, amp_p, amp_c) -> tuple[np.ndarray, int, float]:
        """The heading search of :meth:`estimate`: :meth:`_fit` from ``guess`` turned by each of ``offsets``, the
        fit with the most points within ``min_gate_m`` (then the smallest RMS distance) kept: the estimate, its
        pairs and RMS distance (the guess, 0 pairs and nan when no start fits)."""
        tree = cKDTree(prev[:, :2])
        best = None
        for offset in offsets:
            start = guess + np.array([0.0, 0.0, offset])
            est, pairs, rmse = self._fit(tree, src, prev, start, amp_p, amp_c)
            if pairs:
                d, _ = tree.query(apply_motion(src, est), k=1, distance_upper_bound=self.max_gate_m)
                near = int(np.sum(d <= self.min_gate_m))
                score = (near, -rmse)
                if best is None or score > best[0]:
                    best = (score, est, pairs, rmse)
        if best is None:
            return guess.copy(), 0, float("nan")
        _, est, pairs, rmse = best
        return est, pairs, rmse

    def _search_compiled(self, src, prev, guess, offsets, amp_p, amp_c) -> tuple[np.ndarray, int, float]:
        """The heading search of :meth:`estimate` by :func:`slam.core.kernels.icp_search` (:meth:`_fit` from every
        start, compiled with brute-force neighbours, the same score): the estimate, its pairs and RMS distance (the
        guess, 0 pairs and nan when no start fits)."""
        from slam.core.kernels import icp_search

        use_amp = amp_p is not None
        ones = np.ones(1)
        est, pairs, rmse, found = icp_search(
            np.ascontiguousarray(src, dtype=float), np.ascontiguousarray(prev[:, :2], dtype=float), guess,
            np.ascontiguousarray(offsets, dtype=float), amp_p if use_amp else ones, amp_c if use_amp else ones,
            use_amp, self.max_iterations, float(self.max_gate_m), float(self.min_gate_m), float(self.outlier_factor),
            float(self.tol_m), float(self.tol_rad), int(self.min_pairs))
        if not found:
            return guess.copy(), 0, float("nan")
        return est, int(pairs), float(rmse)

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
            gate = max(self.min_gate_m, self.outlier_factor * _median(d[ok]))
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


#: the ICP heading search's two implementations, chosen when :attr:`ICPRegistration.kernels` is set
_STAGES = KernelTable("slam.core.registration")
_STAGES.stage("search", "numpy")(ICPRegistration._search_numpy)
_STAGES.stage("search", "numba")(ICPRegistration._search_compiled)


class OdometryRegistration:
    """Oracle registration: the true motion plus Gaussian noise.

    The truth comes explicitly: a ``truth()`` callback returning the true motion
    of the cycle (the SLAM env wrapper passes one), or :meth:`set_true_motion`
    before each :meth:`estimate` (``run_scenario`` does); the clouds are ignored. Noise stds: ``trans_std_m`` per axis (m), ``rot_std_rad``
    (rad), and ``trans_frac`` times the travelled distance (m/m).
    """

    def __init__(
        self,
        rng=None,
        trans_std_m: float = 0.0,
        rot_std_rad: float = 0.0,
        trans_frac: float = 0.0,
        truth: Callable[[], np.ndarray] | None = None,
    ) -> None:
        check_range("trans_std_m", trans_std_m, 0.0, 1e3)
        check_range("rot_std_rad", rot_std_rad, 0.0, math.pi)
        check_range("trans_frac", trans_frac, 0.0, 1.0)
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.trans_std_m = float(trans_std_m)
        self.rot_std_rad = float(rot_std_rad)
        self.trans_frac = float(trans_frac)
        self._truth: np.ndarray | None = None
        self.truth = truth

    def set_true_motion(self, motion: np.ndarray) -> None:
        """The true ``(dx, dy, dth)`` for the next :meth:`estimate` call."""
        self._truth = np.asarray(motion, dtype=float).reshape(3).copy()

    def estimate(
        self, prev_points: np.ndarray, points: np.ndarray, prior: np.ndarray | None = None
    ) -> np.ndarray:
        """True motion + noise; the prior (or zero) when no truth was given."""
        if self.truth is not None:
            self.set_true_motion(self.truth())
        if self._truth is None:
            return np.zeros(3) if prior is None else np.asarray(prior, dtype=float).reshape(3).copy()
        m = self._truth.copy()
        s_t = math.hypot(self.trans_std_m, self.trans_frac * math.hypot(m[0], m[1]))
        if s_t > 0:
            m[:2] += s_t * self.rng.standard_normal(2)
        if self.rot_std_rad > 0:
            m[2] += self.rot_std_rad * self.rng.standard_normal()
        return m


REGISTRATIONS = ("cnn", "icp", "odometry")
#: Default registration, chosen by measurement (docs/results/registration.md): ICP is more
#: accurate than the CNN on held-out simulator pairs and in the loop on the paper scene.
#: The trained CNN stays available.
DEFAULT_REGISTRATION = "icp"


def make_registration(
    kind: str,
    rng: np.random.Generator | None = None,
    weights: str | None = None,
    truth: Callable[[], np.ndarray] | None = None,
    icp: ICPConfig | None = None,
) -> Registration:
    """``cnn`` (the shipped trained CNN), ``icp`` (classical baseline, settings ``icp``) or ``odometry``
    (the oracle: ``truth()`` returns the true motion of the cycle)."""
    check_choice("registration", kind, REGISTRATIONS)
    if kind == "cnn":
        from slam.core.cnn_registration import CNNRegistration

        return CNNRegistration(weights)
    if kind == "icp":
        return ICPRegistration(icp)
    return OdometryRegistration(rng=rng, truth=truth)
