"""Rao-Blackwellized particle filter SLAM (FastSLAM 2.0 / 1.0), vectorized over particles.

Paper section VII-C ("Information Update"). Each particle c carries a vehicle pose
``p_c = (x, y, th)`` in the map frame (m, m, rad) and, per landmark u, a Gaussian
``N(e_cu, Lambda_cu)`` (m, m^2). All particle state lives in dense arrays

- ``pose`` (P, 3), ``logw`` (P,) normalized log-weights,
- ``mean`` (P, Lmax, 2), ``cov`` (P, Lmax, 2, 2), ``active`` (P, Lmax) bool,
- ``last_seen`` (P, Lmax) cycle index, ``hits`` (P, Lmax) update count,

and slot ``j`` is the *same* landmark (id ``slot_id[j]``) in every particle that
holds it: a landmark created from one observation gets one slot, activated in every
particle that did not associate that observation. Averaging a landmark across
particles is therefore a weighted mean over one slot.

**Measurement model.** An observation is a point ``z`` in the vehicle frame with its
own covariance ``Q`` (m^2): the radar's range / angle std of the point turned into
Cartesian form (:func:`slam.core.association.point_covariance`), fused over a cluster,
plus ``measurement_floor_m^2 I`` (errors outside the radar: clustering, timing).
``measurement_noise="fixed"`` uses ``range_std_m`` / ``bearing_std_rad`` for every
point instead (the first round's model). The prediction of landmark ``e`` from pose
``p = (t, th)`` is ``h(p, e) = R(th)^T (e - t)``, linear in ``e`` (``H_e = R^T``) with
the pose Jacobian ``H_p = [-R^T | (h_y, -h_x)^T]``.

One cycle (:meth:`RBPFSlam.update`): predict, associate, update, weight, resample.

1. **Predict.** The registration estimate ``m = (dx, dy, dth)`` (current vehicle frame
   in the previous one) moves every particle, ``mu_c = p_c (+) m``; its uncertainty is
   ``Sigma_p = diag(sigma_t^2, sigma_t^2, sigma_th^2)`` (map frame) with
   ``sigma_t = sqrt(trans_std^2 + (trans_frac |d|)^2 + (accel_std dt^2 / 2)^2)`` (m)
   and ``sigma_th = sqrt(rot_std^2 + (yaw_accel_std dt^2 / 2)^2)`` (rad): a constant
   random acceleration over the cycle displaces the vehicle by ``a dt^2 / 2``.
   FastSLAM 1.0 samples ``p_c ~ N(mu_c, Sigma_p)`` here.
2. **Associate** (per particle, at ``mu_c``): innovation ``nu = t + R z - e`` (map frame)
   with covariance ``C = Lambda + R (Q + H_p,z Sigma_p H_p,z^T) R^T`` (``H_p`` evaluated
   at the observation); gate ``nu^T C^-1 nu <= gate_mahalanobis^2``, mutual exclusion
   (:func:`slam.core.association.mahalanobis_associate`); an observation within
   ``new_gate_mahalanobis`` of a landmark it did not get is dropped, not made a new
   landmark. ``association="nearest"`` is the paper's nearest landmark within ``delta_m``.
   Recovery (FastSLAM 2.0): when the particles match fewer than
   ``recovery_match_fraction`` of 3 or more observations, ``Sigma_p`` is inflated by
   ``recovery_std_factor^2`` and the association repeated.
3. **Update.**
   *FastSLAM 2.0* (Montemerlo et al. 2003), all matched observations k of particle c
   at once (they are independent given the pose): with ``nu_k = z_k - h(mu_c, e_k)``,
   ``S_k = R^T Lambda_k R + Q_k``,

   ``Lambda_p = Sigma_p^-1 + sum_k H_k^T S_k^-1 H_k``,  ``g = sum_k H_k^T S_k^-1 nu_k``,
   ``p_c ~ N(mu_c + Lambda_p^-1 g, Lambda_p^-1)``

   (the measurement-updated proposal, one Gauss-Newton step). Joint compatibility,
   where cheap: a match whose residual at the corrected pose,
   ``(nu_k - H_k delta)^T S_k^-1 (nu_k - H_k delta)``, exceeds the gate is dropped and
   the proposal recomputed once. The importance weight is the joint marginal
   likelihood of the matched observations, by Woodbury and the determinant lemma

   ``log w_c += -(a - g^T Lambda_p^-1 g) / 2 - n log(2 pi)
   - (sum_k log det S_k + log det Sigma_p + log det Lambda_p) / 2``,
   ``a = sum_k nu_k^T S_k^-1 nu_k``.

   *FastSLAM 1.0*: ``log w_c += sum_k log N(nu_k; 0, S_k)`` at the sampled pose.
   Then, at the particle's pose, the landmark Kalman update (exact, the model is linear
   in ``e``), in the map frame ``Q' = R Q R^T``, ``S = Lambda + Q'``:
   ``e <- e + Lambda S^-1 nu``,  ``Lambda <- Lambda - Lambda S^-1 Lambda`` (symmetrized).
   A new landmark starts at ``e = t + R z``, ``Lambda = R Q R^T``; it adds the constant
   ``log N`` at Mahalanobis distance ``new_landmark_mahalanobis`` of the covariance a
   match would have had.
   ``weighting="amplitude"`` (FastSLAM 1.0 only) is the paper's option: per-observation
   log-likelihoods weighted by ``a_m / mean(a)``.
4. **Weight**: log-sum-exp normalisation; non-finite weights fall back to uniform.
5. **Prune**: a landmark not re-observed for ``prune_after_cycles`` cycles (or a
   tentative one, fewer than ``min_hits`` updates, for ``tentative_prune_after_cycles``)
   is dropped from the particle; a slot held by no particle is freed. Confirmed
   landmarks leaving memory are archived (their weighted mean only) so the full
   map of a long run stays available (:meth:`RBPFSlam.full_map`), capped at
   ``max_retired``. When all ``max_landmarks`` slots are busy the oldest slot is
   evicted.
6. **Estimate** (before resampling): weighted mean pose, heading on the circle
   ``atan2(sum w sin th, sum w cos th)``; landmarks weighted across the particles
   holding them.
7. **Resample**: systematic, when ``ESS = 1 / sum w^2 < resample_threshold P``;
   all arrays are copied by fancy indexing (never aliased).

Stage times (s) per cycle are in :attr:`SlamEstimate.stage_times`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rhs_common.geometry import circular_mean, wrap_angle
from rhs_common.jit import KERNELS, KernelTable
from rhs_common.timing import StageTimer
from rhs_common.validation import check_bool, check_choice, check_int, check_memory, check_range, check_types
from slam.core.association import (
    DROPPED,
    NEW,
    associate,
    cluster_covariance,
    cluster_points,
    mahalanobis_associate,
    point_covariance,
    static_mask,
    sym2_inverse,
    to_map_frame,
)

__all__ = [
    "Observations", "RBPFSlam", "SlamConfig", "SlamEstimate", "StageTimer", "circular_mean", "log_sum_exp",
    "rotate_sym2", "wrap_angle",
]

_LOG2PI = math.log(2.0 * math.pi)
VARIANTS = ("fastslam2", "fastslam1")
ASSOCIATIONS = ("mahalanobis", "nearest")
NOISE_MODELS = ("per_point", "fixed")
_EYE2 = np.eye(2)
_EYE2.setflags(write=False)
#: up to this many particles the landmark statistics are compiled (:func:`slam.core.kernels.slot_estimates`, whose
#: emulation of numpy's sums is tested up to there); with more they stay numpy's
_SLOT_KERNEL_MAX_PARTICLES = 4096


def log_sum_exp(a: np.ndarray) -> np.float64:
    """``log sum_p exp(a_p)`` of a 1-D array with a finite maximum (entries may be -inf), shifted for precision.

    With ``a* = max_p a_p`` taken by the ``k`` entries equal to it, and ``s = sum_{a_p < a*} exp(a_p - a*) / k``,

        log sum_p exp(a_p) = a* + log(k) + log1p(s),

    evaluated as ``(log1p(s) + log(k)) + a*`` (``s = 0`` kept when no other entry counts): the operations of
    ``scipy.special.logsumexp`` (scipy 1.17) on such an array, the same value, without its array-API
    dispatch (~0.1 ms a call, once per SLAM cycle).
    """
    a_max = np.max(a)
    top = a == a_max
    k = np.sum(top.astype(a.dtype))
    s = np.sum(np.exp(np.where(top, -np.inf, a) - a_max))
    s = s if s == 0 else s / k
    return np.log1p(s) + np.log(k) + a_max


def _pairs(idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The matched (particle, observation) pairs of ``idx`` (P, M), row-major, as contiguous index arrays (``np.nonzero``'s
    are strided views, contiguous only when they hold one pair or none: one layout keeps one compiled signature)."""
    pp, mm = np.nonzero(idx >= 0)
    return np.ascontiguousarray(pp), np.ascontiguousarray(mm)


