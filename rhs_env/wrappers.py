"""Gymnasium wrappers that put the RHS radar on any highway-env environment.

:class:`RadarObservation` replaces the observation with the point cloud of the
ego vehicle's four RHS radars:

``Dict(points=Box((N_max, 7), float32), points_mask=MultiBinary(N_max))``

``points`` rows (:data:`POINT_FEATURES`) are x, y (vehicle frame, m), radial
velocity (m/s, > 0 receding), amplitude (linear, over the noise std), range
std (m) and angle std (rad) of the point (its Cramer-Rao bounds at its SNR plus
a floor, :mod:`rhs_env.uncertainty`; the angle is measured from the boresight
of the radar that saw it) and that radar's index (0 front, 1 left, 2 rear,
3 right, mounts from :meth:`rhs_env.radar_config.MountingConfig.mounts`), zero padded,
inside finite bounds (x, y: the radars' reach; velocity: the unambiguous
radial speed; amplitude: [0, 1e9]; range std: [0, 1e3] m; angle std:
[0, pi] rad; radar: [0, 3]); when the
radar returns more than ``N_max`` points the weakest are dropped (the kept
points stay in the radar's order). ``points_mask`` is 1 on real rows.

The wrapper owns the :class:`rhs_env.radar.RadarSystem`. At every reset its
random generator is spawned from the env's ``np_random`` (a child seed
sequence, which leaves the env's own stream untouched), so the same reset seed
gives the same episode, radar noise included. ``info`` gets
``radar_points_total`` / ``radar_points_dropped``, with ``scatterers_in_info=True``
``scatterers`` (the ground truth handed to the radar, a dict of variable-length
arrays in the vehicle frame), and, with
``stage_times_in_info=True``, ``radar_stage_times`` (seconds per processing
stage; off by default because timings differ between otherwise identical runs,
which the determinism checks of ``check_env`` would flag). The last stage
times are always on ``wrapper.stage_times``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from rhs_common.threads import blas_threads_limit, check_blas_threads
from rhs_common.validation import build, check_bool, check_choice, check_int
from rhs_env.array_models import ANTENNA_KINDS
from rhs_env.scene import (
    ScatterConfig,
    draw_disks,
    scatterers_to_dict,
    scene_scatterers,
    vehicle_to_he_xy,
    world_surface_pixels,
)
from rhs_env.uncertainty import POINT_COLUMNS, point_rows

if TYPE_CHECKING:  # pragma: no cover - annotations only (the radar is imported when built)
    from rhs_env.point_cloud import PointCloud
    from rhs_env.radar import RadarSystem
    from rhs_env.scatterers import Scatterers

__all__ = ["AMPLITUDE_MAX", "POINT_COLOR", "POINT_FEATURES", "RANGE_STD_MAX", "RadarObservation", "make_radar_config"]

POINT_FEATURES = POINT_COLUMNS  # x, y, radial_velocity, amplitude, range_std, angle_std, radar
RANGE_STD_MAX = 1e3  # m; a point without a usable SNR is clipped to this
POINT_COLOR = (255, 40, 40)
AMPLITUDE_MAX = 1e9  # linear echo amplitude over noise std; far above any physical echo


def make_radar_config(radar: Any = None, antenna: str | None = None):
    """A validated :class:`rhs_env.radar.RadarConfig` from ``None`` / a config / a nested dict of its fields.

    ``{"scan": {"grid_deg": 5}, "max_range_m": 80, "detection": {"pfa": 1e-5}}`` (the groups of
    :mod:`rhs_env.radar_config`; the former flat names, ``{"cfar_pfa": 1e-5}``, still work with a
    ``DeprecationWarning``); ``antenna`` (rhs | phased |
    random | hologram) overrides the antenna kind of a ``RadarConfig``; given beside a dict that
    names another ``antenna`` it is a ``ValueError`` naming both. Errors name the field path
    (``radar.scan.grid_deg must be ...``): ``ValueError`` for unknown fields and
    out-of-range values, ``TypeError`` for wrong types.
    """
    from rhs_env.radar import RadarConfig

    if antenna is not None:
        check_choice("antenna", antenna, ANTENNA_KINDS)
        if isinstance(radar, RadarConfig):
            return replace(radar, antenna=antenna)
        if isinstance(radar, Mapping) and "antenna" in radar and radar["antenna"] != antenna:
            raise ValueError(f"antenna={antenna!r} conflicts with radar.antenna={radar['antenna']!r}; "
                             "give the antenna once")
        radar = {**(radar or {}), "antenna": antenna} if radar is None or isinstance(radar, Mapping) else radar
    return build(RadarConfig, radar, "radar")


def _spawn_rng(env: gym.Env) -> np.random.Generator:
    """A child generator of the env's ``np_random`` (same env seed -> same child)."""
    parent = env.unwrapped.np_random
    try:
        return parent.spawn(1)[0]
    except (TypeError, ValueError, AttributeError):
        # a generator without a seed sequence: draw a seed from its stream instead
        return np.random.default_rng(int(parent.integers(0, 2**63 - 1)))


