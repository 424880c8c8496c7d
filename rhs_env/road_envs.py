"""highway-env's other roads for the RHS radar: merge, roundabout, intersection, exit and racetrack.

Each class is highway-env's own env of that road (``MergeEnv``, ``RoundaboutEnv``,
``IntersectionEnv``, ``ExitEnv``, ``RacetrackEnv``: its road network, traffic, rewards,
termination and **default action type**) with what :class:`rhs_env.envs.RHSHighwayEnv`
adds to the highway: static roadside landmarks along every lane edge of the network
(:func:`rhs_env.scene.place_roadside_landmarks`: curves, ramps and junctions included,
none inside a lane), ``info["world_pose"]``, the landmarks drawn in ``render()``, and
validated config (unknown keys and bad values raise ``ValueError`` naming the field).

The one change to highway-env's defaults is the decision rate: ``policy_frequency``
= 5 Hz, the radar / SLAM cycle rate (highway-env's 1 Hz moves the car 8-30 m between
scans, more than the landmark spacing, and the SLAM's association aliases). The
racetrack already runs at 5 Hz. The exit road simulates at 15 Hz as the others (highway-env's
5 Hz there, one frame per cycle, lost the SLAM in its dense traffic: :class:`RHSExitEnv`). The intersection spawns traffic once per action
(``spawn_probability``), so at 5 Hz its traffic is denser than highway-env's at 1 Hz.

========================  =========================================  ==========================================
class                     highway-env env                            default action (highway-env's)
========================  =========================================  ==========================================
:class:`RHSMergeEnv`      ``merge-v0`` (ends past x = 370 m)         ``DiscreteMetaAction``
:class:`RHSRoundaboutEnv` ``roundabout-v0`` (11 s)                   ``DiscreteMetaAction``, speeds 0 / 8 / 16
:class:`RHSIntersectionEnv` ``intersection-v0`` (13 s)               ``DiscreteMetaAction``, longitudinal only
:class:`RHSExitEnv`       ``exit-v0`` (18 s)                         ``DiscreteMetaAction``, speeds 18 / 24 / 30
:class:`RHSRacetrackEnv`  ``racetrack-v0`` (300 s)                   ``ContinuousAction``, steering only
========================  =========================================  ==========================================

The landmarks are placed after highway-env has built the road and its traffic, from
the same ``np_random``: the traffic of a seed is the traffic highway-env's env draws for
it (at the same config), and the landmarks are a function of the seed too.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any, ClassVar

from highway_env import utils
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.exit_env import ExitEnv
from highway_env.envs.intersection_env import IntersectionEnv
from highway_env.envs.merge_env import MergeEnv
from highway_env.envs.racetrack_env import RacetrackEnv
from highway_env.envs.roundabout_env import RoundaboutEnv

from rhs_common.validation import check_int, check_range
from rhs_env.envs import RHSHighwayEnv, check_display_config
from rhs_env.highway_config import CHECKS
from rhs_env.scene import LandmarkConfig

__all__ = [
    "ROAD_ENVS", "RHSExitEnv", "RHSIntersectionEnv", "RHSMergeEnv", "RHSRacetrackEnv", "RHSRoadEnv",
    "RHSRoundaboutEnv", "intersection_vehicle_type", "make_exit_radar", "make_intersection_radar", "make_merge_radar",
    "make_racetrack_radar", "make_road_radar", "make_roundabout_radar",
]

#: the decision / radar / SLAM cycle rate of every road, Hz
CYCLE_HZ = 5


class RHSRoadEnv(RHSHighwayEnv):
    """Base of the road scenes: highway-env's env :attr:`ROAD` with the RHS landmarks, checks and rendering.

    A subclass lists ``(RHSRoadEnv, <highway-env env>)`` as its bases. The method resolution order is then
    ``RHSRoadEnv``, :class:`RHSHighwayEnv` (reset / step / render / config checks), highway-env's ``HighwayEnv``,
    the road's env, ``AbstractEnv``: whatever the road's env and ``HighwayEnv`` both define (its road, traffic,
    rewards, termination, default config) is taken from :attr:`ROAD` here, so ``HighwayEnv`` contributes nothing.

    Extra config key beyond the road's: ``landmarks`` (:class:`rhs_env.scene.LandmarkConfig` fields).
    """

    #: highway-env's env of this road
    ROAD: ClassVar[type[AbstractEnv]]
    #: highway-env observation types of this road accepted beside :data:`rhs_env.highway_config.OBSERVATION_TYPES`
    OWN_OBSERVATIONS: ClassVar[tuple[str, ...]] = ()
    #: this road's changes to highway-env's config
    RHS_DEFAULTS: ClassVar[dict[str, Any]] = {}

    @classmethod
    def default_config(cls) -> dict:
        config = cls.ROAD.default_config()
        utils.update_config(config, {"policy_frequency": CYCLE_HZ, "landmarks": LandmarkConfig().to_dict(),
                                     **cls.RHS_DEFAULTS})
        return config

    # ---- the road's own scene, traffic, rewards and ends (RHSHighwayEnv / HighwayEnv define these too)
    #: ``reset`` keeps the landmarks of the previous episode when :attr:`keep_landmarks` is set (the SLAM
    #: wrapper's ``reset(options={"keep_map": True})``: the same world, mapped before); read once, then cleared
    keep_landmarks = False

    def _reset(self) -> None:
        self.ROAD._reset(self)
        previous = getattr(self, "landmarks", None) if self.keep_landmarks else None
        self._create_landmarks()  # drawn in any case: the traffic's draws after it stay the same
        if previous is not None:
            self.landmarks = previous
        self.keep_landmarks = False

    def _reward(self, action: Any) -> float:
        return self.ROAD._reward(self, action)

    def _rewards(self, action: Any) -> dict[str, float]:
        return self.ROAD._rewards(self, action)

    def _is_terminated(self) -> bool:
        return self.ROAD._is_terminated(self)

    def _is_truncated(self) -> bool:
        return self.ROAD._is_truncated(self)

    # ---- configuration
    def _validate_config(self) -> None:
        """The checks of :class:`RHSHighwayEnv` that apply to every road (the keys this road has)."""
        c = self.config
        check_display_config(c, self.default_config())
        check_range("simulation_frequency", c["simulation_frequency"], 1.0, 1000.0)
        check_range("policy_frequency", c["policy_frequency"], 0.0, c["simulation_frequency"], low_open=True)
        for key, high in (("controlled_vehicles", 10), ("vehicles_count", 500), ("initial_vehicle_count", 500), ("lanes_count", 20),
                          ("other_vehicles", 500)):
            if key in c:
                check_int(key, c[key], 1 if key in ("controlled_vehicles", "lanes_count") else 0, high)
        if "duration" in c:
            check_range("duration", c["duration"], 0.0, 3600.0, low_open=True)
        if "vehicles_density" in c:
            check_range("vehicles_density", c["vehicles_density"], 0.0, 100.0, low_open=True)
        if "spawn_probability" in c:
            check_range("spawn_probability", c["spawn_probability"], 0.0, 1.0)
        own = isinstance(c.get("observation"), dict) and c["observation"].get("type") in self.OWN_OBSERVATIONS
        for key, check in CHECKS.items():
            if key in c and not (own and key == "observation"):
                check(c)
        self.landmark_config = LandmarkConfig.make(c["landmarks"])
        c["landmarks"] = self.landmark_config.to_dict()


class RHSMergeEnv(RHSRoadEnv, MergeEnv):
    """highway-env's ``merge-v0`` (a two-lane highway, a ramp merging from the right) with roadside landmarks.

    The episode ends when the ego passes x = 370 m or crashes (highway-env's; no time limit).
    """

    ROAD = MergeEnv


class RHSRoundaboutEnv(RHSRoadEnv, RoundaboutEnv):
    """highway-env's ``roundabout-v0`` (a two-lane ring of radius 20 m, four approaches) with landmarks
    beyond the ring's outer edge, on its central island and along the approaches."""

    ROAD = RoundaboutEnv


def intersection_vehicle_type(type_path: str) -> str:
    """The import path of a subclass of ``type_path`` private to the intersection (made once per class).

    highway-env's intersection sets ``DISTANCE_WANTED``, ``COMFORT_ACC_MAX`` and ``COMFORT_ACC_MIN`` on the other
    vehicles' *class* when it builds its traffic, so every env made later in the process (a highway, a SLAM env)
    drove with the intersection's IDM constants. On the subclass the same values reach the intersection's
    vehicles only.
    """
    base = utils.class_from_path(type_path)
    if base.__module__ == __name__:
        return type_path
    name = f"Intersection{base.__name__}"
    if name not in globals():
        globals()[name] = type(name, (base,), {"__module__": __name__, "__qualname__": name})
    return f"{__name__}.{name}"


class RHSIntersectionEnv(RHSRoadEnv, IntersectionEnv):
    """highway-env's ``intersection-v0`` (a four-way junction the ego crosses to its destination) with landmarks beside
    the approaches and the corners' kerbs. Its traffic is highway-env's; the IDM constants highway-env sets for it
    stay on a private subclass (:func:`intersection_vehicle_type`)."""

    ROAD = IntersectionEnv

    @contextlib.contextmanager
    def _private_vehicle_type(self) -> Iterator[None]:
        original = self.config["other_vehicles_type"]
        self.config["other_vehicles_type"] = intersection_vehicle_type(original)
        try:
            yield
        finally:
            self.config["other_vehicles_type"] = original

    def _make_vehicles(self, n_vehicles: int = 10) -> None:
        with self._private_vehicle_type():
            super()._make_vehicles(n_vehicles)

    def _spawn_vehicle(self, *args: Any, **kwargs: Any) -> Any:
        with self._private_vehicle_type():
            return super()._spawn_vehicle(*args, **kwargs)


class RHSExitEnv(RHSRoadEnv, ExitEnv):
    """highway-env's ``exit-v0`` (a six-lane highway with an exit lane and a curved off-ramp) with landmarks.

    Simulated at 15 Hz (highway-env's exit: 5 Hz, one frame per radar cycle, under which the SLAM lost the car
    among the exit's dense traffic: 52 m worst error on a seed where 15 Hz gives 0.07 m); the other roads
    simulate at 15 Hz already. Its own observation ``ExitObservation`` is accepted on ``rhs-exit-v0``.
    """

    ROAD = ExitEnv
    OWN_OBSERVATIONS = ("ExitObservation",)
    RHS_DEFAULTS: ClassVar[dict[str, Any]] = {"simulation_frequency": 15}


class RHSRacetrackEnv(RHSRoadEnv, RacetrackEnv):
    """highway-env's ``racetrack-v0`` (a closed two-lane circuit of straights and arcs) with landmarks
    beside both edges. highway-env's default action: ``ContinuousAction`` with lateral control only
    (steering in [-1, 1]; the speed is the controller's)."""

    ROAD = RacetrackEnv


#: road name -> env class (the ids ``rhs-<road>-v0``, ``rhs-<road>-radar-v0``, ``rhs-<road>-slam-v0``)
ROAD_ENVS: dict[str, type[RHSRoadEnv]] = {
    "merge": RHSMergeEnv,
    "roundabout": RHSRoundaboutEnv,
    "intersection": RHSIntersectionEnv,
    "exit": RHSExitEnv,
    "racetrack": RHSRacetrackEnv,
}


def make_road_radar(road: str, kwargs: dict[str, Any]) -> Any:
    """``rhs-<road>-radar-v0``: the road's scene (:data:`ROAD_ENVS`) under :class:`rhs_env.wrappers.RadarObservation`.

    Kwargs of :class:`RadarObservation` (by its signature) go to the wrapper, the rest (``config``,
    ``render_mode``, config keys) to the scene, as for ``rhs-highway-radar-v0``.

    Args:
        road: a key of :data:`ROAD_ENVS`.
        kwargs: the ``gym.make`` kwargs.

    Returns:
        The radar env.
    """
    from rhs_env.registration import check_vector_info_flags, route_kwargs, with_cheap_base_observation
    from rhs_env.wrappers import RadarObservation

    check_vector_info_flags(kwargs)
    (wrapper_kwargs,), env_kwargs = route_kwargs(kwargs, RadarObservation)
    return RadarObservation(ROAD_ENVS[road](**with_cheap_base_observation(env_kwargs)), **wrapper_kwargs)


def make_merge_radar(**kwargs: Any) -> Any:
    """``rhs-merge-radar-v0``: :class:`RHSMergeEnv` under the radar."""
    return make_road_radar("merge", kwargs)


def make_roundabout_radar(**kwargs: Any) -> Any:
    """``rhs-roundabout-radar-v0``: :class:`RHSRoundaboutEnv` under the radar."""
    return make_road_radar("roundabout", kwargs)


def make_intersection_radar(**kwargs: Any) -> Any:
    """``rhs-intersection-radar-v0``: :class:`RHSIntersectionEnv` under the radar."""
    return make_road_radar("intersection", kwargs)


def make_exit_radar(**kwargs: Any) -> Any:
    """``rhs-exit-radar-v0``: :class:`RHSExitEnv` under the radar."""
    return make_road_radar("exit", kwargs)


def make_racetrack_radar(**kwargs: Any) -> Any:
    """``rhs-racetrack-radar-v0``: :class:`RHSRacetrackEnv` under the radar."""
    return make_road_radar("racetrack", kwargs)