def rotate_sym2(c, s, b00, b01, b11):
    """Components of ``R B R^T`` for symmetric B, ``R = [[c, -s], [s, c]]`` (broadcasting)."""
    cc, ss, cs = c * c, s * s, c * s
    return (
        cc * b00 - 2.0 * cs * b01 + ss * b11,
        cs * (b00 - b11) + (cc - ss) * b01,
        ss * b00 + 2.0 * cs * b01 + cc * b11,
    )


#: upper bounds of the noise settings: orders of magnitude past any physical use, low enough that their squares
#: and the Gaussians built from them stay finite in float64 (1e300 overflowed)
MAX_MAHALANOBIS = 1e3  # gates and the new-landmark distance (a 3-sigma gate is 3)
MAX_STD_M = 1e3  # range / translation / floor std, m
MAX_DISTANCE_M = 1e4  # gates, cluster radius and the nearest range, m (the radars see 100 m)
MAX_CYCLES = 10**9  # cycle counts (pruning, hits): 6 years at 5 Hz
#: bytes of filter state per particle and landmark slot: mean (2 float64), covariance (4), active flag,
#: last-seen cycle and hit count (int64): :meth:`RBPFSlam.reset`
STATE_BYTES_PER_SLOT = 2 * 8 + 4 * 8 + 1 + 8 + 8


@dataclass(frozen=True)
class SlamConfig:
    """RBPF SLAM settings (SI units). Validated at construction.

    n_particles: particles P. max_landmarks: landmark slots Lmax per particle.
    variant: "fastslam2" (pose from the measurement-updated proposal) | "fastslam1"
    (the paper's: pose from the motion model). association: "mahalanobis" (gated on
    the full innovation covariance, mutual exclusion) | "nearest" (the paper's nearest
    landmark within delta_m). gate_mahalanobis: match gate (Mahalanobis distance).
    new_gate_mahalanobis: an unmatched observation this close to a landmark is dropped
    instead of starting a new one. association_rounds: mutual-nearest rounds.
    recovery_std_factor, recovery_match_fraction: FastSLAM 2.0 recovery: when the particles
    match fewer than this fraction of >= 3 observations (the registration motion is likely
    wrong, e.g. a collision), the motion std is multiplied by the factor and the association
    repeated (1 disables).
    joint_compatibility: drop matches inconsistent with the pose they jointly imply
    (FastSLAM 2.0). measurement_noise: "per_point" (each point's own covariance) |
    "fixed" (range_std_m, bearing_std_rad for every point). measurement_floor_m:
    isotropic std added to every observation (m). delta_m: "nearest" gate (m).
    cluster_radius_m: points closer than this are one object (m, 0 disables).
    trans_std_m, trans_frac, rot_std_rad, accel_std_mps2, yaw_accel_std_radps2:
    propagation noise (see module docstring). resample_threshold: resample when
    ESS < threshold * P. weighting: "likelihood" | "amplitude" (fastslam1 only).
    new_landmark_mahalanobis: Mahalanobis distance defining the new-landmark
    log-likelihood. prune_after_cycles / tentative_prune_after_cycles / min_hits:
    pruning. min_existence: report a landmark when the weight of the particles
    holding it is at least this. dynamic_threshold_mps: moving-point filter
    threshold (m/s). min_range_m: observations closer than this are ignored (m).
    max_retired: cap on archived landmarks. retire_min_hits: updates needed to
    archive a pruned landmark. kernels: "numba" (default: the Mahalanobis association, the
    FastSLAM 2.0 proposal, the landmark update, the particle-weighted estimates, the pruning, the cluster fusion
    and the ICP fit compiled, :mod:`slam.core.kernels`) | "numpy" (the reference; the same results to round-off).

    Bounds: Mahalanobis gates and distances at most 1e3, std values 1e3 m (accelerations 1e3), distances
    1e4 m, cycle counts 1e9; ``n_particles x max_landmarks`` state within the memory limit
    (:func:`rhs_common.validation.check_memory`, 8 GiB unless ``$RHS_SLAM_MEMORY_LIMIT``).
    """

    n_particles: int = 100
    max_landmarks: int = 256
    variant: str = "fastslam2"
    association: str = "mahalanobis"
    gate_mahalanobis: float = 3.5
    new_gate_mahalanobis: float = 6.0
    association_rounds: int = 3
    joint_compatibility: bool = True
    recovery_std_factor: float = 10.0
    recovery_match_fraction: float = 0.2
    measurement_noise: str = "per_point"
    measurement_floor_m: float = 0.03
    delta_m: float = 2.0
    cluster_radius_m: float = 1.0
    range_std_m: float = 0.3
    bearing_std_rad: float = math.radians(1.0)
    trans_std_m: float = 0.05
    trans_frac: float = 0.05
    rot_std_rad: float = 0.005
    accel_std_mps2: float = 0.5
    yaw_accel_std_radps2: float = 0.05
    resample_threshold: float = 0.5
    weighting: str = "likelihood"
    new_landmark_mahalanobis: float = 3.0
    prune_after_cycles: int = 50
    tentative_prune_after_cycles: int = 3
    min_hits: int = 2
    min_existence: float = 0.5
    dynamic_threshold_mps: float = 1.0
    min_range_m: float = 0.5
    max_retired: int = 100_000
    retire_min_hits: int = 3
    kernels: str = "numba"

    def __post_init__(self) -> None:
        check_types(self)
        check_int("n_particles", self.n_particles, 1, 100_000)
        check_int("max_landmarks", self.max_landmarks, 1, 100_000)
        check_choice("variant", self.variant, VARIANTS)
        check_choice("association", self.association, ASSOCIATIONS)
        check_range("gate_mahalanobis", self.gate_mahalanobis, 0.0, MAX_MAHALANOBIS, low_open=True)
        check_range("new_gate_mahalanobis", self.new_gate_mahalanobis, self.gate_mahalanobis, MAX_MAHALANOBIS)
        check_int("association_rounds", self.association_rounds, 1, 100)
        check_bool("joint_compatibility", self.joint_compatibility)
        check_range("recovery_std_factor", self.recovery_std_factor, 1.0, 1e3)
        check_range("recovery_match_fraction", self.recovery_match_fraction, 0.0, 1.0)
        check_choice("measurement_noise", self.measurement_noise, NOISE_MODELS)
        check_range("measurement_floor_m", self.measurement_floor_m, 0.0, MAX_STD_M)
        check_range("delta_m", self.delta_m, 0.0, MAX_DISTANCE_M, low_open=True)
        check_range("cluster_radius_m", self.cluster_radius_m, 0.0, MAX_DISTANCE_M)
        check_range("range_std_m", self.range_std_m, 0.0, MAX_STD_M, low_open=True)
        check_range("bearing_std_rad", self.bearing_std_rad, 0.0, math.pi, low_open=True)
        check_range("trans_std_m", self.trans_std_m, 0.0, MAX_STD_M)
        check_range("trans_frac", self.trans_frac, 0.0, 1.0)
        check_range("rot_std_rad", self.rot_std_rad, 0.0, math.pi)
        check_range("accel_std_mps2", self.accel_std_mps2, 0.0, 1e3)
        check_range("yaw_accel_std_radps2", self.yaw_accel_std_radps2, 0.0, 1e3)
        check_range("resample_threshold", self.resample_threshold, 0.0, 1.0)
        check_choice("weighting", self.weighting, ("likelihood", "amplitude"))
        check_choice("kernels", self.kernels, KERNELS)
        if self.weighting == "amplitude" and self.variant != "fastslam1":
            raise ValueError("weighting='amplitude' needs variant='fastslam1' (per-observation likelihoods)")
        check_range("new_landmark_mahalanobis", self.new_landmark_mahalanobis, 0.0, MAX_MAHALANOBIS, low_open=True)
        check_int("prune_after_cycles", self.prune_after_cycles, 1, MAX_CYCLES)
        check_int("tentative_prune_after_cycles", self.tentative_prune_after_cycles, 1, MAX_CYCLES)
        check_int("min_hits", self.min_hits, 1, MAX_CYCLES)
        check_range("min_existence", self.min_existence, 0.0, 1.0)
        check_range("dynamic_threshold_mps", self.dynamic_threshold_mps, 0.0, 1e4)
        check_range("min_range_m", self.min_range_m, 0.0, MAX_DISTANCE_M, low_open=True)
        check_int("max_retired", self.max_retired, 0, 10_000_000)
        check_int("retire_min_hits", self.retire_min_hits, 1, MAX_CYCLES)
        P, L = self.n_particles, self.max_landmarks
        check_memory(f"n_particles x max_landmarks = {P} x {L} landmark slots ({STATE_BYTES_PER_SLOT} bytes each)",
                     P * L * STATE_BYTES_PER_SLOT)


