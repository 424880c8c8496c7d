"""Gymnasium registration of the RHS environments (called on ``import rhs_env``).

Entry points are strings (``"module:callable"``), so subprocess vector envs
(``gym.make_vec(..., vectorization_mode="async")``, stable-baselines3's
``SubprocVecEnv``) can rebuild them after importing ``rhs_env``. Where a fresh
worker process looks an id up by name (stable-baselines3's
``make_vec_env(id, vec_env_cls=SubprocVecEnv)`` with the default forkserver
start method), write it ``"rhs_env:rhs-highway-radar-v0"``: gymnasium then
imports ``rhs_env`` first, which registers the ids. ``gym.make_vec`` needs no
prefix (it ships the resolved spec, whose entry point imports the package). Inside
``gym.make_vec`` the entry points refuse the info flags gymnasium cannot stack
(:func:`check_vector_info_flags`); :mod:`rhs_env.vector` has vector-env helpers whose faults are
named and never hang. Every id also registers a ``vector_entry_point`` (:func:`vector_entry_point`): the native
vector env of :mod:`rhs_env.vector_native`, ``gym.make_vec``'s choice when no ``vectorization_mode`` is given.

=========================  ==============================================  =====================
id                         entry point                                     observation
=========================  ==============================================  =====================
``rhs-highway-v0``         ``rhs_env.envs:RHSHighwayEnv``                  Kinematics (truth)
``rhs-highway-radar-v0``   ``rhs_env.registration:make_highway_radar``     radar point cloud
``rhs-highway-slam-v0``    ``slam.gym.envs:make_highway_slam``             cloud + SLAM
``rhs-paper-v0``           ``slam.gym.envs:make_paper_slam``               cloud + SLAM
``rhs-dense-v0``           ``slam.gym.envs:make_dense_slam``               cloud + SLAM
=========================  ==============================================  =====================

highway-env's other roads (:data:`ROAD_NAMES`: merge, roundabout, intersection, exit, racetrack), each with its
roadside landmarks, highway-env's traffic, rewards and default action (:mod:`rhs_env.road_envs`), get the same
three ids: ``rhs-<road>-v0`` (``rhs_env.road_envs:RHS<Road>Env``, highway-env's own observation),
``rhs-<road>-radar-v0`` (``rhs_env.road_envs:make_<road>_radar``) and ``rhs-<road>-slam-v0``
(``slam.gym.road_envs:make_<road>_slam``).

The fast variants (labelled, as highway-env's ``highway-fast-v0``): ``rhs-highway-radar-fast-v0``
(``rhs_env.registration:make_highway_radar_fast``) and ``rhs-highway-slam-fast-v0``
(``slam.gym.envs:make_highway_slam_fast``) draw the point cloud from the exact radar's measured detector
(``radar_model="fast"``, :mod:`rhs_env.fast_radar`). Policies trained on them are to be evaluated on the exact ids.

Traffic: every straight-road id (``rhs-highway-*``, ``rhs-dense-v0``, ``rhs-paper-v0``) steps its traffic with the
compiled core of :mod:`rhs_env.traffic` by default (``sim="auto"``: aligned with highway-env to the bit on these
scenes, ``results/traffic_alignment.md``), and with highway-env's own Python where the config or the scene is one
the core does not port (``sim="auto"`` falls back without an error; ``sim="compiled"`` makes that an error);
``sim="highway-env"`` selects the original. The ``rhs-<road>-*`` ids always run highway-env's own code.

Keyword arguments of ``gym.make`` go to the entry point: env config keys
(``lanes_count=3``, ``landmarks={"spacing_m": 10}``, ``config={...}``,
``render_mode="rgb_array"``) and the wrappers' own arguments, routed by their
signatures (:func:`route_kwargs`): ``radar={...}`` (``RadarConfig`` fields),
``antenna="phased"``, ``max_points=...``, ``scatter={...}`` for the radar;
``slam={...}``, ``registration=...``, ``icp={...}``, ``pipeline={...}`` for the
SLAM; ``map_gate_m``, ``landmarks_in_info`` for the SLAM metrics in ``info``;
``stage_times_in_info=True`` and ``blas_threads=1`` (BLAS / OpenMP threads
inside each step, restored after it; ``None`` opts into the process's own thread
pools, see :mod:`rhs_common.threads`) for both wrappers.
"""

from __future__ import annotations

import importlib
import inspect
import sys
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np

__all__ = [
    "DENSE_ID", "ENV_SPECS", "HIGHWAY_ID", "HIGHWAY_RADAR_FAST_ID", "HIGHWAY_RADAR_ID", "HIGHWAY_SLAM_FAST_ID",
    "HIGHWAY_SLAM_ID", "NULL_OBSERVATION", "PAPER_ID", "ROAD_NAMES", "SLAM_ENV_SPECS", "check_env_id", "fast_variant_kwargs",
    "make_highway_radar", "make_highway_radar_fast", "register_envs", "route_kwargs",
    "with_cheap_base_observation",
]

