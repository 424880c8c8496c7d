"""The paper-figure scripts (Fig. 5a, 5c) run end to end with ``--quick`` and write their files."""

from __future__ import annotations

import importlib
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

SCRIPTS = Path(__file__).resolve().parent.parent / "scripts"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run_script(name: str, *args: str) -> subprocess.CompletedProcess:
    env = {
        **os.environ,
        "OMP_NUM_THREADS": "1",
        "MPLBACKEND": "Agg",
        "SDL_VIDEODRIVER": "dummy",
    }
    return subprocess.run(
        [sys.executable, str(SCRIPTS / name), *args],
        check=False,
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )


def load_script(name: str):
    """The study module that ``scripts/<name>`` runs."""
    return importlib.import_module(f"rhs_studies.{name.removesuffix('.py')}")


def check_png(path: Path) -> None:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC and len(data) > 5000


def test_fig5a_quick(tmp_path):
    # phased and random need no pattern library; hologram stands in for a surface antenna
    proc = run_script("fig5a_slam_rmse.py", "--quick", "--antennas", "phased", "random", "hologram", "--registration", "icp", "--out-dir",
                      str(tmp_path), "--no-progress")
    assert proc.returncode == 0, proc.stderr[-3000:]
    check_png(tmp_path / "fig5a.png")
    res = json.loads((tmp_path / "fig5a.json").read_text())
    assert res["figure"] == "5a" and res["paper_ratio"] == pytest.approx(1 / 3)
    assert "third" in res["paper_claim"] and "tx_power_dbm" in res["snr_sweep"]
    s = res["settings"]
    assert (
        s["antennas"] == ["phased", "random", "hologram"] and s["registration"] == "icp"
    )
    assert s["seeds"] == [0] and s["powers_dbm"] == [30.0] and s["cycles"] == 10
    assert len(res["episodes"]) == 3
    for ep in res["episodes"]:
        assert ep["cycles"] == 10
        assert math.isfinite(ep["vehicle_rmse_m"]) and 0 <= ep["vehicle_rmse_m"] < 20
        assert ep["map_matched"] + ep["map_missed"] == 5  # the paper's five obstacles
        assert ep["obstacle_rmse_m"] is None or 0 <= ep["obstacle_rmse_m"] <= 2.0
        assert {"registration", "predict", "update"} <= set(
            ep["slam_stage_times_ms"]
        )
    rows = {r["antenna"]: r for r in res["rows"]}
    assert set(rows) == {"phased", "random", "hologram"}
    for r in rows.values():
        assert r["seeds"] == 1 and r["vehicle_rmse_m"]["n"] == 1
        ep = next(e for e in res["episodes"] if e["antenna"] == r["antenna"])
        assert r["vehicle_rmse_m"]["mean"] == pytest.approx(ep["vehicle_rmse_m"])
    ratios = {q["antenna"]: q for q in res["ratios"]}
    assert set(ratios) == {
        "random",
        "hologram",
    }  # every antenna against the phased reference
    for a, q in ratios.items():
        expect = (
            rows[a]["vehicle_rmse_m"]["mean"] / rows["phased"]["vehicle_rmse_m"]["mean"]
        )
        assert q["vehicle_rmse_ratio"] == pytest.approx(expect)
    # measured in quick mode: the phased array tracks the 12 m drive to a few cm with ICP
    assert rows["phased"]["vehicle_rmse_m"]["mean"] < 0.5
    md = (tmp_path / "fig5a.md").read_text()
    assert md.count("\n| 30 |") == 3 and "third" in md and "1 (reference)" in md


