"""highway-env's IDM + MOBIL driver in the ego's seat of a highway-env scene.

:func:`swap_ego_for_idm` replaces the ego (the ``MDPVehicle`` of a ``DiscreteMetaAction``, or the racetrack's plain
``Vehicle`` of its steering-only ``ContinuousAction``) by a ``highway_env.vehicle.behavior.IDMVehicle`` at the same
dynamical state (``IDMVehicle.create_from``: position m, heading rad, speed m/s, target lane, route, lane-change timer
s), in ``road.vehicles`` (the same slot), ``controlled_vehicles`` and the action type. From then on the env's
``road.act()`` drives it at the simulation rate like the traffic: IDM longitudinal control,

    a = a_max [1 - (v / v0)^delta - (d*(v, dv) / d)^2],
    d* = d0 + v T + v dv / (2 sqrt(a_max b)),

with desired speed ``v0`` = the target speed (m/s), and MOBIL lane changes (taken when the ego's acceleration gain
exceeds ``LANE_CHANGE_MIN_ACC_GAIN`` and the braking imposed on the new follower stays under
``LANE_CHANGE_MAX_BRAKING_IMPOSED``). The action sent to ``env.step`` is ignored by ``IDMVehicle.act``; rewards,
collisions, radar and SLAM see the swapped vehicle (they read ``env.unwrapped.vehicle`` / ``road.vehicles``).

Used by :class:`agents.evaluate.IDMMobilPolicy`, the pose-covariance calibration's drives
(:func:`slam.gym.pose_calibration.calibration_rows`) and the racetrack study's driver.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["DEFAULT_TARGET_SPEED", "swap_ego_for_idm"]

#: the desired speed (m/s) when neither the action type's target speeds nor the ego's lane give one
DEFAULT_TARGET_SPEED = 30.0


def swap_ego_for_idm(env: Any, target_speed: float | None = None) -> Any:
    """Put highway-env's IDM + MOBIL driver (``IDMVehicle``) in the ego's seat (module docstring).

    An ego without a target lane (the racetrack's steering-only ``Vehicle``) is first given its current lane as the
    target lane, no route (the lanes' successors) and the target speed, which ``IDMVehicle.create_from`` needs. An
    ego that already is an ``IDMVehicle`` is left as it is, so calling this before every step swaps once per episode.

    Args:
        env: a highway-env env (``AbstractEnv``) or a gymnasium wrapper of one (``env.unwrapped`` is used).
        target_speed: the driver's desired speed, m/s (> 0). None: the highest target speed of the action type
            (``DiscreteMetaAction.target_speeds``), else the ego lane's ``speed_limit`` (the racetrack's 10 m/s),
            else :data:`DEFAULT_TARGET_SPEED`.

    Returns:
        The ``IDMVehicle`` now in the ego's seat (the ego itself when it already was one); None when the env has no
        ego (no controlled vehicle).

    Raises:
        ValueError: ``env`` is not a highway-env env, ``target_speed`` is not a finite positive speed, or the ego is
            not among ``road.vehicles``.

    Example:
        >>> import gymnasium as gym
        >>> import rhs_env
        >>> env = gym.make("rhs-highway-v0", vehicles_count=5)
        >>> _ = env.reset(seed=0)
        >>> swap_ego_for_idm(env).target_speed
        30.0
    """
    from highway_env.vehicle.behavior import IDMVehicle

    base = getattr(env, "unwrapped", env)
    if not all(hasattr(base, name) for name in ("road", "vehicle", "action_type", "controlled_vehicles")):
        raise ValueError(f"swap_ego_for_idm needs a highway-env env (env.unwrapped.road, .vehicle, .action_type), "
                         f"got {type(base).__name__}")
    if target_speed is not None and (isinstance(target_speed, bool) or not isinstance(target_speed, (int, float, np.number))
                                     or not math.isfinite(float(target_speed)) or float(target_speed) <= 0.0):
        raise ValueError(f"swap_ego_for_idm: target_speed must be a finite speed > 0 m/s, got {target_speed!r}")
    ego = base.vehicle
    if ego is None or isinstance(ego, IDMVehicle):
        return ego
    if target_speed is None:
        speeds = getattr(base.action_type, "target_speeds", None)
        limit = getattr(getattr(ego, "lane", None), "speed_limit", None)
        target = float(np.max(speeds)) if speeds is not None else float(limit) if limit else DEFAULT_TARGET_SPEED
    else:
        target = float(target_speed)
    vehicles = base.road.vehicles
    slot = next((i for i, v in enumerate(vehicles) if v is ego), None)
    if slot is None:
        raise ValueError("swap_ego_for_idm: the ego is not among env.unwrapped.road.vehicles")
    if not hasattr(ego, "target_lane_index"):
        ego.target_lane_index, ego.route, ego.target_speed = ego.lane_index, None, target
    idm = IDMVehicle.create_from(ego)
    idm.target_speed = target
    idm.crashed = ego.crashed
    vehicles[slot] = idm
    base.controlled_vehicles = [idm if v is ego else v for v in base.controlled_vehicles]
    base.action_type.controlled_vehicle = idm
    return idm
