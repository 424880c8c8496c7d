"""highway-env scenes for the RHS radar: traffic plus static roadside landmarks.

* :class:`RHSHighwayEnv` (``rhs-highway-v0``): highway-env's ``HighwayEnv``
  with landmarks on both road sides. Defaults: 4 lanes, 30 other vehicles,
  40 s episodes at a **5 Hz policy / SLAM-cycle rate** (200 cycles), simulation
  at 15 Hz. At the ego's 20-30 m/s a cycle moves it 4-6 m, well under the
  20 m landmark spacing, so consecutive point clouds overlap strongly and data
  association is not aliased by the landmark period (1 Hz would move it 25 m,
  more than a spacing).
* :class:`RHSPaperEnv`: the paper's Fig. 5c layout. The
  obstacles are at (10, 65), (25, 10), (30, 65), (35, 10), (50, 65) m and the
  vehicle starts at (0, 37.5) heading +x, in the **world frame** (y up, see
  :mod:`rhs_env.scene`). highway-env's y axis points down, so the road is built
  at highway-env ``y = -37.5`` (three 4 m lanes, the ego in the middle one) and
  the obstacles at highway-env ``y = -65 / -10``: on screen the picture looks
  like the paper's figure. The ego drives at 6 m/s: 50 cycles at 5 Hz = 10 s
  = 60 m. No traffic by default (``vehicles_count`` > 0 adds some ahead).

Both take their highway-env config as ``config={...}`` and/or as keyword
arguments (``gym.make("rhs-highway-v0", lanes_count=3, landmarks={"spacing_m": 10})``);
unknown keys and out-of-range values raise ``ValueError`` naming the field, highway-env's own
keys included (:mod:`rhs_env.highway_config`: target speeds, lane ids against ``lanes_count``,
``policy_frequency`` dividing ``simulation_frequency``, ...), and a key given both ways with
different values (``config={"lanes_count": 2}, lanes_count=3``) names both. ``reset`` takes numpy
integer seeds (as stable-baselines3 passes them); a ``step`` after the episode ended warns once.
Landmarks are arrays on the env (``env.unwrapped.landmarks``, a
:class:`rhs_env.scene.Landmarks`), never highway-env road objects, so they do
not appear in the Kinematics observation and cannot end an episode. ``info``
gets ``world_pose`` = (x, y, heading) of the ego in the world frame.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from highway_env import utils
from highway_env.envs.highway_env import HighwayEnv
from highway_env.road.lane import LineType, StraightLane
from highway_env.road.road import Road, RoadNetwork

from rhs_common.validation import check_bool, check_choice, check_int, check_memory, check_range
from rhs_env.highway_config import check_highway_config, check_numbers, compiled_unsupported, merge_config, plain
from rhs_env.scene import (
    DENSE_LANDMARKS,
    MAX_SCATTER_RANGE_M,
    LandmarkConfig,
    Landmarks,
    place_roadside_landmarks,
    world_pose,
)

#: the paper's obstacles (world frame, m) and start pose
PAPER_OBSTACLES = ((10.0, 65.0), (25.0, 10.0), (30.0, 65.0), (35.0, 10.0), (50.0, 65.0))
PAPER_START = (0.0, 37.5)
#: bound of the paper scene's coordinates, m (that of ``road_start_m``): doubles keep 1e-11 m there
MAX_WORLD_M = 1e5

LANDMARK_COLOR = (60, 220, 60)
#: most obstacles of the paper scene: each is a scatterer of every sweep (10 000 made a step last minutes)
MAX_OBSTACLES = 1000
#: half the ego's box (highway-env's Vehicle: 5 m x 2 m): an obstacle inside it at the start is refused
EGO_HALF_LENGTH_M, EGO_HALF_WIDTH_M = 2.5, 1.0
#: smallest ``scaling`` (pixels per metre): a 600 px view of 60 km; highway-env draws a lane's stripes over the
#: whole view, ``2 (W + H) / (STRIPE_SPACING scaling)`` of them, so 1e-9 asked for 2.7 TiB
MIN_SCALING = 0.01
#: highway-env's reward weights and their bound (a sum of 1e308s overflows to inf)
REWARD_KEYS = ("collision_reward", "right_lane_reward", "high_speed_reward", "lane_change_reward")
MAX_REWARD = 1e6
#: the keys ``reset(options=...)`` takes (highway-env's: a config update before the reset)
RESET_OPTIONS = ("config",)


class EnvClosedError(gym.error.ClosedEnvironmentError, RuntimeError):
    """``step`` or ``render`` after ``close``."""


def check_reset_options(options: Any) -> None:
    """``TypeError`` unless ``options`` is None or a dict, ``ValueError`` for keys other than :data:`RESET_OPTIONS`."""
    if options is None:
        return
    if not isinstance(options, Mapping):
        raise TypeError(f"reset options must be None or a dict such as {{'config': {{...}}}}, got {options!r} "
                        f"({type(options).__name__})")
    unknown = sorted(str(k) for k in options if k not in RESET_OPTIONS)
    if unknown:
        raise ValueError(f"reset options has unknown key(s) {', '.join(map(repr, unknown))}; allowed: "
                         f"{', '.join(RESET_OPTIONS)}")


def check_manual_control(render_mode: str | None) -> None:
    """``ValueError`` unless ``manual_control=True`` can work: the keyboard of a ``render_mode="human"`` window.

    Without that window highway-env drops the agent's actions and reads no keys: the ego would drive uncontrolled.
    """
    import os

    if render_mode != "human":
        raise ValueError(f"manual_control=True steers the ego from the keyboard of the render window: it needs "
                         f"render_mode='human', got render_mode={render_mode!r}")
    if os.environ.get("SDL_VIDEODRIVER") == "dummy" or not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ValueError("manual_control=True needs a display for its window (DISPLAY / WAYLAND_DISPLAY unset or "
                         "SDL_VIDEODRIVER=dummy); set manual_control=False")


def check_display_config(config: Mapping[str, Any], defaults: Mapping[str, Any]) -> None:
    """The checks every rhs env makes first: the value types against ``defaults``, the screen size, the scaling and
    the frame's memory (:func:`check_render_memory`)."""
    check_config_types(config, defaults)
    check_range("screen_width", config["screen_width"], 1, 4096)
    check_range("screen_height", config["screen_height"], 1, 4096)
    check_range("scaling", config["scaling"], MIN_SCALING, 1000.0)
    check_render_memory(config)


