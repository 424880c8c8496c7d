"""highway-env's per-frame traffic dynamics as compiled kernels over arrays (the ``sim="compiled"`` core).

Each function ports one highway-env method, statement by statement and in the same floating-point order
(named in its docstring); highway-env itself (``sim="highway-env"``) stays the reference, and
``tests/test_traffic_core.py`` / ``scripts/traffic_alignment.py`` drive both with the same actions.

One simulation frame (``AbstractEnv._simulate``, one iteration) is:

1. at the frame that starts a policy step, the controlled vehicle takes the meta-action
   (``DiscreteMetaAction.act`` -> ``MDPVehicle.act``);
2. ``Road.act``: every vehicle in list order decides (``IDMVehicle.act``: MOBIL lane change, IDM
   acceleration, lane-following steering; ``ControlledVehicle.act``: speed and steering controllers);
   a vehicle sees the targets its predecessors in the list set in this frame, as in highway-env;
3. ``Road.step``: every vehicle integrates the kinematic bicycle model (``Vehicle.step``, lane-change
   timer of ``IDMVehicle.step``, closest lane of ``on_state_update``), then every pair ``i < j`` is
   checked for collision (``RoadObject.handle_collisions``: the separating-axis test of
   ``utils.are_polygons_intersecting`` with the next frame's displacement, the impact applied at the
   next step, ``crashed`` set on both).

State layout (one row per vehicle of ``road.vehicles``, in its order):

* ``f`` float64 ``(n, NF)``: :data:`X` ... :data:`ACC` (``impact`` is ``IMP_X, IMP_Y`` with ``HAS_IMPACT``);
* ``k`` int64 ``(n, NK)``: :data:`LANE` ... :data:`SPEED_INDEX` (lane ids on the road's one edge);
* ``p`` float64 ``(n, NP)``: the vehicle's constants, read from the object (class attributes or
  per-vehicle overrides such as the ``DELTA`` drawn by ``randomize_behavior``);
* ``lanes`` float64 ``(m, NL)``: the straight lanes of the edge (``StraightLane`` fields);
* ``speeds``: the controlled vehicle's ``target_speeds``.

``arcsin``, ``arctan``, ``tan``, ``power`` and the 2-vector dot products come from :mod:`rhs_env.traffic.npmath`
(numpy's own SVML functions where numpy uses them, BLAS's fused dot), so that the kernels' numbers are numpy's to
the bit.

Supported: straight lanes on one road edge (``StraightLane``), no road objects, ``IDMVehicle`` and
``MDPVehicle`` instances (exact classes, checked by :mod:`rhs_env.traffic.state`), no route.
"""

from __future__ import annotations

import math

import numpy as np

from rhs_common.jit import njit
from rhs_env.traffic import npmath

__all__ = [
    "ACTION_CODES", "K_IDM", "K_MDP", "NF", "NK", "NL", "NP", "reward_terms", "simulate",
]

# ---- f columns
X, Y, H, V, TARGET_SPEED, TIMER, IMP_X, IMP_Y, STEER, ACC = range(10)
NF = 10
# ---- k columns
LANE, TARGET_LANE, CRASHED, HAS_IMPACT, KIND, CHECK_COLL, ENABLE_LC, SPEED_INDEX = range(8)
NK = 8
#: vehicle kinds: highway-env's IDMVehicle, MDPVehicle
K_IDM, K_MDP = 0, 1
# ---- p columns
(P_LENGTH, P_WIDTH, P_DIAGONAL, P_MAX_SPEED, P_MIN_SPEED, P_KP_A, P_KP_HEADING, P_KP_LATERAL, P_MAX_STEERING,
 P_TAU_PURSUIT, P_ACC_MAX, P_COMFORT_ACC_MAX, P_COMFORT_ACC_MIN, P_DISTANCE_WANTED, P_TIME_WANTED, P_DELTA,
 P_POLITENESS, P_MIN_ACC_GAIN, P_MAX_BRAKING, P_LC_DELAY, P_DELTA_SPEED) = range(21)
