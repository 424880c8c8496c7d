"""Vector-env faults are clean, named and never hang (:mod:`rhs_env.vector`).

gymnasium (``rhs_env.vector.make_vec``, ``gym.make_vec``) and stable-baselines3
(``rhs_env.vector.make_subproc_vec_env``): ``num_envs=0``, info flags that cannot be stacked,
sub-envs whose kwargs shape different spaces, a worker's exception (bad kwarg, bad action) and a
worker killed mid-run. Every case ends in a named error within seconds and ``close()`` returns
(each guarded by a deadline, so a hang fails instead of stopping the suite). Two-step episodes on a
coarse scan; forked workers.
"""

from __future__ import annotations

import os
import signal
import threading
import time

import gymnasium as gym
import numpy as np
import pytest
from conftest import small_env_kwargs

import rhs_env  # noqa: F401  (registers the ids)
from rhs_env.vector import AsyncVectorEnv, WorkerError, differing_kwargs, make_subproc_vec_env, make_vec

HW, RADAR, SLAM = "rhs-highway-v0", "rhs-highway-radar-v0", "rhs-highway-slam-v0"
SMALL = {"vehicles_count": 2, "lanes_count": 2, "duration": 0.4}
RADAR_KW = {**SMALL, **small_env_kwargs(slam=False, max_points=16)}
SLAM_KW = {**RADAR_KW, "slam": {"n_particles": 8}, "max_landmarks": 8}
FORK = {"context": "fork"}


def _within(seconds: float, fn):
    """``fn()``'s result, or its exception, within ``seconds``; a hang fails the test."""
    box: dict = {}

    def target():
        try:
            box["value"] = fn()
        except BaseException as exc:
            box["error"] = exc

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), f"still running after {seconds} s (hang)"
    if "error" in box:
        raise box["error"]
    return box.get("value")


# --------------------------------------------------------------------------- gymnasium
@pytest.mark.parametrize("n", [0, -1, 2.0, 10**6, True])
def test_make_vec_num_envs_is_named(n):
    with pytest.raises(ValueError, match=r"num_envs must be an integer in \[1, 256\]"):
        make_vec(HW, num_envs=n, **SMALL)


@pytest.mark.parametrize("mode", ["sync", "async", "vector_entry_point", None])
@pytest.mark.parametrize("n", [0, -1, 2.5])
def test_gym_make_vec_num_envs_is_named(mode, n):
    """gymnasium's own ``make_vec`` on the project's ids: the spec kwargs' check, not gymnasium's IndexError."""
    with pytest.raises(ValueError, match=r"num_envs must be an integer in \[1, 256\]"):
        _within(30, lambda: gym.make_vec(HW, num_envs=n, vectorization_mode=mode, **SMALL))


def test_gym_make_vec_spec_kwargs_stay_a_dict():
    """The registered kwargs (:class:`rhs_env.vector.SpecKwargs`) act as a dict: one env per num_envs, kwargs kept."""
    from rhs_env.vector import SpecKwargs

    assert isinstance(gym.spec(HW).kwargs, SpecKwargs) and gym.spec(HW).kwargs == {}
    env = gym.make_vec(HW, num_envs=2, vectorization_mode="sync", **SMALL)
    try:
        assert env.num_envs == 2 and env.spec.kwargs["vehicles_count"] == 2
    finally:
        env.close()


def test_async_vector_env_of_no_envs_is_named():
    with pytest.raises(ValueError, match="num_envs"):
        AsyncVectorEnv([])


@pytest.mark.parametrize("flag", ["landmarks_in_info", "scatterers_in_info"])
@pytest.mark.parametrize("how", ["helper", "gym.make_vec async", "gym.make_vec sync"])
def test_unstackable_info_flags_are_refused_when_the_vector_env_is_made(flag, how):
    """Before: the reset failed stacking the info and close() waited for ever. Now: a ValueError naming the flag."""
    kw = {**SLAM_KW, flag: True}

    def make():
        if how == "helper":
            return make_vec(SLAM, num_envs=2, vector_kwargs=FORK, **kw)
        mode = how.split()[-1]
        return gym.make_vec(SLAM, num_envs=2, vectorization_mode=mode,
                            **({"vector_kwargs": FORK} if mode == "async" else {}), **kw)

    with pytest.raises(ValueError, match=f"{flag}=True .* cannot stack"):
        _within(60, make)


