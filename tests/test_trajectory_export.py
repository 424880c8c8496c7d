"""Trajectories in the formats SLAM tools read: TUM / KITTI files that ``evo`` reads, with its APE equal to ours.

The writers (:mod:`slam.core.trajectory_formats`) round-trip; an env episode exported by
:class:`slam.gym.trajectory.TrajectoryRecorder`, ``rhs-slam scenario --trajectories`` and ``rhs-slam evaluate
--trajectories`` give files whose APE in ``evo`` (translation part, no alignment: both trajectories are in the
map frame) is the project's ATE / position RMSE (:func:`slam.core.metrics.position_rmse`) to 1e-6 m, at the
env's simulated times.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import rhs_env  # noqa: F401
from rhs_slam.cli import main as cli_main
from slam.core.metrics import position_rmse
from slam.core.trajectory_formats import (
    formats_of,
    kitti_text,
    read_kitti,
    read_tum,
    tum_text,
    write_trajectory_pair,
    yaw_quaternion,
)
from slam.gym.trajectory import TrajectoryRecorder

ROOT = Path(__file__).resolve().parent.parent
FAST = {"radar": {"scan": {"grid_deg": 5}}, "slam": {"n_particles": 8}, "vehicles_count": 3}
STEPS = 20


def _poses(n: int = 15, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([np.cumsum(rng.uniform(3, 6, n)), rng.normal(0, 2, n), rng.uniform(-3.1, 3.1, n)])


def test_tum_and_kitti_round_trip(tmp_path):
    poses, times = _poses(), 0.2 * np.arange(1, 16)
    est_tum, gt_tum, est_kitti, gt_kitti = write_trajectory_pair(tmp_path, "run", times, poses + 0.1, poses, ("tum", "kitti"))
    assert [p.name for p in (est_tum, gt_tum, est_kitti, gt_kitti)] == ["run_est.tum", "run_gt.tum", "run_est.kitti", "run_gt.kitti"]
    t, back = read_tum(gt_tum)
    np.testing.assert_allclose(t, times, atol=1e-9)
    np.testing.assert_allclose(back[:, :2], poses[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (back[:, 2] - poses[:, 2]))), 0.0, atol=1e-9)
    k = read_kitti(gt_kitti)
    np.testing.assert_allclose(k[:, :2], poses[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (k[:, 2] - poses[:, 2]))), 0.0, atol=1e-9)
    row = np.asarray(gt_tum.read_text().split("\n")[0].split(), dtype=float)  # planar: z = 0, a unit yaw quaternion
    assert row.shape == (8,) and row[3] == 0.0 and row[4] == row[5] == 0.0 and math.isclose(np.hypot(row[6], row[7]), 1.0)
    np.testing.assert_allclose(yaw_quaternion(np.array([math.pi / 2])), [[0, 0, math.sqrt(0.5), math.sqrt(0.5)]])
    assert len(kitti_text(poses).splitlines()[0].split()) == 12


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: tum_text([0.0, 0.0], np.zeros((2, 3))), "increase strictly"),
        (lambda: tum_text([0.0], np.zeros((2, 3))), "one entry per pose"),
        (lambda: tum_text([0.0, 1.0], np.full((2, 3), np.nan)), "finite"),
        (lambda: kitti_text(np.zeros((2, 2))), r"\(T, 3\)"),
        (lambda: write_trajectory_pair("/tmp", "x", [0.0], np.zeros((1, 3)), np.zeros((1, 3)), ("g2o",)), "formats"),
        (lambda: write_trajectory_pair("/tmp", "x", [0.0], np.zeros((1, 3)), np.zeros((2, 3))), "same length"),
        (lambda: formats_of("csv"), "--trajectory-format"),
    ],
)
def test_bad_trajectories_are_refused(call, match):
    with pytest.raises(ValueError, match=match):
        call()


# ---------------------------------------------------------------- evo (the slam-eval and test extras)
@pytest.fixture
def evo_file_interface():
    """evo's file reader (the tests below skip without evo, which the test extra installs)."""
    return pytest.importorskip("evo.tools.file_interface", reason="evo (pip install -e '.[slam-eval]')")


def evo_ape(gt: Path, est: Path) -> float:
    """evo's APE RMSE, translation part, no alignment; TUM pairs associated by timestamp."""
    from evo.core import metrics, sync
    from evo.tools import file_interface as evo_file_interface

    if gt.suffix == ".tum":
        ref, traj = evo_file_interface.read_tum_trajectory_file(str(gt)), evo_file_interface.read_tum_trajectory_file(str(est))
        ref, traj = sync.associate_trajectories(ref, traj, max_diff=1e-6)
    else:
        ref, traj = evo_file_interface.read_kitti_poses_file(str(gt)), evo_file_interface.read_kitti_poses_file(str(est))
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, traj))
    return float(ape.get_statistic(metrics.StatisticsType.rmse))