@dataclass
class SlamEstimate:
    """Output of one SLAM cycle (map frame = the first vehicle pose).

    pose (3,) x, y (m), heading (rad); pose_std (3,) weighted particle std;
    landmarks (L, 2) map frame (m); landmark_std (L,) per-axis RMS std
    ``sqrt(trace(Sigma) / 2)`` (m) including the spread across particles;
    landmark_cov (L, 2, 2) (m^2); landmark_ids (L,) persistent ids; ess: effective
    sample size before resampling; resampled: whether resampling ran;
    n_static_points / n_observations / n_matched: points kept by the moving-point
    filter, clustered observations, mean matches per particle; stage_times (s).
    """

    pose: np.ndarray
    pose_std: np.ndarray
    landmarks: np.ndarray
    landmark_std: np.ndarray
    landmark_ids: np.ndarray
    landmark_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    ess: float = float("nan")
    resampled: bool = False
    n_static_points: int = 0
    n_observations: int = 0
    n_matched: float = 0.0
    stage_times: dict = field(default_factory=dict)

    def landmarks_vehicle(self) -> np.ndarray:
        """Landmarks in the estimated vehicle frame: ``R(th)^T (e - [x, y])`` (L, 2)."""
        x, y, th = self.pose
        d = self.landmarks - np.array([x, y])
        c, s = math.cos(th), math.sin(th)
        return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)


@dataclass
class Observations:
    """Clustered static observations of one cycle: z (M, 2) vehicle frame (m), Q (M, 2, 2) (m^2), amp (M,)."""

    z: np.ndarray
    Q: np.ndarray
    amp: np.ndarray
    n_static: int = 0

    def __len__(self) -> int:
        return len(self.z)