HIGHWAY_ID = "rhs-highway-v0"
HIGHWAY_RADAR_ID = "rhs-highway-radar-v0"
HIGHWAY_SLAM_ID = "rhs-highway-slam-v0"
PAPER_ID = "rhs-paper-v0"
HIGHWAY_RADAR_FAST_ID = "rhs-highway-radar-fast-v0"
HIGHWAY_SLAM_FAST_ID = "rhs-highway-slam-fast-v0"
DENSE_ID = "rhs-dense-v0"  # the highway with DENSE_LANDMARKS (guard-rail posts, paired poles, gantries)
#: highway-env's other roads (rhs_env.road_envs.ROAD_ENVS): ids rhs-<road>-v0, rhs-<road>-radar-v0, rhs-<road>-slam-v0
ROAD_NAMES = ("merge", "roundabout", "intersection", "exit", "racetrack")

def route_kwargs(kwargs: dict[str, Any], *wrappers: type) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Split ``gym.make`` kwargs among wrapper classes by their ``__init__`` signatures.

    A name every given wrapper accepts (``stage_times_in_info``) goes to each of them;
    whatever no wrapper accepts is returned last: the env's own kwargs (highway-env
    config keys, ``config``, ``render_mode``).
    """
    params = [set(inspect.signature(w).parameters) - {"env"} for w in wrappers]
    rest = {k: v for k, v in kwargs.items() if not any(k in p for p in params)}
    return [{k: v for k, v in kwargs.items() if k in p} for p in params], rest


def make_highway_radar(**kwargs: Any) -> gym.Env:
    """``rhs-highway-radar-v0``: :class:`RHSHighwayEnv` under :class:`RadarObservation`.

    Kwargs of :class:`RadarObservation` (by its signature) go to the wrapper, the
    rest (``config``, ``render_mode``, config keys) to the env.
    """
    from rhs_env.envs import RHSHighwayEnv
    from rhs_env.wrappers import RadarObservation

    check_vector_info_flags(kwargs)
    (wrapper_kwargs,), env_kwargs = route_kwargs(kwargs, RadarObservation)
    return RadarObservation(RHSHighwayEnv(**with_cheap_base_observation(env_kwargs)), **wrapper_kwargs)


def fast_variant_kwargs(kwargs: dict[str, Any], env_id: str) -> dict[str, Any]:
    """``kwargs`` of a ``-fast-`` id: ``radar_model="fast"`` (the traffic: the ids' default ``sim="auto"``).

    Args:
        kwargs: the ``gym.make`` kwargs.
        env_id: the id, for the error message.

    Returns:
        The kwargs with the fast variant's radar; ``radar_model="exact"`` is a ``ValueError`` naming the exact id.
    """
    model = kwargs.get("radar_model", "fast")
    if model not in ("fast", "fast-calibrate"):
        raise ValueError(f"{env_id} is the fast radar variant; radar_model={model!r} is not one of 'fast', "
                         f"'fast-calibrate'. For the exact radar use {env_id.replace('-fast', '')}")
    return {**kwargs, "radar_model": model}


def make_highway_radar_fast(**kwargs: Any) -> gym.Env:
    """``rhs-highway-radar-fast-v0``: :func:`make_highway_radar` with the fast radar (:func:`fast_variant_kwargs`)."""
    return make_highway_radar(**fast_variant_kwargs(kwargs, HIGHWAY_RADAR_FAST_ID))


#: highway-env observation that costs nothing: the radar wrapper replaces the
#: base observation anyway, and the Kinematics table costs ~4 ms per step (pandas).
NULL_OBSERVATION = {"type": "AttributesObservation", "attributes": []}
#: highway-env observation types named in the refusal of an ``observation`` on a radar id (rhs-highway-v0 takes them)
SUPPORTED_BASE_OBSERVATIONS = ("Kinematics", "OccupancyGrid", "TimeToCollision", "GrayscaleObservation")


def with_cheap_base_observation(env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """``env_kwargs`` with the base observation set to :data:`NULL_OBSERVATION`.

    The radar wrapper replaces highway-env's observation by the point cloud, so an ``observation``
    given by the caller (``{"type": "Kinematics"}``) could only be ignored: it is a ``ValueError``
    naming it and the ids that take it; :data:`NULL_OBSERVATION` itself is accepted.
    """
    from rhs_env.highway_config import same_value

    config = env_kwargs.get("config")
    given = [v for v in (env_kwargs.get("observation"), config.get("observation") if isinstance(config, Mapping)
                         else None) if v is not None]
    for value in given:
        if not same_value(value, NULL_OBSERVATION):
            raise ValueError(f"observation={value!r} is highway-env's observation, which the radar replaces by its "
                             "point cloud (points, points_mask; the SLAM adds pose, landmarks): it would be ignored. "
                             f"Drop it; for highway-env's observations ({', '.join(SUPPORTED_BASE_OBSERVATIONS)}) "
                             f"use {HIGHWAY_ID}")
    return env_kwargs if given else {**env_kwargs, "observation": dict(NULL_OBSERVATION)}


#: (id, entry point) of the envs registered here
ENV_SPECS: tuple[tuple[str, str], ...] = (
    (HIGHWAY_ID, "rhs_env.envs:RHSHighwayEnv"),
    (HIGHWAY_RADAR_ID, "rhs_env.registration:make_highway_radar"),
    (HIGHWAY_RADAR_FAST_ID, "rhs_env.registration:make_highway_radar_fast"),
    *((f"rhs-{road}-v0", f"rhs_env.road_envs:RHS{road.capitalize()}Env") for road in ROAD_NAMES),
    *((f"rhs-{road}-radar-v0", f"rhs_env.road_envs:make_{road}_radar") for road in ROAD_NAMES),
)

#: the SLAM ids: scene -> RadarObservation -> SlamObservation -> SlamMetricsInfo. They live one
#: layer up (slam.gym.envs); the string entry point is resolved only when such an env is made.
SLAM_ENV_SPECS: tuple[tuple[str, str], ...] = (
    (HIGHWAY_SLAM_ID, "slam.gym.envs:make_highway_slam"),
    (PAPER_ID, "slam.gym.envs:make_paper_slam"),
    (DENSE_ID, "slam.gym.envs:make_dense_slam"),
    (HIGHWAY_SLAM_FAST_ID, "slam.gym.envs:make_highway_slam_fast"),
    *((f"rhs-{road}-slam-v0", f"slam.gym.road_envs:make_{road}_slam") for road in ROAD_NAMES),
)


def check_env_id(env_id: str) -> None:
    """``ValueError`` saying "unknown env id" with the registered rhs ids, unless gymnasium knows ``env_id``.

    ``"module:id"`` imports the module first, as ``gym.make`` does.
    """
    ours = ", ".join(env_id for env_id, _ in ENV_SPECS + SLAM_ENV_SPECS)
    if not isinstance(env_id, str):
        raise TypeError(f"env id must be a string such as {HIGHWAY_SLAM_ID!r}, got {env_id!r}")
    try:
        module, _, name = env_id.rpartition(":")
        if module:
            importlib.import_module(module)
        gym.spec(name)
    except (gym.error.Error, ImportError) as exc:
        raise ValueError(f"unknown env id {env_id!r} ({exc}); this package registers {ours}") from None


#: flags whose info entries vary in length between envs and steps: gymnasium's vector envs cannot stack them
UNSTACKABLE_INFO_FLAGS = ("landmarks_in_info", "scatterers_in_info")


def _inside_gym_make_vec() -> bool:
    """The caller runs inside ``gymnasium.make_vec``'s env constructor (a sync or async vector env's env)."""
    frame = sys._getframe(1)
    while frame is not None:
        code = frame.f_code
        if code.co_name == "create_single_env" and "gymnasium" in code.co_filename:
            return True
        frame = frame.f_back  # type: ignore[assignment]
    return False


def check_vector_info_flags(kwargs: Mapping[str, Any], force: bool = False) -> None:
    """``ValueError`` naming the flag when :data:`UNSTACKABLE_INFO_FLAGS` are on in a gymnasium vector env.

    Called by the entry points with their kwargs: it acts only inside ``gym.make_vec`` (or with
    ``force=True``, as :func:`rhs_env.vector.make_vec` calls it). A single env, and stable-baselines3's vector envs
    (which keep one info dict per env), take the flags.
    """
    on = [k for k in UNSTACKABLE_INFO_FLAGS if kwargs.get(k) is True or isinstance(kwargs.get(k), np.bool_)
          and bool(kwargs.get(k))]
    if on and (force or _inside_gym_make_vec()):
        raise ValueError(
            f"{', '.join(f'{k}=True' for k in on)} puts arrays of a length that varies between envs into info, "
            "which a gymnasium vector env cannot stack; leave it off in vector envs, use a single env, or "
            "stable-baselines3's vector envs (one info dict per env: rhs_env.vector.make_subproc_vec_env)")


def register_envs() -> None:
    """Register every id once (re-importing or calling again is a no-op), each with its native vector env."""
    from rhs_env.num_envs import SpecKwargs  # gym.make_vec(id, num_envs=0) is its ValueError

    for env_id, entry_point in ENV_SPECS + SLAM_ENV_SPECS:
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point, vector_entry_point=vector_entry_point(env_id),
                         kwargs=SpecKwargs())


def vector_entry_point(env_id: str) -> str:
    """The id's native vector env (:mod:`rhs_env.vector_native`): ``"rhs_env.vector_native:make_rhs_highway_v0"``."""
    return f"rhs_env.vector_native:make_{env_id.replace('-', '_')}"
