"""A lookahead driver on the privileged simulator: the rollout improvement of :class:`agents.policies.expert.HeadwayDriver`.

At each decision the driver copies the road (the ego and the traffic from ``reach_behind_m`` behind it to
``reach_ahead_m`` ahead), and for each
meta-action ``a`` drives the copy for ``horizon_s`` seconds: ``a`` now, then the headway driver deciding once a
second (pulse mode, IDLE between), as the ego will. highway-env's traffic (IDM + MOBIL) is deterministic given the
state, so each copy is a forecast of what the action leads to. The score of ``a`` is the return of its forecast,

    Q(a) = sum_{t < H} r_t  -  crash_penalty [crashed before H]  -  unsafe_penalty [min headway < min_headway_s],

with r_t highway-env's normalised per-step reward (speed in ``reward_speed_range``, right lane, on road) and the
margin term: the smaller time gap of the ego's lane (to its leader at the ego's speed, to its follower at the
follower's) falling below ``min_headway_s`` at any step. Without the margin the driver is faster still, by
following at short gaps, which a student that sees only radar points could not copy. The
driver takes ``argmax_a Q(a)`` unless it beats the headway driver's own action by less than ``tie_margin``
(then the headway driver's action): a one-step rollout policy, which by the rollout argument (Bertsekas,
*Rollout algorithms*, 1997) returns at least what its base policy returns over the horizon in a deterministic
world. A crash ends an episode (all later reward is lost), so ``crash_penalty`` is of the order of an episode's
remaining return.

Cost: up to ``5 x horizon_s x policy_frequency x frames_per_step`` simulator frames per decision on the copied
traffic (150 frames with the defaults, about 0.12 s per decision on one core, ``results/teachers.md``; the env's own 3 frames per step
triple it). It reads ``env.unwrapped.road`` and ``.vehicle`` and ignores the
observation, like :class:`agents.policies.expert.HeadwayDriver`.

Examples:
    >>> import gymnasium as gym, rhs_env
    >>> env = gym.make("rhs-highway-v0", vehicles_count=5)
    >>> _ = env.reset(seed=0)
    >>> driver = LookaheadDriver(env, {"horizon_s": 2.0})
    >>> action, _ = driver.predict(None)
    >>> action in range(5)
    True
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass, field
from typing import Any

from agents.policies.decision import FASTER, IDLE, LANE_LEFT, LANE_RIGHT, SLOWER
from agents.policies.expert import HeadwayDriver, HeadwayDriverConfig, bumper_gap, check_highway_env
from rhs_common.validation import build, check_int, check_range, check_types

__all__ = ["LookaheadDriver", "LookaheadDriverConfig", "META_ACTIONS"]

#: highway-env's meta-action names, in DiscreteMetaAction's order (LANE_LEFT, IDLE, LANE_RIGHT, FASTER, SLOWER)
META_ACTIONS = ("LANE_LEFT", "IDLE", "LANE_RIGHT", "FASTER", "SLOWER")


@dataclass(frozen=True)
class LookaheadDriverConfig:
    """Horizon, decision period and scoring of :class:`LookaheadDriver` (s, m, reward units)."""

    horizon_s: float = 6.0  # H: how far each action's forecast runs
    decision_s: float = 1.0  # the forecast's base policy decides once per this period (pulse mode)
    crash_penalty: float = 100.0  # subtracted from a forecast that crashes (about an episode's remaining return)
    tie_margin: float = 0.5  # another action must beat the headway driver's by this much return
    min_headway_s: float = 0.6  # a forecast whose ego comes closer than this time gap to a car ahead or behind ...
    unsafe_penalty: float = 20.0  # ... loses this much (0: no margin asked)
    reach_ahead_m: float = 150.0  # traffic copied ahead of the ego
    reach_behind_m: float = 80.0  # and behind it
    frames_per_step: int = 1  # simulator frames per env step in a forecast (0: the env's, 15 Hz / 5 Hz = 3)
    headway: HeadwayDriverConfig = field(default_factory=HeadwayDriverConfig)  # the base policy of the forecasts

    def __post_init__(self) -> None:
        check_types(self)
        check_range("horizon_s", self.horizon_s, 0.0, 60.0, low_open=True)
        check_range("decision_s", self.decision_s, 0.0, 10.0, low_open=True)
        check_range("crash_penalty", self.crash_penalty, 0.0, 1e6)
        check_range("tie_margin", self.tie_margin, 0.0, 1e3)
        check_range("min_headway_s", self.min_headway_s, 0.0, 10.0)
        check_range("unsafe_penalty", self.unsafe_penalty, 0.0, 1e6)
        check_range("reach_ahead_m", self.reach_ahead_m, 0.0, 5000.0)
        check_range("reach_behind_m", self.reach_behind_m, 0.0, 5000.0)
        check_int("frames_per_step", self.frames_per_step, 0, 100)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class _Forecast:
    """A copy of the road around the ego, read the way the env reads itself: ``.unwrapped.road`` / ``.vehicle`` for
    the headway driver, and the env class's own reward (highway-env's ``_reward`` / ``_rewards``) on the copy."""

    def __init__(self, road, ego, env):
        self.road, self.vehicle, self.config = road, ego, env.config
        self.action_type = None  # HeadwayDriver only checks that it exists
        self._env_cls = type(env)

    @property
    def unwrapped(self) -> _Forecast:
        return self

    def _compiled_traffic(self) -> None:
        """None: the copy is stepped by highway-env's own Python (the env's reward then reads it as highway-env does)."""
        return None

    def _rewards(self, action):
        return self._env_cls._rewards(self, action)

    def reward(self) -> float:
        """The env's normalised per-step reward of the copy's state."""
        return float(self._env_cls._reward(self, None))


class LookaheadDriver:
    """One-step rollout of the headway driver on copies of the true traffic (see the module docstring).

    Args:
        env: a highway-env env (or a wrapper of one) whose ego is an ``MDPVehicle``.
        config: a :class:`LookaheadDriverConfig` or a dict of its fields.
    """

    def __init__(self, env: Any, config: Any = None):
        check_highway_env(env, "the lookahead driver")
        self.env = env
        self.config = build(LookaheadDriverConfig, config, "lookahead")
        self.base_driver = HeadwayDriver(env, self.config.headway)

    def _copy(self):
        """The road with the ego and the traffic within reach, deep-copied (the lane network shared), and the ego's copy."""
        base, c = self.env.unwrapped, self.config
        road, ego = base.road, base.vehicle
        x0 = ego.position[0]
        near = [v for v in road.vehicles if v is ego or -c.reach_behind_m <= v.position[0] - x0 <= c.reach_ahead_m]
        everyone = road.vehicles
        memo = {id(road.network): road.network, id(road.np_random): road.np_random}
        try:
            road.vehicles = near
            road_copy = copy.deepcopy(road, memo)
        finally:
            road.vehicles = everyone
        return road_copy, memo[id(ego)]

    def forecast(self, action: int) -> float:
        """Q(action): the return of ``action`` now, then the headway driver once per ``decision_s``, over the horizon."""
        base, c = self.env.unwrapped, self.config
        sim_hz, pol_hz = base.config["simulation_frequency"], base.config["policy_frequency"]
        frames = c.frames_per_step or int(sim_hz // pol_hz)  # simulator frames per env step
        dt = 1.0 / (pol_hz * frames)
        steps = max(1, int(round(c.horizon_s * pol_hz)))
        every = max(1, int(round(c.decision_s * pol_hz)))
        road, ego = self._copy()
        sim = _Forecast(road, ego, base)
        driver = HeadwayDriver(sim, self.config.headway)
        total, unsafe = 0.0, False
        for k in range(steps):
            act = action if k == 0 else (driver.act() if k % every == 0 else IDLE)
            if act != IDLE:
                ego.act(META_ACTIONS[act])
            for _ in range(frames):
                road.act()
                road.step(dt)
            if ego.crashed:  # the episode ends here: no reward for this step, the crash penalty instead
                total -= c.crash_penalty
                break
            total += sim.reward()
            unsafe = unsafe or (c.unsafe_penalty > 0 and self._headway_s(ego, road) < c.min_headway_s)
        return total - (c.unsafe_penalty if unsafe else 0.0)

    @staticmethod
    def _headway_s(ego, road) -> float:
        """The smaller time gap of the ego's lane: to its leader at the ego's speed, to its follower at the follower's (s)."""
        front, rear = road.neighbour_vehicles(ego, ego.lane_index)
        out = float("inf")
        if front is not None:
            out = min(out, bumper_gap(ego, front) / max(ego.speed, 1.0))
        if rear is not None:
            out = min(out, bumper_gap(ego, rear) / max(rear.speed, 1.0))
        return out

    def candidates(self) -> list[int]:
        """The meta-actions that change something: no lane change off the road, no speed step past the ends."""
        ego = self.env.unwrapped.vehicle
        side = {lane[2] for lane in self.env.unwrapped.road.network.side_lanes(ego.target_lane_index)}
        lane = ego.target_lane_index[2]
        out = [IDLE]
        if lane - 1 in side:
            out.append(LANE_LEFT)
        if lane + 1 in side:
            out.append(LANE_RIGHT)
        if ego.speed_index + 1 < len(ego.target_speeds):
            out.append(FASTER)
        if ego.speed_index > 0:
            out.append(SLOWER)
        return out

    def decide(self) -> tuple[int, int, dict[int, float]]:
        """The meta-action, the headway driver's own and the forecast return Q of every candidate."""
        default = self.base_driver.act()
        cand = self.candidates()
        if default not in cand:
            cand.append(default)
        q = {a: self.forecast(a) for a in cand}
        best = max(q, key=lambda a: q[a])
        return (best if q[best] > q[default] + self.config.tie_margin else default), default, q

    def act(self) -> int:
        """The meta-action for the current state."""
        return self.decide()[0]

    def predict(self, obs, deterministic: bool = True):
        """SB3's ``predict`` signature; the observation is not used."""
        return self.act(), None