def check_render_memory(config: Mapping[str, Any]) -> None:
    """``ValueError`` (:func:`rhs_common.validation.check_memory`) when a frame's lane stripes would exhaust memory."""
    from highway_env.road.graphics import LaneGraphics

    w, h, scaling = int(config["screen_width"]), int(config["screen_height"]), float(config["scaling"])
    stripes = 2 * (w + h) / (LaneGraphics.STRIPE_SPACING * scaling)
    check_memory(f"screen_width + screen_height = {w} + {h} px at scaling={scaling:g} px/m: {stripes:.3g} lane "
                 "stripes per frame", stripes * 8 * 4)


def check_config_types(config: Mapping[str, Any], defaults: Mapping[str, Any]) -> None:
    """``TypeError`` naming the first config key whose value's kind differs from its default's.

    Applies to the scalar keys: a default bool needs a bool; a default number
    (int or float) a real number, finite (``duration="40"`` or ``collision_reward=None``
    would otherwise fail deep inside highway-env). The range checks follow in
    ``_validate_config``.
    """
    for key, default in defaults.items():
        value = config.get(key, default)
        if isinstance(default, bool):
            check_bool(key, value)
        elif isinstance(default, (int, float)):
            check_range(key, value)  # a finite number; the ranges of the keys we use follow