NP = 21
# ---- lane columns (``speed_limit`` NaN for None)
L_SX, L_SY, L_DX, L_DY, L_LX, L_LY, L_LENGTH, L_WIDTH, L_HEADING, L_SPEED_LIMIT, L_FORBIDDEN = range(11)
NL = 11
#: the lane's ``VEHICLE_LENGTH`` (``AbstractLane.VEHICLE_LENGTH``)
LANE_VEHICLE_LENGTH = 5.0

#: meta-action label -> code of :func:`simulate` (-1: no action this step)
ACTION_CODES = {"LANE_LEFT": 0, "IDLE": 1, "LANE_RIGHT": 2, "FASTER": 3, "SLOWER": 4}
A_LEFT, A_IDLE, A_RIGHT, A_FASTER, A_SLOWER = range(5)


@njit
def not_zero(x: float) -> float:
    """``utils.not_zero`` (eps 1e-2)."""
    if abs(x) > 1e-2:
        return x
    if x >= 0:
        return 1e-2
    return -1e-2


@njit
def wrap_to_pi(x: float) -> float:
    """``utils.wrap_to_pi``."""
    return ((x + np.pi) % (2 * np.pi)) - np.pi


@njit
def clip(x: float, lo: float, hi: float) -> float:
    """``np.clip`` of a scalar."""
    return min(max(x, lo), hi)


@njit
def local_long(lanes: np.ndarray, ln: int, x: float, y: float) -> float:
    """``StraightLane.local_coordinates(position)[0]``."""
    return npmath.dot2(x - lanes[ln, L_SX], y - lanes[ln, L_SY], lanes[ln, L_DX], lanes[ln, L_DY])


@njit
def local_lat(lanes: np.ndarray, ln: int, x: float, y: float) -> float:
    """``StraightLane.local_coordinates(position)[1]``."""
    return npmath.dot2(x - lanes[ln, L_SX], y - lanes[ln, L_SY], lanes[ln, L_LX], lanes[ln, L_LY])


@njit
def on_lane(lanes: np.ndarray, ln: int, s: float, r: float, margin: float) -> bool:
    """``AbstractLane.on_lane`` given the local coordinates."""
    return (abs(r) <= lanes[ln, L_WIDTH] / 2 + margin
            and -LANE_VEHICLE_LENGTH <= s < lanes[ln, L_LENGTH] + LANE_VEHICLE_LENGTH)


@njit
def reachable(lanes: np.ndarray, ln: int, x: float, y: float) -> bool:
    """``AbstractLane.is_reachable_from``."""
    if lanes[ln, L_FORBIDDEN] != 0.0:
        return False
    s = local_long(lanes, ln, x, y)
    r = local_lat(lanes, ln, x, y)
    return abs(r) <= 2 * lanes[ln, L_WIDTH] and 0 <= s < lanes[ln, L_LENGTH] + LANE_VEHICLE_LENGTH


@njit
def closest_lane(lanes: np.ndarray, x: float, y: float, heading: float) -> int:
    """``RoadNetwork.get_closest_lane_index`` (``distance_with_heading``, first minimum)."""
    best = 0
    best_d = np.inf
    for ln in range(lanes.shape[0]):
        s = local_long(lanes, ln, x, y)
        r = local_lat(lanes, ln, x, y)
        angle = abs(wrap_to_pi(heading - lanes[ln, L_HEADING]))
        d = abs(r) + max(s - lanes[ln, L_LENGTH], 0.0) + max(0 - s, 0.0) + 1.0 * angle
        if d < best_d:
            best_d = d
            best = ln
    return best


