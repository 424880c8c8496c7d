"""Entry points of the SLAM env ids: scene -> RadarObservation -> SlamObservation -> SlamMetricsInfo.

Registered by :mod:`rhs_env.registration` through string entry points
(``"slam.gym.envs:make_highway_slam"``), so ``rhs_env`` never imports this layer.
``gym.make`` kwargs are routed to each wrapper by its signature
(:func:`rhs_env.registration.route_kwargs`); the rest configure the scene.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from slam.gym import precompile

__all__ = ["make_dense_slam", "make_highway_slam", "make_highway_slam_fast", "make_paper_slam", "make_slam_env",
           "scene_class"]


def scene_class(name: str) -> type[gym.Env]:
    """The scene class called ``name``: a straight-road scene of :mod:`rhs_env.envs` or a road of
    :mod:`rhs_env.road_envs` (the name :func:`make_slam_env` records in ``slam_make_args``, which the pose
    calibration's drives make again)."""
    from rhs_env import envs, road_envs

    for module in (envs, road_envs):
        found = getattr(module, name, None)
        if isinstance(found, type) and issubclass(found, gym.Env):
            return found
    raise ValueError(f"scene: no scene class {name!r} in rhs_env.envs or rhs_env.road_envs")


def make_slam_env(env_cls: type[gym.Env] | str, kwargs: dict[str, Any]) -> gym.Env:
    """``env_cls`` (a highway-env scene, or its class name: :func:`scene_class`) under the radar, SLAM and
    SLAM-metrics wrappers. On an empty kernel cache the kernels a first step reaches last (the SLAM's, the OMP's
    refinement stages, then the one-call OMP) start compiling in a background process
    (:func:`slam.gym.precompile.start`) while this one compiles the rest: first thing, before this module imports
    the scene and the wrappers (~2 s), so the background's own imports run beside them."""
    precompile.start()
    from rhs_env.registration import check_vector_info_flags, route_kwargs, with_cheap_base_observation
    from rhs_env.wrappers import RadarObservation
    from slam.gym.metrics_info import SlamMetricsInfo
    from slam.gym.wrappers import SlamObservation

    check_vector_info_flags(kwargs)
    scene = scene_class(env_cls) if isinstance(env_cls, str) else env_cls
    (radar_kw, slam_kw, metrics_kw), env_kw = route_kwargs(kwargs, RadarObservation, SlamObservation, SlamMetricsInfo)
    base = scene(**with_cheap_base_observation(env_kw))
    slam_env = SlamObservation(RadarObservation(base, **radar_kw), **slam_kw)
    env = SlamMetricsInfo(slam_env, **metrics_kw)
    env.slam_make_args = (scene.__name__, dict(kwargs))  # type: ignore[attr-defined]  # the pose calibration reads it
    if slam_env.pipeline_config.pose_covariance == "calibrated":  # the configuration's factors: shipped, cached or fitted
        from slam.gym.pose_calibration import attach

        attach(env, scene.__name__, kwargs, make_slam_env)
    return env


def make_highway_slam(**kwargs: Any) -> gym.Env:
    """``rhs-highway-slam-v0``: the highway scene with traffic and roadside landmarks."""
    return make_slam_env("RHSHighwayEnv", kwargs)


def make_highway_slam_fast(**kwargs: Any) -> gym.Env:
    """``rhs-highway-slam-fast-v0``: the highway SLAM env with the fast radar (``radar_model="fast"``,
    :mod:`rhs_env.fast_radar`) and the compiled traffic unless ``sim`` is given
    (:func:`rhs_env.registration.fast_variant_kwargs`)."""
    from rhs_env.registration import HIGHWAY_SLAM_FAST_ID, fast_variant_kwargs

    return make_slam_env("RHSHighwayEnv", fast_variant_kwargs(kwargs, HIGHWAY_SLAM_FAST_ID))


def make_dense_slam(**kwargs: Any) -> gym.Env:
    """``rhs-dense-v0``: the highway with a dense roadside (:data:`rhs_env.scene.DENSE_LANDMARKS`)."""
    return make_slam_env("RHSDenseEnv", kwargs)


def make_paper_slam(**kwargs: Any) -> gym.Env:
    """``rhs-paper-v0``: the paper's Fig. 5c scene (50 cycles)."""
    return make_slam_env("RHSPaperEnv", kwargs)
