"""highway-env's IDM + MOBIL driver in the ego's seat (rhs_env.idm_driver.swap_ego_for_idm)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from highway_env.vehicle.behavior import IDMVehicle

import rhs_env  # noqa: F401  (registers the ids)
from rhs_env.idm_driver import DEFAULT_TARGET_SPEED, swap_ego_for_idm


def _state(v) -> tuple:
    return (tuple(np.asarray(v.position, float)), float(v.heading), float(v.speed), v.lane_index, bool(v.crashed))


def test_the_swapped_ego_is_an_idm_vehicle_at_the_same_state_in_the_same_seat():
    env = gym.make("rhs-highway-v0", vehicles_count=6, duration=4)
    env.reset(seed=2)
    base = env.unwrapped
    ego = base.vehicle
    slot = base.road.vehicles.index(ego)
    before, n = _state(ego), len(base.road.vehicles)
    idm = swap_ego_for_idm(env)
    assert type(idm) is IDMVehicle and idm is not ego and idm.enable_lane_change  # MOBIL on
    assert _state(idm) == before and idm.target_lane_index == ego.target_lane_index
    assert idm.target_speed == float(np.max(base.action_type.target_speeds)) == 30.0
    assert base.vehicle is idm and base.road.vehicles[slot] is idm and len(base.road.vehicles) == n
    assert ego not in base.road.vehicles and base.action_type.controlled_vehicle is idm
    assert swap_ego_for_idm(env, 12.0) is idm and idm.target_speed == 30.0  # once an IDMVehicle, left as it is
    x0 = float(idm.position[0])
    env.step(1)  # the meta-action is ignored; road.act() drives it
    assert base.vehicle is idm and float(idm.position[0]) > x0
    env.reset(seed=2)  # a fresh ego at every reset, swapped again, with the given target speed
    assert swap_ego_for_idm(base, 22).target_speed == 22.0  # the unwrapped env works too
    env.close()


def test_on_the_racetrack_the_steering_only_ego_gets_its_lane_and_the_speed_limit():
    env = gym.make("rhs-racetrack-v0")
    env.reset(seed=0)
    base = env.unwrapped
    ego = base.vehicle
    assert not hasattr(ego, "target_lane_index")  # ContinuousAction's plain Vehicle
    before, lane = _state(ego), ego.lane_index
    idm = swap_ego_for_idm(env)
    assert type(idm) is IDMVehicle and _state(idm) == before
    assert idm.target_lane_index == lane and idm.route is None
    assert idm.target_speed == float(ego.lane.speed_limit) == 10.0
    env.step(np.zeros(env.action_space.shape, env.action_space.dtype))
    assert base.vehicle is idm and not idm.crashed
    env.close()
    assert DEFAULT_TARGET_SPEED == 30.0


def test_bad_input_raises_a_clear_error():
    with pytest.raises(ValueError, match="highway-env env"):
        swap_ego_for_idm(object())
    with pytest.raises(ValueError, match="highway-env env"):
        swap_ego_for_idm(gym.make("CartPole-v1"))
    env = gym.make("rhs-highway-v0", vehicles_count=3, duration=2)
    env.reset(seed=0)
    for bad in (-3.0, 0, float("nan"), float("inf"), True, "fast"):
        with pytest.raises(ValueError, match="target_speed"):
            swap_ego_for_idm(env, bad)
    base = env.unwrapped
    base.road.vehicles.remove(base.vehicle)
    with pytest.raises(ValueError, match="not among"):
        swap_ego_for_idm(env)
    env.close()
