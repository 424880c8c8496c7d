"""Every env id under every vector API: gymnasium ``make_vec`` (sync, async) and
stable-baselines3 (``DummyVecEnv``, ``SubprocVecEnv``), two envs, whole episodes
with autoreset; a worker error reaches the parent as an exception and nothing hangs.

Episodes are 2 steps (``duration=0.4`` s at 5 Hz) on a coarse 5-degree scan so the
whole file runs in seconds. Subprocess workers are forked (they inherit the
parent's imports and the radar's cached CFAR constant); the forkserver path with
``"rhs_env:<id>"`` names is covered in ``test_envs.py``.
"""

from __future__ import annotations

import threading
import time

import gymnasium as gym
import numpy as np
import pytest
from conftest import small_env_kwargs

import rhs_env  # noqa: F401  (registers the ids)

IDS = ("rhs-highway-v0", "rhs-highway-radar-v0", "rhs-highway-slam-v0", "rhs-paper-v0")
STEPS_PER_EPISODE = 2
RADAR = small_env_kwargs(slam=False, max_points=32)
SLAM = {"slam": {"n_particles": 8}, "max_landmarks": 8}


def kwargs_for(env_id: str) -> dict:
    kw: dict = {"duration": STEPS_PER_EPISODE / 5.0}
    if env_id != "rhs-paper-v0":
        kw.update(vehicles_count=2, lanes_count=2)
    if env_id != "rhs-highway-v0":
        kw.update(RADAR)
    if env_id in ("rhs-highway-slam-v0", "rhs-paper-v0"):
        kw.update(SLAM)
    return kw


def _finite_obs(obs) -> None:
    for key, value in (obs.items() if isinstance(obs, dict) else [("obs", obs)]):
        assert np.all(np.isfinite(np.asarray(value, dtype=float))), key


def _check_info(info: dict, n: int) -> None:
    """Every stacked info entry is a numeric array of one row per env (never an object array)."""
    for key, value in info.items():
        if isinstance(value, dict):
            _check_info(value, n)
            continue
        assert isinstance(value, np.ndarray) and value.shape[0] == n, key
        assert value.dtype != object, f"info[{key!r}] stacks into an object array"


def _with_deadline(fn, seconds: float) -> None:
    """Run ``fn`` in a thread; fail (instead of hanging the suite) if it does not return in time."""
    errors: list[BaseException] = []

    def target():
        try:
            fn()
        except BaseException as exc:
            errors.append(exc)

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), f"still running after {seconds} s (hang)"
    if errors:
        raise errors[0]


@pytest.mark.parametrize("mode", ["sync", "async"])
@pytest.mark.parametrize("env_id", IDS)
def test_gym_make_vec_whole_episodes(env_id, mode):
    kwargs = {"vector_kwargs": {"context": "fork"}} if mode == "async" else {}
    env = gym.make_vec(env_id, num_envs=2, vectorization_mode=mode, **kwargs, **kwargs_for(env_id))
    try:
        obs, info = env.reset(seed=[0, 1])
        assert env.single_observation_space.contains(row(obs, 0))
        _finite_obs(obs)
        _check_info(info, 2)
        ends = np.zeros(2, int)
        for _ in range(2 * STEPS_PER_EPISODE + 1):  # two episodes each, with the autoreset step between
            obs, reward, terminated, truncated, info = env.step(np.array([1, 1]))
            _finite_obs(obs)
            _check_info(info, 2)
            assert np.all(np.isfinite(reward))
            ends += terminated | truncated
        assert np.all(ends >= 2), ends  # both envs finished an episode, were reset and finished another
    finally:
        _with_deadline(env.close, 30)


def row(obs, i: int):
    """The i-th env's observation out of a batched (dict) observation."""
    return {k: v[i] for k, v in obs.items()} if isinstance(obs, dict) else obs[i]


@pytest.mark.parametrize("vec", ["dummy", "subproc"])
@pytest.mark.parametrize("env_id", IDS)
def test_sb3_vec_env_whole_episodes(env_id, vec):
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    cls, vkw = (DummyVecEnv, None) if vec == "dummy" else (SubprocVecEnv, {"start_method": "fork"})
    venv = make_vec_env(env_id, n_envs=2, seed=0, env_kwargs=kwargs_for(env_id), vec_env_cls=cls, vec_env_kwargs=vkw)
    try:
        obs = venv.reset()
        _finite_obs(obs)
        dones = 0
        for _ in range(STEPS_PER_EPISODE):
            obs, reward, done, infos = venv.step(np.array([1, 1]))
            _finite_obs(obs)
            dones += int(done.sum())
            for d, inf in zip(done, infos):
                if d:  # SB3 resets at once and keeps the last observation of the episode here
                    _finite_obs(inf["terminal_observation"])
        assert dones == 2
    finally:
        _with_deadline(venv.close, 30)


@pytest.mark.parametrize("env_id", ["rhs-highway-v0", "rhs-highway-slam-v0"])
def test_async_worker_errors_surface_and_close_returns(env_id):
    """An invalid action raises in the parent within seconds, naming the action space; close() returns.

    (gymnasium shuts a failed worker down: the vector env is then only good for ``close()``.)
    """
    env = gym.make_vec(env_id, num_envs=2, vectorization_mode="async", vector_kwargs={"context": "fork"},
                       **kwargs_for(env_id))
    try:
        env.reset(seed=[0, 1])
        t0 = time.perf_counter()
        with pytest.raises(ValueError, match=r"action space Discrete\(5\)"):
            env.step(np.array([1, 7]))
        assert time.perf_counter() - t0 < 30
    finally:
        _with_deadline(env.close, 30)


def test_async_close_returns_after_a_failed_reset_in_one_worker():
    """One worker's reset fails, the other's succeeds: the error is raised, then close() still returns."""
    env = gym.make_vec("rhs-highway-v0", num_envs=2, vectorization_mode="async", vector_kwargs={"context": "fork"},
                       **kwargs_for("rhs-highway-v0"))
    try:
        with pytest.raises(Exception, match="(?i)seed"):
            env.reset(seed=[0, "b"])
    finally:
        _with_deadline(env.close, 30)


def test_info_is_vector_friendly_by_default_and_variable_truth_is_opt_in():
    """The default info has only scalars and fixed-shape arrays; the variable-length truth needs its flag."""
    kw = kwargs_for("rhs-highway-slam-v0")
    env = gym.make("rhs-highway-slam-v0", **kw)
    _, info = env.reset(seed=0)
    _, *_, info2 = env.step(1)
    for inf in (info, info2):
        for key, value in inf.items():
            assert isinstance(value, (bool, int, float, np.ndarray, dict, np.number)), (key, type(value))
        assert "scatterers" not in inf and "true_landmarks" not in inf
    env.close()
    env = gym.make("rhs-highway-slam-v0", scatterers_in_info=True, landmarks_in_info=True, **kw)
    _, info = env.reset(seed=0)
    assert {"scatterers", "true_landmarks", "estimated_landmarks"} <= set(info)
    env.close()