def test_a_single_env_still_takes_the_info_flags():
    env = gym.make(SLAM, landmarks_in_info=True, scatterers_in_info=True, **SLAM_KW)
    _, info = env.reset(seed=0)
    assert "true_landmarks" in info and "scatterers" in info
    env.close()


def test_differing_kwargs_names_each_value():
    assert differing_kwargs([{"max_points": 8, "a": {"b": 1}}, {"max_points": 16, "a": {"b": 1}}]) == \
        "max_points (env 0: 8, env 1: 16)"
    assert differing_kwargs([{"x": np.array([1.0])}, {"x": [1.0]}]) == ""
    assert differing_kwargs([{"radar": {"scan": {"grid_deg": 5}}}, {}]) == \
        "radar.scan.grid_deg (env 0: 5, env 1: <default>)"


@pytest.mark.parametrize("mode", ["async", "sync"])
def test_mismatched_sub_env_kwargs_are_named(mode):
    """Before: gymnasium's space RuntimeError, no word of which kwarg. Now: the kwarg and each env's value."""
    per_env = [{"max_points": 8}, {"max_points": 16}]
    with pytest.raises(ValueError, match=r"max_points \(env 0: 8, env 1: 16\)"):
        _within(60, lambda: make_vec(RADAR, num_envs=2, vectorization_mode=mode, vector_kwargs=FORK if mode == "async"
                                     else None, per_env=per_env, **{k: v for k, v in RADAR_KW.items()
                                                                    if k != "max_points"}))


def test_mismatched_spaces_of_a_plain_async_vector_env_are_named():
    """Env functions the helper never saw: the kwargs are read back from each worker's env spec."""
    fns = [lambda m=m: gym.make(RADAR, **{**RADAR_KW, "max_points": m}) for m in (8, 16)]
    with pytest.raises(ValueError, match=r"max_points \(env 0: 8, env 1: 16\)"):
        _within(60, lambda: AsyncVectorEnv(fns, context="fork"))


def test_async_worker_error_reaches_the_parent_and_close_returns():
    env = make_vec(HW, num_envs=2, vector_kwargs=FORK, **SMALL)
    try:
        env.reset(seed=[0, 1])
        with pytest.raises(ValueError, match=r"action space Discrete\(5\)"):
            _within(30, lambda: env.step(np.array([1, 7])))
    finally:
        _within(30, env.close)


def test_async_killed_worker_is_named_and_close_returns():
    """Before: BrokenPipeError at the next step. Now: WorkerError naming the worker and SIGKILL."""
    env = make_vec(HW, num_envs=2, vector_kwargs=FORK, **SMALL)
    try:
        env.reset(seed=[0, 1])
        os.kill(env.processes[1].pid, signal.SIGKILL)
        env.processes[1].join(10)
        with pytest.raises(WorkerError, match=r"worker 1 .*SIGKILL"):
            _within(30, lambda: env.step(np.array([1, 1])))
    finally:
        _within(30, env.close)


def test_async_bad_kwarg_is_raised_in_the_parent():
    with pytest.raises(ValueError, match="max_points"):
        _within(60, lambda: make_vec(RADAR, num_envs=2, vector_kwargs=FORK, **{**RADAR_KW, "max_points": 0}))


def test_make_vec_whole_episodes_still_work():
    env = make_vec(SLAM, num_envs=2, vector_kwargs=FORK, **SLAM_KW)
    try:
        env.reset(seed=[0, 1])
        ends = 0
        for _ in range(3):
            *_, term, trunc, _ = env.step(np.array([1, 1]))
            ends += int(np.sum(term | trunc))
        assert ends == 2
    finally:
        _within(30, env.close)


