"""The core's arrays written back into highway-env's vehicle objects (what rendering, the radar and users read)."""

from __future__ import annotations

import numpy as np

from rhs_env.traffic import core
from rhs_env.traffic.state import TrafficState

__all__ = ["write_back"]


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
