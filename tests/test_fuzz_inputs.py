"""Seeded fuzzing of every input door: nested ``gym.make`` kwargs, highway-env's own config keys,
the paper scene's start and obstacles, scan scenes and scenario documents (as Python values and
as the bytes of their JSON files), the command line's flags and actions. Every outcome is a
success (finite observation / result) or a ``ValueError`` / ``TypeError`` whose message names the
mutated field, raised by the validation code itself (the innermost traceback frame is in a
validation function, not deep in the radar or highway-env), or, on the command line, exit 2 and
one line naming the file or flag. No case may hang (each is cheap: a coarse scan, episodes of 2 steps).

:data:`bad_input_table.CASES` (every input a new user tried, with its expected class of outcome)
runs first, one test per row.
"""

from __future__ import annotations

import copy
import json
import math
import os
import signal
import traceback
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from bad_input_table import CASES, HW, PAPER, PAPER_KW, SMALL, classify, expected_class, run_case
from conftest import SMALL_RADAR

import rhs_env  # noqa: F401
from rhs_env.scan_cli import SceneError, parse_scene
from rhs_slam.cli import main
from slam.gym.scenario_cli import parse_scenario

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_every_tried_input_has_its_class_of_outcome(case, tmp_path, monkeypatch):
    """Clean error naming the field / flag / file, or accepted and finite (and saying so where it must)."""
    monkeypatch.chdir(ROOT)  # the student zip is named relative to the repository
    monkeypatch.setenv("RHS_SLAM_CACHE", str(tmp_path / "cache"))  # no library may be built, none is reused
    monkeypatch.delenv("RHS_SLAM_BUILD_PATTERNS", raising=False)
    outcome = run_case(case, tmp_path)
    assert classify(case, outcome) == expected_class(case), (outcome.message or outcome.text)[-1500:]
    if case.kind == "cli" and case.expect == "refuse":  # one line on stderr, naming what is wrong
        assert len([ln for ln in outcome.text.splitlines() if ln.strip()]) == 1, outcome.text

#: a valid, cheap radar/SLAM configuration: every leaf is a field the fuzzer mutates (the
#: closed-form hologram antenna: a valid mutation never starts a pattern-library build)
BASE = {
    "radar": {**SMALL_RADAR, "antenna": "hologram",
              "link": {"tx_power_dbm": 30.0, "add_noise": True}, "detection": {"pfa": 1e-6},
              "estimation": {"max_targets": 4}},
    "max_points": 32,
    "scatter": {"vehicle_rcs_m2": 10.0, "points_per_face": 2},
    "landmarks": {"spacing_m": 20.0, "rcs_m2": 5.0},
    "vehicles_count": 2,
    "lanes_count": 2,
    "duration": 0.4,
    "slam": {"n_particles": 8, "delta_m": 2.0},
    "max_landmarks": 8,
    "map_gate_m": 2.0,
}
#: innermost frames allowed to raise: the validators and the parsers of the documents
VALIDATORS = ("check_", "_check_", "build", "_validate_config", "__post_init__", "configure", "__init__", "parse_", "_array",
              "_number", "_check_speed", "make_registration", "make_radar_config", "_type_error", "make")

BAD_VALUES = ("20", None, [1, 2], {"x": 1}, math.nan, math.inf, -math.inf, -1, 0, 1e300, -1e300, 10**12, True, 2.5,
              "bogus")


def _leaves(d: dict, path=()):
    for k, v in d.items():
        if isinstance(v, dict):
            yield from _leaves(v, (*path, k))
        else:
            yield (*path, k)


def _set(d: dict, path: tuple, value) -> None:
    for k in path[:-1]:
        d = d[k]
    d[path[-1]] = value


def _mutations(rng: np.random.Generator, n: int):
    leaves = list(_leaves(BASE))
    for _ in range(n):
        kw = copy.deepcopy(BASE)
        path = leaves[rng.integers(len(leaves))]
        if rng.random() < 0.1:  # an unknown key beside a real one (a typo)
            path = (*path[:-1], path[-1] + "_x")
        value = BAD_VALUES[rng.integers(len(BAD_VALUES))]
        _set(kw, path, value)
        yield path, value, kw