def test_evo_ape_on_an_env_episode_is_the_position_rmse(tmp_path, evo_file_interface):
    env = TrajectoryRecorder(gym.make("rhs-highway-slam-v0", **FAST), tmp_path, formats=("tum", "kitti"), prefix="hw")
    env.reset(seed=3)
    errors, est, true = [], [], []
    for _ in range(STEPS):
        _, _, terminated, truncated, info = env.step(1)  # IDLE
        errors.append(info["position_error_m"])
        est.append(info["estimated_pose"])
        true.append(info["true_pose"])
        assert not (terminated or truncated)
    freq = env.unwrapped.config["policy_frequency"]
    sim_end = env.unwrapped.time
    env.close()
    assert sorted(p.name for p in env.paths) == ["hw_0000_est.kitti", "hw_0000_est.tum", "hw_0000_gt.kitti", "hw_0000_gt.tum"]
    ate = float(np.sqrt(np.mean(np.square(errors))))  # rhs-slam evaluate's position_rmse_m
    assert ate > 1e-4  # a real error to compare, not two identical files
    assert position_rmse(np.asarray(est), np.asarray(true)) == pytest.approx(ate, abs=1e-12)
    assert evo_ape(tmp_path / "hw_0000_gt.tum", tmp_path / "hw_0000_est.tum") == pytest.approx(ate, abs=1e-6)
    assert evo_ape(tmp_path / "hw_0000_gt.kitti", tmp_path / "hw_0000_est.kitti") == pytest.approx(ate, abs=1e-6)
    ref = evo_file_interface.read_tum_trajectory_file(str(tmp_path / "hw_0000_gt.tum"))
    assert ref.num_poses == STEPS  # every step paired, none dropped by the association
    # the simulated time, one policy period per step (not the wall clock)
    np.testing.assert_allclose(ref.timestamps, np.arange(1, STEPS + 1) / freq, atol=1e-9)
    assert ref.timestamps[-1] == pytest.approx(sim_end, abs=1e-9)
    assert evo_file_interface.read_kitti_poses_file(str(tmp_path / "hw_0000_est.kitti")).num_poses == STEPS


def test_recorder_needs_the_slam_info_and_writes_per_episode(tmp_path):
    env = TrajectoryRecorder(gym.make("rhs-highway-v0", vehicles_count=3), tmp_path)
    env.reset(seed=0)
    with pytest.raises(KeyError, match="SlamMetricsInfo"):
        env.step(1)
    with pytest.raises(ValueError, match="formats"):
        TrajectoryRecorder(gym.make("rhs-highway-v0"), tmp_path, formats="tum")
    env = TrajectoryRecorder(gym.make("rhs-highway-slam-v0", **FAST), tmp_path)
    for seed in (0, 1):  # a reset writes the episode before it
        env.reset(seed=seed)
        env.step(1)
    env.close()
    assert sorted(p.name for p in env.paths) == ["episode_0000_est.tum", "episode_0000_gt.tum",
                                                 "episode_0001_est.tum", "episode_0001_gt.tum"]


def test_scenario_cli_exports_what_evo_reads(tmp_path, capsys, evo_file_interface):
    out = tmp_path / "result.json"
    code = cli_main(["scenario", str(ROOT / "examples" / "scenario.json"), "--out", str(out), "--trajectories",
                     str(tmp_path / "traj"), "--trajectory-format", "both", "--no-progress"])
    assert code == 0
    result = json.loads(out.read_text())
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["trajectory_files"] == result["trajectory_files"]
    gt, est = tmp_path / "traj" / "scenario_gt.tum", tmp_path / "traj" / "scenario_est.tum"
    assert result["ate_rmse_m"] > 1e-4
    assert evo_ape(gt, est) == pytest.approx(result["ate_rmse_m"], abs=1e-6)
    assert evo_ape(gt.with_suffix(".kitti"), est.with_suffix(".kitti")) == pytest.approx(result["ate_rmse_m"], abs=1e-6)
    dt = json.loads((ROOT / "examples" / "scenario.json").read_text())["dt"]
    t, _ = read_tum(gt)
    np.testing.assert_allclose(t, dt * np.arange(len(result["true_poses"])), atol=1e-9)


def test_evaluate_exports_each_episode_and_evo_ape_prints_its_rmse(tmp_path, capsys, evo_file_interface):
    kwargs = json.dumps({**FAST, "duration": 3})
    out = tmp_path / "eval.json"
    code = cli_main(["evaluate", "--policy", "idm", "--env", "rhs-highway-slam-v0", "--episodes", "1", "--seed", "5",
                     "--env-kwargs", kwargs, "--out", str(out), "--trajectories", str(tmp_path / "traj"), "--no-progress"])
    assert code == 0
    summary = json.loads(out.read_text())
    run = summary["runs"][0]
    gt, est = tmp_path / "traj" / "seed_5_gt.tum", tmp_path / "traj" / "seed_5_est.tum"
    assert summary["trajectory_files"] == [str(est), str(gt)]
    assert evo_ape(gt, est) == pytest.approx(run["position_rmse_m"], abs=1e-6)
    assert run["time_s"] == pytest.approx(list(np.arange(1, run["steps"] + 1) * 0.2), abs=1e-9)  # 5 Hz
    # the command line a user types, with its printed figure (6 decimals)
    exe = Path(sys.executable).with_name("evo_ape")
    exe_path = str(exe) if exe.exists() else shutil.which("evo_ape")
    assert exe_path, "evo_ape not found beside the interpreter nor on PATH"
    env = {**os.environ, "HOME": str(tmp_path), "MPLBACKEND": "Agg"}  # evo keeps its settings in ~/.evo
    env.pop("DISPLAY", None)
    text = subprocess.run([exe_path, "tum", str(gt), str(est)], capture_output=True, text=True, env=env, timeout=120,
                          check=True).stdout
    match = re.search(r"rmse\s+([0-9.eE+-]+)", text)
    assert match, text
    assert float(match.group(1)) == pytest.approx(run["position_rmse_m"], abs=1e-6)
    capsys.readouterr()
    code = cli_main(["evaluate", "--policy", "idm", "--env", "rhs-highway-v0", "--episodes", "1", "--out",
                     str(tmp_path / "x.json"), "--trajectories", str(tmp_path / "traj"), "--no-progress"])
    assert code == 2 and "no SLAM estimate" in capsys.readouterr().err
    assert not (tmp_path / "x.json").exists()