class RBPFSlam:
    """FastSLAM 2.0 (default) or 1.0 with dense, particle-vectorized state (module docstring).

    ``RBPFSlam(config, rng)``; ``rng`` is a ``numpy.random.Generator`` (or a seed).
    The first :meth:`update` after :meth:`reset` defines the map frame (its motion is
    ignored); later ones take the registration motion of the current vehicle frame in
    the previous one.
    """

    def __init__(self, config: SlamConfig | None = None, rng=None) -> None:
        self.config = config if config is not None else SlamConfig()
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self._impl = _STAGES.choose(self.config.kernels)  # the compiled or the numpy stages
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Clear the map and put every particle at the origin with equal weight."""
        c = self.config
        P, L = c.n_particles, c.max_landmarks
        self.pose = np.zeros((P, 3))
        self.logw = np.full(P, -math.log(P))
        self.mean = np.zeros((P, L, 2))
        self.cov = np.zeros((P, L, 2, 2))
        self.active = np.zeros((P, L), dtype=bool)
        self.last_seen = np.zeros((P, L), dtype=np.int64)
        self.hits = np.zeros((P, L), dtype=np.int64)
        self.slot_used = np.zeros(L, dtype=bool)
        self.slot_id = np.full(L, -1, dtype=np.int64)
        self.cycle = -1
        self.next_id = 0
        self.retired_xy = np.zeros((0, 2))
        self.retired_ids = np.zeros(0, dtype=np.int64)
        self.pose_var = np.zeros(3)  # diagonal of Sigma_p of the last prediction
        self.last_estimate: SlamEstimate | None = None

    @property
    def weights(self) -> np.ndarray:
        """Normalized particle weights (P,)."""
        return np.exp(self.logw)

    # ---------------------------------------------------------------- update
    def update(
        self,
        points: np.ndarray,
        motion: np.ndarray | None,
        dt: float,
        ego_velocity: np.ndarray | None = None,
        cov: np.ndarray | None = None,
    ) -> SlamEstimate:
        """One SLAM cycle: predict, associate, update, weight, resample.

        points: (N, 4) x, y (vehicle frame, m), radial velocity (m/s), amplitude;
        (N, 2) is accepted (radial velocity 0, amplitude 1).
        motion: (3,) (dx, dy, dth) of the current vehicle frame in the previous one
        (m, m, rad); ignored on the first cycle.
        dt: cycle duration (s), > 0.
        ego_velocity: optional (2,) ego velocity (m/s, vehicle frame) or (3,) with the
        yaw rate (rad/s); enables the moving-point filter.
        cov: optional (N, 2, 2) vehicle-frame covariance of each point (m^2), used with
        ``measurement_noise="per_point"``; without it the fixed model applies.
        """
        if not dt > 0 or not math.isfinite(dt):
            raise ValueError(f"dt must be in (0, inf), got {dt!r}")
        timer = StageTimer()
        with timer("preprocess"):
            obs = self._observations(points, ego_velocity, cov)
        self.cycle += 1
        with timer("predict"):
            self._predict(motion, dt)
        with timer("associate"):
            idx = self._associate(obs)
            if self._lost(idx):
                self.pose_var = self.pose_var * self.config.recovery_std_factor**2
                idx = self._associate(obs)
        with timer("update"):
            loglik, idx = self._update(idx, obs)
        with timer("new_landmarks"):
            loglik += self._add_landmarks(idx, obs)
        with timer("weight"):
            ess = self._weight(loglik)
        with timer("prune"):
            self._prune()
        with timer("estimate"):
            est = self._estimate()
        with timer("resample"):
            est.resampled = self._maybe_resample(ess)
        est.ess, est.n_static_points, est.n_observations = ess, obs.n_static, len(obs)
        est.n_matched = float(np.mean(np.sum(idx >= 0, axis=1))) if idx.size else 0.0
        est.stage_times = timer.times
        self.last_estimate = est
        return est

    # ------------------------------------------------------------ stages
    def _observations(self, points, ego_velocity, cov) -> Observations:
        """Finite, static, clustered observations with their covariance (+ floor)."""
        c = self.config
        pts = np.asarray(points, dtype=float)
        if pts.size == 0:
            pts = np.zeros((0, 4))
        if pts.ndim != 2 or pts.shape[1] not in (2, 4):
            raise ValueError(f"points must have shape (N, 4) or (N, 2), got {pts.shape}")
        if pts.shape[1] == 2:
            pts = np.concatenate([pts, np.zeros((len(pts), 1)), np.ones((len(pts), 1))], axis=1)
        if cov is None or c.measurement_noise == "fixed":
            rows = np.column_stack([pts, np.full(len(pts), c.range_std_m), np.full(len(pts), c.bearing_std_rad),
                                    np.zeros(len(pts))])
            cov = point_covariance(rows)
        cov = np.asarray(cov, dtype=float).reshape(-1, 2, 2)
        ok = np.all(np.isfinite(pts), axis=1) & np.all(np.isfinite(cov), axis=(1, 2))
        pts, cov = pts[ok], cov[ok]
        if ego_velocity is not None:
            ev = np.asarray(ego_velocity, dtype=float).ravel()
            keep = static_mask(pts, ev[:2], c.dynamic_threshold_mps, yaw_rate=float(ev[2]) if ev.size > 2 else 0.0)
            pts, cov = pts[keep], cov[keep]
        obs, labels = cluster_points(pts, c.cluster_radius_m, kernels=c.kernels)
        Q = np.zeros((0, 2, 2))
        if len(obs):
            obs[:, :2], Q = cluster_covariance(pts, labels, cov, len(obs), kernels=c.kernels)
        Q = Q + c.measurement_floor_m**2 * _EYE2
        far = np.hypot(obs[:, 0], obs[:, 1]) >= c.min_range_m
        return Observations(obs[far, :2], Q[far], obs[far, 3], len(pts))

    def _predict(self, motion, dt: float) -> None:
        """mu_c = p_c (+) m; Sigma_p = diag(s_t^2, s_t^2, s_th^2); FastSLAM 1.0 samples from it."""
        c = self.config
        self.pose_var = np.zeros(3)
        if self.cycle == 0:
            return
        m = np.zeros(3) if motion is None else np.asarray(motion, dtype=float).reshape(3)
        if not np.all(np.isfinite(m)):
            m = np.zeros(3)
        dist = math.hypot(m[0], m[1])
        var_t = c.trans_std_m**2 + (c.trans_frac * dist) ** 2 + (0.5 * c.accel_std_mps2 * dt * dt) ** 2
        var_r = c.rot_std_rad**2 + (0.5 * c.yaw_accel_std_radps2 * dt * dt) ** 2
        th = self.pose[:, 2]
        cth, sth = np.cos(th), np.sin(th)
        self.pose[:, 0] += cth * m[0] - sth * m[1]
        self.pose[:, 1] += sth * m[0] + cth * m[1]
        self.pose[:, 2] = th + m[2]
        self.pose_var = np.array([var_t, var_t, var_r])
        if c.variant == "fastslam1":
            self.pose += np.sqrt(self.pose_var) * self.rng.standard_normal(self.pose.shape)
            self.pose_var = np.zeros(3)
        self.pose[:, 2] = wrap_angle(self.pose[:, 2])

    def _lost(self, idx: np.ndarray) -> bool:
        """FastSLAM 2.0 recovery test: the map is non-empty, at least 3 observations, and the particles
        match fewer than ``recovery_match_fraction`` of them (the motion prior is likely wrong)."""
        c = self.config
        M = idx.shape[1]
        if c.variant != "fastslam2" or c.recovery_std_factor <= 1 or self.cycle == 0 or M < 3:
            return False
        if not self.slot_used.any():
            return False
        return float(np.mean(np.sum(idx >= 0, axis=1))) < c.recovery_match_fraction * M

    def _observation_with_pose(self, obs: Observations):
        """Vehicle-frame ``Q + H_p Sigma_p H_p^T`` per observation (``H_p`` at z): components (M,)."""
        vt, _, vr = self.pose_var
        zx, zy = obs.z[:, 0], obs.z[:, 1]
        return (obs.Q[:, 0, 0] + vt + vr * zy * zy, obs.Q[:, 0, 1] - vr * zx * zy, obs.Q[:, 1, 1] + vt + vr * zx * zx)

    def _associate(self, obs: Observations) -> np.ndarray:
        """idx (P, M): landmark slot, NEW or DROPPED per particle and observation."""
        c = self.config
        P, M = c.n_particles, len(obs)
        used = np.flatnonzero(self.slot_used)
        if M == 0 or used.size == 0:
            return np.full((P, M), NEW, dtype=np.int64)
        return self._impl.associate(self, obs, used)

    def _associate_compiled(self, obs: Observations, used: np.ndarray) -> np.ndarray:
        """:meth:`_associate` of the observations against the held slots ``used``: the Mahalanobis association with
        the same frames, distances and rounds, compiled (:func:`slam.core.kernels.mahalanobis_association_at`); the
        nearest-landmark association stays numpy's (:meth:`_associate_numpy`)."""
        c = self.config
        if c.association != "mahalanobis":
            return self._associate_numpy(obs, used)
        from slam.core.kernels import mahalanobis_association_at

        th = self.pose[:, 2]
        return mahalanobis_association_at(self.pose, np.cos(th), np.sin(th), obs.z, *self._observation_with_pose(obs),
                                          self.mean, self.cov, self.active, used, c.gate_mahalanobis**2,
                                          c.new_gate_mahalanobis**2, c.association_rounds)

    def _associate_numpy(self, obs: Observations, used: np.ndarray) -> np.ndarray:
        """:meth:`_associate` of the observations against the held slots ``used`` in numpy (the reference): the map
        frame per particle, then the nearest landmark within ``delta_m`` or the gated Mahalanobis rounds."""
        c = self.config
        obs_map = to_map_frame(obs.z, self.pose)  # (P, M, 2)
        if c.association == "nearest":
            sub, _ = associate(obs_map, self.mean[:, used], self.active[:, used], c.delta_m)
        else:
            cth, sth = np.cos(self.pose[:, 2])[:, None], np.sin(self.pose[:, 2])[:, None]
            a00, a01, a11 = rotate_sym2(cth, sth, *self._observation_with_pose(obs))  # (P, M)
            lam = self.cov[:, used]  # (P, L, 2, 2)
            s00 = a00[:, :, None] + lam[:, None, :, 0, 0]
            s01 = a01[:, :, None] + lam[:, None, :, 0, 1]
            s11 = a11[:, :, None] + lam[:, None, :, 1, 1]
            i00, i01, i11, _ = sym2_inverse(s00, s01, s11)
            nx = obs_map[:, :, None, 0] - self.mean[:, None, used, 0]
            ny = obs_map[:, :, None, 1] - self.mean[:, None, used, 1]
            d2 = i00 * nx * nx + 2.0 * i01 * nx * ny + i11 * ny * ny
            d2[~np.broadcast_to(self.active[:, None, used], d2.shape)] = np.inf
            sub = mahalanobis_associate(d2, c.gate_mahalanobis**2, c.new_gate_mahalanobis**2, c.association_rounds)
        return np.where(sub >= 0, used[np.maximum(sub, 0)], sub)

    def _update(self, idx: np.ndarray, obs: Observations) -> tuple[np.ndarray, np.ndarray]:
        """Pose (FastSLAM 2.0 proposal) and landmark updates; returns (log-likelihood (P,), idx)."""
        c = self.config
        loglik = np.zeros(c.n_particles)
        if c.variant == "fastslam2" and self.cycle > 0:
            loglik, idx = self._sample_proposal(idx, obs)
        pp, mm = _pairs(idx)
        if pp.size:
            ll_pair = self._landmark_update(pp, mm, idx[pp, mm], obs)
            if c.variant == "fastslam1":
                loglik += np.bincount(pp, weights=ll_pair * self._obs_weights(obs)[mm], minlength=c.n_particles)
        return loglik, idx

    def _obs_weights(self, obs: Observations) -> np.ndarray:
        """Per-observation weight of the log-likelihood: 1, or ``a_m / mean(a)`` for "amplitude"."""
        if self.config.weighting != "amplitude" or len(obs) == 0:
            return np.ones(len(obs))
        amp = np.maximum(obs.amp, 0.0)
        mamp = amp.mean()
        return amp / mamp if mamp > 0 else np.ones(len(obs))

    def _proposal_terms(self, pp, mm, ll, obs: Observations):
        """Per matched pair at mu: H_k (K, 2, 3), S_k^-1 (K, 2, 2), nu_k (K, 2), log det S_k (K,)."""
        th = self.pose[pp, 2]
        return self._impl.proposal_terms(self, pp, mm, ll, obs, np.cos(th), np.sin(th))

    def _proposal_terms_compiled(self, pp, mm, ll, obs: Observations, cth, sth):
        """:meth:`_proposal_terms` with the same operations pair by pair, compiled (:func:`slam.core.kernels.proposal_terms`)."""
        from slam.core.kernels import proposal_terms

        H, Si, nu, det = proposal_terms(self.pose, cth, sth, obs.z, obs.Q, self.mean, self.cov, pp, mm, ll)
        return H, Si, nu, np.log(det)

    def _proposal_terms_numpy(self, pp, mm, ll, obs: Observations, cth, sth):
        """:meth:`_proposal_terms` in numpy (the reference), at the headings' cosines ``cth`` and sines ``sth`` (K,)."""
        d = self.mean[pp, ll] - self.pose[pp, :2]
        hx, hy = cth * d[:, 0] + sth * d[:, 1], -sth * d[:, 0] + cth * d[:, 1]
        nu = obs.z[mm] - np.stack([hx, hy], axis=1)
        lam = self.cov[pp, ll]
        l00, l01, l11 = rotate_sym2(cth, -sth, lam[:, 0, 0], lam[:, 0, 1], lam[:, 1, 1])  # R^T Lambda R
        i00, i01, i11, det = sym2_inverse(l00 + obs.Q[mm, 0, 0], l01 + obs.Q[mm, 0, 1], l11 + obs.Q[mm, 1, 1])
        H = np.zeros((pp.size, 2, 3))
        H[:, 0, 0], H[:, 0, 1], H[:, 0, 2] = -cth, -sth, hy
        H[:, 1, 0], H[:, 1, 1], H[:, 1, 2] = sth, -cth, -hx
        Si = np.stack([np.stack([i00, i01], -1), np.stack([i01, i11], -1)], -2)
        return H, Si, nu, np.log(det)

    def _sample_proposal(self, idx: np.ndarray, obs: Observations) -> tuple[np.ndarray, np.ndarray]:
        """FastSLAM 2.0: sample every pose from its measurement-updated proposal (module docstring).

        ``Lambda_p = Sigma_p^-1 + sum_k H_k^T S_k^-1 H_k``, ``g = sum_k H_k^T S_k^-1 nu_k``, ``delta = Lambda_p^-1 g``;
        joint compatibility drops the pairs with ``r^T S^-1 r > gate^2``, ``r = nu - H delta``, and solves once
        more; ``p ~ N(mu + delta, Lambda_p^-1)``. Returns (log w increment (P,), idx without the dropped pairs).
        """
        return self._impl.sample_proposal(self, idx, obs)

    def _sample_proposal_numpy(self, idx: np.ndarray, obs: Observations) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_sample_proposal` in numpy (the reference): the information sums by ``np.add.at``, the inverse, the
        joint-compatibility test, the weight and the draw."""
        c = self.config
        P = c.n_particles
        pp, mm = _pairs(idx)
        H, Si, nu, logdet = self._proposal_terms(pp, mm, idx[pp, mm], obs)
        prior_var = np.maximum(self.pose_var, 1e-18)
        ok = np.ones(pp.size, dtype=bool)
        for attempt in range(2 if c.joint_compatibility else 1):
            HtSi = np.einsum("kia,kij->kaj", H, Si) * ok[:, None, None]  # (K, 3, 2)
            info = np.zeros((P, 3, 3))
            np.add.at(info, pp, np.einsum("kaj,kjb->kab", HtSi, H))
            g = np.zeros((P, 3))
            np.add.at(g, pp, np.einsum("kaj,kj->ka", HtSi, nu))
            info += np.diag(1.0 / prior_var)
            cov = np.linalg.inv(info)
            delta = np.einsum("pab,pb->pa", cov, g)
            if attempt == 1 or not c.joint_compatibility:
                break
            r = nu - np.einsum("kia,ka->ki", H, delta[pp])
            bad = np.einsum("ki,kij,kj->k", r, Si, r) > c.gate_mahalanobis**2
            if not bad.any():
                break
            ok &= ~bad
            idx = idx.copy()
            idx[pp[bad], mm[bad]] = DROPPED
        quad = np.bincount(pp, weights=ok * np.einsum("ki,kij,kj->k", nu, Si, nu), minlength=P).astype(float)
        quad = quad - np.einsum("pa,pa->p", g, delta)
        n = np.bincount(pp, weights=ok.astype(float), minlength=P)
        sum_logdet = np.bincount(pp, weights=ok * logdet, minlength=P)
        logdet_post = np.sum(np.log(prior_var)) + np.linalg.slogdet(info)[1]
        loglik = -0.5 * quad - n * _LOG2PI - 0.5 * (sum_logdet + logdet_post)
        chol = np.linalg.cholesky(0.5 * (cov + cov.transpose(0, 2, 1)))
        self.pose += delta + np.einsum("pab,pb->pa", chol, self.rng.standard_normal((P, 3)))
        self.pose[:, 2] = wrap_angle(self.pose[:, 2])
        return loglik, idx

    def _sample_proposal_compiled(self, idx: np.ndarray, obs: Observations) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_sample_proposal` on the compiled kernels: the information sums with the prior
        (:func:`slam.core.kernels.proposal_prior_information`), the shift ``delta`` and the joint-compatibility test
        (:func:`~slam.core.kernels.proposal_shift`), the weight and the draw (:func:`~slam.core.kernels.proposal_sample`),
        numpy's sums in numpy's order; the 3 x 3 inverse, log-determinant and Cholesky factor stay numpy's (LAPACK)."""
        from slam.core.kernels import proposal_prior_information, proposal_sample, proposal_shift

        c = self.config
        P = c.n_particles
        pp, mm = _pairs(idx)
        H, Si, nu, logdet = self._proposal_terms(pp, mm, idx[pp, mm], obs)
        prior_var = np.maximum(self.pose_var, 1e-18)
        ok = np.ones(pp.size, dtype=bool)
        info, g = proposal_prior_information(pp, H, Si, nu, ok, prior_var, P)
        cov = np.linalg.inv(info)
        delta, sym, bad, n_bad = proposal_shift(cov, g, pp, H, Si, nu, c.gate_mahalanobis**2, c.joint_compatibility)
        if n_bad:  # drop the incompatible pairs, solve once more
            ok = ~bad
            idx = idx.copy()
            idx[pp[bad], mm[bad]] = DROPPED
            info, g = proposal_prior_information(pp, H, Si, nu, ok, prior_var, P)
            cov = np.linalg.inv(info)
            delta, sym, _, _ = proposal_shift(cov, g, pp, H, Si, nu, 0.0, False)
        logdet_post = np.sum(np.log(prior_var)) + np.linalg.slogdet(info)[1]
        chol = np.linalg.cholesky(sym)
        loglik = proposal_sample(pp, ok, nu, Si, logdet, g, delta, logdet_post, chol, self.rng.standard_normal((P, 3)),
                                 self.pose, _LOG2PI)
        self.pose[:, 2] = wrap_angle(self.pose[:, 2])
        return loglik, idx

    def _landmark_update(self, pp, mm, ll, obs: Observations) -> np.ndarray:
        """Kalman update of the matched landmarks at the particles' poses; log N(nu; 0, S) per pair."""
        th = self.pose[pp, 2]
        return self._impl.landmark_update(self, pp, mm, ll, obs, np.cos(th), np.sin(th))

    def _landmark_update_compiled(self, pp, mm, ll, obs: Observations, cth, sth) -> np.ndarray:
        """:meth:`_landmark_update` with the same operations pair by pair, compiled, in place
        (:func:`slam.core.kernels.landmark_update`)."""
        from slam.core.kernels import landmark_update

        maha, det = landmark_update(self.pose, cth, sth, obs.z, obs.Q, self.mean, self.cov, self.hits,
                                    self.last_seen, pp, mm, ll, self.cycle)
        return -0.5 * maha - _LOG2PI - 0.5 * np.log(det)

    def _landmark_update_numpy(self, pp, mm, ll, obs: Observations, cth, sth) -> np.ndarray:
        """:meth:`_landmark_update` in numpy (the reference), at the headings' cosines ``cth`` and sines ``sth`` (K,)."""
        pose, z = self.pose[pp], obs.z[mm]
        nu = pose[:, :2] + np.stack([cth * z[:, 0] - sth * z[:, 1], sth * z[:, 0] + cth * z[:, 1]], 1) - self.mean[pp, ll]
        q00, q01, q11 = rotate_sym2(cth, sth, obs.Q[mm, 0, 0], obs.Q[mm, 0, 1], obs.Q[mm, 1, 1])
        lam = self.cov[pp, ll]
        l00, l01, l11 = lam[:, 0, 0], 0.5 * (lam[:, 0, 1] + lam[:, 1, 0]), lam[:, 1, 1]
        i00, i01, i11, det = sym2_inverse(l00 + q00, l01 + q01, l11 + q11)
        k00, k01 = l00 * i00 + l01 * i01, l00 * i01 + l01 * i11  # K = Lambda S^-1
        k10, k11 = l01 * i00 + l11 * i01, l01 * i01 + l11 * i11
        self.mean[pp, ll] += np.stack([k00 * nu[:, 0] + k01 * nu[:, 1], k10 * nu[:, 0] + k11 * nu[:, 1]], axis=1)
        new = np.empty_like(lam)  # Lambda - K Lambda, symmetrized
        new[:, 0, 0] = l00 - (k00 * l00 + k01 * l01)
        new[:, 1, 1] = l11 - (k10 * l01 + k11 * l11)
        new[:, 0, 1] = new[:, 1, 0] = l01 - 0.5 * (k00 * l01 + k01 * l11 + k10 * l00 + k11 * l01)
        self.cov[pp, ll] = new
        self.hits[pp, ll] += 1
        self.last_seen[pp, ll] = self.cycle
        maha = i00 * nu[:, 0] ** 2 + 2.0 * i01 * nu[:, 0] * nu[:, 1] + i11 * nu[:, 1] ** 2
        return -0.5 * maha - _LOG2PI - 0.5 * np.log(det)

    def _add_landmarks(self, idx: np.ndarray, obs: Observations) -> np.ndarray:
        """One slot per observation NEW in some particle; returns the new-landmark log-likelihood (P,)."""
        c = self.config
        is_new = idx == NEW  # (P, M)
        cand = np.flatnonzero(is_new.any(axis=0))
        if cand.size == 0:
            return np.zeros(c.n_particles)
        if cand.size > c.max_landmarks:  # keep the strongest echoes
            cand = np.sort(cand[np.argsort(-obs.amp[cand], kind="stable")[: c.max_landmarks]])
            keep = np.zeros(len(obs), dtype=bool)
            keep[cand] = True
            is_new &= keep[None, :]
        slots = self._free_slots(cand.size)
        slot_of_obs = np.full(len(obs), -1, dtype=np.int64)
        slot_of_obs[cand] = slots
        self.slot_used[slots] = True
        self.slot_id[slots] = np.arange(self.next_id, self.next_id + slots.size)
        self.next_id += slots.size
        self.active[:, slots] = False  # fresh slot: no particle holds it yet
        pp, mm = np.nonzero(is_new)
        ll = slot_of_obs[mm]
        th = self.pose[pp, 2]
        cth, sth = np.cos(th), np.sin(th)
        z = obs.z[mm]
        self.mean[pp, ll] = self.pose[pp, :2] + np.stack([cth * z[:, 0] - sth * z[:, 1], sth * z[:, 0] + cth * z[:, 1]], 1)
        q00, q01, q11 = rotate_sym2(cth, sth, obs.Q[mm, 0, 0], obs.Q[mm, 0, 1], obs.Q[mm, 1, 1])
        self.cov[pp, ll] = np.stack([np.stack([q00, q01], -1), np.stack([q01, q11], -1)], -2)
        self.active[pp, ll] = True
        self.hits[pp, ll] = 1
        self.last_seen[pp, ll] = self.cycle
        b00, b01, b11 = self._observation_with_pose(obs)  # a match's S ~ Q + pose terms + Lambda (= Q)
        _, _, _, det = sym2_inverse(b00 + obs.Q[:, 0, 0], b01 + obs.Q[:, 0, 1], b11 + obs.Q[:, 1, 1])
        log_new = -0.5 * c.new_landmark_mahalanobis**2 - _LOG2PI - 0.5 * np.log(det)
        return np.bincount(pp, weights=(log_new * self._obs_weights(obs))[mm], minlength=c.n_particles)

    def _weight(self, loglik: np.ndarray) -> float:
        """log w += loglik; normalise; returns the effective sample size."""
        self.logw = self.logw + loglik
        self._normalize()
        w = self.weights
        return float(1.0 / np.sum(w * w))

    def _maybe_resample(self, ess: float) -> bool:
        """Systematic resampling when ESS < resample_threshold * P."""
        if ess < self.config.resample_threshold * self.config.n_particles:
            self._resample()
            return True
        return False

    def _free_slots(self, n: int) -> np.ndarray:
        """Return ``n`` free slot indices, evicting the least recently seen slots."""
        free = np.flatnonzero(~self.slot_used)
        if free.size >= n:
            return free[:n]
        need = n - free.size
        used = np.flatnonzero(self.slot_used)
        seen = np.where(self.active[:, used], self.last_seen[:, used], -1).max(axis=0)
        evict = used[np.argsort(seen, kind="stable")[:need]]
        self._retire(evict)
        self.active[:, evict] = False
        self.slot_used[evict] = False
        return np.concatenate([free, evict])

    def _normalize(self) -> None:
        """log-sum-exp normalization; non-finite or all-zero likelihoods -> uniform."""
        P = self.config.n_particles
        lw = np.where(np.isfinite(self.logw), self.logw, -np.inf)
        if not np.any(np.isfinite(lw)):
            self.logw = np.full(P, -math.log(P))
            return
        lse = log_sum_exp(lw)
        lw = lw - lse
        if not np.all(np.isfinite(lw) | (lw == -np.inf)) or not math.isfinite(lse):
            self.logw = np.full(P, -math.log(P))
            return
        self.logw = lw

    def _resample(self) -> None:
        """Systematic resampling; every array copied with fancy indexing."""
        P = self.config.n_particles
        w = self.weights
        cdf = np.cumsum(w)
        cdf[-1] = 1.0
        u = (self.rng.random() + np.arange(P)) / P
        src = np.minimum(np.searchsorted(cdf, u, side="left"), P - 1)
        self.pose = self.pose[src]
        self.mean = self.mean[src]
        self.cov = self.cov[src]
        self.active = self.active[src]
        self.last_seen = self.last_seen[src]
        self.hits = self.hits[src]
        self.logw = np.full(P, -math.log(P))

    def _slot_estimates(self, slots: np.ndarray):
        """Weighted landmark statistics for ``slots``: mean (S,2), cov (S,2,2), existence, hits.

        ``W_ps = w_p [p holds s]``, existence ``E_s = sum_p W_ps``, ``Wn = W / E``; ``mu_s = sum_p Wn_ps e_ps``,
        ``Sigma_s = sum_p Wn_ps (Lambda_ps + (e_ps - mu_s)(e_ps - mu_s)^T)``, hits ``sum_p Wn_ps h_ps``
        (compiled: :func:`slam.core.kernels.slot_estimates`, the same sums in the same order).
        """
        return self._impl.slot_estimates(self, slots, self.weights)

    def _slot_estimates_compiled(self, slots: np.ndarray, w: np.ndarray):
        """:meth:`_slot_estimates` at the weights ``w`` (P,), compiled (:func:`slam.core.kernels.slot_estimates`) up to
        :data:`_SLOT_KERNEL_MAX_PARTICLES` particles, numpy's (:meth:`_slot_estimates_numpy`) above."""
        if self.config.n_particles > _SLOT_KERNEL_MAX_PARTICLES:
            return self._slot_estimates_numpy(slots, w)
        from slam.core.kernels import slot_estimates

        return slot_estimates(w, self.active, self.mean, self.cov, self.hits, slots)

    def _slot_estimates_numpy(self, slots: np.ndarray, w: np.ndarray):
        """:meth:`_slot_estimates` at the weights ``w`` (P,) in numpy (the reference: einsum)."""
        W = w[:, None] * self.active[:, slots]  # (P, S)
        exist = W.sum(axis=0)
        Wn = W / np.where(exist > 0, exist, 1.0)
        m = self.mean[:, slots]
        mu = np.einsum("ps,psk->sk", Wn, m)
        d = m - mu[None]
        cov = np.einsum("ps,psij->sij", Wn, self.cov[:, slots]) + np.einsum(
            "ps,psi,psj->sij", Wn, d, d
        )
        hits = np.einsum("ps,ps->s", Wn, self.hits[:, slots])
        return mu, cov, exist, hits

    def _retire(self, slots: np.ndarray) -> None:
        """Archive confirmed landmarks of ``slots`` (weighted mean only), capped."""
        c = self.config
        if slots.size == 0 or c.max_retired == 0:
            return
        mu, _, exist, hits = self._slot_estimates(slots)
        ok = (exist >= c.min_existence) & (hits >= c.retire_min_hits)
        if not ok.any():
            return
        self.retired_xy = np.concatenate([self.retired_xy, mu[ok]])[-c.max_retired :]
        self.retired_ids = np.concatenate([self.retired_ids, self.slot_id[slots[ok]]])[-c.max_retired :]

    def _prune(self) -> None:
        """Drop landmarks not re-observed for K cycles; free empty slots."""
        kept = self._impl.prune(self)
        if kept is None:
            return
        after, gone = kept
        self._retire(gone)  # statistics from the state before the kill
        self.active = after
        self.slot_used[gone] = False

    def _prune_compiled(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The landmarks :meth:`_prune` keeps (P, Lmax) and the slots it empties, by the same test per held landmark,
        compiled, over the slots in use (:func:`slam.core.kernels.prune_slots`); None when it drops none."""
        from slam.core.kernels import prune_slots

        c = self.config
        after, gone, n_kill = prune_slots(self.active, self.last_seen, self.hits, np.flatnonzero(self.slot_used),
                                          self.cycle, c.prune_after_cycles, c.min_hits, c.tentative_prune_after_cycles)
        return None if n_kill == 0 else (after, gone)

    def _prune_numpy(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The landmarks :meth:`_prune` keeps (P, Lmax) and the slots it empties, in numpy (the reference); None when
        it drops none."""
        c = self.config
        age = self.cycle - self.last_seen
        kill = self.active & (
            (age > c.prune_after_cycles)
            | ((self.hits < c.min_hits) & (age > c.tentative_prune_after_cycles))
        )
        if not kill.any():
            return None
        after = self.active & ~kill
        return after, np.flatnonzero(self.slot_used & ~after.any(axis=0))

    def _estimate(self) -> SlamEstimate:
        c = self.config
        w = self.weights
        th = circular_mean(self.pose[:, 2], w)
        x, y, vx, vy, vth = self._impl.pose_moments(self, w, th)
        sx, sy, sth = (math.sqrt(max(v, 0.0)) for v in (vx, vy, vth))
        used = np.flatnonzero(self.slot_used)
        if used.size:
            mu, cov, exist, hits = self._slot_estimates(used)
            rep = (exist >= c.min_existence) & (hits >= c.min_hits)
            lm = mu[rep]
            lstd = np.sqrt(np.maximum(0.5 * (cov[rep, 0, 0] + cov[rep, 1, 1]), 0.0))
            ids = self.slot_id[used[rep]]
            lcov = cov[rep]
        else:
            lm, lstd, ids = np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=np.int64)
            lcov = np.zeros((0, 2, 2))
        return SlamEstimate(
            pose=np.array([x, y, th]),
            pose_std=np.array([sx, sy, sth]),
            landmarks=lm,
            landmark_std=lstd,
            landmark_ids=ids,
            landmark_cov=lcov,
        )

    def _pose_moments_compiled(self, w: np.ndarray, th: float):
        """The weighted mean position and the variances of x, y and the heading about ``th`` (:meth:`_estimate`):
        the same products and sums, compiled (:func:`slam.core.kernels.pose_moments`)."""
        from slam.core.kernels import pose_moments

        return pose_moments(w, self.pose, wrap_angle(self.pose[:, 2] - th))

    def _pose_moments_numpy(self, w: np.ndarray, th: float) -> tuple[float, float, float, float, float]:
        """The weighted mean position and the variances of x, y and the heading about ``th`` (:meth:`_estimate`) in
        numpy (the reference)."""
        x = float(np.sum(w * self.pose[:, 0]))
        y = float(np.sum(w * self.pose[:, 1]))
        vx = float(np.sum(w * (self.pose[:, 0] - x) ** 2))
        vy = float(np.sum(w * (self.pose[:, 1] - y) ** 2))
        vth = float(np.sum(w * wrap_angle(self.pose[:, 2] - th) ** 2))
        return x, y, vx, vy, vth

    def relocalise(self, correction: np.ndarray, drop_from_id: int) -> None:
        """Move every particle by ``correction`` (a motion in its own vehicle frame, ``p <- p (+) m``) and
        drop the landmarks with an id >= ``drop_from_id`` (mapped from the wrong pose)."""
        m = np.asarray(correction, dtype=float).reshape(3)
        th = self.pose[:, 2]
        cth, sth = np.cos(th), np.sin(th)
        self.pose[:, 0] += cth * m[0] - sth * m[1]
        self.pose[:, 1] += sth * m[0] + cth * m[1]
        self.pose[:, 2] = wrap_angle(th + m[2])
        wrong = self.slot_used & (self.slot_id >= drop_from_id)
        self.active[:, wrong] = False
        self.slot_used[wrong] = False
        keep = self.retired_ids < drop_from_id
        self.retired_xy, self.retired_ids = self.retired_xy[keep], self.retired_ids[keep]

    def restart_at(self, pose: np.ndarray) -> None:
        """A new, empty map; every particle at ``pose`` (map frame of the old map), the next
        :meth:`update` applies its motion (the cycle count goes on)."""
        cycle, next_id = self.cycle, self.next_id
        self.reset()
        self.pose[:] = np.asarray(pose, dtype=float).reshape(3)
        self.cycle, self.next_id = max(cycle, 0), next_id

    # --------------------------------------------------------------- queries
    def full_map(self) -> tuple[np.ndarray, np.ndarray]:
        """All landmarks of the run: archived ones plus the current estimate.

        Returns ``(xy (L, 2) map frame, ids (L,))``; ids are unique.
        """
        cur = self.last_estimate
        if cur is None:
            return self.retired_xy.copy(), self.retired_ids.copy()
        keep = ~np.isin(self.retired_ids, cur.landmark_ids)
        return (
            np.concatenate([self.retired_xy[keep], cur.landmarks]),
            np.concatenate([self.retired_ids[keep], cur.landmark_ids]),
        )

    @property
    def n_landmark_slots(self) -> int:
        """Slots in use (landmarks held by at least one particle)."""
        return int(self.slot_used.sum())