def _raised_by_a_validator(exc: BaseException) -> bool:
    name = traceback.extract_tb(exc.__traceback__)[-1].name
    return any(name.startswith(v) for v in VALIDATORS)


def _origin(exc: BaseException) -> BaseException:
    """The exception that started it: gymnasium re-raises with context; ``raise ... from None`` ends the chain."""
    while True:
        nxt = exc.__cause__ or (None if exc.__suppress_context__ else exc.__context__)
        if nxt is None:
            return exc
        exc = nxt


def _short_episode(env_id: str, kw: dict, steps: int = 2) -> None:
    """``gym.make(env_id, **kw)``, a reset and ``steps`` IDLE steps: every observation array and reward finite."""
    env = gym.make(env_id, **kw)
    try:
        obs, _ = env.reset(seed=0)
        for _ in range(steps):
            for key, value in (obs.items() if isinstance(obs, dict) else [("observation", obs)]):
                assert np.all(np.isfinite(value)), key
            obs, reward, *_ = env.step(1)
            assert math.isfinite(reward)
    finally:
        env.close()


def _check_outcome(fn, fields: list[str]):
    """Success, or a ValueError / TypeError from a validator naming one of ``fields``."""
    try:
        return fn()
    except (ValueError, TypeError) as exc:
        cause = _origin(exc)
        message = str(exc).split(" was raised from the environment creator")[0]
        assert any(f in message for f in fields), f"none of {fields} named in {exc!r}"
        assert _raised_by_a_validator(cause), "".join(traceback.format_exception(cause))[-1500:]
        return None


def test_fuzz_env_kwargs():
    rng = np.random.default_rng(20261123)
    outcomes = {"ok": 0, "refused": 0}
    for path, _value, kw in _mutations(rng, 40):
        ok = _check_outcome(lambda kw=kw: _short_episode("rhs-highway-slam-v0", kw) or True, [path[-1]])
        outcomes["ok" if ok else "refused"] += 1
    assert outcomes["refused"] > 20  # most mutations are bad on purpose


def _jitter(rng, doc: dict) -> tuple[str, dict]:
    doc = copy.deepcopy(doc)
    key = list(doc)[rng.integers(len(doc))]
    value = doc[key]
    choice = rng.integers(4)
    if isinstance(value, list) and value and choice < 2:  # corrupt one number of one row
        row = list(value[rng.integers(len(value))])
        if row:
            row[rng.integers(len(row))] = BAD_VALUES[rng.integers(len(BAD_VALUES))]
        value[rng.integers(len(value))] = row
    else:
        doc[key] = BAD_VALUES[rng.integers(len(BAD_VALUES))]
    return key, doc


def test_fuzz_scene_and_scenario_documents():
    rng = np.random.default_rng(7)
    scene = {"targets": [[20.0, 0.0, 5.0], [30.0, 5.0, 5.0, 1.0, 0.0]], "occluders": [[5.0, -1.0, 5.0, 1.0]],
             "antenna": "rhs", "seed": 0}
    scenario = {"landmarks": [[10.0, 5.0], [20.0, -5.0]], "poses": [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]],
                "antenna": "hologram", "seed": 0, "dt": 0.2, "registration": "icp", "rcs_m2": 5.0, "grid_deg": 5.0,
                "particles": 10}
    for _ in range(150):
        key, doc = _jitter(rng, scene)
        try:
            parse_scene(doc)
        except SceneError as exc:
            assert key in str(exc), (doc, exc)
        key, doc = _jitter(rng, scenario)
        _check_outcome(lambda doc=doc: parse_scenario(doc), [key])


