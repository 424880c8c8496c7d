"""The SLAM-in-the-loop cycle shared by the env's SLAM wrapper and ``rhs-slam scenario``.

:func:`run_scenario` drives one scripted run: per cycle t it asks ``cloud_fn(t,
true_pose)`` for the point cloud (vehicle frame), estimates the motion with the
registration on the static points of clouds t-1 and t, and updates the RBPF. The
map frame is the first true pose; estimated poses are compared to the true poses
expressed in that frame.

:class:`SyntheticCloud` is a simple cloud generator for tests and quick studies:
true landmarks moved into the vehicle frame, range/bearing noise, random misses,
uniform false points, Doppler of a static scene (optionally moving targets).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from rhs_common.geometry import compose, points_in_frame, relative_motion
from rhs_common.validation import check_int, check_range
from slam.core.metrics import heading_rmse, map_metrics, position_rmse
from slam.core.pipeline import PipelineConfig, SlamPipeline
from slam.core.rbpf import SlamConfig
from slam.core.registration import Registration

__all__ = ["run_scenario", "SyntheticCloud", "compose", "poses_in_frame"]


def poses_in_frame(poses: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Express world poses (T, 3) in the frame of ``origin`` (3,)."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    return np.stack([relative_motion(origin, p) for p in poses]) if len(poses) else np.zeros((0, 3))


class SyntheticCloud:
    """Synthetic radar-like cloud of point landmarks (callable ``(t, true_pose) -> (N, 4)``).

    Landmark k at world ``l_k`` is at ``R(th)^T (l_k - [x, y])`` in the vehicle frame;
    within ``max_range_m`` it is detected with probability ``1 - p_miss`` at range
    ``r + N(0, range_std_m^2)`` and bearing ``b + N(0, bearing_std_rad^2)``. A Poisson
    number (mean ``false_rate``) of false points is drawn uniformly in the disc.
    Radial velocity of a static point: ``-v . u`` with ``v`` the ego velocity in the
    vehicle frame from the last two poses over ``dt`` (zero on the first call), plus
    ``N(0, doppler_std^2)``. Amplitude: ``amplitude * (10 / max(r, 1))^2`` (R^-2, echo
    over noise, linear). ``movers`` (K2, 4) world x, y, vx, vy are moving targets
    (m, m/s) that move with time ``t dt``. ``report_std=True`` appends each point's
    range std, bearing std and sensor index 0 (rows (N, 7), the sensor at the vehicle
    origin): the true noise of the cloud; false points get the same stds.
    """

    def __init__(
        self,
        landmarks: np.ndarray,
        rng=None,
        *,
        max_range_m: float = 50.0,
        range_std_m: float = 0.0,
        bearing_std_rad: float = 0.0,
        p_miss: float = 0.0,
        false_rate: float = 0.0,
        doppler_std: float = 0.0,
        amplitude: float = 100.0,
        dt: float = 0.1,
        movers: np.ndarray | None = None,
        report_std: bool = False,
    ) -> None:
        check_range("max_range_m", max_range_m, 0.0, 1e5, low_open=True)
        check_range("range_std_m", range_std_m, 0.0, 1e3)
        check_range("bearing_std_rad", bearing_std_rad, 0.0, math.pi)
        check_range("p_miss", p_miss, 0.0, 1.0)
        check_range("false_rate", false_rate, 0.0, 1e4)  # Poisson mean per scan: points drawn
        check_range("doppler_std", doppler_std, 0.0, 1e3)
        check_range("dt", dt, 0.0, 1e3, low_open=True)
        self.landmarks = np.asarray(landmarks, dtype=float).reshape(-1, 2)
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.max_range_m = float(max_range_m)
        self.range_std_m = float(range_std_m)
        self.bearing_std_rad = float(bearing_std_rad)
        self.p_miss = float(p_miss)
        self.false_rate = float(false_rate)
        self.doppler_std = float(doppler_std)
        self.amplitude = float(amplitude)
        self.dt = float(dt)
        self.movers = None if movers is None else np.asarray(movers, dtype=float).reshape(-1, 4)
        self._prev_pose: np.ndarray | None = None
        self.last_true_xy = np.zeros((0, 2))
        self.report_std = bool(report_std)

    def __call__(self, t: int, true_pose: np.ndarray) -> np.ndarray:
        pose = np.asarray(true_pose, dtype=float).reshape(3)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        if self._prev_pose is None:
            v = np.zeros(2)
        else:
            dw = (pose[:2] - self._prev_pose[:2]) / self.dt
            v = np.array([c * dw[0] + s * dw[1], -s * dw[0] + c * dw[1]])
        self._prev_pose = pose.copy()
        xy = points_in_frame(self.landmarks, pose)
        rel_v = np.broadcast_to(-v, xy.shape)
        if self.movers is not None and len(self.movers):
            mw = self.movers[:, :2] + self.movers[:, 2:] * (t * self.dt)
            mxy = points_in_frame(mw, pose)
            mv = self.movers[:, 2:]
            mv_veh = np.stack([c * mv[:, 0] + s * mv[:, 1], -s * mv[:, 0] + c * mv[:, 1]], axis=1)
            xy = np.concatenate([xy, mxy])
            rel_v = np.concatenate([rel_v, mv_veh - v])
        r = np.hypot(xy[:, 0], xy[:, 1])
        keep = (r <= self.max_range_m) & (r > 0.5)
        nl = len(self.landmarks)
        self.last_true_xy = xy[:nl][keep[:nl]]
        keep &= self.rng.random(len(r)) >= self.p_miss
        xy, r, rel_v = xy[keep], r[keep], rel_v[keep]
        b = np.arctan2(xy[:, 1], xy[:, 0])
        u = np.stack([np.cos(b), np.sin(b)], axis=1)
        vr = np.sum(rel_v * u, axis=1)
        rn = r + self.range_std_m * self.rng.standard_normal(len(r))
        bn = b + self.bearing_std_rad * self.rng.standard_normal(len(r))
        vr = vr + self.doppler_std * self.rng.standard_normal(len(r))
        pts = np.stack([rn * np.cos(bn), rn * np.sin(bn), vr, self.amplitude * (10.0 / np.maximum(rn, 1.0)) ** 2], axis=1)
        nf = self.rng.poisson(self.false_rate) if self.false_rate > 0 else 0
        if nf:
            rr = self.max_range_m * np.sqrt(self.rng.random(nf))
            bb = self.rng.uniform(-math.pi, math.pi, nf)
            vr_false = -(v[0] * np.cos(bb) + v[1] * np.sin(bb))
            fp = np.stack([rr * np.cos(bb), rr * np.sin(bb), vr_false, np.full(nf, self.amplitude * 0.05)], axis=1)
            pts = np.concatenate([pts, fp])
        if self.report_std:
            n = len(pts)
            std = np.column_stack([np.full(n, self.range_std_m), np.full(n, self.bearing_std_rad), np.zeros(n)])
            pts = np.concatenate([pts, std], axis=1)
        return pts


def run_scenario(
    landmarks: np.ndarray,
    poses: np.ndarray,
    cloud_fn: Callable[[int, np.ndarray], np.ndarray],
    registration: Registration,
    slam_config: SlamConfig | None = None,
    rng=None,
    *,
    dt: float = 0.1,
    map_gate_m: float = 2.0,
    use_doppler: bool = True,
    progress: bool = False,
    sensor_xy: np.ndarray | None = None,
) -> dict:
    """Run SLAM over a scripted trajectory.

    Parameters
    ----------
    landmarks : (K, 2) true static landmarks, world frame (m).
    poses : (T, 3) true poses per cycle, world frame; ``poses[0]`` defines the map frame.
    cloud_fn : ``cloud_fn(t, true_pose) -> (N, 4)`` point cloud in the vehicle frame, or
        (N, 7) with each point's range std, angle std and radar index.
    registration : object with ``.estimate(prev_points, points, prior=None) -> (3,)``;
        if it has ``set_true_motion`` (the odometry oracle) it receives the truth first.
    slam_config : RBPF settings. rng : numpy Generator or seed.
    dt : cycle duration (s). map_gate_m : gate of the Hungarian map metric (m).
    sensor_xy : (S, 2) radar positions (vehicle frame, m) for (N, 7) clouds; default: the
        cloud's own ``sensor_xy`` attribute when it has one (:class:`slam.gym.radar_cloud.RadarCloud`:
        its radar's mounts), else the vehicle origin.
    use_doppler : filter moving points with the radial velocity. The ego velocity
        comes from the Doppler of the cloud itself (RANSAC fit of
        ``vr = -v . u``, :func:`slam.core.association.estimate_ego_velocity`), which also
        gives the registration its prior displacement ``v dt``; when the fit fails,
        the last registration motion over dt is used.

    Returns
    -------
    dict with ``estimated_poses`` (T, 3) and ``true_poses`` (T, 3) in the map frame,
    ``pose_std`` (T, 3), ``landmarks`` (L, 2) the full estimated map (map frame),
    ``landmark_ids``, ``true_landmarks`` (K, 2) map frame, ``ate_rmse_m``,
    ``heading_rmse_rad``, ``map_rmse_m``, ``map_matched``, ``map_missed``,
    ``map_spurious``, ``dead_reckoning_poses``, ``dead_reckoning_rmse_m``,
    ``motions`` (T, 3) registration estimates, ``max_landmark_slots``, ``finite``
    (no NaN anywhere), ``stage_times_s`` mean seconds per stage per cycle.
    """
    check_range("dt", dt, 0.0, None, low_open=True)
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    T = len(poses)
    check_int("len(poses)", T, 1, None)
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    cfg = slam_config if slam_config is not None else SlamConfig()
    if sensor_xy is None:  # a cloud that knows its radars' mounts (slam.gym.radar_cloud.RadarCloud) says them
        sensor_xy = getattr(cloud_fn, "sensor_xy", None)
    pipe = SlamPipeline(registration, cfg, rng, PipelineConfig(use_doppler=use_doppler), sensor_xy=sensor_xy)
    log = _RunLog(T)
    it = range(T)
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc="SLAM", unit="cycle")
    for t in it:
        pts = np.asarray(cloud_fn(t, poses[t]), dtype=float)
        if t > 0 and hasattr(registration, "set_true_motion"):  # the odometry oracle gets the truth
            registration.set_true_motion(relative_motion(poses[t - 1], poses[t]))
        log.record(t, pipe.step(pts, dt), pipe.slam.n_landmark_slots)
    return log.result(pipe.slam, poses, landmarks, map_gate_m)


class _RunLog:
    """Per-cycle estimates of a scripted run and the summary dict of :func:`run_scenario`."""

    def __init__(self, cycles: int) -> None:
        self.est_poses = np.zeros((cycles, 3))
        self.pose_std = np.zeros((cycles, 3))
        self.dead_reckoning = np.zeros((cycles, 3))
        self.motions = np.zeros((cycles, 3))
        self.stage_sum: dict[str, float] = {}
        self.max_slots = 0
        self.finite = True

    def record(self, t: int, res, slots: int) -> None:
        est, motion = res.estimate, res.motion
        for k, v in est.stage_times.items():
            self.stage_sum[k] = self.stage_sum.get(k, 0.0) + v
        self.motions[t] = motion
        self.est_poses[t] = est.pose
        self.pose_std[t] = est.pose_std
        self.dead_reckoning[t] = motion if t == 0 else compose(self.dead_reckoning[t - 1], motion)
        self.max_slots = max(self.max_slots, slots)
        self.finite &= bool(np.all(np.isfinite(est.pose)) and np.all(np.isfinite(est.landmarks)))

    def result(self, slam, poses: np.ndarray, landmarks: np.ndarray, map_gate_m: float) -> dict:
        origin = poses[0]
        true_map = poses_in_frame(poses, origin)
        true_lm = points_in_frame(np.asarray(landmarks, dtype=float).reshape(-1, 2), origin)
        lm, ids = slam.full_map()
        mm = map_metrics(lm, true_lm, map_gate_m)
        return dict(
            estimated_poses=self.est_poses,
            true_poses=true_map,
            pose_std=self.pose_std,
            landmarks=lm,
            landmark_ids=ids,
            true_landmarks=true_lm,
            ate_rmse_m=position_rmse(self.est_poses, true_map),
            heading_rmse_rad=heading_rmse(self.est_poses, true_map),
            map_rmse_m=mm["rmse"],
            map_matched=mm["matched"],
            map_missed=mm["missed"],
            map_spurious=mm["spurious"],
            dead_reckoning_poses=self.dead_reckoning,
            dead_reckoning_rmse_m=position_rmse(self.dead_reckoning, true_map),
            motions=self.motions,
            max_landmark_slots=self.max_slots,
            finite=self.finite,
            stage_times_s={k: v / len(poses) for k, v in self.stage_sum.items()},
        )