#: the filter's stages in two implementations (:class:`rhs_common.jit.KernelTable`), chosen once by
#: ``SlamConfig.kernels`` when an :class:`RBPFSlam` is made
_STAGES = KernelTable("slam.core.rbpf")
_STAGES.stage("associate", "numba")(RBPFSlam._associate_compiled)
_STAGES.stage("associate", "numpy")(RBPFSlam._associate_numpy)
_STAGES.stage("proposal_terms", "numba")(RBPFSlam._proposal_terms_compiled)
_STAGES.stage("proposal_terms", "numpy")(RBPFSlam._proposal_terms_numpy)
_STAGES.stage("sample_proposal", "numba")(RBPFSlam._sample_proposal_compiled)
_STAGES.stage("sample_proposal", "numpy")(RBPFSlam._sample_proposal_numpy)
_STAGES.stage("landmark_update", "numba")(RBPFSlam._landmark_update_compiled)
_STAGES.stage("landmark_update", "numpy")(RBPFSlam._landmark_update_numpy)
_STAGES.stage("slot_estimates", "numba")(RBPFSlam._slot_estimates_compiled)
_STAGES.stage("slot_estimates", "numpy")(RBPFSlam._slot_estimates_numpy)
_STAGES.stage("prune", "numba")(RBPFSlam._prune_compiled)
_STAGES.stage("prune", "numpy")(RBPFSlam._prune_numpy)
_STAGES.stage("pose_moments", "numba")(RBPFSlam._pose_moments_compiled)
_STAGES.stage("pose_moments", "numpy")(RBPFSlam._pose_moments_numpy)
