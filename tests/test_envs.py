"""Registered envs: checkers, determinism, kwargs validation, rendering, vector envs."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from conftest import small_env_kwargs
from gymnasium.utils.env_checker import check_env as gym_check_env

import rhs_env  # noqa: F401  (registers the ids)
from rhs_env.wrappers import RadarObservation

# Small, fast settings: little traffic, a coarse 5-degree scan of a short RHS.
SMALL_ENV = {"vehicles_count": 8, "lanes_count": 3, "duration": 20}
SMALL_RADAR = small_env_kwargs(slam=False)


def make_highway(**kw):
    return gym.make("rhs-highway-v0", **{**SMALL_ENV, **kw})


def make_radar(**kw):
    return gym.make("rhs-highway-radar-v0", **{**SMALL_ENV, **SMALL_RADAR, **kw})


def _radar_layers(env) -> int:
    n = 0
    while isinstance(env, gym.Wrapper):
        n += isinstance(env, RadarObservation)
        env = env.env
    return n


@pytest.mark.parametrize("maker", [make_highway, make_radar], ids=["highway", "radar"])
def test_gymnasium_and_sb3_check_env(maker):
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = maker()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "env is wrapped" notes from check_env on gym.make envs
        gym_check_env(env)
        sb3_check_env(env, warn=False)
    env.close()


def test_radar_observation_space_and_info():
    env = make_radar(scatterers_in_info=True)
    obs, info = env.reset(seed=0)
    assert set(obs) == {"points", "points_mask"}
    assert obs["points"].shape == (64, 7) and obs["points"].dtype == np.float32
    assert obs["points_mask"].shape == (64,) and obs["points_mask"].dtype == np.int8
    n = int(obs["points_mask"].sum())
    assert n > 0 and np.all(obs["points"][n:] == 0) and np.all(obs["points_mask"][:n] == 1)
    assert env.observation_space.contains(obs)
    sc = info["scatterers"]
    assert {"xy", "velocity", "rcs", "object_id", "is_static"} <= set(sc) and sc["is_static"].any()
    assert info["radar_points_total"] - info["radar_points_dropped"] == n
    assert "radar_stage_times" not in info
    assert _radar_layers(env) == 1
    env.close()


def test_points_truncated_by_amplitude_and_stage_times_on_request():
    env = make_radar(max_points=4, stage_times_in_info=True)
    obs, info = env.reset(seed=0)
    wrapper = env
    while not isinstance(wrapper, RadarObservation):
        wrapper = wrapper.env
    full = wrapper.last_cloud.points
    assert info["radar_points_total"] == len(full) > 4 and info["radar_points_dropped"] == len(full) - 4
    strongest = np.sort(full[:, 3])[-4:]
    np.testing.assert_allclose(np.sort(obs["points"][:, 3]), strongest, rtol=1e-6)
    assert info["radar_stage_times"]["total"] > 0
    env.close()


@pytest.mark.parametrize("maker", [make_highway, make_radar], ids=["highway", "radar"])
def test_same_seed_same_episode(maker):
    def rollout(seed):
        env = maker()
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for a in (1, 3, 1, 0):
            out.append(env.step(a)[0])
        env.close()
        return out

    a, b, c = rollout(7), rollout(7), rollout(8)
    for x, y in zip(a, b):
        assert gym.utils.env_checker.data_equivalence(x, y, exact=True)
    assert not all(gym.utils.env_checker.data_equivalence(x, y) for x, y in zip(a, c))


@pytest.mark.parametrize(
    "env_id, kwargs, field",
    [
        ("rhs-highway-v0", {"lanes_count": 0}, "lanes_count"),
        ("rhs-highway-v0", {"policy_frequency": 100}, "policy_frequency"),
        ("rhs-highway-v0", {"landmarks": {"spacing_m": -1}}, "spacing_m"),
        ("rhs-highway-v0", {"landmarks": {"spacingg": 5}}, "spacingg"),
        ("rhs-highway-v0", {"lanez_count": 3}, "lanez_count"),
        ("rhs-highway-radar-v0", {"antenna": "laser"}, "antenna"),
        ("rhs-highway-radar-v0", {"max_points": 0}, "max_points"),
        ("rhs-highway-radar-v0", {"radar": {"max_range_m": 1e6}}, "max_range_m"),
        ("rhs-highway-radar-v0", {"radar": {"scan": {"grid_deg": 7.0}}}, "grid_deg"),
        ("rhs-highway-radar-v0", {"radar": {"bogus": 1}}, "bogus"),
        ("rhs-highway-radar-v0", {"scatter": {"vehicle_rcs_m2": -2}}, "vehicle_rcs_m2"),
        ("rhs-highway-radar-v0", {"blas_threads": 0}, "blas_threads"),
        ("rhs-highway-slam-v0", {"blas_threads": "many"}, "blas_threads"),
    ],
)
def test_bad_kwargs_raise_value_error_naming_the_field(env_id, kwargs, field):
    with pytest.raises(ValueError, match=field):
        gym.make(env_id, **kwargs)


def test_paper_env_options_are_validated():
    from rhs_env.envs import RHSPaperEnv

    with pytest.raises(ValueError, match="ego_speed"):
        RHSPaperEnv(ego_speed=-1.0)
    with pytest.raises(ValueError, match="start"):
        RHSPaperEnv(start=[1e6, 0.0])


@pytest.mark.parametrize("maker", [make_highway, make_radar], ids=["highway", "radar"])
def test_rgb_array_render(maker):
    env = maker(render_mode="rgb_array")
    env.reset(seed=0)
    env.step(1)
    frame = env.render()
    assert isinstance(frame, np.ndarray) and frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    assert frame.std() > 0  # the road is drawn even with SDL_VIDEODRIVER=dummy
    if maker is make_radar:
        base = env.unwrapped.render()
        assert base.shape == frame.shape and np.any(base != frame)  # points drawn over the road
    env.close()


def test_subproc_vec_env_steps():
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    # "rhs_env:<id>" makes gymnasium import rhs_env (and so register the ids) in the workers
    venv = make_vec_env(
        "rhs_env:rhs-highway-radar-v0",
        n_envs=2,
        seed=0,
        vec_env_cls=SubprocVecEnv,
        env_kwargs={**SMALL_ENV, **SMALL_RADAR},
    )
    obs = venv.reset()
    assert obs["points"].shape == (2, 64, 7)
    obs, rewards, _dones, infos = venv.step(np.array([1, 1]))
    assert rewards.shape == (2,) and len(infos) == 2 and "radar_points_total" in infos[0]
    venv.close()


def test_gym_make_vec_async_steps():
    venv = gym.make_vec("rhs-highway-v0", num_envs=2, vectorization_mode="async", **SMALL_ENV)
    obs, _ = venv.reset(seed=0)
    obs, rewards, *_ = venv.step(np.array([1, 1]))
    assert obs.shape[0] == 2 and rewards.shape == (2,)
    venv.close()


def test_remaking_from_spec_does_not_wrap_twice():
    env = make_radar()
    again = gym.make(env.spec)
    assert _radar_layers(again) == 1
    a, _ = env.reset(seed=3)
    b, _ = again.reset(seed=3)
    assert gym.utils.env_checker.data_equivalence(a, b, exact=True)
    env.close()
    again.close()


@pytest.mark.parametrize("env_id", ["highway-fast-v0", "merge-v1"])
def test_radar_wrapper_on_plain_highway_env(env_id):
    import highway_env  # noqa: F401

    env = RadarObservation(gym.make(env_id, render_mode="rgb_array"), **SMALL_RADAR)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    obs, *_ = env.step(1)
    assert env.observation_space.contains(obs)
    frame = env.render()
    assert frame.ndim == 3 and frame.dtype == np.uint8
    env.close()


def test_radar_on_the_paper_scene_sees_the_obstacles():
    from rhs_env.envs import RHSPaperEnv

    env = RadarObservation(RHSPaperEnv(), antenna="hologram", radar={"scan": {"grid_deg": 5.0}}, max_points=64,
                           scatterers_in_info=True)
    obs, info = env.reset(seed=0)
    sc = info["scatterers"]
    assert sc["is_static"].all() and len(sc["xy"]) == 5  # no traffic: the five obstacles
    pts = obs["points"][obs["points_mask"] == 1]
    assert len(pts) > 0
    env.close()


def _blas_threads() -> int:
    from threadpoolctl import threadpool_info

    return max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")


@pytest.mark.parametrize("env_id", ["rhs-highway-radar-v0", "rhs-highway-slam-v0"])
def test_step_runs_single_threaded_blas_and_restores_the_callers_limit(env_id):
    """The radar (and SLAM) work sees 1 BLAS thread inside reset/step; the caller's 2 threads come back after."""
    from threadpoolctl import threadpool_limits

    seen = []
    with threadpool_limits(2, user_api="blas"):
        if _blas_threads() != 2:
            pytest.skip("the BLAS in use does not allow 2 threads here")
        for blas_threads, want in ((1, 1), (None, 2)):
            env = gym.make(env_id, **{**SMALL_ENV, **SMALL_RADAR}, blas_threads=blas_threads)
            radar = env
            while not isinstance(radar, RadarObservation):
                radar = radar.env
            env.reset(seed=0)
            scan = radar.radar.scan
            radar.radar.scan = lambda *a, _f=scan, **k: (seen.append(_blas_threads()), _f(*a, **k))[1]
            slam = env
            while slam is not radar and not hasattr(slam, "pipeline"):
                slam = slam.env
            if slam is not radar:  # the SLAM pipeline's step too
                step = slam.pipeline.step
                slam.pipeline.step = lambda *a, _f=step, **k: (seen.append(_blas_threads()), _f(*a, **k))[1]
            env.step(1)
            env.reset(seed=1)
            assert seen and set(seen) == {want}, (blas_threads, seen)
            assert _blas_threads() == 2  # restored after the step
            seen.clear()
            env.close()


def test_points_carry_their_uncertainty_and_radar():
    env = make_radar()
    obs, _ = env.reset(seed=1)
    wrapper = env
    while not isinstance(wrapper, RadarObservation):
        wrapper = wrapper.env
    cloud = wrapper.last_cloud
    n = int(obs["points_mask"].sum())
    assert n == len(cloud) > 0
    rows = obs["points"][:n]
    np.testing.assert_allclose(rows[:, 4], cloud.range_std_m, rtol=1e-6)
    np.testing.assert_allclose(rows[:, 5], cloud.angle_std_rad, rtol=1e-6)
    np.testing.assert_array_equal(rows[:, 6], cloud.radar)
    # stds are positive, at least the floors, and shrink with the SNR (amplitude)
    cfg = wrapper.radar_config
    assert np.all(rows[:, 4] >= cfg.uncertainty.range_std_floor_m * (1 - 1e-6))
    assert np.all(rows[:, 5] >= np.radians(cfg.uncertainty.angle_std_floor_deg) * (1 - 1e-6))
    order = np.argsort(rows[:, 3])
    assert rows[order[0], 5] > rows[order[-1], 5]
    assert env.observation_space.contains(obs)
    env.close()
