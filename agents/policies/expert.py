"""A scripted driver in the meta-action space that reads the simulator: the expert that imitation learns from.

:class:`HeadwayDriver` chooses highway-env's ``DiscreteMetaAction`` (LANE_LEFT,
IDLE, LANE_RIGHT, FASTER, SLOWER) from the true road state, the way a careful
driver keeps a time gap. For a lane ``L`` with a leader at bumper gap ``g`` (m,
centre distance minus half of both lengths) driving at ``v_f`` (m/s), the speed
that holds the gap at standstill distance ``d0`` and time headway ``T`` is

    v_safe(L) = v_f + (g - d0) / T        (no leader: v_safe = infinity),

capped at the top target speed ``v_max``. Each decision:

1. **Lane.** When no lane change is under way, a side lane ``L`` is *open* when
   the gap to its leader is at least ``d0 + max(0, v - v_f) T`` and the gap to
   its follower (speed ``v_r``) at least ``d0 + 2 T_r max(0, v_r - v) + v_r / 2``
   (``v`` the ego speed). The ego moves right to an open lane whose ``v_safe`` is
   within ``keep_right_tolerance`` of its own lane's and at least its speed
   (highway-env pays for the right lane), and left only for a gain in ``v_safe``
   of more than ``margin + 1`` m/s. When its own lane cannot be held at the
   lowest target speed ``v_min`` (``v_safe < v_min + margin``, or a leader slower
   than ``v_min`` within ``lookahead_m``: meta-actions cannot drive below 20 m/s),
   any side lane with a higher ``v_safe`` is taken as soon as the smaller
   *escape* gaps allow (``d0 / 2`` ahead and behind plus ``T_r`` times the
   follower's closing speed).
2. **Speed.** Otherwise SLOWER when the ego's target speed exceeds
   ``v_safe(own lane)`` or the cruise speed ``v_c``, FASTER when the next target speed is at most
   ``min(v_safe - margin, v_c)``, else IDLE. The cruise speed ``v_c`` (25 m/s)
   is the traffic's pace (highway-env's cars drive 20-25 m/s): at the top
   target speed, 30 m/s, the ego would close on every car ahead at 5-10 m/s.

It needs ``env.unwrapped.vehicle`` to be a highway-env ``MDPVehicle`` (the
meta-action ego) and ``env.unwrapped.road``; it ignores the observation. As a
policy (``rhs-slam evaluate --policy headway``) it is a scripted reference; as
the expert of :mod:`agents.algos.imitation` it labels the states a learning policy
visits. On the 50 policy seeds of ``rhs-highway-v0`` see ``results/policies.md``.

Examples:
    >>> import gymnasium as gym, rhs_env
    >>> env = gym.make("rhs-highway-v0", vehicles_count=5)
    >>> _ = env.reset(seed=0)
    >>> driver = HeadwayDriver(env)
    >>> action, _ = driver.predict(None)
    >>> action in range(5)
    True
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from agents.policies.decision import FASTER, IDLE, LANE_LEFT, LANE_RIGHT, SLOWER
from rhs_common.validation import build, check_range, check_types

__all__ = ["HeadwayDriver", "HeadwayDriverConfig", "bumper_gap", "check_highway_env"]


@dataclass(frozen=True)
class HeadwayDriverConfig:
    """Gaps and margins of :class:`HeadwayDriver` (m, s, m/s)."""

    headway_s: float = 1.5  # T: time gap held to the leader
    standstill_gap_m: float = 8.0  # d0: bumper gap at zero speed
    margin_mps: float = 2.0  # speed margin before FASTER; a left change needs margin + 1 m/s of gain
    rear_headway_s: float = 1.0  # T_r: time gap left to a faster follower in the target lane
    keep_right_tolerance_mps: float = 0.5  # a right lane may be this much slower and still be taken
    lookahead_m: float = 60.0  # a leader slower than the lowest target speed this close makes the lane one to leave
    cruise_speed_mps: float = 25.0  # v_c: the highest target speed chosen (the traffic's pace; 30 m/s closes on it)

    def __post_init__(self) -> None:
        check_types(self)
        check_range("headway_s", self.headway_s, 0.0, 10.0, low_open=True)
        check_range("standstill_gap_m", self.standstill_gap_m, 0.0, 100.0)
        check_range("margin_mps", self.margin_mps, 0.0, 20.0)
        check_range("rear_headway_s", self.rear_headway_s, 0.0, 10.0)
        check_range("keep_right_tolerance_mps", self.keep_right_tolerance_mps, 0.0, 20.0)
        check_range("lookahead_m", self.lookahead_m, 0.0, 500.0)
        check_range("cruise_speed_mps", self.cruise_speed_mps, 0.0, 60.0, low_open=True)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def bumper_gap(ego, other) -> float:
    """Gap along the lane between the bumpers of ``ego`` and ``other``, m (negative when they overlap)."""
    return abs(ego.lane_distance_to(other)) - 0.5 * (ego.LENGTH + other.LENGTH)


def check_highway_env(env, driver: str) -> None:
    """``ValueError`` unless ``env`` (or the env it wraps) is a highway-env env with a road and an action type."""
    base = env.unwrapped
    if not hasattr(base, "road") or not hasattr(base, "action_type"):
        raise ValueError(f"{driver} needs a highway-env env (env.unwrapped.road)")


class HeadwayDriver:
    """Time-gap driver on the true road state (see the module docstring for the rule).

    Args:
        env: a highway-env env (or a wrapper of one) whose ego is an ``MDPVehicle``.
        config: a :class:`HeadwayDriverConfig` or a dict of its fields.
    """

    def __init__(self, env: Any, config: Any = None):
        check_highway_env(env, "the headway driver")
        self.env = env
        self.config = build(HeadwayDriverConfig, config, "expert")

    @property
    def _ego(self):
        ego = self.env.unwrapped.vehicle
        if not hasattr(ego, "target_speeds") or not hasattr(ego, "speed_index"):
            raise ValueError(f"the headway driver needs a meta-action ego (MDPVehicle), got {type(ego).__name__}")
        return ego

    def leader(self, lane_index):
        """The vehicle ahead of the ego in ``lane_index`` (None when the lane ahead is empty)."""
        front, _ = self.env.unwrapped.road.neighbour_vehicles(self._ego, lane_index)
        return front

    def safe_speed(self, lane_index) -> float:
        """v_safe in ``lane_index``, m/s (:meth:`safe_speed_behind` its leader)."""
        return self.safe_speed_behind(self.leader(lane_index))

    def safe_speed_behind(self, front) -> float:
        """v_safe = v_f + (g - d0) / T behind the leader ``front`` (infinity for None), m/s."""
        if front is None:
            return float("inf")
        c = self.config
        return float(front.speed + (bumper_gap(self._ego, front) - c.standstill_gap_m) / c.headway_s)

    def is_open(self, lane_index, escape: bool = False) -> bool:
        """Room to move into ``lane_index`` now: enough gap to its leader and to its (faster) follower.

        ``escape``: the smaller gaps of a forced change (half the standstill gap ahead and
        behind, one rear headway of closing speed behind), for a lane that cannot be held.
        """
        ego, c = self._ego, self.config
        front, rear = self.env.unwrapped.road.neighbour_vehicles(ego, lane_index)
        d0 = 0.5 * c.standstill_gap_m if escape else c.standstill_gap_m
        if front is not None:
            need = d0 + max(0.0, ego.speed - front.speed) * c.headway_s
            if bumper_gap(ego, front) < need:
                return False
        if rear is None:
            return True
        closing = max(0.0, rear.speed - ego.speed)
        need = d0 + c.rear_headway_s * closing if escape else d0 + 2.0 * c.rear_headway_s * closing + 0.5 * rear.speed
        return bumper_gap(ego, rear) > need

    def _lane_action(self, ego, front, v_own: float, v_max: float, v_min: float) -> int | None:
        """LANE_LEFT / LANE_RIGHT when a side lane is worth taking, else None (``front``: the own lane's leader)."""
        c = self.config
        own = ego.target_lane_index
        slow_leader = front is not None and front.speed < v_min and bumper_gap(ego, front) < c.lookahead_m
        # the gap closes, or will, even at the lowest target speed: any better lane will do
        trapped = v_own < v_min + c.margin_mps or slow_leader
        best, best_v, best_right = None, v_own, False
        for lane in self.env.unwrapped.road.network.side_lanes(own):
            if not self.is_open(lane, escape=trapped):
                continue
            v = min(self.safe_speed(lane), v_max)
            right = lane[2] > own[2]
            keep_right = right and v >= v_own - c.keep_right_tolerance_mps and v >= min(v_max, ego.speed)
            worth = keep_right or v - v_own > c.margin_mps + 1.0 or (trapped and v > v_own)
            if worth and (best is None or v > best_v or (right and v >= best_v)):
                best, best_v, best_right = lane, v, right
        if best is None:
            return None
        return LANE_RIGHT if best_right else LANE_LEFT

    def act(self) -> int:
        """The meta-action for the current state."""
        ego, c = self._ego, self.config
        speeds = np.asarray(ego.target_speeds, dtype=float)
        v_max = float(speeds[-1])
        front = self.leader(ego.target_lane_index)
        v_safe = self.safe_speed_behind(front)
        v_own = min(v_safe, v_max)
        if ego.lane_index == ego.target_lane_index:
            lane_action = self._lane_action(ego, front, v_own, v_max, float(speeds[0]))
            if lane_action is not None:
                return lane_action
        i = int(ego.speed_index)
        if speeds[i] > min(v_own, max(c.cruise_speed_mps, float(speeds[0]))) and i > 0:
            return SLOWER
        if i + 1 < len(speeds) and speeds[i + 1] <= min(v_safe - c.margin_mps, c.cruise_speed_mps):
            return FASTER
        return IDLE

    def predict(self, obs, deterministic: bool = True):
        """SB3's ``predict`` signature; the observation is not used."""
        return self.act(), None
