"""SLAM observation wrapper: the RBPF estimate of pose and map on top of the radar point cloud.

Wraps an env whose observation is the radar's ``points`` / ``points_mask``
(:class:`rhs_env.wrappers.RadarObservation`) and runs one SLAM cycle per step
through :class:`slam.core.pipeline.SlamPipeline` (the same code as ``rhs-slam
scenario``). The SLAM state lives here, not in highway-env's observation
object, which highway-env rebuilds at every reset.

Observation, adding to the radar's keys:

* ``pose`` (3,): estimated x, y (m), heading (rad) in the map frame (the start pose is the origin);
* ``pose_std`` (3,): the particles' weighted standard deviation;
* ``landmarks`` (L_max, 2): estimated landmarks in the *estimated vehicle frame*, nearest first;
* ``landmarks_mask`` (L_max,);
* with ``health_in_obs=True`` (off by default: the shipped policies were trained without it)
  ``slam_health`` (1,) and ``slam_lost`` (1,);
* with ``velocity_in_obs=True`` (off by default, likewise) ``velocity`` (3,): the ego velocity the pipeline
  fits to the Doppler of static points (:mod:`slam.core.pipeline`, step 1), vx, vy (m/s, vehicle frame, x
  forward) and yaw rate (rad/s); zeros until the first fit. A car's own speed, which one frame of points
  gives a policy only through the static points' Doppler.

``info`` always gets the track health (:mod:`slam.core.health`): ``slam_health`` in [0, 1],
``slam_lost`` (the filter has lost the car since a loss it has not relocalised from),
``slam_losses`` (losses so far in the episode), ``slam_relocalised`` (relocalisations so far)
and ``slam_map_breaks`` (new maps started after a loss; the map frame restarts at the estimate
of that cycle), ``slam_pose_cov`` (3, 3): the pose covariance, the particles' spread plus the map drift that
they share (:mod:`slam.core.drift`), and ``slam_pose_std`` (3,): its std, and while lost at least the distance
travelled since the loss (the loss's offset is unknown, the drive since bounds it). The observation's
``pose_std`` stays the particles' spread alone (the shipped policies were trained on it).

:meth:`SlamObservation.observation` is the map cloud -> SLAM estimate and
nothing else: ground truth and errors are added to ``info`` by
:class:`slam.gym.metrics_info.SlamMetricsInfo`; the oracle registration
(``registration="odometry"``) gets the true motion through an explicit
callback, :meth:`SlamObservation.true_motion`. With
``stage_times_in_info=True`` ``info`` gets ``slam_stage_times`` (s per SLAM
stage; off by default: timings differ between otherwise identical runs, which
the determinism checks of ``check_env`` flag); the last stage times are always
on ``wrapper.stage_times``.
"""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from rhs_common.geometry import apply_motion, relative_motion
from rhs_common.threads import blas_threads_limit, check_blas_threads
from rhs_common.validation import build, check_bool, check_int
from rhs_env.scene import draw_disks, get_landmarks, he_to_world_xy, world_pose, world_surface_pixels
from slam.core.loop_closure import LoopCloser, LoopClosureConfig, relocalise, seed_landmarks
from slam.core.pipeline import PipelineConfig, SlamPipeline
from slam.core.rbpf import SlamConfig, SlamEstimate
from slam.core.registration import (
    DEFAULT_REGISTRATION,
    ICPConfig,
    make_registration,
)

__all__ = ["EST_COLOR", "SlamObservation", "TRUE_COLOR", "static_features"]

TRUE_COLOR = (30, 30, 30)
EST_COLOR = (255, 140, 0)


