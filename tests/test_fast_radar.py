"""The fast radar variant (rhs_env.fast_radar): its ids, its calibration, its agreement with the exact radar."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import rhs_env  # noqa: F401  (registers the ids)
from rhs_env.fast_radar import FastRadarSystem, calibrate
from rhs_env.fast_radar_calibration import (
    FastRadarTable,
    calibration_scenes,
    load_table,
    match_scan,
    shipped_table_path,
    table_key,
)
from rhs_env.radar import RadarConfig, RadarSystem
from rhs_env.scene import ScatterConfig, scene_scatterers
from rhs_env.uncertainty import POINT_COLUMNS, point_rows
from rhs_env.wrappers import make_radar_config


def _unwrap_to_radar(env: gym.Env):
    e = env
    while not hasattr(e, "radar_model"):
        e = e.env
    return e


def test_default_table_ships_and_default_ids_stay_exact() -> None:
    assert shipped_table_path(RadarConfig()).is_file()
    env = gym.make("rhs-highway-radar-v0")
    try:
        assert type(_unwrap_to_radar(env).radar) is RadarSystem
    finally:
        env.close()


def test_fast_radar_id_passes_check_env() -> None:
    env = gym.make("rhs-highway-radar-fast-v0")
    try:
        wrapper = _unwrap_to_radar(env)
        assert isinstance(wrapper.radar, FastRadarSystem)
        assert env.unwrapped.traffic_sim == "compiled"  # the fast ids step the compiled traffic (the default)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "env is wrapped" notes from check_env on gym.make envs
            check_env(env, skip_render_check=True)
    finally:
        env.close()


def test_fast_slam_id_steps_with_the_exact_observation_space() -> None:
    fast = gym.make("rhs-highway-slam-fast-v0", sim="highway-env")
    exact = gym.make("rhs-highway-slam-v0")
    try:
        assert fast.unwrapped.config["sim"] == "highway-env"  # a given sim is kept
        assert fast.observation_space == exact.observation_space
        obs, _ = fast.reset(seed=3)
        assert fast.observation_space.contains(obs)
        for _ in range(3):
            obs, _, term, trunc, info = fast.step(1)
            assert fast.observation_space.contains(obs)
            assert np.isfinite(info["position_error_m"])
            if term or trunc:
                break
    finally:
        fast.close()
        exact.close()


def test_fast_id_refuses_the_exact_model() -> None:
    with pytest.raises(ValueError, match="rhs-highway-slam-v0"):
        gym.make("rhs-highway-slam-fast-v0", radar_model="exact")


def test_points_have_the_exact_layout() -> None:
    """Columns, radar order, polar <-> Cartesian consistency and finite stds, as the exact path's points."""
    config = RadarConfig()
    fast = FastRadarSystem(config, np.random.default_rng(5))
    for seed, _, env in calibration_scenes([200_500], 3):
        sc, occ = scene_scatterers(env, env.unwrapped.vehicle, ScatterConfig.make(None), config.kernels)
        cloud = fast.scan(sc, occ)
        rows = point_rows(cloud)
        assert rows.shape == (len(cloud), len(POINT_COLUMNS)) and len(cloud) > 10
        assert np.all(np.diff(cloud.radar) >= 0) and set(np.unique(cloud.radar)) <= {0, 1, 2, 3}
        d = cloud.xy - fast.positions[cloud.radar]
        np.testing.assert_allclose(np.hypot(d[:, 0], d[:, 1]), cloud.range_m, atol=1e-9)
        assert np.all((cloud.range_m >= config.min_range_m) & (cloud.range_m <= config.max_range_m))
        assert np.all(np.isfinite(cloud.range_std_m) & (cloud.range_std_m > 0))
        assert np.all(np.isfinite(cloud.angle_std_rad) & (cloud.angle_std_rad > 0))
        assert np.all(np.abs(cloud.points[:, 2]) <= config.max_velocity_mps + 1e-9)
        assert seed == 200_500


def test_fast_and_exact_detection_agree_on_a_small_set() -> None:
    """Pooled P_d on 2 fidelity episodes (scene seeds outside the calibration's). Tolerances from the measured
    spread: ~40 scans hold ~700 moving and ~800 static pairs; the binomial std of a moving P_d (~0.7) is ~0.017
    per radar, ~0.025 for the difference, so 0.08 is > 3 std; static pairs are detected with P_d ~1 (0.02).
    With the table's P_d halved (the behaviour removed) the moving difference is ~0.35."""
    config = RadarConfig()
    exact = RadarSystem(config, np.random.default_rng(1))
    fast = FastRadarSystem(config, np.random.default_rng(2))
    rec: dict[str, list] = {"exact": [], "fast": []}
    for _, _, env in calibration_scenes([200_600, 200_601], 20):
        sc, occ = scene_scatterers(env, env.unwrapped.vehicle, ScatterConfig.make(None), config.kernels)
        rec["exact"].append(match_scan(exact, exact.scan(sc, occ), sc, occ))
        rec["fast"].append(match_scan(fast, fast.scan(sc, occ), sc, occ))

    def pd(records: list, static: bool) -> float:
        det = np.concatenate([r.detected[r.static == static] for r in records])
        return float(det.mean())

    assert abs(pd(rec["fast"], False) - pd(rec["exact"], False)) < 0.08
    assert abs(pd(rec["fast"], True) - pd(rec["exact"], True)) < 0.02
    false_e = np.mean([r.false_points.shape[0] for r in rec["exact"]])
    false_f = np.mean([r.false_points.shape[0] for r in rec["fast"]])
    assert abs(false_f - false_e) < 1.0  # ~2 per scan, std of the mean over ~40 scans ~0.25


def test_calibration_on_a_tiny_config_makes_a_table(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("RHS_SLAM_CACHE", str(tmp_path))
    config = make_radar_config({"scan": {"grid_deg": 5.0}, "max_range_m": 60.0})
    assert table_key(config) != table_key(RadarConfig())
    with pytest.raises(FileNotFoundError, match="calibrate_fast_radar.py"):
        FastRadarSystem(config)
    table = calibrate(config, seeds=[5], steps=3)
    assert table.key == table_key(config) and table.meta["scans"] >= 1 and table.err_pool.shape[1] == 4
    assert np.all((table.pd >= 0) & (table.pd <= 1))
    path = tmp_path / "t.npz"
    table.save(path)
    back = FastRadarTable.load(path)
    np.testing.assert_allclose(back.pd, table.pd)
    assert back.key == table.key and back.false_scale == pytest.approx(table.false_scale)
    assert back.link_scale == pytest.approx(table.link_scale)
    np.testing.assert_array_equal(back.link_start, table.link_start)
    cloud = FastRadarSystem(config, np.random.default_rng(0), table=back).scan(*_scene(config))
    assert cloud.points.shape[1] == 4


def test_missing_table_refusal_and_load(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("RHS_SLAM_CACHE", str(tmp_path))
    assert load_table(RadarConfig()).key == table_key(RadarConfig())
    bad = tmp_path / "bad.npz"
    bad.write_text("not a table")
    with pytest.raises(ValueError, match="not a fast-radar table"):
        FastRadarTable.load(bad)


def _scene(config: RadarConfig):
    for _, _, env in calibration_scenes([7], 0):
        return scene_scatterers(env, env.unwrapped.vehicle, ScatterConfig.make(None), config.kernels)
    raise AssertionError("no scene")