@pytest.mark.parametrize("env_id", ["rhs-highway-v0", "rhs-paper-v0"])
def test_fuzz_actions(env_id):
    rng = np.random.default_rng(3)
    kw = {"duration": 0.4} if env_id == "rhs-highway-v0" else {"radar": BASE["radar"], "duration": 0.4}
    env = gym.make(env_id, **kw)
    env.reset(seed=0)
    pool = [0, 1, 2, 3, 4, 5, -1, 7, 2.5, math.nan, None, "a", "1", [1], [1, 2], np.int64(2), np.array([3]),
            np.array([1.0]), np.array([[1]]), True, 10**20, {}]
    try:
        for _ in range(60):
            action = pool[rng.integers(len(pool))]
            try:
                obs, _, term, trunc, _ = env.step(action)
            except (ValueError, TypeError) as exc:
                assert "action space Discrete(5)" in str(exc)
                continue
            assert isinstance(action, (int, np.integer, np.ndarray)) and not isinstance(action, bool)
            for value in (obs.values() if isinstance(obs, dict) else [obs]):
                assert np.all(np.isfinite(value))
            if term or trunc:
                env.reset(seed=int(rng.integers(100)))
    finally:
        env.close()


# --------------------------------------------------------------------------- highway-env's own keys
HIGHWAY_KEYS = {
    ("action", "target_speeds"): ([], [10.0, math.nan], [30, 20], [0.0, 50.0], np.array([5.0, 10.0]), [1e9], "x",
                                  [10, 10], [-5, 10]),
    ("reward_speed_range",): ([30, 20], [20, 30], "fast", [1, 2, 3], [math.inf, 30], np.array([10.0, 20.0])),
    ("other_vehicles_type",): ("no.such.Vehicle", "math.pi", 5, "highway_env.vehicle.behavior.IDMVehicle",
                               "highway_env.vehicle.behavior.AggressiveVehicle", "os.path"),
    ("initial_lane_id",): (99, -1, 1, 1.5, None, np.int64(1), True),
    ("observation", "vehicles_count"): (-1, 0, 3, 10**6, 2.5, "5"),
    ("centering_position",): ("x", [0.3], [0.3, 0.5], [math.nan, 0.5], [2.0, 0.5], np.array([0.5, 0.5])),
    ("policy_frequency",): (0.7, 4, 3, 5, 15, 30, 7.5, 0),
    ("lanes_count",): (1, 2, 0, 2.0, np.int64(2)),
}


def test_fuzz_highway_env_keys():
    """Random mutations of highway-env's keys, each alone or two at once (lane ids against lanes_count)."""
    rng = np.random.default_rng(26)
    keys = list(HIGHWAY_KEYS)
    outcomes = {"ok": 0, "refused": 0}
    for _ in range(40):
        kw: dict = {**SMALL, "observation": {"type": "Kinematics"}, "action": {"type": "DiscreteMetaAction"}}
        picked = [keys[i] for i in rng.choice(len(keys), size=int(rng.integers(1, 3)), replace=False)]
        for path in picked:
            values = HIGHWAY_KEYS[path]
            _set(kw, path, values[rng.integers(len(values))])
        fields = [p[-1] for p in picked] + ["lanes_count"] if ("initial_lane_id",) in picked else [p[-1] for p in picked]
        ok = _check_outcome(lambda kw=kw: _short_episode(HW, kw) or True, fields)
        outcomes["ok" if ok else "refused"] += 1
    assert outcomes["refused"] > 10 and outcomes["ok"] > 3, outcomes


# --------------------------------------------------------------------------- the paper scene's start / obstacles
def test_fuzz_paper_start_and_obstacles():
    rng = np.random.default_rng(5)
    coords = [0.0, 10.0, 37.5, 60.0, -20.0, 1e9, -1e9, math.nan, math.inf, 1e5, 2e5]
    shapes = ("pairs", "flat", "one", "empty", "nested", "string", "bools")
    outcomes = {"ok": 0, "refused": 0}
    for _ in range(30):
        kw = dict(PAPER_KW)
        if rng.random() < 0.5:
            kw["start"] = [float(rng.uniform(-40, 300)), coords[rng.integers(len(coords))]]
        shape = shapes[rng.integers(len(shapes))]
        pick = lambda: coords[rng.integers(len(coords))]
        kw["obstacles"] = {
            "pairs": [[pick(), pick()] for _ in range(int(rng.integers(1, 4)))],
            "flat": [pick() for _ in range(4)],
            "one": [[pick()]],
            "empty": [],
            "nested": [[[pick(), pick()]]],
            "string": "10,65",
            "bools": [[True, False]],
        }[shape]
        ok = _check_outcome(lambda kw=kw: _short_episode(PAPER, kw) or True, ["start", "obstacles"])
        outcomes["ok" if ok else "refused"] += 1
    assert outcomes["refused"] > 10 and outcomes["ok"] > 2, outcomes


