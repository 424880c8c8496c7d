"""The calibrated pose covariance (slam.core.pose_calibration, slam.gym.pose_calibration)."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest

from slam.core.pose_calibration import (
    ROW_COLUMNS,
    PoseCalibration,
    calibrated_covariance,
    fit_calibration,
    nees_coverage,
    row_nees,
)


def _rows(rng: np.random.Generator, k: np.ndarray, n: int = 3000) -> np.ndarray:
    """Rows whose errors are drawn from the calibrated covariance with the factors ``k`` (the truth)."""
    rows = np.zeros((n, len(ROW_COLUMNS)))
    for t in range(n):
        v = np.array([1e-4, 4e-4, 1e-7]) * rng.uniform(0.2, 5.0, 3)
        A = rng.normal(size=(3, 3)) * np.array([0.02, 0.05, 1e-3])[:, None]
        P = A @ A.T * rng.uniform(0.1, 3.0)
        th, s = rng.uniform(-0.3, 0.3), rng.uniform(0.05, 1.0)
        d = rng.uniform(0.0, 300.0)  # m since the map began: a frozen heading error's lever arm
        B = np.array([[0.0, 0.0, 0.0], [0.0, d * d, d], [0.0, d, 1.0]]) * (1.0 - math.exp(-d / 10.0))
        C = calibrated_covariance(v, P, th, s, k, B)
        e = rng.multivariate_normal(np.zeros(3), C)
        rows[t] = [*e, *v, *P.ravel(), s, th, 0.0, *B.ravel()]
    return rows


def test_fit_recovers_known_factors() -> None:
    """Errors drawn with known factors, the map-start term's among them: the fit finds them, and the NEES under
    them is chi2(3)."""
    rng = np.random.default_rng(5)
    k_true = np.array([0.3, 2.0, 6.0, 0.5, 4e-8])  # a map-start heading std of 0.2 mrad
    rows = _rows(rng, k_true)
    k, used = fit_calibration(rows)
    assert used == len(rows)
    # within 20 %, k_p within 30 % (the particles' term is the smallest, and the map-start term shares its axes)
    assert np.all(np.abs(k / k_true - 1.0) < [0.3, 0.2, 0.2, 0.2, 0.2]), k
    cov = nees_coverage(row_nees(rows, k))
    assert cov["goal_met"] and cov["anees"] == pytest.approx(3.0, rel=0.1)
    lost = rows.copy()
    lost[:, 17] = 1.0  # lost cycles are not fitted
    assert fit_calibration(lost)[1] == 0


def test_nees_coverage_tails() -> None:
    """Below / inside / above the chi2(3) 95 % band [0.216, 9.35] and the ANEES interval."""
    c = nees_coverage(np.array([0.1, 1.0, 2.0, 3.0, 20.0]))
    assert (c["below"], c["above"]) == (0.2, 0.2) and c["inside"] == pytest.approx(0.6) and not c["goal_met"]
    assert nees_coverage(np.zeros(0)) == {"cycles": 0}
    lo, hi = nees_coverage(np.full(1000, 3.0))["anees_interval"]
    assert lo < 3.0 < hi and hi - lo < 0.4


def test_calibration_json_round_trip_and_validation() -> None:
    cal = PoseCalibration(0.5, 1.5, 7.0, 3.0, key="abc", seeds=(1, 2), cycles=60, fit_cycles=120, setup={"a": 1})
    back = PoseCalibration.from_json(cal.to_json())
    assert back == cal and back.setup == {"a": 1}
    with pytest.raises(ValueError, match="pose_calibration.cross"):
        PoseCalibration(1.0, 1.0, -1.0, 1.0)
    with pytest.raises(ValueError, match="version"):
        PoseCalibration.from_json(json.dumps({**json.loads(cal.to_json()), "version": 0}))


def test_calibrated_covariance_axes_follow_the_heading() -> None:
    """``k_along`` scales the drift along the vehicle's heading, whatever the heading."""
    P = np.diag([1.0, 1.0, 0.0])
    th = math.pi / 2  # driving along +y: along-track is the map's y
    C = calibrated_covariance(np.zeros(3), P, th, 1.0, np.array([1.0, 4.0, 1.0, 1.0]))
    assert C[1, 1] == pytest.approx(4.0) and C[0, 0] == pytest.approx(1.0)


def _drive(env_id: str, kwargs: dict, seed: int, cycles: int):
    import gymnasium as gym

    import rhs_env  # noqa: F401
    from slam.gym.pose_calibration import calibration_rows, slam_wrapper

    env = gym.make(env_id, **kwargs, pipeline={"pose_covariance": "calibrated"})
    try:
        cal = slam_wrapper(env).pipeline.pose_calibration
        return cal, calibration_rows(env, seed, cycles)
    finally:
        env.close()