@njit
def neighbours(f: np.ndarray, lanes: np.ndarray, i: int, ln: int) -> tuple[int, int]:
    """``Road.neighbour_vehicles(vehicle i, lane ln)``: (front, rear) row, -1 for None (one road edge, no objects)."""
    s = local_long(lanes, ln, f[i, X], f[i, Y])
    front = -1
    rear = -1
    s_front = 0.0
    s_rear = 0.0
    for j in range(f.shape[0]):
        if j == i:
            continue
        s_v = local_long(lanes, ln, f[j, X], f[j, Y])
        lat_v = local_lat(lanes, ln, f[j, X], f[j, Y])
        if not on_lane(lanes, ln, s_v, lat_v, 1.0):
            continue
        if s <= s_v and (front < 0 or s_v <= s_front):
            s_front = s_v
            front = j
        if s_v < s and (rear < 0 or s_v > s_rear):
            s_rear = s_v
            rear = j
    return front, rear


@njit
def lane_distance(f: np.ndarray, k: np.ndarray, lanes: np.ndarray, i: int, j: int) -> float:
    """``RoadObject.lane_distance_to``: vehicle j's distance ahead of i along i's lane."""
    ln = k[i, LANE]
    return local_long(lanes, ln, f[j, X], f[j, Y]) - local_long(lanes, ln, f[i, X], f[i, Y])


@njit
def desired_gap(f: np.ndarray, p: np.ndarray, me: int, e: int, fr: int) -> float:
    """``IDMVehicle.desired_gap`` of vehicle ``me``'s constants, for ego ``e`` behind ``fr`` (projected)."""
    d0 = p[me, P_DISTANCE_WANTED]
    tau = p[me, P_TIME_WANTED]
    ab = -p[me, P_COMFORT_ACC_MAX] * p[me, P_COMFORT_ACC_MIN]
    ce = math.cos(f[e, H])
    se = math.sin(f[e, H])
    cf = math.cos(f[fr, H])
    sf = math.sin(f[fr, H])
    dv = npmath.dot2(f[e, V] * ce - f[fr, V] * cf, f[e, V] * se - f[fr, V] * sf, ce, se)
    return d0 + f[e, V] * tau + f[e, V] * dv / (2 * np.sqrt(ab))


@njit
def idm_acceleration(f: np.ndarray, k: np.ndarray, p: np.ndarray, lanes: np.ndarray, me: int, e: int,
                     fr: int) -> float:
    """``IDMVehicle.acceleration`` with vehicle ``me``'s constants for ego ``e`` and front ``fr`` (-1: None)."""
    if e < 0:
        return 0.0
    ets = f[e, TARGET_SPEED]
    limit = lanes[k[e, LANE], L_SPEED_LIMIT]
    if not np.isnan(limit):
        ets = clip(ets, 0.0, limit)
    speed = f[e, V]
    base = (speed if not 0 > speed else 0.0) / abs(not_zero(ets))
    acc = p[me, P_COMFORT_ACC_MAX] * (1 - npmath.power(base, p[me, P_DELTA]))
    if fr >= 0:
        d = lane_distance(f, k, lanes, e, fr)
        acc -= p[me, P_COMFORT_ACC_MAX] * np.power(desired_gap(f, p, me, e, fr) / not_zero(d), 2)
    return acc


@njit
def steering_control(f: np.ndarray, p: np.ndarray, lanes: np.ndarray, i: int, ln: int) -> float:
    """``ControlledVehicle.steering_control(target lane ln)`` (a straight lane: ``heading_at`` is constant)."""
    lat = local_lat(lanes, ln, f[i, X], f[i, Y])
    lane_future_heading = lanes[ln, L_HEADING]
    lateral_speed_command = -p[i, P_KP_LATERAL] * lat
    heading_command = npmath.arcsin(clip(lateral_speed_command / not_zero(f[i, V]), -1.0, 1.0))
    heading_ref = lane_future_heading + clip(heading_command, -np.pi / 4, np.pi / 4)
    heading_rate_command = p[i, P_KP_HEADING] * wrap_to_pi(heading_ref - f[i, H])
    slip_angle = npmath.arcsin(clip(p[i, P_LENGTH] / 2 / not_zero(f[i, V]) * heading_rate_command, -1.0, 1.0))
    steering_angle = npmath.arctan(2 * npmath.tan(slip_angle))
    return clip(steering_angle, -p[i, P_MAX_STEERING], p[i, P_MAX_STEERING])