def check_action(space: gym.spaces.Space, action: Any) -> Any:
    """``action`` as the env's action space takes it, or a clear error naming the space.

    ``Discrete(n)``: an integer (Python or numpy, or a one-element integer array) in
    ``[start, start + n - 1]``; other types raise ``TypeError`` (``None``, ``"a"``,
    ``2.5``), other values ``ValueError`` (``7``, ``-1``). ``Box``: a finite array of the
    space's shape. Other spaces: ``space.contains(action)``.
    """
    if isinstance(space, gym.spaces.Discrete):
        a = action
        if isinstance(a, np.ndarray) and a.size == 1 and a.ndim <= 1:
            a = a.reshape(())[()]
        lo, hi = int(space.start), int(space.start + space.n - 1)
        if not isinstance(a, (int, np.integer)) or isinstance(a, (bool, np.bool_)):
            raise TypeError(f"action must be an integer in [{lo}, {hi}] (action space {space}), "
                            f"got {action!r} ({type(action).__name__})")
        if not lo <= int(a) <= hi:
            raise ValueError(f"action must be in [{lo}, {hi}] (action space {space}), got {action!r}")
        return int(a)
    if isinstance(space, gym.spaces.Box):
        try:
            kind = np.asarray(action).dtype.kind
            if kind not in "iuf":  # strings ("1.0" would convert), booleans, objects: not numbers
                raise TypeError(kind)
            a = np.asarray(action, dtype=float)
        except (TypeError, ValueError):
            raise TypeError(f"action must be an array of shape {space.shape} (action space {space}), "
                            f"got {action!r} ({type(action).__name__})") from None
        if a.shape != space.shape or not np.all(np.isfinite(a)):
            raise ValueError(f"action must be a finite array of shape {space.shape} (action space {space}), got {action!r}")
        return a
    if not space.contains(action):
        raise ValueError(f"action {action!r} is not in the action space {space}")
    return action


