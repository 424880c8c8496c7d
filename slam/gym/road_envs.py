"""Entry points of the SLAM ids of highway-env's other roads: ``rhs-<road>-slam-v0``.

The scene is :data:`rhs_env.road_envs.ROAD_ENVS`'s (highway-env's road, traffic and rewards with roadside
landmarks) under the radar, SLAM and SLAM-metrics wrappers (:func:`slam.gym.envs.make_slam_env`: the kwargs
are routed as for ``rhs-highway-slam-v0``).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

__all__ = [
    "make_exit_slam", "make_intersection_slam", "make_merge_slam", "make_racetrack_slam", "make_road_slam",
    "make_roundabout_slam",
]


def make_road_slam(road: str, kwargs: dict[str, Any]) -> gym.Env:
    """The SLAM env of ``road`` (a key of :data:`rhs_env.road_envs.ROAD_ENVS`) with the ``gym.make`` kwargs.

    Args:
        road: ``merge``, ``roundabout``, ``intersection``, ``exit`` or ``racetrack``.
        kwargs: scene config keys and the wrappers' arguments.

    Returns:
        The wrapped env (its info carries the SLAM metrics).
    """
    from rhs_env.road_envs import ROAD_ENVS
    from slam.gym.envs import make_slam_env

    return make_slam_env(ROAD_ENVS[road], kwargs)


def make_merge_slam(**kwargs: Any) -> gym.Env:
    """``rhs-merge-slam-v0``: highway-env's merge with roadside landmarks, radar and SLAM."""
    return make_road_slam("merge", kwargs)


def make_roundabout_slam(**kwargs: Any) -> gym.Env:
    """``rhs-roundabout-slam-v0``: highway-env's roundabout with landmarks, radar and SLAM."""
    return make_road_slam("roundabout", kwargs)


def make_intersection_slam(**kwargs: Any) -> gym.Env:
    """``rhs-intersection-slam-v0``: highway-env's intersection with landmarks, radar and SLAM."""
    return make_road_slam("intersection", kwargs)


def make_exit_slam(**kwargs: Any) -> gym.Env:
    """``rhs-exit-slam-v0``: highway-env's exit with landmarks, radar and SLAM."""
    return make_road_slam("exit", kwargs)


def make_racetrack_slam(**kwargs: Any) -> gym.Env:
    """``rhs-racetrack-slam-v0``: highway-env's racetrack with landmarks, radar and SLAM."""
    return make_road_slam("racetrack", kwargs)