def test_fig5c_quick(tmp_path):
    proc = run_script("fig5c_trajectory_map.py", "--quick", "--antenna", "phased", "--registration", "icp", "--out-dir", str(tmp_path),
                      "--no-progress")
    assert proc.returncode == 0, proc.stderr[-3000:]
    check_png(tmp_path / "fig5c.png")
    res = json.loads((tmp_path / "fig5c.json").read_text())
    assert (
        res["figure"] == "5c"
        and res["settings"]["antenna"] == "phased"
        and res["settings"]["cycles"] == 10
    )
    true, est = (
        np.asarray(res["true_trajectory"]),
        np.asarray(res["estimated_trajectory"]),
    )
    assert true.shape == est.shape == (11, 3)  # reset + 10 cycles
    np.testing.assert_allclose(
        true[0], [0.0, 37.5, 0.0], atol=1e-6
    )  # the paper's start, world frame
    np.testing.assert_allclose(
        true[-1], [12.0, 37.5, 0.0], atol=0.05
    )  # 10 cycles at 6 m/s, 5 Hz
    np.testing.assert_allclose(est[0], true[0], atol=1e-6)
    obstacles = np.asarray(res["true_obstacles"])
    np.testing.assert_allclose(
        obstacles, [[10, 65], [25, 10], [30, 65], [35, 10], [50, 65]], atol=1e-6
    )
    assert len(res["matches"]) == 5 and res["map_matched"] + res["map_missed"] == 5
    emap = np.asarray(res["estimated_map"]).reshape(-1, 2)
    for m in res["matches"]:
        if m["estimated_xy"] is not None:  # matches point into the estimated map
            assert np.min(np.hypot(*(emap - np.asarray(m["estimated_xy"])).T)) < 1e-3
            assert m["error_m"] == pytest.approx(
                np.hypot(*(np.subtract(m["estimated_xy"], m["true_xy"]))), abs=1e-3
            )
    pos = np.hypot(est[1:, 0] - true[1:, 0], est[1:, 1] - true[1:, 1])
    assert res["vehicle_rmse_m"] == pytest.approx(
        float(np.sqrt(np.mean(pos**2))), abs=1e-3
    )
    assert (
        res["vehicle_rmse_m"] < 0.5 and res["map_matched"] >= 4
    )  # measured 0.02 m, 5 / 5
    md = (tmp_path / "fig5c.md").read_text()
    assert "vehicle RMSE" in md and "(10.0, 65.0)" in md


@pytest.mark.parametrize("name", ["fig5a_slam_rmse.py", "fig5c_trajectory_map.py"])
def test_default_registration_is_the_envs_default(name):
    from slam.core.registration import DEFAULT_REGISTRATION

    mod = load_script(name)
    assert mod.parse_args([]).registration == DEFAULT_REGISTRATION
    assert mod.parse_args(["--registration", "odometry"]).registration == "odometry"


def test_fig5a_defaults_are_the_paper_schemes():
    a = load_script("fig5a_slam_rmse.py").parse_args([])
    assert a.antennas == ["rhs", "phased", "random"] and a.seeds == 20
    assert a.powers == [30.0, 20.0, 10.0, 0.0, -10.0]  # down to where detection fails
    assert a.cycles == 50 and a.grid_deg == 1.0 and a.out_dir == "results"


def test_fig5a_resume_skips_done_episodes(tmp_path):
    args = ["--quick", "--antennas", "phased", "--registration", "icp", "--out-dir", str(tmp_path), "--no-progress"]
    mod = load_script("fig5a_slam_rmse.py")
    a = mod.parse_args(args)
    fake = {"antenna": "phased", "seed": 0, "tx_power_dbm": 30.0, "cycles": 10, "vehicle_rmse_m": 123.0,
            "vehicle_max_error_m": 1.0, "final_position_error_m": 1.0, "heading_rmse_rad": 0.0,
            "obstacle_rmse_m": None, "map_matched": 0, "map_missed": 5, "map_spurious": 0,
            "slam_stage_times_ms": {"registration": 1.0}, "wall_s": 0.0}
    (tmp_path / "fig5a.partial.json").write_text(json.dumps({"settings": mod.episode_settings(a), "episodes": [fake]}))
    proc = run_script("fig5a_slam_rmse.py", *args, "--resume")
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads((tmp_path / "fig5a.json").read_text())
    assert [e["vehicle_rmse_m"] for e in res["episodes"]] == [123.0]  # taken from the partial file, not rerun
    assert not (tmp_path / "fig5a.partial.json").exists()
    assert res["provenance"]["command"][1] == "scripts/fig5a_slam_rmse.py" and res["provenance"]["config"]["resume"]