class RHSHighwayEnv(HighwayEnv):
    """Highway with traffic and static roadside landmarks (the RHS radar's map features).

    Extra config keys beyond highway-env's ``HighwayEnv``:
        landmarks: dict of :class:`rhs_env.scene.LandmarkConfig` fields (validated).
    """

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        utils.update_config(
            config,
            {
                "lanes_count": 4,
                "vehicles_count": 30,
                "duration": 40,  # [s] -> 200 cycles at 5 Hz
                "policy_frequency": 5,  # [Hz] = radar / SLAM cycle rate
                "simulation_frequency": 15,  # [Hz], a multiple of policy_frequency
                "ego_spacing": 2,
                "vehicles_density": 1,
                "screen_width": 600,
                "screen_height": 200,  # room for the roadside landmarks
                "landmarks": LandmarkConfig().to_dict(),
                # who steps the traffic (rhs_env.traffic): "auto" the compiled core where it ports the config and
                # the scene, else highway-env; "compiled" the core (an unported config is an error); "highway-env"
                "sim": "auto",
            },
        )
        return config

    def __init__(self, config: dict | None = None, render_mode: str | None = None, **kwargs: Any) -> None:
        if render_mode is not None:
            check_choice("render_mode", render_mode, tuple(self.metadata["render_modes"]))
        if config is not None and not isinstance(config, Mapping):
            raise TypeError(f"config must be a dict of config keys, got {config!r} ({type(config).__name__})")
        self._ended = self._warned_after_end = self._closed = False
        super().__init__(merge_config(config, kwargs), render_mode)
        if self.config["manual_control"]:
            check_manual_control(render_mode)

    def close(self) -> None:
        """highway-env's close; ``step`` and ``render`` then raise :class:`EnvClosedError` until ``reset``."""
        self._closed = True
        super().close()

    def _check_open(self, call: str, scene: bool = True) -> None:
        """:class:`EnvClosedError` after ``close()``; with ``scene``, ``ResetNeeded`` after a refused ``reset()``."""
        if getattr(self, "_closed", False):
            raise EnvClosedError(f"{call}() called after close(); call reset() to start a new episode, "
                                 "or make a new env")
        if scene and getattr(self, "_reset_refused", False):  # the last reset raised: no episode to go on with
            raise gym.error.ResetNeeded(f"{call}() after a reset() that raised an error: call reset() again "
                                        "with valid arguments")

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """highway-env's reset. ``seed``: None or an integer >= 0; a numpy integer (``np.int64(5)``, as
        stable-baselines3 and ``np.random`` hand them out) is taken as the Python int of the same
        value (gymnasium itself accepts only ``int``). Other types raise ``TypeError``, negative
        seeds ``ValueError``, both naming ``seed``."""
        try:
            if seed is not None:
                if not isinstance(seed, (int, np.integer)) or isinstance(seed, (bool, np.bool_)):
                    raise TypeError(f"seed must be None or an integer >= 0, got {seed!r} ({type(seed).__name__})")
                if seed < 0:
                    raise ValueError(f"seed must be None or an integer >= 0, got {seed!r}")
                seed = int(seed)
            check_reset_options(options)
            self._ended = self._warned_after_end = self._closed = self._reset_refused = False
            return super().reset(seed=seed, options=options)
        except Exception:
            self._reset_refused = True  # no episode to go on with: a step raises ResetNeeded until a reset works
            raise

    def step(self, action: Any):
        """highway-env's step after :func:`check_action` (a clear error naming the action space).

        A step after the episode ended (``terminated`` or ``truncated`` returned, no ``reset()``
        since) warns once per episode, as gymnasium's order checks do, and is then carried out
        (highway-env keeps simulating).
        """
        self._check_open("step")
        action = check_action(self.action_space, action)
        if self._ended and not self._warned_after_end:
            self._warned_after_end = True
            warnings.warn("step() called after the episode ended (terminated or truncated); call reset() to start "
                          "a new episode: the steps after the end are not part of it", UserWarning, stacklevel=2)
        result = super().step(action)
        self._ended = self._ended or bool(result[2] or result[3])
        return result

    # ---- traffic: highway-env's Python, or the compiled core (config "sim", :mod:`rhs_env.traffic`)
    def _compiled_traffic(self) -> Any:
        """The env's :class:`rhs_env.traffic.engine.CompiledTraffic` when it steps the current scene, else None.

        ``sim="compiled"``: always (an unported scene raises); ``sim="auto"``: when the config and the scene are
        ones the core ports (:func:`rhs_env.highway_config.compiled_unsupported`,
        :func:`rhs_env.traffic.state.unsupported`); ``sim="highway-env"`` (or a config without ``sim``): never.
        """
        sim = self.config.get("sim")
        if sim not in ("auto", "compiled") or (sim == "auto" and compiled_unsupported(self.config)):
            return None
        traffic = getattr(self, "_traffic", None)
        if traffic is None or traffic[0] is not self.road or traffic[1].strict != (sim == "compiled"):
            from rhs_env.traffic.engine import CompiledTraffic  # a new scene (reset): pack it again

            traffic = self._traffic = (self.road, CompiledTraffic(strict=sim == "compiled"))
        return traffic[1] if traffic[1].supports(self) else None

    @property
    def traffic_sim(self) -> str:
        """Who steps the current scene's traffic: ``"compiled"`` (:mod:`rhs_env.traffic`) or ``"highway-env"`` (before
        the first reset: what the config selects)."""
        if getattr(self, "road", None) is None or getattr(self.action_type, "controlled_vehicle", None) is None:
            sim = self.config.get("sim")
            ported = sim == "compiled" or (sim == "auto" and not compiled_unsupported(self.config))
            return "compiled" if ported else "highway-env"
        return "highway-env" if self._compiled_traffic() is None else "compiled"

    def _simulate(self, action: Any = None) -> None:
        traffic = self._compiled_traffic()
        if traffic is None or not traffic.simulate(self, action):
            super()._simulate(action)

    def _rewards(self, action: Any) -> dict[str, float]:
        traffic = self._compiled_traffic()
        return HighwayEnv._rewards(self, action) if traffic is None else traffic.rewards(self)

    def _reward(self, action: Any) -> float:
        traffic = self._compiled_traffic()
        return HighwayEnv._reward(self, action) if traffic is None else traffic.reward(self)

    # ---- configuration
    def configure(self, config: dict | None) -> None:
        """Update the config (validated: unknown keys and bad values raise ``ValueError``)."""
        if config:
            known = set(self.default_config()) | set(self.config)
            unknown = sorted(set(config) - known)
            if unknown:
                raise ValueError(
                    f"unknown config key(s) {', '.join(map(repr, unknown))} for {type(self).__name__}; "
                    f"allowed: {', '.join(sorted(known))}"
                )
            config = dict(config)
            if "landmarks" in config:
                # merge a partial dict onto the current landmark settings
                current = dict(self.config.get("landmarks") or {})
                lm = config["landmarks"]
                if isinstance(lm, LandmarkConfig):
                    lm = lm.to_dict()
                if lm is not None and not isinstance(lm, Mapping):
                    raise ValueError(f"landmarks must be a dict of LandmarkConfig fields, got {type(lm).__name__}")
                current.update(lm or {})
                config["landmarks"] = current
        super().configure(config)
        self._validate_config()

    def _validate_config(self) -> None:
        c = self.config
        check_display_config(c, self.default_config())
        check_int("lanes_count", c["lanes_count"], 1, 20)
        check_int("vehicles_count", c["vehicles_count"], 0, 500)
        check_int("controlled_vehicles", c["controlled_vehicles"], 1, 10)
        check_range("duration", c["duration"], 0.0, 3600.0, low_open=True)
        check_range("simulation_frequency", c["simulation_frequency"], 1.0, 1000.0)
        check_range("policy_frequency", c["policy_frequency"], 0.0, c["simulation_frequency"], low_open=True)
        check_range("vehicles_density", c["vehicles_density"], 0.0, 100.0, low_open=True)
        check_range("ego_spacing", c["ego_spacing"], 0.0, 100.0)  # 0: as highway-env, the ego at the lane start
        for key in REWARD_KEYS:
            check_range(key, c[key], -MAX_REWARD, MAX_REWARD)
        if c["normalize_reward"] and not c["collision_reward"] < c["high_speed_reward"] + c["right_lane_reward"]:
            raise ValueError(
                "normalize_reward maps [collision_reward, high_speed_reward + right_lane_reward] onto [0, 1]: it needs "
                f"collision_reward < high_speed_reward + right_lane_reward, got {c['collision_reward']!r} and "
                f"{c['high_speed_reward']!r} + {c['right_lane_reward']!r}; or set normalize_reward=False")
        check_highway_config(c)
        self.landmark_config = LandmarkConfig.make(c["landmarks"])
        c["landmarks"] = self.landmark_config.to_dict()

    # ---- scene
    def _reset(self) -> None:
        self._create_road()
        self._create_landmarks()
        self._create_vehicles()

    def _create_landmarks(self) -> None:
        """Place the roadside landmarks (drawn from ``np_random`` before the traffic)."""
        self.landmarks: Landmarks = place_roadside_landmarks(self.road.network, self.landmark_config, self.np_random)

    def _is_truncated(self) -> bool:
        """Time limit, robust to the float sum of 1 / policy_frequency steps."""
        return self.time >= self.config["duration"] - 1e-6

    def _info(self, obs, action=None) -> dict:
        info = super()._info(obs, action)
        info["world_pose"] = world_pose(self.vehicle)
        return info

    # ---- rendering
    def render(self) -> np.ndarray | None:
        """highway-env's render with the landmarks drawn over the road (headless with rgb_array)."""
        if self.render_mode is None:  # highway-env's warning; after close() the error
            self._check_open("render", scene=False)
            return super().render()
        self._check_open("render")
        from highway_env.envs.common.graphics import EnvViewer

        viewer: Any = self.viewer  # type: ignore[has-type]  # highway-env's EnvViewer, made on the first render
        if viewer is None:
            viewer = self.viewer = EnvViewer(self)
            if viewer.offscreen:
                # highway-env disables its viewer under SDL_VIDEODRIVER=dummy, but
                # offscreen drawing needs no display: keep rgb_array working headless.
                viewer.enabled = True
        self.enable_auto_render = True
        viewer.display()
        self._draw_landmarks()
        if not viewer.offscreen:
            import pygame

            viewer.screen.blit(viewer.sim_surface, (0, 0))
            pygame.display.flip()
            viewer.handle_events()
        if self.render_mode == "rgb_array":
            return viewer.get_image()
        return None

    def _draw_landmarks(self) -> None:
        import pygame

        lms = getattr(self, "landmarks", None)
        if not self.viewer.enabled or not isinstance(lms, Landmarks) or len(lms) == 0 or self.vehicle is None:
            return
        surface = self.viewer.sim_surface
        view_m = np.hypot(surface.get_width(), surface.get_height()) / surface.scaling
        center = np.asarray(surface.origin, float) + np.array([surface.get_width(), surface.get_height()]) / (
            2 * surface.scaling
        )
        radius = max(3, surface.pix(0.6))
        for i in lms.near(center, view_m):
            pygame.draw.circle(surface, LANDMARK_COLOR, surface.vec2pix(lms.xy_he[i]), radius)


