"""scripts/slam_accuracy.py on its small config, and the Doppler track hold of the pipeline."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rhs_studies import slam_accuracy
from slam.core.pipeline import PipelineConfig, SlamPipeline
from slam.core.registration import OdometryRegistration


def test_quick_run_records_provenance_and_targets(tmp_path):
    out = tmp_path / "acc"
    assert slam_accuracy.main(["--quick", "--parts", "paper", "dense", "--no-progress", "--out", str(out)]) == 0
    doc = json.loads(out.with_suffix(".json").read_text())
    assert doc["commit"] and "--quick" in doc["command"] and doc["seeds"] == [100]
    paper, dense = doc["parts"]["paper"], doc["parts"]["dense"]
    assert paper["slam_config"]["variant"] == "fastslam2" and paper["slam_config"]["n_particles"] == 10
    assert paper["runs"][0]["cycles"] == 6 and 0 <= paper["runs"][0]["position_rmse_m"] < 1.0
    row = dense["runs"][0]
    assert 2.0 <= row["separation_deg"][0] <= row["separation_deg"][1] <= 5.0
    assert row["ratio_rhs_phased"] == pytest.approx(row["rhs_ate_m"] / row["phased_ate_m"])
    md = out.with_suffix(".md").read_text()
    assert "| paper | position_rmse_m |" in md and "| dense | ratio_rhs_phased |" in md


def test_dense_scene_pairs_two_to_five_degrees_apart_in_one_range_cell_from_mid_drive():
    lm, poses, delta = slam_accuracy.dense_scene(3, 40)
    k = len(lm) // 2
    a, b = lm[:k], lm[k:]
    mid = np.array([poses[-1, 0] / 2, 0.0])
    # seen from the middle of the drive: delta apart, at equal ranges (one range cell)
    ta, tb = np.arctan2(*(a - mid)[:, ::-1].T), np.arctan2(*(b - mid)[:, ::-1].T)
    np.testing.assert_allclose(np.degrees(np.abs(np.angle(np.exp(1j * (ta - tb))))), delta, rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(a - mid, axis=1), np.linalg.norm(b - mid, axis=1))
    assert np.all((delta >= 2.0) & (delta <= 5.0)) and poses.shape == (40, 3)
    assert poses[-1, 0] == pytest.approx(6.0 * 0.2 * 39) and k >= 10
    lateral = np.abs((a[:, 1] + b[:, 1]) / 2)
    assert np.all((lateral >= 20.0) & (lateral <= 35.0))


def test_pair_geometry_counts_the_regime():
    lm, poses, _ = slam_accuracy.dense_scene(0, 40)
    g = slam_accuracy.pair_geometry(lm, poses)
    assert 0.3 < g["regime"] <= min(g["angle_2_5_deg"], g["same_range_cell"]) <= 1
    assert g["regime_pair_cycles"] > 0
    # a pair straight ahead, its gap along the line of sight: never in one range cell
    ahead = np.array([[50.0, 0.0], [52.0, 0.0]])
    g2 = slam_accuracy.pair_geometry(ahead, np.zeros((3, 3)))
    assert g2["same_range_cell"] == 0.0 and g2["regime"] == 0.0


def test_quick_highway_drives_slower_and_reports_the_measured_fraction(tmp_path):
    out = tmp_path / "hw"
    assert slam_accuracy.main(["--quick", "--parts", "highway", "--seeds", "0", "--no-progress", "--out", str(out)]) == 0
    hw = json.loads(out.with_suffix(".json").read_text())["parts"]["highway"]
    run = hw["runs"][0]
    assert hw["action"] == slam_accuracy.SLOWER and run["cycles"] == 10 and not run["crashed"]
    assert run["measured"] <= run["seen"] and sum(run["unmatched_by_scans"].values()) == run["missed"]
    assert 0 <= run["measured_matched_fraction"] <= 1
    assert "| highway | measured_matched_fraction |" in out.with_suffix(".md").read_text()


def test_drivers_part_gives_the_same_runs_with_two_workers(capsys):
    """The drivers' episodes spread over processes are the runs of one process (each episode starts from its
    seed), in the same order; the progress line counts them."""
    argv = ["--parts", "drivers", "--drivers", "random", "--driver-envs", "rhs-highway-slam-v0",
            "--driver-seeds", "7", "8", "--driver-cycles", "4", "--slam", '{"n_particles": 10}']
    one = slam_accuracy.run_drivers(*slam_accuracy.parse_args([*argv, "--no-progress"]))
    two = slam_accuracy.run_drivers(*slam_accuracy.parse_args([*argv, "--workers", "2"]))
    assert "[drivers 2/2 " in capsys.readouterr().err

    def runs(res: dict) -> list[dict]:
        return [{k: v for k, v in r.items() if k != "wall_s"} for r in res["combos"]["rhs-highway-slam-v0/random"]["runs"]]

    assert [r["seed"] for r in runs(one)] == [7, 8] and all(r["cycles"] >= 1 for r in runs(one))
    assert runs(one) == runs(two)
    with pytest.raises(SystemExit):
        slam_accuracy.parse_args(["--workers", "0"])


def test_drivers_part_takes_radar_overrides():
    """``--radar`` reaches the drivers' envs merged group by group over the policy's own env kwargs (its
    ``scan.grid_deg`` stays); a non-object is refused."""
    est = {"estimation": {"refine_passes": 8, "refine_tol": 0.01}, "scan": {"sector_deg": 90.0}}
    argv = ["--parts", "drivers", "--drivers", "idm", "--driver-envs", "rhs-dense-v0", "--driver-seeds", "3",
            "--driver-cycles", "2", "--slam", '{"n_particles": 10}', "--radar", json.dumps(est), "--no-progress"]
    res = slam_accuracy.run_drivers(*slam_accuracy.parse_args(argv))
    combo = res["combos"]["rhs-dense-v0/idm"]
    assert combo["env_kwargs"]["radar"]["estimation"] == est["estimation"] and combo["runs"][0]["cycles"] >= 1
    assert combo["env_kwargs"]["radar"]["scan"] == {"grid_deg": 5, "sector_deg": 90.0}
    with pytest.raises(SystemExit):
        slam_accuracy.parse_args(["--radar", "[1, 2]"])


def _ring(v: np.ndarray, n: int = 24, r: float = 20.0) -> np.ndarray:
    """Points on a ring around the car with the Doppler of a world moving at -v relative to it."""
    b = np.linspace(-math.pi, math.pi, n, endpoint=False)
    u = np.stack([np.cos(b), np.sin(b)], 1)
    return np.column_stack([r * u, -(u @ v), np.full(n, 100.0)])


@pytest.mark.parametrize("hold", [5, 0])
def test_established_velocity_track_holds_through_a_platoon(hold):
    pipe = SlamPipeline(OdometryRegistration(0), rng=0, options=PipelineConfig(reacquire_after_cycles=hold))
    static = _ring(np.array([15.0, 0.0]))
    for _ in range(5):
        pipe.step(static, 0.2)
    assert pipe.velocity[0] == pytest.approx(15.0, abs=0.1)
    pipe.step(_ring(np.array([3.0, 0.0])), 0.2)  # only a platoon moving 12 m/s slower is in view
    assert pipe.velocity[0] == pytest.approx(15.0 if hold else 3.0, abs=0.1)
