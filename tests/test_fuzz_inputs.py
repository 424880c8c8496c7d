"""Seeded fuzzing of every input door: nested ``gym.make`` kwargs, scan scenes, scenario
documents and actions. Every outcome is a success (finite observation) or a ``ValueError`` /
``TypeError`` whose message names the mutated field, raised by the validation code itself
(the innermost traceback frame is in a validation function, not deep in the radar or
highway-env). No case may hang (each is cheap: a coarse scan, episodes of 2 steps).
"""

from __future__ import annotations

import copy
import math
import traceback

import gymnasium as gym
import numpy as np
import pytest
from conftest import SMALL_RADAR

import rhs_env  # noqa: F401
from rhs_env.scan_cli import SceneError, parse_scene
from slam.scenario_cli import parse_scenario

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
VALIDATORS = ("check_", "build", "_validate_config", "__post_init__", "configure", "__init__", "parse_", "_array",
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


def _check_outcome(fn, field: str):
    """Run ``fn``: success, or a ValueError/TypeError naming ``field`` from a validator."""
    try:
        return fn()
    except (ValueError, TypeError) as exc:
        cause = exc
        while cause.__cause__ is not None or cause.__context__ is not None:  # gymnasium re-raises with context
            cause = cause.__cause__ or cause.__context__
        assert field in str(exc), f"{field!r} not named in {exc!r}"
        assert _raised_by_a_validator(cause), "".join(traceback.format_exception(cause))[-1500:]
        return None


def _episode(kw: dict) -> None:
    env = gym.make("rhs-highway-slam-v0", **kw)
    try:
        obs, _ = env.reset(seed=0)
        for _ in range(2):
            for key, value in obs.items():
                assert np.all(np.isfinite(value)), key
            obs, *_ = env.step(1)
    finally:
        env.close()


def test_fuzz_env_kwargs():
    rng = np.random.default_rng(20261123)
    outcomes = {"ok": 0, "refused": 0}
    for path, _value, kw in _mutations(rng, 40):
        ok = _check_outcome(lambda kw=kw: _episode(kw) or True, path[-1])
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
        _check_outcome(lambda doc=doc: parse_scenario(doc), key)


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