# --------------------------------------------------------------------------- JSON files, byte by byte
SCENE_DOC = {"targets": [[20.0, 0.0, 5.0], [30.0, 5.0, 5.0, 1.0, 0.0]], "antenna": "hologram", "seed": 3}
SCENARIO_DOC = {"landmarks": [[10.0, 5.0], [20.0, -5.0]], "poses": [[0.0, 0.0, 0.0], [1.0, 0.0, 0.1]],
                "antenna": "hologram", "grid_deg": 10.0, "registration": "odometry", "particles": 5, "seed": 1}


def _corrupt(rng: np.random.Generator, text: bytes) -> tuple[str, bytes]:
    """One corruption of a JSON file: bad UTF-8, deep nesting, a long integer, a huge float, a string or a
    boolean for a number, an absurd heading, a truncation, or none."""
    numbers = [m for m in range(len(text)) if text[m:m + 1].isdigit() and not text[m - 1:m].isdigit()]
    at = numbers[rng.integers(len(numbers))]
    end = at
    while text[end:end + 1].isdigit() or text[end:end + 1] == b".":
        end += 1
    kinds = ("utf8", "deep", "long_int", "huge_float", "string", "bool", "heading", "truncate", "none")
    kind = kinds[rng.integers(len(kinds))]
    if kind == "utf8":
        i = int(rng.integers(len(text)))
        return kind, text[:i] + bytes([int(rng.choice([0xFF, 0xC3, 0x80, 0xFE]))]) + text[i:]
    if kind == "deep":
        n = int(rng.choice([65, 1000, 200_000]))
        return kind, text[:at] + b"[" * n + text[at:end] + b"]" * n + text[end:]
    if kind == "long_int":
        return kind, text[:at] + b"9" * int(rng.choice([31, 400, 5000])) + text[end:]
    if kind == "huge_float":
        return kind, text[:at] + b"1e400" + text[end:]
    if kind == "string":
        return kind, text[:at] + b'"' + text[at:end] + b'"' + text[end:]
    if kind == "bool":
        return kind, text[:at] + b"true" + text[end:]
    if kind == "heading":
        return kind, text.replace(b"0.1]", b"1e12]")
    if kind == "truncate":
        return kind, text[: int(rng.integers(1, len(text)))]
    return kind, text


@pytest.mark.parametrize("command, doc", [("scan", SCENE_DOC), ("scenario", SCENARIO_DOC)])
def test_fuzz_json_files(command, doc, tmp_path, capsys):
    """Exit 0 with a finite result, or exit 2 and one line that names the file; never a traceback."""
    rng = np.random.default_rng(11 if command == "scan" else 12)
    base = json.dumps(doc).encode()
    seen = set()
    for n in range(30):
        kind, data = _corrupt(rng, base)
        seen.add(kind)
        path = tmp_path / f"doc{n}.json"
        path.write_bytes(data)
        out = tmp_path / f"out{n}.json"
        extra = ["--grid-deg", "10"] if command == "scan" else ["--no-progress"]
        code = main([command, str(path), "--out", str(out), *extra])
        err = capsys.readouterr().err.strip()
        if code == 0:
            result = json.loads(out.read_text())
            assert _all_finite(result), (kind, result)
        else:
            lines = [ln for ln in err.splitlines() if ln.strip() and "SLAM:" not in ln]
            assert code == 2 and len(lines) == 1 and str(path) in lines[0] and "Traceback" not in err, (kind, err)
    assert {"utf8", "deep", "long_int", "string", "bool"} <= seen