# --------------------------------------------------------------------------- stable-baselines3
def test_subproc_bad_kwarg_is_named_before_any_worker_starts():
    """Before: ConnectionResetError, the worker's ValueError lost. Now: the ValueError naming the field."""
    with pytest.raises(ValueError, match="slam.n_particles"):
        make_subproc_vec_env(SLAM, 2, env_kwargs={**SLAM_KW, "slam": {"n_particles": 0}}, start_method="fork")


def test_subproc_bad_kwarg_in_the_worker_reaches_the_parent():
    """Without the parent-side check the worker's own error still arrives, type and message."""
    with pytest.raises(ValueError, match=r"in vector env worker 0: .*max_points"):
        _within(60, lambda: make_subproc_vec_env(RADAR, 2, env_kwargs={**RADAR_KW, "max_points": 0},
                                                 start_method="fork", check=False))


def test_subproc_worker_error_on_a_bad_action_reaches_the_parent():
    """Before: a hang (forked workers hold each other's pipe ends). Now: the ValueError, and close() returns."""
    venv = make_subproc_vec_env(HW, 2, seed=0, env_kwargs=SMALL, start_method="fork")
    try:
        venv.reset()
        t0 = time.perf_counter()
        with pytest.raises(ValueError, match=r"in vector env worker 1: .*action space Discrete\(5\)"):
            _within(30, lambda: venv.step(np.array([1, 7])))
        assert time.perf_counter() - t0 < 30
    finally:
        _within(30, venv.close)


def test_subproc_killed_worker_is_named():
    venv = make_subproc_vec_env(HW, 2, seed=0, env_kwargs=SMALL, start_method="fork")
    try:
        venv.reset()
        os.kill(venv.processes[0].pid, signal.SIGKILL)
        venv.processes[0].join(10)
        with pytest.raises(WorkerError, match=r"worker 0 .*SIGKILL"):
            _within(30, lambda: venv.step(np.array([1, 1])))
    finally:
        _within(30, venv.close)


def test_subproc_whole_episodes_with_variable_info():
    """SB3 keeps one info dict per env: the variable-length truth is fine there."""
    venv = make_subproc_vec_env(SLAM, 2, seed=0, env_kwargs={**SLAM_KW, "landmarks_in_info": True},
                                start_method="fork")
    try:
        venv.reset()
        dones = 0
        for _ in range(2):
            _, reward, done, infos = venv.step(np.array([1, 1]))
            assert np.all(np.isfinite(reward)) and all("true_landmarks" in i for i in infos)
            dones += int(done.sum())
        assert dones == 2
    finally:
        _within(30, venv.close)


# --------------------------------------------------------------------------- training runs (agents.run_setup)
def test_training_vector_env_bad_kwarg_in_a_worker_reaches_the_parent():
    """A training run's workers (``agents.algos.vec_env.make_vec_env``, rhs_env.vector's SubprocVecEnv): the worker's
    ValueError naming the field, not SB3's ConnectionResetError."""
    from agents.algos.vec_env import make_vec_env

    with pytest.raises(ValueError, match=r"in vector env worker \d: .*vehicles_count must be in \[0, 500\]"):
        _within(120, lambda: make_vec_env(HW, 2, 0, env_kwargs={**SMALL, "vehicles_count": -1}))


def test_training_vector_env_bad_action_reaches_the_parent_and_close_returns():
    from agents.algos.vec_env import make_vec_env
    from rhs_env.vector import SubprocVecEnv

    venv = _within(120, lambda: make_vec_env(HW, 2, 0, env_kwargs=SMALL))
    try:
        assert isinstance(venv, SubprocVecEnv)
        venv.reset()
        with pytest.raises(Exception, match=r"in vector env worker \d"):
            _within(60, lambda: venv.step(np.array([99, 99])))
    finally:
        _within(30, venv.close)
