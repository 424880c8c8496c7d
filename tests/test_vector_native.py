"""The native vector env (``vectorization_mode="vector_entry_point"``): the same results as gymnasium's
``SyncVectorEnv`` of single envs with the same seeds, gymnasium's autoreset modes, clear errors, and
stable-baselines3 through :func:`rhs_env.vector_native.to_sb3`."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from conftest import small_env_kwargs
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

import rhs_env  # noqa: F401  (registers the ids)
from rhs_env.registration import ENV_SPECS, SLAM_ENV_SPECS
from rhs_env.vector_native import RhsVectorEnv, to_sb3

HW = "rhs-highway-v0"
RADAR = "rhs-highway-radar-v0"
#: short episodes (5 steps at 5 Hz) so autoresets happen inside a 30-step run
HW_KW = {"vehicles_count": 6, "lanes_count": 3, "duration": 1.0}
RADAR_KW = small_env_kwargs(slam=False, max_points=32, vehicles_count=3, lanes_count=2, duration=1.0)


#: highway-env's reset info holds ``action_space.sample()`` of an unseeded action space, and the racetrack's its
#: reward term: random in any vector env (and in single envs)
UNSEEDED = {"action", "_action", "action_reward", "_action_reward"}


def _same(a, b, path="obs") -> None:
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in set(a) - UNSEEDED:
            _same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, np.ndarray) and a.dtype == object:  # final_obs / final_info: one entry per env, or None
        assert isinstance(b, np.ndarray) and b.shape == a.shape, path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert (x is None) == (y is None), f"{path}[{i}]"
            if x is not None:
                _same(x, y, f"{path}[{i}]")
    else:
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=path)


def _run_pair(env_id: str, kwargs: dict, n: int = 3, steps: int = 30, mode: AutoresetMode = AutoresetMode.NEXT_STEP,
              workers: int = 1):
    native = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", autoreset_mode=mode,
                          workers=workers, **kwargs)
    sync = gym.make_vec(env_id, num_envs=n, vectorization_mode="sync", vector_kwargs={"autoreset_mode": mode},
                        **kwargs)
    try:
        assert isinstance(native.unwrapped, RhsVectorEnv)
        assert native.observation_space == sync.observation_space
        assert native.action_space == sync.action_space
        obs_n, info_n = native.reset(seed=11)
        obs_s, info_s = sync.reset(seed=11)
        _same(obs_n, obs_s)
        _same(info_n, info_s, "reset info")
        native.action_space.seed(5)
        ends = 0
        for t in range(steps):
            action = native.action_space.sample()
            out_n, out_s = native.step(action), sync.step(action)
            for name, a, b in zip(("obs", "reward", "terminated", "truncated", "info"), out_n, out_s, strict=True):
                _same(a, b, f"step {t} {name}")
            assert native.observation_space.contains(out_n[0])
            ends += int(np.sum(out_n[2] | out_n[3]))
        return ends
    finally:
        native.close()
        sync.close()


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_native_equals_sync_highway(mode):
    ends = _run_pair(HW, HW_KW, mode=mode)
    assert ends >= 3  # autoresets were exercised


def test_native_equals_sync_radar():
    ends = _run_pair(RADAR, RADAR_KW, n=2, steps=12)
    assert ends >= 2


@pytest.mark.parametrize("env_id", ["rhs-highway-slam-fast-v0", "rhs-racetrack-slam-v0"])
def test_native_equals_sync_slam(env_id):
    """A SLAM id (fast radar, compiled traffic) and a road with a Box action: 2-step episodes, autoreset twice."""
    kw = {"slam": {"n_particles": 8}, "max_landmarks": 8, "duration": 0.4}
    if env_id.startswith("rhs-highway"):  # the fast radar's calibration is the default radar's
        kw.update(vehicles_count=3, lanes_count=2)
    else:
        kw.update(small_env_kwargs(max_points=32))
    assert _run_pair(env_id, kw, n=2, steps=6) >= 4


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_native_in_worker_processes_equals_sync_highway(mode):
    """``workers=2``: three envs in two worker processes (groups of 2 and 1), the same results as single envs."""
    assert _run_pair(HW, HW_KW, mode=mode, workers=2) >= 3


def test_native_in_worker_processes_equals_sync_slam():
    kw = {"slam": {"n_particles": 8}, "max_landmarks": 8, "duration": 0.4, "vehicles_count": 3, "lanes_count": 2}
    assert _run_pair("rhs-highway-slam-fast-v0", kw, n=3, steps=6, workers=2) >= 4


def test_workers_attributes_calls_and_errors_reach_the_parent():
    """In worker mode the envs' attributes and methods are read, set and called where the envs live, per env; a
    bad kwarg raised in a worker is the same ``ValueError`` in the parent, naming the worker; a killed worker is a
    ``WorkerError`` at the next step, and ``close()`` returns."""
    from rhs_env.vector import WorkerError

    for bad in (0, 4, True, 1.5):
        with pytest.raises(ValueError, match=r"workers must be an integer in \[1, 3\]"):
            gym.make_vec(HW, num_envs=3, vectorization_mode="vector_entry_point", workers=bad, **HW_KW)
    with pytest.raises(ValueError, match="in vector env worker 0: .*vehicles_count"):
        gym.make_vec(HW, num_envs=2, vectorization_mode="vector_entry_point", workers=2,
                     **{**HW_KW, "vehicles_count": -1})
    env = gym.make_vec(HW, num_envs=3, vectorization_mode="vector_entry_point", workers=2, **HW_KW)
    try:
        vec = env.unwrapped
        assert vec.envs == [] and [len(g) for g in vec.workers.groups] == [2, 1]
        env.reset(seed=0)
        assert env.get_attr("render_mode") == (None, None, None)
        vec.set_attr_at([2], "marker", [7])
        assert vec.get_attr_at([0, 2], "spec")[1].id == HW
        assert vec.call_at([2], "marker") == [7] and vec.is_wrapped_at([0], gym.wrappers.OrderEnforcing) == [True]
        vec.workers.pipes[1].process.kill()
        vec.workers.pipes[1].process.join(5)
        with pytest.raises(WorkerError, match="worker 1 .* is gone"):
            env.step(np.zeros(3, dtype=np.int64))
    finally:
        env.close()
    assert vec.workers is None


def test_every_id_has_a_vector_entry_point():
    for env_id, _ in ENV_SPECS + SLAM_ENV_SPECS:
        spec = gym.spec(env_id)
        assert spec.vector_entry_point is not None, env_id
        creator = gym.envs.registration.load_env_creator(spec.vector_entry_point)
        assert creator.args == (env_id,)


def test_default_mode_metadata_spaces_and_repr():
    env = gym.make_vec(HW, num_envs=2, **HW_KW)
    try:
        assert isinstance(env, RhsVectorEnv)
        assert env.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
        assert env.observation_space == batch_space(env.single_observation_space, 2)
        assert env.action_space == batch_space(env.single_action_space, 2)
        assert repr(env) == f"RhsVectorEnv({HW}, num_envs=2)"
        with pytest.raises(RuntimeError, match="before reset"):
            env.step(env.action_space.sample())
        obs, _ = env.reset(seed=[3, None])
        assert env.observation_space.contains(obs)
        mask = np.array([False, True])
        obs2, _ = env.reset(seed=[None, 4], options={"reset_mask": mask})
        np.testing.assert_array_equal(obs2[0], obs[0])
        with pytest.raises(ValueError, match="reset_mask"):
            env.reset(options={"reset_mask": np.zeros(2, dtype=bool)})
        with pytest.raises(ValueError, match="one per env"):
            env.reset(seed=[1, 2, 3])
    finally:
        env.close()
    env.close()  # a second close is a no-op


@pytest.mark.parametrize("n", [0, -1, 1.5])
def test_num_envs_is_named(n):
    with pytest.raises(ValueError, match="num_envs must be an integer"):
        gym.make_vec(HW, num_envs=n, vectorization_mode="vector_entry_point", **HW_KW)


def test_bad_autoreset_mode_and_info_flag_are_named():
    with pytest.raises(ValueError, match="autoreset_mode must be"):
        gym.make_vec(HW, num_envs=2, vectorization_mode="vector_entry_point", autoreset_mode="sometimes", **HW_KW)
    with pytest.raises(ValueError, match="landmarks_in_info=True"):
        gym.make_vec(RADAR, num_envs=2, vectorization_mode="vector_entry_point", landmarks_in_info=True, **RADAR_KW)


@pytest.mark.parametrize("workers", [1, 2])
def test_disabled_mode_refuses_a_step_of_an_ended_env(workers):
    """The refused step leaves the vector env usable (with workers too: refused before any worker steps)."""
    env = gym.make_vec(HW, num_envs=2, vectorization_mode="vector_entry_point", autoreset_mode="Disabled",
                       workers=workers, **{**HW_KW, "duration": 0.4})
    try:
        env.reset(seed=0)
        a = env.action_space.sample()
        env.step(a)
        _, _, term, trunc, _ = env.step(a)
        assert (term | trunc).all()
        with pytest.raises(RuntimeError, match="DISABLED"):
            env.step(a)
        env.reset(options={"reset_mask": term | trunc})
        env.step(a)
    finally:
        env.close()


@pytest.mark.parametrize("workers", [1, 2])
def test_to_sb3_matches_dummy_vec_env(workers):
    from stable_baselines3.common.vec_env import DummyVecEnv

    native = to_sb3(gym.make_vec(HW, num_envs=2, vectorization_mode="vector_entry_point", autoreset_mode="SameStep",
                                 workers=workers, **HW_KW))
    dummy = DummyVecEnv([lambda: gym.make(HW, **HW_KW) for _ in range(2)])
    try:
        native.seed(7)
        dummy.seed(7)
        _same(native.reset(), dummy.reset())
        rng = np.random.default_rng(0)
        dones = 0
        for t in range(15):
            action = rng.integers(0, 5, size=2)
            native.step_async(action)
            dummy.step_async(action)
            (o1, r1, d1, i1), (o2, r2, d2, i2) = native.step_wait(), dummy.step_wait()
            _same(o1, o2, f"step {t} obs")
            _same(r1, r2, f"step {t} reward")
            _same(d1, d2, f"step {t} done")
            assert r1.dtype == np.float32
            for a, b in zip(i1, i2, strict=True):
                assert set(a) == set(b)
                if "terminal_observation" in a:
                    _same(a["terminal_observation"], b["terminal_observation"])
                assert a["TimeLimit.truncated"] == b["TimeLimit.truncated"]
            dones += int(d1.sum())
        assert dones >= 2
        assert native.get_attr("render_mode") == [None, None]
    finally:
        native.close()
        dummy.close()


def test_to_sb3_refuses_other_envs():
    env = gym.make_vec(HW, num_envs=1, vectorization_mode="vector_entry_point", **HW_KW)
    try:
        with pytest.raises(ValueError, match="SAME_STEP"):
            to_sb3(env)
    finally:
        env.close()
    sync = gym.make_vec(HW, num_envs=1, vectorization_mode="sync", **HW_KW)
    with pytest.raises(TypeError, match="RhsVectorEnv"):
        to_sb3(sync)
    sync.close()


def test_ppo_learns_through_the_adapter():
    from stable_baselines3 import PPO

    venv = to_sb3(gym.make_vec(HW, num_envs=2, vectorization_mode="vector_entry_point", autoreset_mode="SameStep",
                               **HW_KW))
    try:
        model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=1, seed=0, device="cpu", verbose=0)
        model.learn(256)
        assert model.num_timesteps >= 256
    finally:
        venv.close()


def test_benchmark_section_times_native_sync_and_single(monkeypatch):
    from rhs_studies.bench import benchmark

    monkeypatch.setattr(benchmark, "machine_scaling", lambda: {"two_over_one_median": 1.9})
    r = benchmark.bench_vec_native(steps=4, seed=0, block=1, n=2, env_id=HW, workers=2)
    assert r["env_steps_each"] == 4 and r["workers"] == 2
    for k in ("single", "native", "workers", "sync"):
        assert r[f"{k}_steps_per_s"] > 0
    for k in ("vec_native_over_single", "vec_workers_over_single"):
        lo, hi = r[f"{k}_ci"]
        assert lo <= r[k] <= hi
    assert "vec_native" in benchmark.SECTIONS
    line = benchmark._md_vec_native(r)[0]
    assert f"2 x `{HW}`" in line and "1.90 x" in line and "`workers=2`" in line
    goals = benchmark._goals({"vec_native": r})
    assert goals["vec_workers_over_single"]["goal"] == 1.4 and "vec_native_over_single" not in goals


def test_ppo_trains_the_same_through_native_workers_as_through_subproc(tmp_path):
    """``train(..., native_workers=2)``: the envs in two native worker processes instead of SB3's
    ``SubprocVecEnv``; the same envs and seeds, so PPO ends with the same weights to the bit."""
    import torch
    from stable_baselines3 import PPO

    from agents.algos.train import train

    weights = []
    for name, workers in (("subproc", None), ("native", 2)):
        out = tmp_path / name
        s = train("ppo", HW, 128, out, seed=0, n_envs=2, eval_freq=10**9, checkpoint_freq=10**9, progress=False,
                  env_kwargs={"vehicles_count": 6, "duration": 2.0}, native_workers=workers)
        assert s["timesteps"] >= 128
        weights.append(torch.cat([p.detach().ravel() for p in PPO.load(out / "model.zip", device="cpu").policy.parameters()]))
    assert torch.equal(weights[0], weights[1])
