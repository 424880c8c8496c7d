"""One SLAM cycle from a raw point cloud: ego velocity, moving-point filter, registration, RBPF.

This is the single code path shared by the env's SLAM wrapper
(:class:`slam.wrapper.SlamObservation`) and the scripted runs of
:func:`slam.scenario.run_scenario` (``rhs-slam scenario``).

Per cycle, with cloud ``A_z`` (N, 4) in the vehicle frame and cycle length dt (s)
(or (N, 7) rows that add each point's range std (m), angle std (rad) and radar
index: their vehicle-frame covariance, :func:`slam.association.point_covariance`
with the radars at ``sensor_xy``, goes to the RBPF):

1. ego velocity ``v`` from the Doppler of static points (RANSAC fit of
   ``vr = -v . u`` scored by bearing coverage, within ``max_accel * dt`` of the
   last velocity, else unconstrained, :func:`slam.association.estimate_ego_velocity`);
   when the fit fails, the last registration motion over dt (constant velocity);
2. static points: ``|vr + v . u| <= threshold`` (:func:`slam.association.static_mask`);
3. registration of the static points of ``A_{z-1}`` and ``A_z`` with the prior
   displacement ``v dt`` (rotated by the last yaw increment) -> motion ``(dx, dy, dpsi)``;
4. RBPF update (:class:`slam.rbpf.RBPFSlam`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from rhs_common.validation import check_int, check_range, check_types
from slam.association import estimate_ego_velocity, point_covariance, static_mask
from slam.rbpf import RBPFSlam, SlamConfig, SlamEstimate
from slam.registration import Registration


@dataclass(frozen=True)
class PipelineConfig:
    """What the cycle does before the filter.

    ``use_doppler``: estimate the ego velocity from the Doppler of static points and drop
    moving points (else every point is static and the prior is constant velocity);
    ``max_accel_mps2`` [0, 100]: the velocity changes by at most this times dt per cycle;
    ``reacquire_after_cycles`` [0, 1000]: once the velocity is tracked (3 fits within that
    bound), after this many consecutive cycles without such a fit the fit is re-acquired
    without the bound; until then the last velocity holds (an unconstrained fit in dense
    traffic can lock onto a platoon of vehicles). Without a track it re-acquires at once.
    """

    use_doppler: bool = True
    max_accel_mps2: float = 10.0
    reacquire_after_cycles: int = 5

    def __post_init__(self) -> None:
        check_types(self)
        check_range("max_accel_mps2", self.max_accel_mps2, 0.0, 100.0)
        check_int("reacquire_after_cycles", self.reacquire_after_cycles, 0, 1000)


@dataclass
class CycleResult:
    """What one cycle produced: the RBPF estimate, the registration motion, the ego velocity used."""

    estimate: SlamEstimate
    motion: np.ndarray
    velocity: np.ndarray | None
    registration_time_s: float


class SlamPipeline:
    """Stateful SLAM over successive clouds; ``reset()`` starts a new map at the current pose."""

    def __init__(
        self,
        registration: Registration,
        config: SlamConfig | None = None,
        rng: np.random.Generator | None = None,
        options: PipelineConfig | None = None,
        sensor_xy: np.ndarray | None = None,
    ) -> None:
        """``sensor_xy`` (S, 2): radar positions in the vehicle frame (m) indexed by column 6 of
        (N, 7) clouds; ``None`` puts every sensor at the vehicle origin."""
        self.registration = registration
        self.sensor_xy = None if sensor_xy is None else np.asarray(sensor_xy, dtype=float).reshape(-1, 2)
        self.options = options if options is not None else PipelineConfig()
        self.max_accel_mps2 = self.options.max_accel_mps2
        self.config = config if config is not None else SlamConfig()
        if hasattr(registration, "kernels"):  # the ICP fit follows the SLAM's kernels (slam.kernels.icp_fit)
            registration.kernels = self.config.kernels
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.use_doppler = self.options.use_doppler
        self.slam = RBPFSlam(self.config, self.rng)
        self.reset()

    def reset(self, rng: np.random.Generator | None = None) -> None:
        if rng is not None:
            self.rng = rng
            self.slam = RBPFSlam(self.config, rng)
        else:
            self.slam.reset()
        if hasattr(self.registration, "reset"):
            self.registration.reset()
        # the Doppler RANSAC draws from its own stream so it never shifts the particle noise
        self.ransac_rng = np.random.default_rng(np.random.SeedSequence(int(self.rng.integers(2**63))))
        self.cycle = 0
        self.velocity_misses = 0  # consecutive cycles without a Doppler fit near the last velocity
        self.velocity_track = 0  # Doppler fits near the last velocity since the last re-acquisition
        self.prev_static: np.ndarray | None = None
        self.velocity: np.ndarray | None = None  # (vx, vy, yaw rate), current vehicle frame
        self.last_motion: np.ndarray | None = None

    def _static(self, pts: np.ndarray) -> np.ndarray:
        if self.use_doppler and self.velocity is not None:
            return pts[static_mask(pts, self.velocity[:2], self.config.dynamic_threshold_mps)]
        return pts

    def step(self, points: np.ndarray, dt: float) -> CycleResult:
        """Process cloud ``points`` (N, 4) or (N, 7) (with stds and radar) of a cycle of length ``dt`` (s)."""
        rows = np.asarray(points, dtype=float)
        rows = rows.reshape(-1, rows.shape[-1] if rows.ndim == 2 and rows.shape[-1] >= 7 else 4)
        cov = point_covariance(rows, self.sensor_xy) if rows.shape[1] >= 7 else None
        pts = rows[:, :4]
        thr = self.config.dynamic_threshold_mps
        v_dop = None
        if self.use_doppler:
            # bounded acceleration: the new velocity lies within max_accel * dt of the last one
            prior_v = None if self.velocity is None else self.velocity[:2]
            v_dop = estimate_ego_velocity(
                pts, 0.5 * thr, self.ransac_rng, prior=prior_v, max_change=self.max_accel_mps2 * dt + thr
            )
            self.velocity_misses = 0 if v_dop is not None else self.velocity_misses + 1
            self.velocity_track = self.velocity_track + 1 if v_dop is not None else self.velocity_track
            established = self.velocity_track >= 3 and self.velocity_misses <= self.options.reacquire_after_cycles
            if v_dop is None and prior_v is not None and not established:
                # no track yet, or lost for a while: re-acquire without the prior (an established track
                # holds its velocity first: an unconstrained fit in traffic can lock onto a platoon)
                v_dop = estimate_ego_velocity(pts, 0.5 * thr, self.ransac_rng)
                self.velocity_track = 0
        if v_dop is not None:
            self.velocity = np.array([v_dop[0], v_dop[1], 0.0 if self.velocity is None else self.velocity[2]])
        reg_time = 0.0
        if self.cycle == 0:
            motion = np.zeros(3)
        else:
            prior = None
            if v_dop is not None:  # displacement over the cycle from the Doppler velocity
                dth = 0.0 if self.last_motion is None else self.last_motion[2]
                c, s = math.cos(dth), math.sin(dth)
                prior = np.array([(c * v_dop[0] - s * v_dop[1]) * dt, (s * v_dop[0] + c * v_dop[1]) * dt, dth])
            elif self.last_motion is not None:
                prior = self.last_motion.copy()
            t0 = time.perf_counter()
            prev = self.prev_static if self.prev_static is not None else np.zeros((0, 4))
            motion = np.asarray(self.registration.estimate(prev, self._static(pts), prior=prior), dtype=np.float64).reshape(3)
            reg_time = time.perf_counter() - t0
            if not np.all(np.isfinite(motion)):
                motion = np.zeros(3)
            self.last_motion = motion
            c, s = math.cos(motion[2]), math.sin(motion[2])
            if v_dop is None:
                self.velocity = np.array(
                    [(c * motion[0] + s * motion[1]) / dt, (-s * motion[0] + c * motion[1]) / dt, motion[2] / dt]
                )
            else:
                self.velocity = np.array([v_dop[0], v_dop[1], motion[2] / dt])
        est = self.slam.update(pts, motion, dt, ego_velocity=self.velocity if self.use_doppler else None, cov=cov)
        est.stage_times["registration"] = reg_time
        self.prev_static = self._static(pts)
        self.cycle += 1
        vel = None if self.velocity is None else self.velocity.copy()
        return CycleResult(est, motion, vel, reg_time)