def test_calibration_script_reproduces_the_shipped_fast_radar_calibration(tmp_path) -> None:
    """``scripts/calibrate_pose_covariance.py --configs fast`` writes the factors the package ships (same key,
    the scale factors within 10 %, the map-start std within 25 %): the drives are seeded and the fit
    deterministic, but numpy's AVX-512 sin / cos / exp round otherwise than its AVX2 loops, and over 500 cycles that
    moved k_heading by 4.2 % on an AMD EPYC with AVX-512 (6.87 against 6.59, the 10-drive calibration; with numpy,
    OpenBLAS and numba capped at AVX2 the factors were the shipped ones within 2 %)."""
    import importlib.util
    from pathlib import Path

    from slam.gym.pose_calibration import find_calibration, shipped_path

    path = Path(__file__).resolve().parent.parent / "scripts" / "calibrate_pose_covariance.py"
    spec = importlib.util.spec_from_file_location("calibrate_pose_covariance", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["--configs", "fast", "--out-dir", str(tmp_path)]) == 0
    (made,) = tmp_path.glob("pose_cov_*.json")
    fresh = PoseCalibration.from_json(made.read_text())
    shipped = find_calibration(fresh.key)
    assert shipped is not None and shipped_path(fresh.key).is_file(), "the fast radar's calibration is not shipped"
    assert fresh.seeds == shipped.seeds and fresh.cycles == shipped.cycles
    np.testing.assert_allclose(fresh.factors[:4], shipped.factors[:4], rtol=0.10)
    # the map-start variance is the least determined factor (fits on 10 of the 40 drives spread 8.4x on the fast
    # radar: results/pose_calibration_spread.json): its std within 25 %
    np.testing.assert_allclose(np.sqrt(fresh.factors[4]), np.sqrt(shipped.factors[4]), rtol=0.25)


def test_default_drive_covariance_is_neither_3x_too_wide_nor_too_narrow() -> None:
    """A short default drive (the fast radar's default env: the shipped calibration): the median NEES of the
    calibrated covariance (without the studies' std floors) is in [0.7, 8] (chi2(3): 2.37); the same covariance
    3x wider in std (/9 in NEES) or 3x narrower (x9) falls outside, so a calibration off by 3x fails here."""
    cal, rows = _drive("rhs-highway-slam-fast-v0", {}, 13005, 40)
    assert cal is not None and cal.key, "the env attached no calibration"
    k, tracked = cal.factors, rows[rows[:, 17] < 0.5]
    # the model's own covariance (no std floors: at 1 mm / 0.1 mrad they would hide a too narrow covariance)
    median = float(np.median(row_nees(tracked, k, np.zeros(3))))
    assert 0.7 <= median <= 8.0, (median, k)
    for wrong in (9.0, 1 / 9.0):  # std 3x too wide / too narrow: every term's variance 9x / (1/9)x
        x = float(np.median(row_nees(tracked, k * wrong, np.zeros(3))))
        assert not 0.7 <= x <= 8.0, (wrong, x)


def test_key_follows_the_radar_not_the_reporting() -> None:
    """The key changes with the scan grid and the scene, not with the covariance model, rendering or actions."""
    from types import SimpleNamespace

    from slam.core.pipeline import PipelineConfig
    from slam.core.rbpf import SlamConfig
    from slam.core.registration import ICPConfig
    from slam.gym.pose_calibration import calibration_key

    class Radar:
        def __init__(self, grid: float) -> None:
            self.grid = grid

        def flat_dict(self) -> dict:
            return {"scan.grid_deg": self.grid, "kernels": "numba"}

    def env(grid: float, model: str) -> Any:
        inner = SimpleNamespace(radar_config=Radar(grid))
        return SimpleNamespace(env=inner, pipeline_config=PipelineConfig(pose_covariance=model),
                               slam_config=SlamConfig(), icp_config=ICPConfig(), registration_kind="icp")

    base = calibration_key("RHSHighwayEnv", {}, env(1.0, "calibrated"))
    assert calibration_key("RHSHighwayEnv", {"render_mode": "rgb_array", "action": {"type": "X"}},
                           env(1.0, "adaptive")) == base
    assert calibration_key("RHSHighwayEnv", {}, env(5.0, "calibrated")) != base
    assert calibration_key("RHSDenseEnv", {}, env(1.0, "calibrated")) != base
    assert calibration_key("RHSHighwayEnv", {"vehicles_count": 10}, env(1.0, "calibrated")) != base


def test_scene_class_resolves_every_road_and_refuses_an_unknown_name() -> None:
    """The scene names ``make_slam_env`` records (``slam_make_args``) resolve back to their classes, the roads'
    too (the pose calibration makes its drives' envs by that name), and an unknown name says where it looked."""
    from rhs_env import envs
    from rhs_env.road_envs import ROAD_ENVS
    from slam.gym.envs import scene_class

    for cls in (envs.RHSHighwayEnv, envs.RHSDenseEnv, envs.RHSPaperEnv, *ROAD_ENVS.values()):
        assert scene_class(cls.__name__) is cls
    with pytest.raises(ValueError, match="RHSNoSuchEnv.*rhs_env.road_envs"):
        scene_class("RHSNoSuchEnv")


def test_a_road_configuration_calibrates_by_its_scene_name() -> None:
    """``pose_covariance="calibrated"`` on a road env (here the racetrack) fits its factors on drives of envs made
    again from the recorded scene name: two 4-cycle drives give a finite, positive calibration keyed to the road."""
    import gymnasium as gym

    import rhs_env  # noqa: F401  # registers the ids
    from slam.gym.envs import make_slam_env
    from slam.gym.pose_calibration import calibrate

    env = gym.make("rhs-racetrack-slam-v0")
    try:
        scene, made = env.get_wrapper_attr("slam_make_args")
    finally:
        env.close()
    assert scene == "RHSRacetrackEnv"
    cal = calibrate(scene, made, seeds=(0, 1), cycles=4, make=make_slam_env)
    assert np.all(np.isfinite(cal.factors)) and np.all(cal.factors[:4] > 0) and cal.factors[4] >= 0, cal.factors
    assert cal.key and cal.seeds == (0, 1) and cal.cycles == 4