def _all_finite(node) -> bool:
    if isinstance(node, dict):
        return all(_all_finite(v) for v in node.values())
    if isinstance(node, list):
        return all(_all_finite(v) for v in node)
    return not isinstance(node, float) or math.isfinite(node)


# --------------------------------------------------------------------------- the command line's flags
def test_fuzz_env_kwargs_flag(tmp_path, capsys):
    """Broken ``--env-kwargs`` JSON (truncated, a character dropped or added, deep) for train, evaluate, demo:
    exit 2, one line naming ``--env-kwargs``, before any work."""
    rng = np.random.default_rng(9)
    valid = '{"max_points": 8, "radar": {"scan": {"grid_deg": 5.0}}}'
    tried = 0
    while tried < 24:
        i = int(rng.integers(len(valid)))
        text = rng.choice([valid[:i], valid[:i] + valid[i + 1:], valid[:i] + str(rng.choice(list("{[,:\"x"))) +
                                                                   valid[i:], "[" * 100_000])
        try:
            json.loads(text)
            continue  # still a valid document: not what this test feeds
        except (json.JSONDecodeError, RecursionError):
            pass
        command = ["train", "evaluate", "demo"][tried % 3]
        out = str(tmp_path / ("run" if command != "evaluate" else "out.json"))
        code = main([command, "--out", out, "--env-kwargs", str(text)])
        err = capsys.readouterr().err.strip()
        assert code == 2 and "--env-kwargs" in err and len(err.splitlines()) == 1, err
        tried += 1


@pytest.mark.parametrize("command", ["train", "evaluate", "demo"])
def test_unknown_env_id_is_named_with_the_registered_ones(command, tmp_path, capsys):
    out = str(tmp_path / ("run" if command != "evaluate" else "out.json"))
    for env_id in ("bogus-v0", "rhs-highway-v9", "no_such_module:rhs-highway-v0"):
        code = main([command, "--out", out, "--env", env_id])
        err = capsys.readouterr().err.strip()
        assert code == 2 and "unknown env id" in err and "rhs-highway-slam-v0" in err, err
        assert len(err.splitlines()) == 1


# --------------------------------------------------------------------------- evaluate: interrupted, or too long
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_evaluate_writes_what_it_has_when_interrupted(sig, tmp_path, capsys, monkeypatch):
    """The signal arrives during the third episode: two are written, the exit status is 128 + the signal."""
    import agents.evaluate as ev

    calls = []
    real = ev.run_episode

    def episode(env, policy, seed, **kw):
        calls.append(seed)
        if len(calls) == 3:
            os.kill(os.getpid(), sig)
        return real(env, policy, seed, **kw)

    monkeypatch.setattr(ev, "run_episode", episode)
    out = tmp_path / "out.json"
    code = main(["evaluate", "--policy", "constant:1", "--env", HW, "--env-kwargs", json.dumps(SMALL),
                 "--episodes", "6", "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 128 + int(sig), err
    assert "Traceback" not in err and "interrupted" in err
    summary = json.loads(out.read_text())
    assert summary["interrupted"] == sig.name and summary["episodes"] == 2 and summary["seeds"] == [0, 1]
    assert out.with_suffix(".png").exists()
    assert signal.getsignal(sig) is not ev.raise_interrupted  # the handlers are restored


def test_evaluate_estimate_needs_yes(tmp_path, capsys):
    """Past an hour of estimated work: refused with the estimate; ``--yes`` is the confirmation."""
    from agents.evaluate import estimate_hours

    assert estimate_hours("rhs-highway-slam-v0", 100_000, 200) > 300  # ~354 h at 15.7 steps/s
    assert estimate_hours("rhs-highway-v0", 5, 200) < 0.01
    code = main(["evaluate", "--out", str(tmp_path / "o.json"), "--episodes", "100000"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "--yes" in err and " h " in err and len(err.splitlines()) == 1, err