@njit
def mobil(f: np.ndarray, k: np.ndarray, p: np.ndarray, lanes: np.ndarray, i: int, ln: int) -> bool:
    """``IDMVehicle.mobil(lane ln)`` (no route)."""
    new_preceding, new_following = neighbours(f, lanes, i, ln)
    new_following_a = idm_acceleration(f, k, p, lanes, i, new_following, new_preceding)
    new_following_pred_a = idm_acceleration(f, k, p, lanes, i, new_following, i)
    if new_following_pred_a < -p[i, P_MAX_BRAKING]:
        return False
    old_preceding, old_following = neighbours(f, lanes, i, k[i, LANE])
    self_pred_a = idm_acceleration(f, k, p, lanes, i, i, new_preceding)
    self_a = idm_acceleration(f, k, p, lanes, i, i, old_preceding)
    old_following_a = idm_acceleration(f, k, p, lanes, i, old_following, i)
    old_following_pred_a = idm_acceleration(f, k, p, lanes, i, old_following, old_preceding)
    jerk = self_pred_a - self_a + p[i, P_POLITENESS] * (
        new_following_pred_a - new_following_a + old_following_pred_a - old_following_a)
    return not jerk < p[i, P_MIN_ACC_GAIN]


@njit
def change_lane_policy(f: np.ndarray, k: np.ndarray, p: np.ndarray, lanes: np.ndarray, i: int) -> None:
    """``IDMVehicle.change_lane_policy`` (one road edge: every lane index shares ``[:2]``)."""
    if k[i, LANE] != k[i, TARGET_LANE]:
        target = k[i, TARGET_LANE]
        for j in range(f.shape[0]):
            if j != i and k[j, LANE] != target and k[j, TARGET_LANE] == target:
                d = lane_distance(f, k, lanes, i, j)
                d_star = desired_gap(f, p, i, i, j)
                if 0 < d < d_star:
                    k[i, TARGET_LANE] = k[i, LANE]
                    break
        return
    if not p[i, P_LC_DELAY] < f[i, TIMER]:
        return
    f[i, TIMER] = 0.0
    ln0 = k[i, LANE]
    for side in range(2):
        ln = ln0 - 1 if side == 0 else ln0 + 1
        if ln < 0 or ln >= lanes.shape[0]:
            continue
        if not reachable(lanes, ln, f[i, X], f[i, Y]):
            continue
        if np.abs(f[i, V]) < 1:
            continue
        if mobil(f, k, p, lanes, i, ln):
            k[i, TARGET_LANE] = ln


@njit
def idm_act(f: np.ndarray, k: np.ndarray, p: np.ndarray, lanes: np.ndarray, i: int) -> None:
    """``IDMVehicle.act`` (``follow_road`` is a no-op on a road of one edge)."""
    if k[i, CRASHED]:
        return
    if k[i, ENABLE_LC]:
        change_lane_policy(f, k, p, lanes, i)
    f[i, STEER] = clip(steering_control(f, p, lanes, i, k[i, TARGET_LANE]), -p[i, P_MAX_STEERING],
                       p[i, P_MAX_STEERING])
    front, rear = neighbours(f, lanes, i, k[i, LANE])
    acc = idm_acceleration(f, k, p, lanes, i, i, front)
    if k[i, LANE] != k[i, TARGET_LANE]:
        front, rear = neighbours(f, lanes, i, k[i, TARGET_LANE])
        target_acc = idm_acceleration(f, k, p, lanes, i, i, front)
        acc = min(acc, target_acc)
    f[i, ACC] = clip(acc, -p[i, P_ACC_MAX], p[i, P_ACC_MAX])


