"""Reward shaping for training: a time-to-collision penalty and a cost of the shield's interventions (the
evaluation keeps highway-env's reward).

highway-env's reward pays speed a little every step and a crash only by ending the
episode: at 1 Hz a crash costs the rewards the episode would still have paid, seconds
after the decision that caused it, while the speed term is there at once. PPO from scratch
then learns either to hold the lowest speed (safe, and nearly as well paid) or to drive
fast and crash. Shaping brings the danger to the step where it arises:

    r' = r - w * max(0, 1 - TTC / T0),     TTC = g / max(v_ego - v_lead, 0)

with ``g`` the bumper gap to the leader in the ego's lane (m), the closing speed in m/s,
``T0 = ttc_s`` the time to collision below which the penalty starts (s) and ``w = weight``
the penalty at TTC = 0 (in units of highway-env's normalised per-step reward, which lies in
[0, 1]). An open road or a leader pulling away costs nothing. The leader is read from the
simulator (the reward is a training signal, never an observation).

Under the radar safety shield (:mod:`agents.policies.shield`) a policy can leave the braking and the
lane checks to the shield: PPO from scratch learns one action (FASTER, or LANE_RIGHT) and the
shield does the rest. The intervention cost makes the shield's work the policy's loss:

    r'' = r' - c * [the shield replaced the step's action]

with ``c = shield_cost`` per replaced env step (``info["shield"]`` is not None; 0: off). The
shield wraps the env inside this wrapper, so its reasons reach it.

A crash can also be priced at the step where it happens:

    r''' = r'' - P * [the ego crashed at this step]

with ``P = crash_penalty`` (0: off). Why it is needed: with a discount ``gamma`` per decision, a
per-decision reward ``r``, and a speed gain ``g`` that carries a crash hazard ``h`` per decision,
driving faster pays while ``(r + g - P h) / (1 - gamma (1 - h)) > r / (1 - gamma)``, that is up to

    h* = g (1 - gamma) / (r gamma + P (1 - gamma)).

As measured on the campaign's test seeds (``docs/results/campaign.md``: decisions every 5 env steps, the
DAgger start's ``r`` ~ 4.05 at 23.6 m/s, its RL runs' crash-free episodes at ~29 m/s worth ``g`` ~ 0.75),
``gamma = 0.8`` and ``P = 0`` give ``h*`` ~ 4.6 % per decision, against the ~0.8-1.0 % the runs crash with (a
27-33 % collision rate over 40-decision episodes). ``gamma = 0.95`` with ``P = 500`` lowers ``h*`` to ~0.13 %.

The wrapper sits outside the ``Monitor`` of :func:`agents.algos.vec_env.make_vec_env`, so the
monitor files and the learning curves keep the unshaped return; ``info["shaping"]`` is the
penalty of the step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym

from agents.policies.expert import bumper_gap
from rhs_common.validation import build, check_range, check_types

__all__ = ["RewardShaping", "ShapingConfig", "time_to_collision", "ttc_penalty"]


@dataclass(frozen=True)
class ShapingConfig:
    """The penalty of the module docstring."""

    ttc_s: float = 3.0  # T0: time to collision below which the penalty starts, s
    weight: float = 0.5  # w: the penalty at TTC = 0, per env step (highway-env's normalised reward is in [0, 1])
    shield_cost: float = 0.0  # c: the cost of an env step whose action the shield replaced (0: off)
    crash_penalty: float = 0.0  # P: subtracted at the env step the ego crashes (0: off)

    def __post_init__(self) -> None:
        check_types(self)
        check_range("ttc_s", self.ttc_s, 0.0, 60.0, low_open=True)
        check_range("weight", self.weight, 0.0, 100.0)
        check_range("shield_cost", self.shield_cost, 0.0, 100.0)
        check_range("crash_penalty", self.crash_penalty, 0.0, 1.0e4)


def time_to_collision(env: gym.Env) -> float:
    """TTC to the leader in the ego's lane, s (inf for none or a leader not closing in; 0 for an overlap)."""
    base: Any = env.unwrapped
    ego = base.vehicle
    front, _ = base.road.neighbour_vehicles(ego, ego.lane_index)
    if front is None:
        return float("inf")
    closing = float(ego.speed - front.speed)
    gap = bumper_gap(ego, front)
    if gap <= 0:
        return 0.0
    return gap / closing if closing > 0 else float("inf")


def ttc_penalty(ttc: float, config: ShapingConfig) -> float:
    """``w * max(0, 1 - TTC / T0)``.

    >>> ttc_penalty(1.5, ShapingConfig(ttc_s=3.0, weight=0.5)), ttc_penalty(float("inf"), ShapingConfig())
    (0.25, 0.0)
    """
    return config.weight * max(0.0, 1.0 - ttc / config.ttc_s)


class RewardShaping(gym.Wrapper):
    """Subtract :func:`ttc_penalty` of the state reached, ``shield_cost`` for a step the shield replaced and
    ``crash_penalty`` at a crash from each step's reward (see the module docstring); ``info["shaping"]`` is the sum
    subtracted (<= 0).

    Examples:
        >>> import gymnasium as gym, rhs_env
        >>> env = RewardShaping(gym.make("rhs-highway-v0", vehicles_count=5), {"ttc_s": 3.0})
        >>> _ = env.reset(seed=0)
        >>> _, reward, *_, info = env.step(1)
        >>> info["shaping"] <= 0.0
        True
    """

    def __init__(self, env: gym.Env, config: ShapingConfig | dict[str, Any] | None = None):
        super().__init__(env)
        self.config = build(ShapingConfig, config, "reward_shaping")

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        crashed = bool(info.get("crashed"))
        penalty = self.config.crash_penalty if crashed else ttc_penalty(time_to_collision(self.env), self.config)
        if info.get("shield") is not None:
            penalty += self.config.shield_cost
        return obs, float(reward) - penalty, terminated, truncated, {**info, "shaping": -penalty}
