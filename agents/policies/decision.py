"""A decision interval: the agent decides every ``k`` env steps.

The envs step at 5 Hz (one radar scan and SLAM cycle per step, 200 steps per
40 s episode), five times highway-env's usual 1 Hz decision rate. Meta-actions
(FASTER, SLOWER, lane changes) take effect over seconds, so a decision every
step stretches credit assignment over five times as many decisions.

* :class:`HoldAction` (training): one agent step = ``k`` env steps with the
  action held; the reward is the sum of the ``k`` rewards, the episode stops
  early on ``terminated`` / ``truncated``, and the last observation and info are
  returned (``info["held_steps"]``: the env steps taken). SLAM keeps cycling at
  5 Hz underneath: only the agent's decisions are sparser.
* :class:`HeldPolicy` (evaluation): a policy that re-decides every ``k``
  ``predict`` calls and repeats its last action otherwise, so a policy trained
  with :class:`HoldAction` is still scored per env step on the same seeds.
  :func:`agents.evaluate.run_episode` calls its :meth:`HeldPolicy.reset` at
  every episode start.

Two ways to fill the steps between decisions (``decision_mode``):

* ``"hold"`` (default): repeat the action. Right for actions that are levels
  (an acceleration), wrong for highway-env's meta-actions, which are impulses:
  FASTER held 5 steps climbs to the top target speed, LANE_LEFT held changes
  lane twice: a driver that is safe deciding every step crashes when its
  decisions are held.
* ``"pulse"``: the action on the decision step, IDLE (:data:`IDLE`, highway-env's
  DiscreteMetaAction index 1) on the others, i.e. highway-env's usual 1 Hz
  meta-action policy at k = 5.

The interval is the ``decision_interval`` key of a hyperparameter entry
(``agents/hyperparams/ppo.yml`` style, default 1) and the mode its
``decision_mode`` key; ``rhs-slam train`` saves both in the JSON beside the
model zip and :func:`agents.evaluate.load_policy` reads them back.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

__all__ = [
    "DECISION_MODES", "FASTER", "HeldPolicy", "HoldAction", "IDLE", "LANE_LEFT", "LANE_RIGHT", "MAX_DECISION_INTERVAL",
    "SLOWER", "check_decision_interval", "check_decision_mode", "fill_action", "held",
]

#: largest accepted interval (a 40 s episode at 5 Hz has 200 steps)
MAX_DECISION_INTERVAL = 1000
#: how the steps between decisions are filled: the action repeated, or IDLE after it
DECISION_MODES = ("hold", "pulse")
#: highway-env's DiscreteMetaAction indices (``DiscreteMetaAction.ACTIONS_ALL``): the one definition the
#: package, the scripts and the tests use. IDLE keeps lane and target speed; FASTER and SLOWER step the
#: target speed up or down one entry of ``target_speeds``; the lane changes move one lane.
LANE_LEFT, IDLE, LANE_RIGHT, FASTER, SLOWER = 0, 1, 2, 3, 4


def check_decision_mode(value: Any) -> str:
    """``value`` if it is one of :data:`DECISION_MODES`, else ``ValueError`` naming ``decision_mode``."""
    if value not in DECISION_MODES:
        raise ValueError(f"decision_mode must be one of {', '.join(DECISION_MODES)}, got {value!r}")
    return str(value)


def fill_action(mode: str) -> int | None:
    """The action between decisions: None (repeat the decision) for ``"hold"``, :data:`IDLE` for ``"pulse"``."""
    return IDLE if check_decision_mode(mode) == "pulse" else None


def check_decision_interval(value: Any) -> int:
    """``value`` as an int in ``[1, MAX_DECISION_INTERVAL]``: ``TypeError`` if not an int, ``ValueError`` if out of
    range, both naming ``decision_interval``.

    Examples:
        >>> check_decision_interval(5)
        5
        >>> check_decision_interval(0)
        Traceback (most recent call last):
        ...
        ValueError: decision_interval must be an integer in [1, 1000] (env steps per decision), got 0
    """
    if not isinstance(value, int) or isinstance(value, bool):
        raise TypeError(f"decision_interval must be an integer (env steps per decision), got {value!r}")
    if not 1 <= value <= MAX_DECISION_INTERVAL:
        raise ValueError(f"decision_interval must be an integer in [1, {MAX_DECISION_INTERVAL}] "
                         f"(env steps per decision), got {value!r}")  # fmt: skip
    return int(value)


class HoldAction(gym.Wrapper):
    """Hold each action for ``k`` env steps; the reward is their sum.

    Stops early when the episode ends (``terminated`` or ``truncated``) and
    returns the last observation and info, with ``info["held_steps"]`` the env
    steps actually taken. Spaces are the env's. Wrap it outside a ``Monitor``
    so episode returns and lengths stay counted per env step.

    Examples:
        >>> import gymnasium as gym
        >>> env = HoldAction(gym.make("CartPole-v1"), 5)
        >>> obs, info = env.reset(seed=0)
        >>> obs, reward, terminated, truncated, info = env.step(0)
        >>> reward, info["held_steps"]
        (5.0, 5)
        >>> while not (terminated or truncated):
        ...     obs, reward, terminated, truncated, info = env.step(0)
        >>> terminated, info["held_steps"] < 5, reward == info["held_steps"]
        (True, True, True)
    """

    def __init__(self, env: gym.Env, k: int, fill: int | None = None):
        super().__init__(env)
        self.k = check_decision_interval(k)
        self.fill = fill  # None: hold the action; else the action of the steps after the first (decision_mode pulse)

    def step(self, action):
        total, taken = 0.0, 0
        while True:
            obs, reward, terminated, truncated, info = self.env.step(action if taken == 0 or self.fill is None else self.fill)
            total += float(reward)
            taken += 1
            if terminated or truncated or taken == self.k:
                break
        info = {**info, "held_steps": taken}
        return obs, total, terminated, truncated, info


class HeldPolicy:
    """A policy (``predict(obs, deterministic)``) that decides every ``k`` calls and repeats its action between.

    Call :meth:`reset` at the start of each episode (``run_episode`` does), so
    the first step of every episode is a fresh decision.

    Examples:
        >>> class Count:
        ...     calls = 0
        ...     def predict(self, obs, deterministic=True):
        ...         self.calls += 1
        ...         return self.calls, None
        >>> policy = HeldPolicy(Count(), 3)
        >>> [policy.predict(None)[0] for _ in range(7)]
        [1, 1, 1, 2, 2, 2, 3]
        >>> policy.reset()
        >>> policy.predict(None)[0]
        4
    """

    def __init__(self, model, k: int, fill: int | None = None):
        self.model, self.k, self.fill = model, check_decision_interval(k), fill
        self._action: Any = None
        self._state: Any = None
        self._left = 0

    def reset(self) -> None:
        """Forget the held action: the next ``predict`` decides."""
        self._action, self._state, self._left = None, None, 0
        if hasattr(self.model, "reset"):
            self.model.reset()

    def predict(self, obs, *args, **kwargs):
        if self._left <= 0:
            self._action, self._state = self.model.predict(obs, *args, **kwargs)
            self._left = self.k
            self._left -= 1
            return self._action, self._state
        self._left -= 1
        return (self._action if self.fill is None else self.fill), self._state

    def __getattr__(self, name):
        return getattr(self.model, name)


def held(model, k: int, mode: str = "hold"):
    """``model`` itself for ``k == 1``, else a :class:`HeldPolicy` over it (``mode``: :data:`DECISION_MODES`)."""
    k = check_decision_interval(k)
    return model if k == 1 else HeldPolicy(model, k, fill_action(mode))