@njit
def speed_to_index(speeds: np.ndarray, speed: float) -> int:
    """``MDPVehicle.speed_to_index`` (``np.round``: half to even)."""
    n = speeds.size
    if n == 1:
        return 0
    x = (speed - speeds[0]) / (speeds[n - 1] - speeds[0])
    return int(clip(np.rint(x * (n - 1)), 0.0, n - 1.0))


@njit
def meta_action(f: np.ndarray, k: np.ndarray, p: np.ndarray, lanes: np.ndarray, speeds: np.ndarray, i: int,
                code: int) -> None:
    """The meta-action part of ``MDPVehicle.act`` / ``ControlledVehicle.act`` (target speed or target lane)."""
    if code == A_FASTER or code == A_SLOWER:
        step = 1 if code == A_FASTER else -1
        idx = speed_to_index(speeds, f[i, V]) + step
        idx = min(max(idx, 0), speeds.size - 1)
        k[i, SPEED_INDEX] = idx
        f[i, TARGET_SPEED] = speeds[idx]
    elif code == A_LEFT or code == A_RIGHT:
        ln = k[i, TARGET_LANE] + (-1 if code == A_LEFT else 1)
        ln = min(max(ln, 0), lanes.shape[0] - 1)
        if reachable(lanes, ln, f[i, X], f[i, Y]):
            k[i, TARGET_LANE] = ln


@njit
def controlled_act(f: np.ndarray, k: np.ndarray, p: np.ndarray, lanes: np.ndarray, i: int) -> None:
    """``ControlledVehicle.act(None)``: the steering and speed controllers."""
    steer = steering_control(f, p, lanes, i, k[i, TARGET_LANE])
    f[i, ACC] = p[i, P_KP_A] * (f[i, TARGET_SPEED] - f[i, V])
    f[i, STEER] = clip(steer, -p[i, P_MAX_STEERING], p[i, P_MAX_STEERING])


@njit
def vehicle_step(f: np.ndarray, k: np.ndarray, p: np.ndarray, lanes: np.ndarray, i: int, dt: float) -> None:
    """``IDMVehicle.step`` (timer) / ``Vehicle.step``: ``clip_actions``, the bicycle model, the impact, the lane."""
    if k[i, KIND] == K_IDM:
        f[i, TIMER] += dt
    if k[i, CRASHED]:
        f[i, STEER] = 0.0
        f[i, ACC] = -1.0 * f[i, V]
    if f[i, V] > p[i, P_MAX_SPEED]:
        f[i, ACC] = min(f[i, ACC], 1.0 * (p[i, P_MAX_SPEED] - f[i, V]))
    elif f[i, V] < p[i, P_MIN_SPEED]:
        f[i, ACC] = max(f[i, ACC], 1.0 * (p[i, P_MIN_SPEED] - f[i, V]))
    beta = npmath.arctan(1 / 2 * npmath.tan(f[i, STEER]))
    vx = f[i, V] * np.cos(f[i, H] + beta)
    vy = f[i, V] * np.sin(f[i, H] + beta)
    f[i, X] += vx * dt
    f[i, Y] += vy * dt
    if k[i, HAS_IMPACT]:
        f[i, X] += f[i, IMP_X]
        f[i, Y] += f[i, IMP_Y]
        k[i, CRASHED] = 1
        k[i, HAS_IMPACT] = 0
    f[i, H] += f[i, V] * np.sin(beta) / (p[i, P_LENGTH] / 2) * dt
    f[i, V] += f[i, ACC] * dt
    k[i, LANE] = closest_lane(lanes, f[i, X], f[i, Y], f[i, H])