class RHSDenseEnv(RHSHighwayEnv):
    """The highway with a dense roadside (``rhs-dense-v0``): :data:`rhs_env.scene.DENSE_LANDMARKS`.

    Guard-rail posts every 2.5 m, paired poles (2 m apart) every 20 m and sign gantries
    every 150 m: many scatterers a few degrees apart, where the antenna's angular
    resolution matters. A ``landmarks`` dict given by the caller is merged onto this
    preset (``landmarks={"post_spacing_m": 3.0}`` keeps the rest).
    """

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        config["landmarks"] = DENSE_LANDMARKS.to_dict()
        return config


class RHSPaperEnv(RHSHighwayEnv):
    """The paper's Fig. 5c scenario: five obstacles beside a straight road, 50 cycles.

    Extra config keys:
        obstacles: list of [x, y] obstacle positions in the world frame (m); a flat list of
            numbers is refused. Each within the road's x extent +- 1000 m and within 1000 m of
            the start y (:data:`rhs_env.scene.MAX_SCATTER_RANGE_M`: nothing farther is ever
            handed to the radar, so such an obstacle could never be seen).
        obstacle_rcs_m2: their RCS (m^2).
        start: [x, y] start position of the ego in the world frame, heading +x; finite, x on the
            road, |y| <= 1e5 m (:data:`MAX_WORLD_M`).
        ego_speed: ego speed (m/s); the action's target speeds are built around it.
        road_start_m, road_length_m: extent of the road along x.
    The ``landmarks`` (roadside) are disabled by default; the obstacles are the map.
    """

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        utils.update_config(
            config,
            {
                "lanes_count": 3,
                "vehicles_count": 0,
                "duration": 10,  # [s] -> 50 cycles at 5 Hz
                "policy_frequency": 5,
                "simulation_frequency": 15,
                "ego_speed": 6.0,  # [m/s] -> 60 m in 10 s
                "action": {"type": "DiscreteMetaAction", "target_speeds": [0.0, 3.0, 6.0, 9.0]},
                "reward_speed_range": [3.0, 9.0],
                "obstacles": [list(p) for p in PAPER_OBSTACLES],
                "obstacle_rcs_m2": 5.0,
                "start": list(PAPER_START),
                "road_start_m": -50.0,
                "road_length_m": 400.0,
                "landmarks": {**LandmarkConfig().to_dict(), "enabled": False},
                "screen_width": 600,
                "screen_height": 400,
                "scaling": 5.0,
                "centering_position": [0.3, 0.5],
            },
        )
        return config

    def _validate_config(self) -> None:
        super()._validate_config()
        c = self.config
        check_range("ego_speed", c["ego_speed"], 0.0, 40.0)
        check_range("obstacle_rcs_m2", c["obstacle_rcs_m2"], 0.0, 1e4, low_open=True)
        check_range("road_length_m", c["road_length_m"], 10.0, 1e5)
        check_range("road_start_m", c["road_start_m"], -1e5, 1e5)
        start = check_numbers("start", c["start"], 2, -MAX_WORLD_M, MAX_WORLD_M)
        c["start"] = plain(c["start"])
        x0, length = float(c["road_start_m"]), float(c["road_length_m"])
        if not x0 < start[0] < x0 + length:
            raise ValueError(
                f"start x must lie on the road, in ({x0}, {x0 + length}) (road_start_m, road_start_m + road_length_m), "
                f"got {start[0]}"
            )
        obstacles = c["obstacles"]
        if isinstance(obstacles, np.ndarray):
            obstacles = obstacles.tolist()
        if not isinstance(obstacles, (list, tuple)):
            raise TypeError(f"obstacles must be a list of [x, y] pairs in metres, got {obstacles!r} "
                            f"({type(obstacles).__name__})")
        if any(not isinstance(p, (list, tuple, np.ndarray)) for p in obstacles):
            raise TypeError(f"obstacles must be a list of [x, y] pairs in metres (e.g. [[10, 65], [25, 10]]), "
                            f"not a flat list of numbers; got {c['obstacles']!r}")
        if len(obstacles) > MAX_OBSTACLES:
            raise ValueError(f"obstacles must hold at most {MAX_OBSTACLES} [x, y] pairs (each is a scatterer every "
                             f"radar sweep synthesises), got {len(obstacles)}")
        reach = MAX_SCATTER_RANGE_M
        for i, p in enumerate(obstacles):
            x, y = check_numbers(f"obstacles[{i}]", p, 2)
            if abs(x - start[0]) <= EGO_HALF_LENGTH_M and abs(y - start[1]) <= EGO_HALF_WIDTH_M:
                raise ValueError(f"obstacles[{i}] = [{x:g}, {y:g}] lies on the ego at its start = [{start[0]:g}, "
                                 f"{start[1]:g}] (within +-{EGO_HALF_LENGTH_M:g} m along x, +-{EGO_HALF_WIDTH_M:g} m "
                                 "across): move it or the start")
            if not (x0 - reach <= x <= x0 + length + reach and abs(y - start[1]) <= reach):
                raise ValueError(
                    f"obstacles[{i}] = [{x:g}, {y:g}] is beyond what the radar can see from the road: x must be in "
                    f"[{x0 - reach:g}, {x0 + length + reach:g}] (the road, road_start_m .. road_start_m + "
                    f"road_length_m, +-{reach:g} m) and y within +-{reach:g} m of start y = {start[1]:g} "
                    f"({reach:g} m: the farthest any object is handed to the radar)")
        c["obstacles"] = plain(c["obstacles"])

    def _create_road(self) -> None:
        """Straight lanes along +x centred on the start y (world), i.e. highway-env y = -start_y."""
        n = int(self.config["lanes_count"])
        width = StraightLane.DEFAULT_WIDTH
        x0, length = float(self.config["road_start_m"]), float(self.config["road_length_m"])
        y_center_he = -float(self.config["start"][1])
        net = RoadNetwork()
        for k in range(n):
            y = y_center_he + (k - (n - 1) / 2) * width
            line_types = [
                LineType.CONTINUOUS_LINE if k == 0 else LineType.STRIPED,
                LineType.CONTINUOUS_LINE if k == n - 1 else LineType.NONE,
            ]
            net.add_lane("a", "b", StraightLane([x0, y], [x0 + length, y], line_types=line_types, speed_limit=30))
        self.road = Road(
            network=net,
            np_random=self.np_random,
            record_history=self.config["show_trajectories"],
            neighbour_vehicles_connected_lanes=self.config["neighbour_vehicles_connected_lanes"],
        )

    def _create_landmarks(self) -> None:
        super()._create_landmarks()
        obstacles = Landmarks.from_world(np.asarray(self.config["obstacles"], float), self.config["obstacle_rcs_m2"])
        # the paper's obstacles first: ids 0..4 are the obstacles in the listed order
        self.landmarks = obstacles.concat(self.landmarks)

    def _create_vehicles(self) -> None:
        """The ego exactly at the start position heading +x; optional traffic ahead."""
        start_he = np.array([float(self.config["start"][0]), -float(self.config["start"][1])])
        ego = self.action_type.vehicle_class(self.road, start_he, 0.0, float(self.config["ego_speed"]))
        self.controlled_vehicles = [ego]
        self.road.vehicles.append(ego)
        other_type = utils.class_from_path(self.config["other_vehicles_type"])
        for _ in range(int(self.config["vehicles_count"])):
            v = other_type.create_random(self.road, spacing=1 / self.config["vehicles_density"])
            v.randomize_behavior()
            self.road.vehicles.append(v)


__all__ = [
    "EnvClosedError", "MAX_OBSTACLES", "PAPER_OBSTACLES", "PAPER_START", "RHSDenseEnv", "RHSHighwayEnv", "RHSPaperEnv",
    "check_action", "check_config_types", "check_display_config", "check_manual_control", "check_render_memory",
    "check_reset_options",
]