def static_features(env: gym.Env) -> int:
    """Static features of an env's scene that the radar sees and the SLAM can map: its roadside landmarks
    (:func:`rhs_env.scene.get_landmarks`; none on a plain highway-env env) plus the solid road objects
    (highway-env's ``Obstacle``) when the radar scatters from them (``ScatterConfig.include_obstacles``)."""
    base: Any = env.unwrapped
    count = len(get_landmarks(base))
    try:
        obstacles = bool(getattr(env.get_wrapper_attr("scatter_config"), "include_obstacles", True))
    except AttributeError:  # no radar wrapper says: the scene's scatterers include them by default
        obstacles = True
    road = getattr(base, "road", None)
    if obstacles and road is not None:
        count += sum(1 for o in road.objects if getattr(o, "solid", False) and getattr(o, "collidable", True))
    return count


class SlamObservation(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Adds the RBPF SLAM estimate to a radar point-cloud observation.

    Args:
        env: an env with ``points`` / ``points_mask`` observations (RadarObservation).
        slam: a :class:`slam.core.rbpf.SlamConfig` or a dict of its fields.
        registration: ``icp`` (default, :data:`slam.core.registration.DEFAULT_REGISTRATION`), ``cnn`` or ``odometry``.
        icp: a :class:`slam.core.registration.ICPConfig` or a dict of its fields (``registration="icp"``).
        pipeline: a :class:`slam.core.pipeline.PipelineConfig` or a dict (Doppler use, acceleration bound).
        max_landmarks: L_max, rows of the ``landmarks`` observation, [1, 4096].
        stage_times_in_info: add ``slam_stage_times`` to ``info`` (non-deterministic values).
        health_in_obs: add ``slam_health`` and ``slam_lost`` to the observation.
        velocity_in_obs: add ``velocity`` (the Doppler ego velocity: vx, vy m/s, yaw rate rad/s) to the observation.
        loop_closure: None (default: off), ``True`` or a :class:`slam.core.loop_closure.LoopClosureConfig` or a dict
            of its fields: close loops against the archived map (:mod:`slam.core.loop_closure`).

    ``reset(options={"keep_map": True})`` starts the episode from the previous episode's map: the map frame stays
    the previous one, the map goes into the new filter's archive, and the first cloud relocalises the car in it
    (:func:`slam.core.loop_closure.relocalise`; ``info["slam_map_kept"]`` says whether it did: if not, a new map
    starts at the car, as a plain reset does).
        blas_threads: BLAS / OpenMP threads inside ``step`` / ``reset``, restored after
            each call (:mod:`rhs_common.threads`); default 1, ``None`` leaves them alone.

    Examples:
        >>> import gymnasium as gym, rhs_env
        >>> env = gym.make("rhs-highway-slam-v0", radar={"scan": {"grid_deg": 5}}, vehicles_count=3)
        >>> obs, info = env.reset(seed=0)
        >>> sorted(obs)
        ['landmarks', 'landmarks_mask', 'points', 'points_mask', 'pose', 'pose_std']
        >>> obs["pose"].tolist()
        [0.0, 0.0, 0.0]
    """

    def __init__(
        self,
        env: gym.Env,
        slam: Any = None,
        registration: str = DEFAULT_REGISTRATION,
        icp: Any = None,
        pipeline: Any = None,
        max_landmarks: int = 64,
        stage_times_in_info: bool = False,
        blas_threads: int | None = 1,
        health_in_obs: bool = False,
        velocity_in_obs: bool = False,
        loop_closure: Any = None,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, slam=slam, registration=registration, icp=icp, pipeline=pipeline,
            max_landmarks=max_landmarks, stage_times_in_info=stage_times_in_info, blas_threads=blas_threads,
            health_in_obs=health_in_obs, velocity_in_obs=velocity_in_obs, loop_closure=loop_closure,
        )
        gym.ObservationWrapper.__init__(self, env)
        space = env.observation_space
        if not isinstance(space, spaces.Dict) or "points" not in space.spaces or "points_mask" not in space.spaces:
            raise ValueError("SlamObservation needs an env with 'points' and 'points_mask' observations")
        check_int("max_landmarks", max_landmarks, 1, 4096)
        check_bool("stage_times_in_info", stage_times_in_info)
        check_bool("health_in_obs", health_in_obs)
        self.health_in_obs = bool(health_in_obs)
        check_bool("velocity_in_obs", velocity_in_obs)
        self.velocity_in_obs = bool(velocity_in_obs)
        self.blas_threads = check_blas_threads(blas_threads)
        self.slam_config = build(SlamConfig, slam, "slam")
        self.icp_config = build(ICPConfig, icp, "icp")
        self.pipeline_config = build(PipelineConfig, pipeline, "pipeline")
        self.registration_kind = registration
        reg = make_registration(registration, truth=self.true_motion, icp=self.icp_config)
        if icp is not None and registration != "icp":  # settings that cannot apply: refused, not ignored
            raise ValueError(f"icp={icp!r} sets the ICP registration, but registration={registration!r} does not "
                             "use it; drop icp or use registration='icp'")
        radar_cfg = getattr(env, "radar_config", None)  # the radars' mounts place each point's line of sight
        max_range = getattr(radar_cfg, "max_range_m", None)
        if max_range is not None and self.slam_config.min_range_m >= max_range:
            raise ValueError(f"slam.min_range_m={self.slam_config.min_range_m:g} m ignores every point: the radars "
                             f"report ranges up to radar.max_range_m={max_range:g} m; lower slam.min_range_m below it")
        sensor_xy = radar_cfg.mounting.mounts()[0] if radar_cfg is not None else None
        self.pipeline = SlamPipeline(
            reg, self.slam_config, np.random.default_rng(0), self.pipeline_config, sensor_xy=sensor_xy
        )
        if loop_closure is not None and loop_closure is not False:
            lc = build(LoopClosureConfig, {} if loop_closure is True else loop_closure, "loop_closure")
            self.pipeline.loop_closer = LoopCloser(lc) if lc.enabled else None
        self.map_kept: bool | None = None  # None: the last reset did not ask to keep the map
        self.max_landmarks = int(max_landmarks)
        self._warned_no_static = False  # the no-static-scene warning is given once per wrapper
        self.stage_times_in_info = bool(stage_times_in_info)
        self.stage_times: dict[str, float] = {}
        big = np.float32(1e5)
        self.observation_space = spaces.Dict(
            {
                **space.spaces,
                "pose": spaces.Box(-big, big, (3,), np.float32),
                "pose_std": spaces.Box(0.0, big, (3,), np.float32),
                "landmarks": spaces.Box(-big, big, (self.max_landmarks, 2), np.float32),
                "landmarks_mask": spaces.MultiBinary(self.max_landmarks),
                **(
                    {"slam_health": spaces.Box(0.0, 1.0, (1,), np.float32), "slam_lost": spaces.MultiBinary(1)}
                    if self.health_in_obs
                    else {}
                ),
                **({"velocity": spaces.Box(-big, big, (3,), np.float32)} if self.velocity_in_obs else {}),
            }
        )
        self._reset_state()

    def _reset_state(self) -> None:
        self.origin = np.zeros(3)
        self.prev_world: np.ndarray | None = None
        self.true_traj: list[np.ndarray] = []
        self.est_traj: list[np.ndarray] = []
        self.estimate: SlamEstimate | None = None
        self.last_motion = np.zeros(3)

    @property
    def _base(self) -> Any:
        """The highway-env env underneath (its ``vehicle``, ``road``, ``config``: not in gymnasium's Env type)."""
        return self.env.unwrapped

    # ---- gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        with blas_threads_limit(self.blas_threads):
            return self._reset(seed, options)

    def _reset(self, seed: int | None, options: dict[str, Any] | None):
        options = dict(options or {})
        keep = options.pop("keep_map", False)
        check_bool("reset options keep_map", keep)
        kept = self._kept_map() if keep else None
        old_origin = self.origin
        if kept is not None and hasattr(self._base, "keep_landmarks"):  # a road scene keeps its world
            self._base.keep_landmarks = True
        obs, info = self.env.reset(seed=seed, options=options or None)
        self._reset_state()
        parent = self._base.np_random
        rng = np.random.default_rng(int(parent.integers(0, 2**63 - 1)))
        if self.registration_kind == "odometry":
            self.pipeline.registration = make_registration("odometry", rng, truth=self.true_motion)
        self.pipeline.reset(rng)
        self._check_static_scene()
        self.origin = world_pose(self._base.vehicle)
        self.map_kept = (kept is not None and self._start_in_map(obs, kept, old_origin)) if keep else None
        return self._observe(obs), self._with_info(info)

    def _kept_map(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The map of the episode so far (archived landmarks and the current estimate), or None when empty."""
        xy, ids = self.pipeline.slam.full_map()
        return (xy, ids) if len(xy) else None

    def _start_in_map(self, obs: dict[str, np.ndarray], kept: tuple[np.ndarray, np.ndarray],
                      old_origin: np.ndarray) -> bool:
        """Relocalise the new episode's start in the ``kept`` map (frame: ``old_origin``): the first cloud's
        points matched to its landmarks; on success every particle starts at the found pose, the map frame stays
        the old one and the kept landmarks go into the filter's archive (those near the car into its particles).
        """
        pts = np.asarray(obs["points"], dtype=float)[np.asarray(obs["points_mask"]) > 0][:, :2]
        xy, ids = kept
        m = relocalise(pts, xy)
        if m is None:
            return False
        slam = self.pipeline.slam
        slam.pose[:] = np.array([m.t[0], m.t[1], m.phi])
        slam.retired_xy, slam.retired_ids = np.asarray(xy, float).copy(), np.asarray(ids, np.int64).copy()
        slam.next_id = int(np.max(ids)) + 1
        near = np.flatnonzero(np.hypot(*(xy - m.t).T) <= 100.0)
        std = self.pipeline.loop_closer.config.landmark_std_m if self.pipeline.loop_closer is not None else 0.1
        n = seed_landmarks(slam, xy[near], ids[near], std)
        keep = ~np.isin(slam.retired_ids, ids[near[:n]])
        slam.retired_xy, slam.retired_ids = slam.retired_xy[keep], slam.retired_ids[keep]
        self.origin = old_origin
        return True

    def _check_static_scene(self) -> None:
        """Tell the health signal whether the scene holds anything static (:func:`static_features`), and warn
        once when it holds fewer features than the health's ``min_landmarks``: the pose is then the odometry's."""
        count = static_features(self.env)
        self.pipeline.health.static_scene = count > 0
        cfg = self.pipeline.health.config
        if count < max(cfg.min_landmarks, 1) and not self._warned_no_static:
            self._warned_no_static = True
            name = getattr(self._base.spec, "id", None) or type(self._base).__name__
            what = "no static landmarks or obstacles" if count == 0 else f"only {count} static landmark(s) or obstacle(s)"
            warnings.warn(
                f"SlamObservation: the scene of {name} has {what}, so the SLAM has next to nothing static to "
                "map: its pose is odometry-only (Doppler and point-cloud registration, drifting without bound); "
                "info['slam_health'] drops and info['slam_lost'] is set within "
                f"{cfg.unanchored_cycles_ok + 1} cycles without a landmark match. The rhs SLAM envs "
                "(rhs_env.registration) place roadside landmarks for a mapped pose.",
                UserWarning,
                stacklevel=4,
            )

    def step(self, action):
        with blas_threads_limit(self.blas_threads):
            obs, reward, terminated, truncated, info = self.env.step(action)
            return self._observe(obs), reward, terminated, truncated, self._with_info(info)

    @property
    def dt(self) -> float:
        """The SLAM cycle: one policy step, s."""
        return 1.0 / float(self._base.config["policy_frequency"])

    def true_pose(self) -> np.ndarray:
        """The ego's true pose in the map frame (the episode's start pose is the origin)."""
        return relative_motion(self.origin, world_pose(self._base.vehicle))

    def true_motion(self) -> np.ndarray:
        """True motion since the previous cycle, in the previous vehicle frame (the oracle's input)."""
        pose_w = world_pose(self._base.vehicle)
        return np.zeros(3) if self.prev_world is None else relative_motion(self.prev_world, pose_w)

    def _observe(self, observation: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        obs = self.observation(observation)
        self.prev_world = world_pose(self._base.vehicle)
        self.true_traj.append(self.true_pose())
        self.est_traj.append(obs["pose"].astype(float))
        return obs

    def observation(self, observation: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One SLAM cycle on the cloud -> the radar keys plus pose, pose_std and the nearest landmarks."""
        points = np.asarray(observation["points"], dtype=float)[np.asarray(observation["points_mask"]) > 0]
        res = self.pipeline.step(points, self.dt)
        est = self.estimate = res.estimate
        self.last_motion = res.motion
        self.stage_times = dict(est.stage_times)
        lv = est.landmarks_vehicle()
        order = np.argsort(np.hypot(lv[:, 0], lv[:, 1]))[: self.max_landmarks]
        lm_obs = np.zeros((self.max_landmarks, 2), dtype=np.float32)
        lm_obs[: len(order)] = lv[order]
        lm_mask = np.zeros(self.max_landmarks, dtype=np.int8)
        lm_mask[: len(order)] = 1
        out = {
            **observation,
            "pose": np.asarray(est.pose, dtype=np.float32),
            "pose_std": np.asarray(est.pose_std, dtype=np.float32),
            "landmarks": lm_obs,
            "landmarks_mask": lm_mask,
        }
        if self.health_in_obs:
            health = self.pipeline.health
            out["slam_health"] = np.array([health.health], dtype=np.float32)
            out["slam_lost"] = np.array([int(health.lost)], dtype=np.int8)
        if self.velocity_in_obs:
            v = self.pipeline.velocity
            out["velocity"] = np.zeros(3, np.float32) if v is None else np.asarray(v, dtype=np.float32)
        return out

    def _with_info(self, info: dict[str, Any]) -> dict[str, Any]:
        pipe = self.pipeline
        health = pipe.health
        out = {
            **info,
            "slam_health": float(health.health),
            "slam_lost": bool(health.lost),
            "slam_losses": int(health.losses),
            "slam_relocalised": int(pipe.relocalisations),
            "slam_map_breaks": int(pipe.map_breaks),
            "slam_pose_std": pipe.honest_pose_std(),
            "slam_pose_cov": pipe.pose_covariance(),
        }
        if pipe.loop_closer is not None:
            out["slam_loop_closures"] = int(pipe.loop_closer.closures)
            out["slam_landmarks_merged"] = int(pipe.loop_closer.merged)
        if self.map_kept is not None:
            out["slam_map_kept"] = bool(self.map_kept)
        if self.stage_times_in_info:
            out["slam_stage_times"] = dict(self.stage_times)
        return out

    def render(self):
        """The radar frame plus the true (dark) and estimated (orange) trajectory and estimated map."""
        frame = self.env.render()
        if not isinstance(frame, np.ndarray) or frame.ndim != 3 or not self.true_traj:
            return frame
        frame = np.ascontiguousarray(frame).copy()

        def he(xy_map: np.ndarray) -> np.ndarray:
            return he_to_world_xy(apply_motion(xy_map, self.origin))  # the y flip is its own inverse

        layers = [
            (np.asarray(self.true_traj)[:, :2], TRUE_COLOR, 1),
            (np.asarray(self.est_traj)[:, :2], EST_COLOR, 1),
        ]
        if self.estimate is not None and len(self.estimate.landmarks):
            layers.append((self.estimate.landmarks, EST_COLOR, 3))
        for xy, color, radius in layers:
            px = world_surface_pixels(self.env, he(xy))
            if px is not None and len(px):
                draw_disks(frame, px, color, radius=radius)
        return frame