@njit
def polygon(f: np.ndarray, p: np.ndarray, i: int, out: np.ndarray) -> None:
    """``RoadObject.polygon``: the 4 corners and the first again, ``out`` (5, 2)."""
    hl = p[i, P_LENGTH] / 2
    hw = p[i, P_WIDTH] / 2
    c = np.cos(f[i, H])
    s = np.sin(f[i, H])
    for q in range(4):
        px = -hl if q < 2 else hl
        py = -hw if q == 0 or q == 3 else hw
        out[q, 0] = (c * px + -s * py) + f[i, X]
        out[q, 1] = (s * px + c * py) + f[i, Y]
    out[4, 0] = out[0, 0]
    out[4, 1] = out[0, 1]


@njit
def project(poly: np.ndarray, nx: float, ny: float) -> tuple[float, float]:
    """``utils.project_polygon`` (min, max)."""
    lo = np.inf
    hi = -np.inf
    for q in range(poly.shape[0]):
        v = npmath.dot2(poly[q, 0], poly[q, 1], nx, ny)
        if v < lo:
            lo = v
        if v > hi:
            hi = v
    return lo, hi


@njit
def interval_distance(min_a: float, max_a: float, min_b: float, max_b: float) -> float:
    """``utils.interval_distance``."""
    return min_b - max_a if min_a < min_b else min_a - max_b


@njit
def polygons_intersecting(a: np.ndarray, b: np.ndarray, dax: float, day: float, dbx: float,
                          dby: float) -> tuple[bool, bool, float, float]:
    """``utils.are_polygons_intersecting``: (intersecting, will intersect, translation x, y)."""
    intersecting = True
    will_intersect = True
    min_distance = np.inf
    axis_x = 0.0
    axis_y = 0.0
    for which in range(2):
        poly = a if which == 0 else b
        for q in range(poly.shape[0] - 1):
            nx = -poly[q + 1, 1] + poly[q, 1]
            ny = poly[q + 1, 0] - poly[q, 0]
            norm = np.sqrt(npmath.dot2(nx, ny, nx, ny))
            nx /= norm
            ny /= norm
            min_a, max_a = project(a, nx, ny)
            min_b, max_b = project(b, nx, ny)
            if interval_distance(min_a, max_a, min_b, max_b) > 0:
                intersecting = False
            velocity_projection = npmath.dot2(nx, ny, dax - dbx, day - dby)
            if velocity_projection < 0:
                min_a += velocity_projection
            else:
                max_a += velocity_projection
            distance = interval_distance(min_a, max_a, min_b, max_b)
            if distance > 0:
                will_intersect = False
            if not intersecting and not will_intersect:
                break
            if abs(distance) < min_distance:
                min_distance = abs(distance)
                cax = (((a[0, 0] + a[1, 0]) + a[2, 0]) + a[3, 0]) / 4
                cay = (((a[0, 1] + a[1, 1]) + a[2, 1]) + a[3, 1]) / 4
                cbx = (((b[0, 0] + b[1, 0]) + b[2, 0]) + b[3, 0]) / 4
                cby = (((b[0, 1] + b[1, 1]) + b[2, 1]) + b[3, 1]) / 4
                if npmath.dot2(cax - cbx, cay - cby, nx, ny) > 0:
                    axis_x, axis_y = nx, ny
                else:
                    axis_x, axis_y = -nx, -ny
    if will_intersect:
        return intersecting, True, min_distance * axis_x, min_distance * axis_y
    return intersecting, False, 0.0, 0.0