class RadarObservation(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Point-cloud observation of the ego vehicle's four RHS radars, on any highway-env env.

    Args:
        env: a highway-env environment (``env.unwrapped.vehicle`` is the ego;
            ``env.unwrapped.landmarks`` adds static landmarks when present).
        radar: a ``RadarConfig`` or a dict of its fields (validated).
        antenna: shortcut overriding the radar's antenna kind.
        max_points: N_max, rows of the ``points`` observation, [1, 65536].
        scatter: a :class:`rhs_env.scene.ScatterConfig` or dict (range cut, vehicle RCS, ...).
        stage_times_in_info: add ``radar_stage_times`` to ``info`` (non-deterministic values).
        scatterers_in_info: add the ground-truth ``scatterers`` to ``info`` (variable length:
            off by default so vector envs can stack ``info``).
        blas_threads: BLAS / OpenMP threads inside ``step`` / ``reset`` (the radar's
            work and the env's), restored after each call (:mod:`rhs_common.threads`);
            default 1, ``None`` leaves the user's thread pools alone (opt into threads).
        radar_model: "exact" (the default: :class:`rhs_env.radar.RadarSystem` synthesises the range spectrum),
            "fast" (:class:`rhs_env.fast_radar.FastRadarSystem`: points drawn from the exact radar's measured
            detector, the ``-fast-`` ids; a labelled variant) or "fast-calibrate" (the same, calibrating radar
            settings without a table at first use).

    Examples:
        >>> import gymnasium as gym
        >>> from rhs_env.envs import RHSPaperEnv
        >>> env = RadarObservation(RHSPaperEnv(), radar={"scan": {"grid_deg": 5}}, max_points=32)
        >>> obs, info = env.reset(seed=0)
        >>> obs["points"].shape, int(obs["points_mask"].sum()) > 0
        ((32, 7), True)
    """

    def __init__(
        self,
        env: gym.Env,
        radar: Any = None,
        antenna: str | None = None,
        max_points: int = 256,
        scatter: Any = None,
        stage_times_in_info: bool = False,
        scatterers_in_info: bool = False,
        blas_threads: int | None = 1,
        radar_model: str = "exact",
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self,
            radar=radar,
            antenna=antenna,
            max_points=max_points,
            scatter=scatter,
            stage_times_in_info=stage_times_in_info,
            scatterers_in_info=scatterers_in_info,
            blas_threads=blas_threads,
            radar_model=radar_model,
        )
        gym.ObservationWrapper.__init__(self, env)
        from rhs_env.fast_radar import RADAR_MODELS

        check_choice("radar_model", radar_model, RADAR_MODELS)
        self.radar_model = radar_model
        check_int("max_points", max_points, 1, 65536)
        check_bool("stage_times_in_info", stage_times_in_info)
        check_bool("scatterers_in_info", scatterers_in_info)
        self.blas_threads = check_blas_threads(blas_threads)
        self.max_points = int(max_points)
        self.radar_config = make_radar_config(radar, antenna)
        self.scatter_config = ScatterConfig.make(scatter)
        self.stage_times_in_info = bool(stage_times_in_info)
        # bounds of a point: x, y within the radars' reach, the unambiguous radial
        # speed, amplitudes (echo / noise std) up to a physical ceiling
        cfg = self.radar_config
        reach = cfg.max_range_m + 0.5 * np.hypot(cfg.mounting.vehicle_length_m, cfg.mounting.vehicle_width_m)
        vmax = cfg.max_velocity_mps
        self._low = np.array([-reach, -reach, -vmax, 0.0, 0.0, 0.0, 0.0], dtype=np.float32)
        self._high = np.array([reach, reach, vmax, AMPLITUDE_MAX, RANGE_STD_MAX, np.pi, 3.0], dtype=np.float32)
        width = len(POINT_FEATURES)
        self.scatterers_in_info = bool(scatterers_in_info)
        self.observation_space = spaces.Dict(
            {
                "points": spaces.Box(
                    np.broadcast_to(self._low, (self.max_points, width)),
                    np.broadcast_to(self._high, (self.max_points, width)),
                    dtype=np.float32,
                ),
                "points_mask": spaces.MultiBinary(self.max_points),
            }
        )
        self.radar: RadarSystem | None = None
        self._build_radar(np.random.default_rng(0))  # built now so bad configs fail here; rng replaced at reset
        self.stage_times: dict[str, float] = {}
        self.last_cloud: PointCloud | None = None
        self.last_scatterers: Scatterers | None = None
        self._points_he = np.zeros((0, 2))

    @property
    def _base(self) -> Any:
        """The highway-env env underneath (its ``vehicle``, ``road``, ``config``: not in gymnasium's Env type)."""
        return self.env.unwrapped

    # ---- gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        with blas_threads_limit(self.blas_threads):
            obs, info = self.env.reset(seed=seed, options=options)
            self._build_radar(_spawn_rng(self.env))
            return self.observation(obs), self._with_info(info)

    def step(self, action):
        with blas_threads_limit(self.blas_threads):
            obs, reward, terminated, truncated, info = self.env.step(action)
            return self.observation(obs), reward, terminated, truncated, self._with_info(info)

    def observation(self, observation: Any) -> dict[str, np.ndarray]:
        """Scan the current scene -> the padded point cloud (the env's own observation is ignored).

        Keeps the scan (``last_cloud``, ``last_scatterers``) as the sensor's state; ``info`` is
        built from it in :meth:`step` / :meth:`reset`.
        """
        if self.radar is None:
            self._build_radar(_spawn_rng(self.env))
        assert self.radar is not None
        base = self._base
        ego = base.vehicle
        scatterers, occluders = scene_scatterers(base, ego, self.scatter_config, self.radar_config.kernels)
        cloud = self.radar.scan(scatterers, occluders)
        self.last_cloud, self.last_scatterers = cloud, scatterers
        self.stage_times = dict(getattr(cloud, "stage_times", {}) or {})
        points = point_rows(cloud)
        if len(points) > self.max_points:  # keep the strongest, in the radar's order
            points = points[np.sort(np.argpartition(-points[:, 3], self.max_points - 1)[: self.max_points])]
        n = len(points)
        out_points = np.zeros((self.max_points, len(POINT_FEATURES)), dtype=np.float32)
        out_points[:n] = np.clip(points, self._low, self._high)
        mask = np.zeros(self.max_points, dtype=np.int8)
        mask[:n] = 1
        self._points_he = vehicle_to_he_xy(points[:, :2], ego) if n else np.zeros((0, 2))
        return {"points": out_points, "points_mask": mask}

    def render(self):
        """The env's frame with the point cloud drawn over it (rgb_array); other modes pass through."""
        frame = self.env.render()
        viewer = getattr(self._base, "viewer", None)
        if frame is not None and viewer is not None and viewer.offscreen and not getattr(viewer, "enabled", True):
            # highway-env disables its viewer under SDL_VIDEODRIVER=dummy; offscreen needs no display
            viewer.enabled = True
            frame = self.env.render()
        if not isinstance(frame, np.ndarray) or frame.ndim != 3:
            return frame
        frame = np.ascontiguousarray(frame).copy()
        px = world_surface_pixels(self.env, self._points_he)
        if px is not None and len(px):
            draw_disks(frame, px, POINT_COLOR, radius=2)
        return frame

    # ---- helpers
    def _build_radar(self, rng: np.random.Generator) -> None:
        """Give the radar this episode's generator.

        The antennas and OMP dictionaries do not depend on the rng except for the
        ``random`` antenna, whose patterns are drawn per episode: only then is the
        radar rebuilt; otherwise the existing one gets the new generator.
        """
        from rhs_env.radar import RadarSystem

        if self.radar is None or self.radar_config.antenna == "random":
            if self.radar_model == "exact":
                self.radar = RadarSystem(self.radar_config, rng)
            else:
                from rhs_env.fast_radar import FastRadarSystem

                self.radar = FastRadarSystem(self.radar_config, rng,
                                             calibrate_missing=self.radar_model == "fast-calibrate")
        else:
            self.radar.rng = rng

    def _with_info(self, info: dict[str, Any]) -> dict[str, Any]:
        """``info`` plus the last scan's point counts (and, when asked, its truth and stage times)."""
        total = len(self.last_cloud) if self.last_cloud is not None else 0
        out = {**info, "radar_points_total": total, "radar_points_dropped": max(0, total - self.max_points)}
        if self.scatterers_in_info and self.last_scatterers is not None:
            out["scatterers"] = scatterers_to_dict(self.last_scatterers)
        if self.stage_times_in_info:
            out["radar_stage_times"] = dict(self.stage_times)
        return out
