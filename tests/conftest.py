"""Test-wide settings (headless plotting and rendering, deterministic threads) and the shared small env.

The small env every env-level test builds: a coarse 5-degree scan (I = 18 slots) of a
short closed-form RHS (``antenna="hologram"``: no pattern library to build), 80 m range,
64 points; the SLAM envs add ICP registration (the CNN weights are trained separately)
and 16 landmarks. Tests take the kwargs (:func:`small_env_kwargs`, or the constants for
module-level use: ``from conftest import SMALL_SLAM_ENV``) or the :func:`small_env`
fixture, which builds such envs and closes them after the test.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Callable, Iterator
from typing import Any

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("OMP_NUM_THREADS", "1")

#: the small radar (``radar=`` of every rhs env): seconds per episode, not minutes
SMALL_RADAR: dict[str, Any] = {"scan": {"grid_deg": 5.0}, "rhs": {"elements": 24}, "max_range_m": 80.0}
#: kwargs of a small radar env (rhs-highway-radar-v0, RadarObservation)
SMALL_RADAR_ENV: dict[str, Any] = {"antenna": "hologram", "radar": SMALL_RADAR, "max_points": 64}
#: kwargs of a small SLAM env (rhs-highway-slam-v0, rhs-paper-v0, rhs-highway-dense-v0)
SMALL_SLAM_ENV: dict[str, Any] = {**SMALL_RADAR_ENV, "registration": "icp", "max_landmarks": 16}


#: the point-set policy of the tiny training runs (16-unit layers: seconds per update)
TINY_POLICY_KWARGS: dict[str, Any] = {
    "features_extractor_class": "point_set",
    "features_extractor_kwargs": {"point_dim": 16, "box_dim": 8},
    "net_arch": [16],
}


def tiny_hyperparams(env_id: str, **fields: Any) -> str:
    """A hyperparameter file (rl-zoo YAML) for ``env_id``: ``MultiInputPolicy``, ``fields``, the tiny policy."""
    import yaml

    entry = {"policy": "MultiInputPolicy", **fields, "policy_kwargs": copy.deepcopy(TINY_POLICY_KWARGS)}
    return yaml.safe_dump({env_id: entry}, sort_keys=False)


def small_env_kwargs(slam: bool = True, **overrides: Any) -> dict[str, Any]:
    """A fresh copy of the small env's kwargs (SLAM or radar only) with ``overrides`` on top."""
    return {**copy.deepcopy(SMALL_SLAM_ENV if slam else SMALL_RADAR_ENV), **overrides}


@pytest.fixture
def small_env() -> Iterator[Callable[..., Any]]:
    """``small_env(env_id, **overrides)``: ``gym.make`` of the small env, closed after the test."""
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids)

    made: list[Any] = []

    def make(env_id: str, slam: bool = True, **overrides: Any) -> Any:
        env = gym.make(env_id, **small_env_kwargs(slam, **overrides))
        made.append(env)
        return env

    yield make
    for env in made:
        env.close()


# ---------------------------------------------------------------- the fine-tuning tests' toy observation
def privileged_space() -> Any:
    """A small point set, a box and the critic's privileged vector: the observation of the fine-tuning tests."""
    import gymnasium as gym
    import numpy as np

    from agents.policies.privileged import PRIVILEGED_DIM, PRIVILEGED_KEY

    return gym.spaces.Dict({
        "points": gym.spaces.Box(-100.0, 100.0, shape=(8, 3), dtype=np.float32),
        "points_mask": gym.spaces.MultiBinary(8),
        "ego": gym.spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32),
        PRIVILEGED_KEY: gym.spaces.Box(-1.0, 1.0, shape=(PRIVILEGED_DIM,), dtype=np.float32),
    })


def reward_two_env() -> Any:
    """A 10-step episode of random point sets (the actor's part of :func:`privileged_space`) paying 1 for action 2:
    something for PPO to move towards, in a few hundred steps."""
    import gymnasium as gym

    from agents.policies.privileged import without_privileged

    class RewardTwoEnv(gym.Env):
        observation_space = without_privileged(privileged_space())
        action_space = gym.spaces.Discrete(5)

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            self.t = 0
            self.observation_space.seed(seed)
            return self.observation_space.sample(), {}

        def step(self, action):
            self.t += 1
            return self.observation_space.sample(), float(action == 2), False, self.t >= 10, {}

    return RewardTwoEnv()