@njit
def handle_collisions(f: np.ndarray, k: np.ndarray, p: np.ndarray, i: int, j: int, dt: float, pa: np.ndarray,
                      pb: np.ndarray) -> None:
    """``RoadObject.handle_collisions(i, j, dt)`` for two solid, collidable vehicles."""
    if not (k[i, CHECK_COLL] or k[j, CHECK_COLL]):
        return
    dx = f[j, X] - f[i, X]
    dy = f[j, Y] - f[i, Y]
    if np.sqrt(npmath.dot2(dx, dy, dx, dy)) > (p[i, P_DIAGONAL] + p[j, P_DIAGONAL]) / 2 + f[i, V] * dt:
        return
    polygon(f, p, i, pa)
    polygon(f, p, j, pb)
    dax = f[i, V] * np.cos(f[i, H]) * dt
    day = f[i, V] * np.sin(f[i, H]) * dt
    dbx = f[j, V] * np.cos(f[j, H]) * dt
    dby = f[j, V] * np.sin(f[j, H]) * dt
    intersecting, will_intersect, tx, ty = polygons_intersecting(pa, pb, dax, day, dbx, dby)
    if will_intersect:
        f[i, IMP_X] = tx / 2
        f[i, IMP_Y] = ty / 2
        k[i, HAS_IMPACT] = 1
        f[j, IMP_X] = -tx / 2
        f[j, IMP_Y] = -ty / 2
        k[j, HAS_IMPACT] = 1
    if intersecting:
        k[i, CRASHED] = 1
        k[j, CRASHED] = 1


@njit
def simulate(f: np.ndarray, k: np.ndarray, p: np.ndarray, lanes: np.ndarray, speeds: np.ndarray, frames: int,
             action_frame: int, action_code: int, ctrl: int, dt: float) -> None:
    """``frames`` iterations of ``AbstractEnv._simulate``, in place.

    Args:
        f: vehicle floats (the module docstring has the columns of every state array).
        k: vehicle integers.
        p: vehicle constants.
        lanes: lane geometry.
        speeds: the controlled vehicle's target speeds.
        frames: simulation frames to run.
        action_frame: the frame (0-based) at which the controlled vehicle takes ``action_code``; -1 for none.
        action_code: a code of :data:`ACTION_CODES`; an ``IDMVehicle`` in control ignores it (but acts once more
            at that frame, as ``DiscreteMetaAction.act`` calls its ``act``).
        ctrl: row of the controlled vehicle.
        dt: ``1 / simulation_frequency`` (s).
    """
    n = f.shape[0]
    pa = np.empty((5, 2))
    pb = np.empty((5, 2))
    for frame in range(frames):
        if frame == action_frame:
            if k[ctrl, KIND] == K_MDP:
                meta_action(f, k, p, lanes, speeds, ctrl, action_code)
                controlled_act(f, k, p, lanes, ctrl)
            else:
                idm_act(f, k, p, lanes, ctrl)
        for i in range(n):
            if k[i, KIND] == K_MDP:
                controlled_act(f, k, p, lanes, i)
            else:
                idm_act(f, k, p, lanes, i)
        for i in range(n):
            vehicle_step(f, k, p, lanes, i, dt)
        for i in range(n):
            for j in range(i + 1, n):
                handle_collisions(f, k, p, i, j, dt, pa, pb)


@njit
def reward_terms(f: np.ndarray, k: np.ndarray, lanes: np.ndarray, ego: int, speed_lo: float,
                 speed_hi: float) -> tuple[float, float, float, float]:
    """``HighwayEnv._rewards``: (collision, right lane, high speed, on road) of vehicle ``ego``."""
    n_lanes = lanes.shape[0]
    lane = k[ego, TARGET_LANE]
    forward_speed = f[ego, V] * np.cos(f[ego, H])
    scaled_speed = 0 + (forward_speed - speed_lo) * (1 - 0) / (speed_hi - speed_lo)
    ln = k[ego, LANE]
    s = local_long(lanes, ln, f[ego, X], f[ego, Y])
    r = local_lat(lanes, ln, f[ego, X], f[ego, Y])
    return (float(k[ego, CRASHED]), lane / max(n_lanes - 1, 1), clip(scaled_speed, 0.0, 1.0),
            1.0 if on_lane(lanes, ln, s, r, 0.0) else 0.0)
