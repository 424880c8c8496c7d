"""``rhs-slam scan SCENE.json --out CLOUD.json`` (rhs_env.scan_cli)."""

from __future__ import annotations

import json

import pytest

from rhs_slam.cli import main


def _run(tmp_path, scene, capsys, extra=()):
    p = tmp_path / "scene.json"
    p.write_text(scene if isinstance(scene, str) else json.dumps(scene))
    out = tmp_path / "cloud.json"
    rc = main(["scan", str(p), "--out", str(out), *extra])
    cap = capsys.readouterr()
    return rc, out, cap


def test_scan_writes_points(tmp_path, capsys):
    scene = {"targets": [[30.0, 3.0, 5.0], [-20.0, -2.0, 5.0], [5.0, 25.0, 10.0, 0.0, -3.0]],
             "antenna": "hologram", "seed": 3}
    rc, out, cap = _run(tmp_path, scene, capsys)
    assert rc == 0, cap.err
    pts = json.loads(out.read_text())["points"]
    assert all(len(p) == 4 for p in pts)
    for x, y in [(30.0, 3.0), (-20.0, -2.0), (5.0, 25.0)]:
        assert min((p[0] - x) ** 2 + (p[1] - y) ** 2 for p in pts) < 0.5 ** 2
    # same seed -> same output
    _rc2, out2, _ = _run(tmp_path, scene, capsys)
    assert json.loads(out2.read_text())["points"] == pts


def test_scan_occluder_hides_target(tmp_path, capsys):
    scene = {"targets": [[40.0, 0.0, 5.0]], "occluders": [[20.0, -2.0, 20.0, 2.0]], "antenna": "phased"}
    rc, out, cap = _run(tmp_path, scene, capsys)
    assert rc == 0, cap.err
    assert json.loads(out.read_text())["points"] == []


@pytest.mark.parametrize(
    "scene, fragment",
    [
        ("{not json", "not valid JSON"),
        ({"targets": [[1.0, 2.0]]}, "targets[0]"),
        ({"targets": [[1.0, 2.0, -1.0]]}, "rcs_m2 must be in [0, 10000]"),
        ('{"targets": [[1.0, NaN, 5.0]]}', "finite"),
        ({"points": []}, "unknown scene key"),
        ({}, "missing the 'targets'"),
        ({"targets": [[10.0, 0.0, 5.0]], "antenna": "horn"}, "unknown antenna"),
        ({"targets": [[10.0, 0.0, 5.0]], "seed": -1}, "seed"),
        ({"targets": "abc"}, "must be a list"),
        ([1, 2, 3], "JSON object"),
    ],
)
def test_scan_refuses_bad_scene(tmp_path, capsys, scene, fragment):
    rc, out, cap = _run(tmp_path, scene, capsys)
    assert rc != 0
    assert fragment in cap.err
    assert "Traceback" not in cap.err
    assert len(cap.err.strip().splitlines()) == 1
    assert not out.exists()


def test_scan_missing_file(tmp_path, capsys):
    rc = main(["scan", str(tmp_path / "nope.json"), "--out", str(tmp_path / "o.json")])
    assert rc != 0
    assert "cannot read" in capsys.readouterr().err
