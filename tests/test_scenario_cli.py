"""``rhs-slam scenario SCENARIO.json --out RESULT.json``: a scripted SLAM run and its input checks."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from rhs_slam.cli import main

# 8 cycles straight along x at 6 m/s (dt 0.2 s), four landmarks on both sides, the coarse
# 5-degree scan (I = 18) of the same-cost phased array: no pattern library, about a second.
POSES = [[1.2 * k, 0.0, 0.0] for k in range(8)]
LANDMARKS = [[10.0, 8.0], [15.0, -8.0], [20.0, 8.0], [5.0, -10.0]]
GOOD = {
    "landmarks": LANDMARKS,
    "poses": POSES,
    "antenna": "phased",
    "grid_deg": 5,
    "seed": 1,
    "dt": 0.2,
    "registration": "icp",
}


def write(tmp_path, doc, name="scenario.json"):
    path = tmp_path / name
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


def run_cli(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run(
        [sys.executable, "-m", "rhs_slam.cli", "scenario", *args],
        check=False,
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )


def test_scripted_run_writes_the_result(tmp_path):
    scen, out = write(tmp_path, GOOD), tmp_path / "result.json"
    proc = run_cli(str(scen), "--out", str(out), "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    res = json.loads(out.read_text())
    assert {
        "estimated_poses",
        "landmarks",
        "ate_rmse_m",
        "map_rmse_m",
        "map_matched",
    } <= set(res)
    est, true = np.asarray(res["estimated_poses"]), np.asarray(res["true_poses"])
    assert est.shape == true.shape == (8, 3)
    np.testing.assert_allclose(
        true, np.asarray(POSES), atol=1e-9
    )  # the first pose is the map origin
    np.testing.assert_allclose(est[0], 0.0, atol=1e-9)
    # the reported ATE is the position RMSE of the written poses (rounded to 0.1 mm)
    ate = math.sqrt(np.mean(np.sum((est[:, :2] - true[:, :2]) ** 2, axis=1)))
    assert res["ate_rmse_m"] == pytest.approx(ate, abs=1e-3)
    assert res["ate_rmse_m"] < 0.3  # measured 0.016 m
    lm = np.asarray(res["landmarks"])
    assert lm.ndim == 2 and lm.shape[1] == 2
    assert (
        res["map_matched"] == 4 and res["map_missed"] == 0
    )  # measured: all four, 0.02 m RMSE
    assert res["map_rmse_m"] is not None and res["map_rmse_m"] < 0.5
    for p in LANDMARKS:  # every true landmark has an estimate nearby
        assert np.min(np.hypot(*(lm - np.asarray(p)).T)) < 0.5
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["ate_rmse_m"] == res["ate_rmse_m"]


def test_same_scenario_same_result(tmp_path):
    scen = write(tmp_path, GOOD)
    outs = []
    for k in range(2):
        out = tmp_path / f"r{k}.json"
        assert main(["scenario", str(scen), "--out", str(out), "--no-progress"]) == 0
        outs.append(json.loads(out.read_text()))
    assert outs[0] == outs[1]
    other = write(tmp_path, {**GOOD, "seed": 2}, "other.json")
    out = tmp_path / "r2.json"
    assert main(["scenario", str(other), "--out", str(out), "--no-progress"]) == 0
    assert json.loads(out.read_text())["estimated_poses"] != outs[0]["estimated_poses"]


def _without(key):
    return {k: v for k, v in GOOD.items() if k != key}


BAD = [
    ("missing landmarks", _without("landmarks"), "landmarks"),
    ("missing poses", _without("poses"), "poses"),
    ("NaN pose", {**GOOD, "poses": [[0, 0, 0], [1, float("nan"), 0]]}, "poses"),
    ("NaN landmark", {**GOOD, "landmarks": [[1, 2], [float("nan"), 3]]}, "landmarks"),
    ("pose of 2 numbers", {**GOOD, "poses": [[0, 0], [1, 0]]}, "poses"),
    ("landmark of 3 numbers", {**GOOD, "landmarks": [[1, 2, 3]]}, "landmarks"),
    ("ragged poses", {**GOOD, "poses": [[0, 0, 0], [1, 0]]}, "poses"),
    ("text pose", {**GOOD, "poses": [[0, 0, 0], [1, "a", 0]]}, "poses"),
    ("single pose", {**GOOD, "poses": [[0, 0, 0]]}, "poses"),
    ("negative dt", {**GOOD, "dt": -0.1}, "dt"),
    ("zero dt", {**GOOD, "dt": 0}, "dt"),
    ("text dt", {**GOOD, "dt": "fast"}, "dt"),
    ("unknown antenna", {**GOOD, "antenna": "laser"}, "antenna"),
    ("unknown registration", {**GOOD, "registration": "gps"}, "registration"),
    ("negative seed", {**GOOD, "seed": -1}, "seed"),
    ("grid not dividing 90", {**GOOD, "grid_deg": 7}, "grid_deg"),
    ("unknown key", {**GOOD, "speed": 3}, "speed"),
    ("not an object", [1, 2, 3], "JSON object"),
    ("invalid JSON", '{"landmarks": [[1, 2]], "poses": ', "not valid JSON"),
]


@pytest.mark.parametrize("doc, needle", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_scenario_fails_with_one_clear_line(tmp_path, capsys, doc, needle):
    if isinstance(doc, dict):
        doc = json.dumps(
            doc
        )  # NaN is written as the JSON extension NaN, which Python reads back
    scen, out = write(tmp_path, doc), tmp_path / "result.json"
    code = main(["scenario", str(scen), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert code != 0
    assert not out.exists()
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("rhs-slam scenario: error:") and needle in lines[0]
    assert "Traceback" not in err


def test_missing_file_and_unwritable_output(tmp_path, capsys):
    code = main(
        ["scenario", str(tmp_path / "nope.json"), "--out", str(tmp_path / "r.json")]
    )
    err = capsys.readouterr().err.strip()
    assert (
        code != 0
        and len(err.splitlines()) == 1
        and "no such file" in err
        and "nope.json" in err
    )
    code = main(
        ["scenario", str(tmp_path), "--out", str(tmp_path / "r.json")]
    )  # a directory
    err = capsys.readouterr().err.strip()
    assert code != 0 and len(err.splitlines()) == 1 and "cannot read" in err
    scen = write(tmp_path, GOOD)
    (tmp_path / "a_file").write_text("")
    code = main(
        [
            "scenario",
            str(scen),
            "--out",
            str(tmp_path / "a_file" / "r.json"),  # a file where the parent directory should be
            "--no-progress",
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code != 0 and len(err.splitlines()) == 1 and "cannot write" in err


def test_bad_scenario_in_a_subprocess_has_no_traceback(tmp_path):
    proc = run_cli(
        str(write(tmp_path, {**GOOD, "dt": -1})), "--out", str(tmp_path / "r.json")
    )
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    assert (
        proc.stderr.strip().splitlines() == [proc.stderr.strip()]
        and "'dt'" in proc.stderr
    )
    proc = run_cli(str(tmp_path / "missing.json"), "--out", str(tmp_path / "r.json"))
    assert (
        proc.returncode != 0
        and "Traceback" not in proc.stderr
        and "missing.json" in proc.stderr
    )


def test_missing_cnn_weights_is_a_clear_error(tmp_path, capsys, monkeypatch):
    import slam.core.cnn_registration as cnn

    monkeypatch.setattr(cnn, "DEFAULT_WEIGHTS", tmp_path / "no_weights.pt")
    scen = write(tmp_path, {**GOOD, "registration": "cnn"})
    code = main(
        ["scenario", str(scen), "--out", str(tmp_path / "r.json"), "--no-progress"]
    )
    err = capsys.readouterr().err.strip()
    assert (
        code != 0
        and len(err.splitlines()) == 1
        and "no_weights.pt" in err
        and "Traceback" not in err
    )
