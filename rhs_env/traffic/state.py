"""highway-env's road packed into the arrays of :mod:`rhs_env.traffic.core`, and what the core supports.

:func:`pack` reads every vehicle of ``road.vehicles`` (in its order) into the state arrays; :func:`unsupported`
says, in one sentence, why a scene cannot run on the core (then ``sim="highway-env"`` is the choice).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from highway_env.road.lane import StraightLane
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import MDPVehicle

from rhs_env.traffic import core

__all__ = ["TrafficState", "pack", "unsupported"]

#: the vehicle classes the core ports (exact classes: a subclass may change any method)
KINDS: dict[type, int] = {IDMVehicle: core.K_IDM, MDPVehicle: core.K_MDP}
#: vehicle attribute -> column of ``p`` (read per vehicle: class constants or per-vehicle overrides)
PARAMS: dict[str, int] = {
    "LENGTH": core.P_LENGTH, "WIDTH": core.P_WIDTH, "diagonal": core.P_DIAGONAL, "MAX_SPEED": core.P_MAX_SPEED,
    "MIN_SPEED": core.P_MIN_SPEED, "KP_A": core.P_KP_A, "KP_HEADING": core.P_KP_HEADING,
    "KP_LATERAL": core.P_KP_LATERAL, "MAX_STEERING_ANGLE": core.P_MAX_STEERING, "TAU_PURSUIT": core.P_TAU_PURSUIT,
    "DELTA_SPEED": core.P_DELTA_SPEED,
}
#: the IDM / MOBIL constants (of ``IDMVehicle``; an MDP vehicle never uses its own)
IDM_PARAMS: dict[str, int] = {
    "ACC_MAX": core.P_ACC_MAX, "COMFORT_ACC_MAX": core.P_COMFORT_ACC_MAX, "COMFORT_ACC_MIN": core.P_COMFORT_ACC_MIN,
    "DISTANCE_WANTED": core.P_DISTANCE_WANTED, "TIME_WANTED": core.P_TIME_WANTED, "DELTA": core.P_DELTA,
    "POLITENESS": core.P_POLITENESS, "LANE_CHANGE_MIN_ACC_GAIN": core.P_MIN_ACC_GAIN,
    "LANE_CHANGE_MAX_BRAKING_IMPOSED": core.P_MAX_BRAKING, "LANE_CHANGE_DELAY": core.P_LC_DELAY,
}


@dataclass
class TrafficState:
    """The arrays of one scene (see :mod:`rhs_env.traffic.core` for the columns) and the objects they came from."""

    f: np.ndarray
    k: np.ndarray
    p: np.ndarray
    lanes: np.ndarray
    speeds: np.ndarray
    #: the road's one edge (``_from``, ``_to``) and its lane objects, by id
    edge: tuple[Any, Any]
    lane_objects: list[Any]
    vehicles: list[Any]
    ctrl: int
    #: ``id`` of every vehicle, of the controlled one and of the road: a change means "pack again"
    key: tuple[int, ...]


def scene_key(road: Any, controlled: Any) -> tuple[int, ...]:
    """What :func:`pack` depends on beyond the vehicles' state: the road and its network, the number of road
    objects, the controlled vehicle and the vehicle list."""
    return (id(road), id(road.network), len(road.objects), id(controlled), *map(id, road.vehicles))


def unsupported(road: Any, controlled: Any) -> str:
    """Why ``road`` cannot be stepped by the core ("" when it can)."""
    graph = road.network.graph
    edges = [(a, b) for a, tos in graph.items() for b in tos]
    if len(edges) != 1:
        return f"the road has {len(edges)} edges (the compiled traffic steps one straight road edge)"
    lanes = graph[edges[0][0]][edges[0][1]]
    if any(type(lane) is not StraightLane for lane in lanes):
        return "the road has lanes other than StraightLane"
    if road.objects:
        return "the road holds road objects (obstacles / landmarks)"
    if road.record_history:
        return "show_trajectories is on (vehicle history)"
    if controlled not in road.vehicles:
        return "the controlled vehicle is not on the road"
    for v in road.vehicles:
        if type(v) not in KINDS:
            return (f"a vehicle is a {type(v).__module__}.{type(v).__qualname__} (the compiled traffic ports "
                    "IDMVehicle and MDPVehicle)")
        if getattr(v, "route", None):
            return "a vehicle follows a route"
        if not (v.collidable and v.solid):
            return "a vehicle is not collidable or not solid"
        if v.lane_index is None or tuple(v.lane_index[:2]) != edges[0]:
            return "a vehicle is off the road's lanes"
    return ""


def pack(road: Any, controlled: Any) -> TrafficState:
    """The state arrays of ``road`` (call :func:`unsupported` first)."""
    graph = road.network.graph
    edge = next((a, b) for a, tos in graph.items() for b in tos)
    lane_objects = list(graph[edge[0]][edge[1]])
    lanes = np.zeros((len(lane_objects), core.NL))
    for i, lane in enumerate(lane_objects):
        lanes[i, core.L_SX:core.L_SY + 1] = lane.start
        lanes[i, core.L_DX:core.L_DY + 1] = lane.direction
        lanes[i, core.L_LX:core.L_LY + 1] = lane.direction_lateral
        lanes[i, core.L_LENGTH] = lane.length
        lanes[i, core.L_WIDTH] = lane.width
        lanes[i, core.L_HEADING] = lane.heading
        lanes[i, core.L_SPEED_LIMIT] = np.nan if lane.speed_limit is None else lane.speed_limit
        lanes[i, core.L_FORBIDDEN] = float(bool(lane.forbidden))
    vehicles = list(road.vehicles)
    n = len(vehicles)
    f = np.zeros((n, core.NF))
    k = np.zeros((n, core.NK), dtype=np.int64)
    p = np.zeros((n, core.NP))
    for i, v in enumerate(vehicles):
        kind = KINDS[type(v)]
        f[i, core.X], f[i, core.Y] = v.position
        f[i, core.H] = v.heading
        f[i, core.V] = v.speed
        f[i, core.TARGET_SPEED] = v.target_speed
        f[i, core.STEER] = v.action["steering"]
        f[i, core.ACC] = v.action["acceleration"]
        k[i, core.LANE] = v.lane_index[2]
        k[i, core.TARGET_LANE] = v.target_lane_index[2]
        k[i, core.CRASHED] = int(bool(v.crashed))
        if v.impact is not None:
            f[i, core.IMP_X], f[i, core.IMP_Y] = v.impact
            k[i, core.HAS_IMPACT] = 1
        k[i, core.KIND] = kind
        k[i, core.CHECK_COLL] = int(bool(v.check_collisions))
        for name, col in PARAMS.items():
            p[i, col] = getattr(v, name)
        source = v if kind == core.K_IDM else IDMVehicle
        for name, col in IDM_PARAMS.items():
            p[i, col] = getattr(source, name)
        if kind == core.K_IDM:
            f[i, core.TIMER] = v.timer
            k[i, core.ENABLE_LC] = int(bool(v.enable_lane_change))
        else:
            k[i, core.SPEED_INDEX] = int(v.speed_index)
    speeds = np.asarray(getattr(controlled, "target_speeds", [0.0]), dtype=float).ravel()
    return TrafficState(f, k, p, lanes, speeds, edge, lane_objects, vehicles, vehicles.index(controlled),
                        scene_key(road, controlled))
