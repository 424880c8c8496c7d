"""Rao-Blackwellized particle filter SLAM (FastSLAM 1.0), vectorized over particles.

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

One cycle (:meth:`RBPFSlam.update`):

1. **Moving-point filter and clustering** (``slam.association``).
2. **Propagation** (white-noise-acceleration model around the registration
   estimate ``m = (dx, dy, dth)``, the current vehicle frame in the previous one):
   ``p_c <- p_c (+) (m + n_c)``, i.e. ``[x, y] += R(th) [dx + n_x, dy + n_y]``,
   ``th += dth + n_th``. The noise per axis has the std
   ``sigma_t = sqrt(trans_std^2 + (trans_frac |d|)^2 + (accel_std dt^2 / 2)^2)`` (m)
   and ``sigma_th = sqrt(rot_std^2 + (yaw_accel_std dt^2 / 2)^2)`` (rad): a constant
   random acceleration over the cycle displaces the vehicle by ``a dt^2 / 2``, on top
   of the registration error floor.
3. **Association** per particle: nearest landmark within ``delta_m`` (paper).
4. **Landmark EKF** (paper eqs. 10-12). The paper writes the update loosely
   (``e += Lambda F^T J^-1 (p_hat - p)``); we implement the standard FastSLAM EKF:
   range-bearing measurement ``z = (r, b)`` of the observation in the vehicle frame,
   prediction ``f(e, p) = (|e - [x, y]|, atan2(e_y - y, e_x - x) - th)``,

   ``F = df/de = [[dx/r, dy/r], [-dy/r^2, dx/r^2]]``,
   ``S = F Lambda F^T + Q``,   ``Q = diag(range_std^2, bearing_std^2)``,
   ``K = Lambda F^T S^-1``,   ``nu = z - f(e, p)`` (bearing wrapped),
   ``e <- e + K nu``,   ``Lambda <- (I - K F) Lambda`` (evaluated as
   ``Lambda - K (Lambda F^T)^T`` and symmetrized; the batched 2 x 2 algebra is written
   out on component arrays).

   Range-bearing is chosen because it is the radar's native error structure: range
   error is set by the bandwidth (c/2B = 0.6 m bins) and bearing error by the beam
   grid, so a Cartesian error ellipse grows with range along the cross-range
   direction; a constant Cartesian Q would over-trust far points and under-trust
   near ones.
   A new landmark is initialised by inverting the measurement:
   ``e = [x, y] + r (cos(b + th), sin(b + th))``, ``Lambda = G Q G^T`` with
   ``G = [[cos phi, -r sin phi], [sin phi, r cos phi]]``, ``phi = b + th``.
5. **Weights**: ``log w_c += sum_m l_cm`` with the Gaussian log-likelihood
   ``l = -nu^T S^-1 nu / 2 - log(2 pi) - log det(S) / 2`` for a matched observation and
   a constant ``l_new`` (the same density at Mahalanobis distance
   ``new_landmark_mahalanobis`` with ``S0 = 2 Q``, the innovation covariance of a
   freshly initialised landmark) for a new one. ``weighting="amplitude"`` is the
   paper's option ("weight of each obstacle = reflection amplitude, particle weight =
   product"): taken literally it gives every particle the same factor whenever the
   associations agree, so we read it as amplitude-weighted log-likelihoods,
   ``log w_c += sum_m (a_m / mean(a)) l_cm``, stronger echoes counting more.
   Normalisation by log-sum-exp; non-finite weights fall back to uniform.
6. **Pruning**: a landmark not re-observed for ``prune_after_cycles`` cycles (or a
   tentative one, fewer than ``min_hits`` updates, for ``tentative_prune_after_cycles``)
   is dropped from the particle; a slot held by no particle is freed. Confirmed
   landmarks leaving memory are archived (their weighted mean only) so the full
   map of a long run stays available (:meth:`RBPFSlam.full_map`), capped at
   ``max_retired``. When all ``max_landmarks`` slots are busy the oldest slot is
   evicted.
7. **Estimate** (before resampling): weighted mean pose, heading on the circle
   ``atan2(sum w sin th, sum w cos th)``; landmarks weighted across the particles
   holding them.
8. **Resampling**: systematic, when ``ESS = 1 / sum w^2 < resample_threshold P``;
   all arrays are copied by fancy indexing (never aliased).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.special import logsumexp

from rhs_common.geometry import circular_mean, wrap_angle
from rhs_common.validation import check_choice, check_int, check_range, check_types
from slam.association import NEW, associate, cluster_points, static_mask, to_map_frame

__all__ = ["SlamConfig", "SlamEstimate", "RBPFSlam", "wrap_angle", "circular_mean"]

_LOG2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class SlamConfig:
    """RBPF SLAM settings (SI units). Validated at construction.

    n_particles: particles P. max_landmarks: landmark slots Lmax per particle.
    delta_m: association gate (m). cluster_radius_m: points closer than this are one
    object (m, 0 disables). range_std_m, bearing_std_rad: measurement noise Q.
    trans_std_m, trans_frac, rot_std_rad, accel_std_mps2, yaw_accel_std_radps2:
    propagation noise (see module docstring). resample_threshold: resample when
    ESS < threshold * P. weighting: "likelihood" | "amplitude".
    new_landmark_mahalanobis: Mahalanobis distance defining the new-landmark
    log-likelihood. prune_after_cycles / tentative_prune_after_cycles / min_hits:
    pruning. min_existence: report a landmark when the weight of the particles
    holding it is at least this. dynamic_threshold_mps: moving-point filter
    threshold (m/s). min_range_m: observations closer than this are ignored (m).
    max_retired: cap on archived landmarks. retire_min_hits: updates needed to
    archive a pruned landmark.
    """

    n_particles: int = 100
    max_landmarks: int = 256
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

    def __post_init__(self) -> None:
        check_types(self)
        check_int("n_particles", self.n_particles, 1, 100_000)
        check_int("max_landmarks", self.max_landmarks, 1, 100_000)
        check_range("delta_m", self.delta_m, 0.0, None, low_open=True)
        check_range("cluster_radius_m", self.cluster_radius_m, 0.0, None)
        check_range("range_std_m", self.range_std_m, 0.0, None, low_open=True)
        check_range("bearing_std_rad", self.bearing_std_rad, 0.0, math.pi, low_open=True)
        check_range("trans_std_m", self.trans_std_m, 0.0, None)
        check_range("trans_frac", self.trans_frac, 0.0, 1.0)
        check_range("rot_std_rad", self.rot_std_rad, 0.0, math.pi)
        check_range("accel_std_mps2", self.accel_std_mps2, 0.0, None)
        check_range("yaw_accel_std_radps2", self.yaw_accel_std_radps2, 0.0, None)
        check_range("resample_threshold", self.resample_threshold, 0.0, 1.0)
        check_choice("weighting", self.weighting, ("likelihood", "amplitude"))
        check_range("new_landmark_mahalanobis", self.new_landmark_mahalanobis, 0.0, None, low_open=True)
        check_int("prune_after_cycles", self.prune_after_cycles, 1, None)
        check_int("tentative_prune_after_cycles", self.tentative_prune_after_cycles, 1, None)
        check_int("min_hits", self.min_hits, 1, None)
        check_range("min_existence", self.min_existence, 0.0, 1.0)
        check_range("dynamic_threshold_mps", self.dynamic_threshold_mps, 0.0, None)
        check_range("min_range_m", self.min_range_m, 0.0, None, low_open=True)
        check_int("max_retired", self.max_retired, 0, None)
        check_int("retire_min_hits", self.retire_min_hits, 1, None)


@dataclass
class SlamEstimate:
    """Output of one SLAM cycle (map frame = the first vehicle pose).

    pose (3,) x, y (m), heading (rad); pose_std (3,) weighted particle std;
    landmarks (L, 2) map frame (m); landmark_std (L,) per-axis RMS std
    ``sqrt(trace(Sigma) / 2)`` (m) including the spread across particles;
    landmark_ids (L,) persistent ids; ess: effective sample size before resampling;
    resampled: whether resampling ran; n_static_points / n_observations: points kept
    by the moving-point filter and clustered observations; stage_times (s).
    """

    pose: np.ndarray
    pose_std: np.ndarray
    landmarks: np.ndarray
    landmark_std: np.ndarray
    landmark_ids: np.ndarray
    ess: float = float("nan")
    resampled: bool = False
    n_static_points: int = 0
    n_observations: int = 0
    stage_times: dict = field(default_factory=dict)

    def landmarks_vehicle(self) -> np.ndarray:
        """Landmarks in the estimated vehicle frame: ``R(th)^T (e - [x, y])`` (L, 2)."""
        x, y, th = self.pose
        d = self.landmarks - np.array([x, y])
        c, s = math.cos(th), math.sin(th)
        return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)


class RBPFSlam:
    """FastSLAM 1.0 with dense, particle-vectorized state (see the module docstring).

    ``RBPFSlam(config, rng)``; ``rng`` is a ``numpy.random.Generator`` (or a seed).
    The first :meth:`update` after :meth:`reset` defines the map frame (its motion is
    ignored); later ones take the registration motion of the current vehicle frame in
    the previous one.
    """

    def __init__(self, config: SlamConfig | None = None, rng=None) -> None:
        self.config = config if config is not None else SlamConfig()
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
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
        self.Q = np.diag([c.range_std_m**2, c.bearing_std_rad**2])
        S0 = 2.0 * self.Q
        self.log_new = float(
            -0.5 * c.new_landmark_mahalanobis**2 - _LOG2PI - 0.5 * math.log(np.linalg.det(S0))
        )
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
    ) -> SlamEstimate:
        """One SLAM cycle.

        points: (N, 4) x, y (vehicle frame, m), radial velocity (m/s), amplitude;
        (N, 2) is accepted (radial velocity 0, amplitude 1).
        motion: (3,) (dx, dy, dth) of the current vehicle frame in the previous one
        (m, m, rad); ignored on the first cycle.
        dt: cycle duration (s), > 0.
        ego_velocity: optional (2,) ego velocity (m/s, vehicle frame) or (3,) with the
        yaw rate (rad/s); enables the moving-point filter.
        """
        c = self.config
        if not dt > 0 or not math.isfinite(dt):
            raise ValueError(f"dt must be in (0, inf), got {dt!r}")
        times: dict[str, float] = {}
        t0 = time.perf_counter()
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] not in (2, 4):
            if pts.size == 0:
                pts = np.zeros((0, 4))
            else:
                raise ValueError(f"points must have shape (N, 4) or (N, 2), got {pts.shape}")
        if pts.shape[1] == 2:
            pts = np.concatenate([pts, np.zeros((len(pts), 1)), np.ones((len(pts), 1))], axis=1)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if ego_velocity is not None:
            ev = np.asarray(ego_velocity, dtype=float).ravel()
            yaw = float(ev[2]) if ev.size > 2 else 0.0
            pts = pts[static_mask(pts, ev[:2], c.dynamic_threshold_mps, yaw_rate=yaw)]
        n_static = len(pts)
        obs, _ = cluster_points(pts, c.cluster_radius_m)
        rng_obs = np.hypot(obs[:, 0], obs[:, 1])
        obs = obs[rng_obs >= c.min_range_m]
        times["preprocess"] = time.perf_counter() - t0

        self.cycle += 1
        t0 = time.perf_counter()
        if self.cycle > 0:
            if motion is None:
                motion = np.zeros(3)
            motion = np.asarray(motion, dtype=float).reshape(3)
            if not np.all(np.isfinite(motion)):
                motion = np.zeros(3)
            self._propagate(motion, dt)
        times["propagate"] = time.perf_counter() - t0

        M = len(obs)
        P = c.n_particles
        loglik = np.zeros((P, M))
        if M:
            t0 = time.perf_counter()
            obs_map = to_map_frame(obs[:, :2], self.pose)  # (P, M, 2)
            used = np.flatnonzero(self.slot_used)
            idx_sub, _ = associate(
                obs_map, self.mean[:, used], self.active[:, used], c.delta_m
            )
            idx = np.where(idx_sub >= 0, used[np.maximum(idx_sub, 0)] if used.size else 0, idx_sub)
            times["association"] = time.perf_counter() - t0

            t0 = time.perf_counter()
            z = np.stack([np.hypot(obs[:, 0], obs[:, 1]), np.arctan2(obs[:, 1], obs[:, 0])], axis=1)
            self._ekf_update(idx, z, loglik)
            times["ekf_update"] = time.perf_counter() - t0

            t0 = time.perf_counter()
            self._add_landmarks(idx, obs, obs_map, z, loglik)
            times["new_landmarks"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        if M:
            if c.weighting == "amplitude":
                amp = np.maximum(obs[:, 3], 0.0)
                mamp = amp.mean()
                wm = amp / mamp if mamp > 0 else np.ones(M)
            else:
                wm = np.ones(M)
            self.logw = self.logw + loglik @ wm
        self._normalize()
        w = self.weights
        ess = float(1.0 / np.sum(w * w))
        times["weights"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        self._prune()
        times["prune"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        est = self._estimate()
        times["estimate"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        resampled = ess < c.resample_threshold * P
        if resampled:
            self._resample()
        times["resample"] = time.perf_counter() - t0

        est.ess = ess
        est.resampled = bool(resampled)
        est.n_static_points = int(n_static)
        est.n_observations = int(M)
        est.stage_times = times
        self.last_estimate = est
        return est

    # ------------------------------------------------------------ internals
    def _propagate(self, motion: np.ndarray, dt: float) -> None:
        """Pose composition with white-noise-acceleration noise (module docstring)."""
        c = self.config
        P = c.n_particles
        dist = math.hypot(motion[0], motion[1])
        s_t = math.sqrt(c.trans_std_m**2 + (c.trans_frac * dist) ** 2 + (0.5 * c.accel_std_mps2 * dt * dt) ** 2)
        s_r = math.sqrt(c.rot_std_rad**2 + (0.5 * c.yaw_accel_std_radps2 * dt * dt) ** 2)
        d = np.broadcast_to(motion, (P, 3)).copy()
        if s_t > 0:
            d[:, :2] += s_t * self.rng.standard_normal((P, 2))
        if s_r > 0:
            d[:, 2] += s_r * self.rng.standard_normal(P)
        th = self.pose[:, 2]
        cth, sth = np.cos(th), np.sin(th)
        self.pose[:, 0] += cth * d[:, 0] - sth * d[:, 1]
        self.pose[:, 1] += sth * d[:, 0] + cth * d[:, 1]
        self.pose[:, 2] = wrap_angle(th + d[:, 2])

    def _ekf_update(self, idx: np.ndarray, z: np.ndarray, loglik: np.ndarray) -> None:
        """Batched EKF over every matched (particle, observation) pair (eqs. 10-12)."""
        pp, mm = np.nonzero(idx >= 0)
        if pp.size == 0:
            return
        ll = idx[pp, mm]
        e = self.mean[pp, ll]  # (K, 2) copies
        Lam = self.cov[pp, ll]  # (K, 2, 2)
        pose = self.pose[pp]
        dx = e[:, 0] - pose[:, 0]
        dy = e[:, 1] - pose[:, 1]
        q = np.maximum(dx * dx + dy * dy, 1e-12)
        r = np.sqrt(q)
        zhat_b = np.arctan2(dy, dx) - pose[:, 2]
        nu = np.stack([z[mm, 0] - r, wrap_angle(z[mm, 1] - zhat_b)], axis=1)  # (K, 2)
        # explicit 2 x 2 algebra on (K,) component arrays (Lambda and S symmetric)
        a, b, c_, d = dx / r, dy / r, -dy / q, dx / q  # F = [[a, b], [c, d]]
        l00, l01, l11 = Lam[:, 0, 0], 0.5 * (Lam[:, 0, 1] + Lam[:, 1, 0]), Lam[:, 1, 1]
        g00 = l00 * a + l01 * b  # G = Lambda F^T
        g01 = l00 * c_ + l01 * d
        g10 = l01 * a + l11 * b
        g11 = l01 * c_ + l11 * d
        s00 = a * g00 + b * g10 + self.Q[0, 0]  # S = F Lambda F^T + Q
        s01 = a * g01 + b * g11
        s11 = c_ * g01 + d * g11 + self.Q[1, 1]
        det = np.maximum(s00 * s11 - s01 * s01, 1e-300)
        i00, i01, i11 = s11 / det, -s01 / det, s00 / det  # S^-1
        k00 = g00 * i00 + g01 * i01  # K = Lambda F^T S^-1
        k01 = g00 * i01 + g01 * i11
        k10 = g10 * i00 + g11 * i01
        k11 = g10 * i01 + g11 * i11
        e_new = e + np.stack([k00 * nu[:, 0] + k01 * nu[:, 1], k10 * nu[:, 0] + k11 * nu[:, 1]], axis=1)
        # (I - K F) Lambda = Lambda - K (Lambda F^T)^T, symmetrized
        a01 = 0.5 * (k00 * g10 + k01 * g11 + k10 * g00 + k11 * g01)
        Lam_new = np.empty_like(Lam)
        Lam_new[:, 0, 0] = l00 - (k00 * g00 + k01 * g01)
        Lam_new[:, 0, 1] = Lam_new[:, 1, 0] = l01 - a01
        Lam_new[:, 1, 1] = l11 - (k10 * g10 + k11 * g11)
        self.mean[pp, ll] = e_new
        self.cov[pp, ll] = Lam_new
        self.hits[pp, ll] += 1
        self.last_seen[pp, ll] = self.cycle
        maha = i00 * nu[:, 0] ** 2 + 2.0 * i01 * nu[:, 0] * nu[:, 1] + i11 * nu[:, 1] ** 2
        loglik[pp, mm] = -0.5 * maha - _LOG2PI - 0.5 * np.log(det)

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

    def _add_landmarks(self, idx, obs, obs_map, z, loglik) -> None:
        """Create one slot per observation that is NEW in at least one particle."""
        c = self.config
        is_new = idx == NEW  # (P, M)
        cand = np.flatnonzero(is_new.any(axis=0))
        if cand.size == 0:
            return
        if cand.size > c.max_landmarks:  # keep the strongest echoes
            order = np.argsort(-obs[cand, 3], kind="stable")
            cand = np.sort(cand[order[: c.max_landmarks]])
            keep = np.zeros(obs.shape[0], dtype=bool)
            keep[cand] = True
            is_new &= keep[None, :]
        slots = self._free_slots(cand.size)
        slot_of_obs = np.full(obs.shape[0], -1, dtype=np.int64)
        slot_of_obs[cand] = slots
        self.slot_used[slots] = True
        self.slot_id[slots] = np.arange(self.next_id, self.next_id + slots.size)
        self.next_id += slots.size
        self.active[:, slots] = False  # fresh slot: no particle holds it yet
        pp, mm = np.nonzero(is_new)
        ll = slot_of_obs[mm]
        phi = z[mm, 1] + self.pose[pp, 2]
        r = z[mm, 0]
        G = np.empty((pp.size, 2, 2))
        G[:, 0, 0] = np.cos(phi)
        G[:, 0, 1] = -r * np.sin(phi)
        G[:, 1, 0] = np.sin(phi)
        G[:, 1, 1] = r * np.cos(phi)
        self.mean[pp, ll] = obs_map[pp, mm]
        self.cov[pp, ll] = G @ self.Q @ G.transpose(0, 2, 1)
        self.active[pp, ll] = True
        self.hits[pp, ll] = 1
        self.last_seen[pp, ll] = self.cycle
        loglik[pp, mm] = self.log_new

    def _normalize(self) -> None:
        """log-sum-exp normalization; non-finite or all-zero likelihoods -> uniform."""
        P = self.config.n_particles
        lw = np.where(np.isfinite(self.logw), self.logw, -np.inf)
        if not np.any(np.isfinite(lw)):
            self.logw = np.full(P, -math.log(P))
            return
        lse = logsumexp(lw)
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
        """Weighted landmark statistics for ``slots``: mean (S,2), cov (S,2,2), existence, hits."""
        w = self.weights
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
        c = self.config
        age = self.cycle - self.last_seen
        kill = self.active & (
            (age > c.prune_after_cycles)
            | ((self.hits < c.min_hits) & (age > c.tentative_prune_after_cycles))
        )
        if not kill.any():
            return
        after = self.active & ~kill
        gone = np.flatnonzero(self.slot_used & ~after.any(axis=0))
        self._retire(gone)  # statistics from the state before the kill
        self.active = after
        self.slot_used[gone] = False

    def _estimate(self) -> SlamEstimate:
        c = self.config
        w = self.weights
        x = float(np.sum(w * self.pose[:, 0]))
        y = float(np.sum(w * self.pose[:, 1]))
        th = circular_mean(self.pose[:, 2], w)
        sx = math.sqrt(max(float(np.sum(w * (self.pose[:, 0] - x) ** 2)), 0.0))
        sy = math.sqrt(max(float(np.sum(w * (self.pose[:, 1] - y) ** 2)), 0.0))
        sth = math.sqrt(max(float(np.sum(w * wrap_angle(self.pose[:, 2] - th) ** 2)), 0.0))
        used = np.flatnonzero(self.slot_used)
        if used.size:
            mu, cov, exist, hits = self._slot_estimates(used)
            rep = (exist >= c.min_existence) & (hits >= c.min_hits)
            lm = mu[rep]
            lstd = np.sqrt(np.maximum(0.5 * (cov[rep, 0, 0] + cov[rep, 1, 1]), 0.0))
            ids = self.slot_id[used[rep]]
        else:
            lm, lstd, ids = np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=np.int64)
        return SlamEstimate(
            pose=np.array([x, y, th]),
            pose_std=np.array([sx, sy, sth]),
            landmarks=lm,
            landmark_std=lstd,
            landmark_ids=ids,
        )

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
