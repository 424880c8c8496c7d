"""The core's arrays and highway-env's vehicle objects kept equal: written back after every step (what rendering,
the radar, the drivers of :mod:`agents` and users read) and read in before every step (what a user or a driver set
on a vehicle between steps: its position, speed, target lane, target speed, ...)."""

from __future__ import annotations

import numpy as np

from rhs_env.traffic import core
from rhs_env.traffic.state import TrafficState

__all__ = ["read_in", "write_back"]


def write_back(state: TrafficState) -> None:
    """Every vehicle's position (in place), heading, speed, lanes, targets, timer, crash flag, impact and last action.

    The values are the core's float64 numbers as Python floats / ints: ``lane_index`` is the tuple highway-env
    builds (``(_from, _to, id)``) and ``lane`` its lane object.
    """
    f = state.f.tolist()
    k = state.k.tolist()
    a, b = state.edge
    lanes = state.lane_objects
    for v, fi, ki in zip(state.vehicles, f, k, strict=True):
        pos = v.position
        pos[0] = fi[core.X]
        pos[1] = fi[core.Y]
        v.heading = fi[core.H]
        v.speed = fi[core.V]
        ln = ki[core.LANE]
        if v.lane_index[2] != ln:
            v.lane_index = (a, b, ln)
            v.lane = lanes[ln]
        tl = ki[core.TARGET_LANE]
        if v.target_lane_index[2] != tl:
            v.target_lane_index = (a, b, tl)
        v.crashed = bool(ki[core.CRASHED])
        v.impact = np.array([fi[core.IMP_X], fi[core.IMP_Y]]) if ki[core.HAS_IMPACT] else None
        v.action = {"steering": fi[core.STEER], "acceleration": fi[core.ACC]}
        v.target_speed = fi[core.TARGET_SPEED]
        if ki[core.KIND] == core.K_IDM:
            v.timer = fi[core.TIMER]
        else:
            v.speed_index = ki[core.SPEED_INDEX]


def read_in(state: TrafficState) -> bool:
    """The vehicles' state as the objects hold it, into the arrays: what :func:`write_back` writes (the same numbers
    when nothing changed them) and ``check_collisions`` / ``enable_lane_change``. The per-vehicle parameters
    (lengths, gains, IDM constants) are read once, when the scene is packed.

    Returns:
        False, and the arrays left as they were, when a vehicle's lane or target lane left the road's edge (the
        scene must then be checked and packed again: :func:`rhs_env.traffic.state.unsupported`).
    """
    edge = state.edge
    rows: list[list[float]] = []
    flags: list[list[int]] = []
    f_old, k_old = state.f.tolist(), state.k.tolist()
    for v, fo, ko in zip(state.vehicles, f_old, k_old, strict=True):
        li, ti = v.lane_index, v.target_lane_index
        if li is None or ti is None or (li[0], li[1]) != edge or (ti[0], ti[1]) != edge:
            return False
        pos, impact, action = v.position, v.impact, v.action
        idm = ko[core.KIND] == core.K_IDM
        rows.append([pos[0], pos[1], v.heading, v.speed, v.target_speed, v.timer if idm else fo[core.TIMER],
                     *((impact[0], impact[1]) if impact is not None else (fo[core.IMP_X], fo[core.IMP_Y])),
                     action["steering"], action["acceleration"]])
        flags.append([li[2], ti[2], int(bool(v.crashed)), int(impact is not None), ko[core.KIND],
                      int(bool(v.check_collisions)), int(bool(v.enable_lane_change)) if idm else ko[core.ENABLE_LC],
                      ko[core.SPEED_INDEX] if idm else int(v.speed_index)])
    if rows:
        state.f[:] = rows
        state.k[:] = flags
    return True
