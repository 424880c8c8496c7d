"""The decision interval (agents.policies.decision): HoldAction's step accounting, the
``decision_interval`` validation, and a policy trained with an interval being
evaluated with it (re-deciding every k env steps, reset at each episode).

Small and fast: a counting stub env, and a 64-env-step PPO run on short
ground-truth episodes. No test measures time.
"""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

import rhs_env  # noqa: F401  (registers the ids)
from agents.algos.train import train, train_rllib_backend
from agents.evaluate import evaluate, load_policy, make_env, run_episode
from agents.policies.decision import HeldPolicy, HoldAction, check_decision_interval, check_decision_mode, fill_action, held

TRUTH = "rhs-highway-v0"
TRUTH_SMALL = {"vehicles_count": 5, "lanes_count": 3, "duration": 4}  # 20 env steps per episode


class Counter(gym.Env):
    """Reward = the step number (1, 2, ...); terminates after ``end`` steps; obs = the step number."""

    observation_space = spaces.Box(0, 1000, (1,), np.float32)
    action_space = spaces.Discrete(3)

    def __init__(self, end: int = 7):
        self.end, self.t, self.actions = end, 0, []

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.array([0], np.float32), {}

    def step(self, action):
        self.t += 1
        self.actions.append(int(action))
        return np.array([self.t], np.float32), float(self.t), self.t >= self.end, False, {"t": self.t}


def test_hold_action_sums_k_rewards_and_stops_at_the_end():
    env = HoldAction(Counter(end=7), 3)
    obs, _ = env.reset(seed=0)
    obs, r, term, trunc, info = env.step(2)
    assert r == 1 + 2 + 3 and info["held_steps"] == 3 and info["t"] == 3 and obs[0] == 3 and not term
    obs, r, term, trunc, info = env.step(1)
    assert r == 4 + 5 + 6 and info["held_steps"] == 3 and not term
    obs, r, term, trunc, info = env.step(0)  # one step left: early stop, last obs / info
    assert r == 7 and info["held_steps"] == 1 and term and obs[0] == 7 and info["t"] == 7
    assert env.unwrapped.actions == [2, 2, 2, 1, 1, 1, 0]
    assert env.observation_space == Counter.observation_space and env.action_space == Counter.action_space


def test_pulse_mode_takes_the_action_once_then_idle():
    """decision_mode "pulse": meta-actions are impulses, so the steps after a decision get IDLE (1)."""
    env = HoldAction(Counter(end=7), 3, fill=fill_action("pulse"))
    env.reset(seed=0)
    _, r, *_ = env.step(2)
    env.step(0)
    assert r == 1 + 2 + 3 and env.unwrapped.actions == [2, 1, 1, 0, 1, 1]
    assert fill_action("hold") is None
    with pytest.raises(ValueError, match="decision_mode must be one of hold, pulse"):
        check_decision_mode("repeat")

    class Inner:
        def predict(self, obs, deterministic=True):
            return 4, None

    policy = held(Inner(), 3, "pulse")
    assert [policy.predict(None)[0] for _ in range(7)] == [4, 1, 1, 4, 1, 1, 4]
    with pytest.raises(ValueError, match="decision_mode"):
        held(Inner(), 3, "sometimes")


def test_hold_action_of_one_is_the_env():
    a, b = HoldAction(Counter(), 1), Counter()
    a.reset(seed=0)
    b.reset(seed=0)
    ra, rb = a.step(1), b.step(1)
    assert ra[1] == rb[1] and ra[4]["held_steps"] == 1


@pytest.mark.parametrize(("bad", "error"), [(0, ValueError), (-1, ValueError), (1001, ValueError), (2.5, TypeError),
                                            (True, TypeError), ("5", TypeError), (None, TypeError)])
def test_decision_interval_is_validated(bad, error):
    with pytest.raises(error, match="decision_interval"):
        check_decision_interval(bad)
    with pytest.raises(error, match="decision_interval"):
        HoldAction(Counter(), bad)
    with pytest.raises(error, match="decision_interval"):
        held(object(), bad)


def test_train_rejects_a_bad_decision_interval_from_the_yaml(tmp_path):
    hp = tmp_path / "ppo.yml"
    hp.write_text(f"{TRUTH}:\n  policy: MlpPolicy\n  decision_interval: 0\n")
    with pytest.raises(ValueError, match="decision_interval"):
        train("ppo", TRUTH, 64, tmp_path / "run", hyperparams=hp, progress=False)
    assert not (tmp_path / "run").exists()  # rejected before anything is built
    with pytest.raises(ValueError, match="decision_interval"):
        train_rllib_backend(TRUTH, 64, tmp_path / "rl", hyperparams=hp, progress=False)


def test_held_policy_repeats_and_resets():
    class Inner:
        calls = 0

        def predict(self, obs, deterministic=True):
            self.calls += 1
            return np.int64(self.calls % 3), None

    inner = Inner()
    policy = HeldPolicy(inner, 4)
    env = Counter(end=10)
    r1 = run_episode(env, policy, seed=0)  # 10 steps: decisions at steps 1, 5, 9
    assert r1["steps"] == 10 and inner.calls == 3
    assert env.actions == [1] * 4 + [2] * 4 + [0] * 2
    run_episode(env, policy, seed=1)  # reset: the new episode starts with a fresh decision
    assert inner.calls == 6 and env.actions[10] == 1
    assert held(inner, 1) is inner


def test_policy_trained_with_an_interval_is_evaluated_with_it(tmp_path):
    hp = tmp_path / "ppo.yml"
    hp.write_text(f"""
{TRUTH}:
  policy: MlpPolicy
  n_envs: 1
  n_steps: 16
  batch_size: 16
  n_epochs: 1
  gamma: 0.8
  decision_interval: 4
  policy_kwargs:
    net_arch: [8]
""")
    s = train("ppo", TRUTH, 64, tmp_path / "run", hyperparams=hp, env_kwargs=TRUTH_SMALL, eval_freq=0,
              checkpoint_freq=0, progress=False)  # fmt: skip
    assert s["decision_interval"] == 4 and s["decisions"] == 16 and s["timesteps"] == 64
    assert "decision_interval" not in s["hyperparams"] or s["hyperparams"]["decision_interval"] == 4
    model_zip = tmp_path / "run" / "model.zip"
    meta = json.loads(model_zip.with_suffix(".json").read_text())
    assert meta["decision_interval"] == 4
    # the monitor counts env steps: full episodes are 20 steps long, not 5 decisions
    rows = [line.split(",") for line in next((tmp_path / "run" / "monitor").glob("*.csv")).read_text().splitlines()[2:]]
    assert rows and all(int(r[1]) <= 20 for r in rows) and any(int(r[1]) > 5 for r in rows)

    env = make_env(TRUTH, TRUTH_SMALL)
    policy = load_policy(model_zip, env)
    assert isinstance(policy, HeldPolicy) and policy.k == 4
    inner = policy.model
    calls = []
    real = inner.predict
    inner.predict = lambda obs, *a, **kw: (calls.append(1), real(obs, *a, **kw))[1]
    steps = [run_episode(env, policy, seed)["steps"] for seed in (0, 1)]
    env.close()
    assert len(calls) == sum(math.ceil(n / 4) for n in steps)  # one decision per 4 env steps, reset per episode

    ev = evaluate(model_zip, episodes=2, seed=0, progress=False)  # env id and kwargs from model.json
    assert ev["env_id"] == TRUTH and [r["steps"] for r in ev["runs"]] == steps  # scored per env step