def test_registration_in_loop_quick(tmp_path):
    proc = run_script("registration_in_loop.py", "--quick", "--registrations", "icp", "odometry", "--antenna",
                      "phased", "--out-dir", str(tmp_path), "--no-progress")
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads((tmp_path / "registration_in_loop.json").read_text())
    rows = {r["registration"]: r for r in res["rows"]}
    assert set(rows) == {"icp", "odometry"} and len(res["episodes"]) == 2
    assert rows["icp"]["vehicle_rmse_ratio_to_icp"] == pytest.approx(1.0)
    assert rows["icp"]["vehicle_rmse_m"]["mean"] < 0.5  # ICP tracks the 9.6 m quick drive (measured a few cm)
    ep = {e["registration"]: e for e in res["episodes"]}
    assert rows["odometry"]["vehicle_rmse_ratio_to_icp"] == pytest.approx(
        ep["odometry"]["vehicle_rmse_m"] / ep["icp"]["vehicle_rmse_m"])
    assert res["provenance"]["fingerprint"]["name"] == "registration_in_loop"
    md = (tmp_path / "registration_in_loop.md").read_text()
    assert "| icp |" in md and "| odometry |" in md


def test_fig5b_small_run_writes_png_json_md(tmp_path):
    """Fig. 5b on two tiny configs (library for M=12 built into a private cache)."""
    out = tmp_path / "fig5b"
    env_cache = {**os.environ, "RHS_SLAM_CACHE": str(tmp_path / "cache")}
    res = subprocess.run(
        [sys.executable, str(SCRIPTS / "fig5b_pointcloud_vs_elements.py"), "--elements", "12", "24",
         "--grids", "5", "--cycles", "1", "--out", str(out)],
        capture_output=True, text=True, timeout=600, env={**env_cache, "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg"},
    )
    assert res.returncode == 0, res.stderr[-2000:]
    assert out.with_suffix(".png").read_bytes()[:8] == PNG_MAGIC
    rows = json.loads(out.with_suffix(".json").read_text())["rows"]
    assert [r["elements"] for r in rows] == [12, 24]
    for r in rows:
        assert 0.0 <= r["rhs"]["detection_rate"] <= 1.0
        assert r["rhs"]["crb_cross_range_m"] > 0 and r["phased"]["crb_cross_range_m"] > 0
        assert r["phased_elements"] == max(2, round(r["elements"] / 6))
    md = out.with_suffix(".md").read_text()
    assert "| 5 | 24 |" in md and "phased CRB (m)" in md and "CRB ratio" in md
    res = json.loads(out.with_suffix(".json").read_text())
    assert res["provenance"]["config"]["elements"] == [12, 24] and res["provenance"]["fingerprint"]["hash"]


def test_detection_curves_quick_writes_json_md_png(tmp_path):
    """scripts/detection_curves.py --quick: files, provenance, and the theory curves ordered as physics says."""
    res = run_script("detection_curves.py", "--quick", "--snr-min", "-16", "--snr-max", "-6",
                     "--max-range", "45", "--out-dir", str(tmp_path))
    assert res.returncode == 0, res.stderr[-2000:]
    out = json.loads((tmp_path / "detection_curves.json").read_text())
    assert len(out["provenance"]["commit"]) == 40 and "scripts/detection_curves.py" in out["provenance"]["command"]
    check_png(tmp_path / "detection_curves.png")
    assert "footprint" in (tmp_path / "detection_curves.md").read_text()
    for ant in ("rhs", "phased"):
        th = out["theory"][ant]
        # the coherent matched filter bounds the footprint energy detector, which beats the slot sum
        assert np.all(np.array(th["matched_filter"]) >= np.array(th["footprint_known_noise"]) - 1e-9)
        assert np.all(np.array(th["footprint_known_noise"]) >= np.array(th["summed_known_noise"]) - 1e-9)
        for d in ("summed", "footprint"):
            assert all(0.0 <= p <= 1.0 for p in out["measured"][ant][d])
    assert out["timing"]["detect_ratio_footprint_over_summed"] > 0
