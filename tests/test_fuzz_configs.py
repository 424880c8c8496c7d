"""Property-based fuzzing of the config builders (hypothesis; profile in ``tests/fuzz_settings.py``).

The rule: :func:`rhs_common.validation.build` of any nested mapping, of valid and invalid types and
magnitudes at any depth (numbers near the default scaled by up to 1e400, NaN, infinities, integers past
the float range, numpy scalars, strings, booleans, None, lists, dicts, unknown keys), either returns a
config of the class or raises ``ValueError`` / ``TypeError`` whose message starts with the field path
(``radar.waveform.chirp_s must be ...``); never another exception (no ``OverflowError``, no
``MemoryError``, no ``KeyError``). The same rule holds for ``gym.make`` of ``rhs-highway-v0`` with
random highway-env keys, through a reset and a step.
"""

from __future__ import annotations

import dataclasses
import math
import typing
import warnings

import fuzz_settings  # noqa: F401  (loads the hypothesis profile)
import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import rhs_env  # noqa: F401  (registers the ids)
from rhs_common.validation import build
from rhs_env.radar_config import RadarConfig
from rhs_env.scene import LandmarkConfig, ScatterConfig
from slam.core.health import HealthConfig
from slam.core.pipeline import PipelineConfig
from slam.core.rbpf import SlamConfig
from slam.core.registration import ICPConfig

#: (path as gym.make names it, config class)
CONFIGS = [("slam", SlamConfig), ("pipeline", PipelineConfig), ("icp", ICPConfig), ("health", HealthConfig),
           ("radar", RadarConfig), ("landmarks", LandmarkConfig), ("scatter", ScatterConfig)]

JUNK = st.one_of(
    st.none(), st.booleans(), st.text(max_size=4), st.just([1, 2]), st.just({"x": 1}), st.just([]),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324, 0.0, -0.0, -1, 0, 10**400, -10**400,
                     10**5000, 2**63, np.float32(2.0), np.int64(3), np.float64(1e300), np.bool_(True), np.array([1.0]),
                     "1e3", b"1"]),
)


def _nested(hint: typing.Any) -> type | None:
    for h in typing.get_args(hint) or (hint,):
        if dataclasses.is_dataclass(h) and isinstance(h, type):
            return h
    return None


def _near(default: typing.Any) -> st.SearchStrategy:
    """A value of the default's kind, scaled by 10^k (k in [-400, 400]) or shifted, as Python or numpy numbers."""
    if isinstance(default, bool):
        return st.booleans()
    if isinstance(default, int):
        return st.one_of(st.integers(-10, 10**7), st.integers(-(10**30), 10**30),
                         st.integers(0, 10**6).map(np.int64),
                         st.sampled_from([default, default + 1, max(default - 1, 0), 2 * default]))
    if isinstance(default, float):
        scaled = st.tuples(st.sampled_from([1.0, -1.0]), st.integers(-400, 400)).map(
            lambda t, d=default: t[0] * (abs(d) or 1.0) * 10.0 ** max(min(t[1], 308), -323))
        return st.one_of(st.just(default), scaled, st.floats(allow_nan=True, allow_infinity=True),
                         st.floats(-1e4, 1e4).map(np.float32), st.integers(-5, 10**6))
    if isinstance(default, str):
        return st.one_of(st.just(default), st.text(max_size=6))
    return JUNK


def config_dicts(cls: type, depth: int = 0) -> st.SearchStrategy:
    """Mappings of some of ``cls``'s fields (nested groups as mappings, None or junk), sometimes an unknown key."""
    hints = typing.get_type_hints(cls)
    fields = {}
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        nested = _nested(hints.get(f.name))
        if nested is not None and depth < 2:
            fields[f.name] = st.one_of(config_dicts(nested, depth + 1), st.none(), JUNK)
        else:
            default = f.default if f.default is not dataclasses.MISSING else (
                f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
            fields[f.name] = st.one_of(_near(default), JUNK) if nested is None else JUNK
    keys = sorted(fields)
    picked = st.lists(st.sampled_from(keys), max_size=4, unique=True)
    base = picked.flatmap(lambda ks: st.fixed_dictionaries({k: fields[k] for k in ks}))
    typo = st.tuples(base, st.sampled_from(keys), st.integers(0, 9)).map(
        lambda t: {**t[0], t[1] + "_x": 1} if t[2] == 0 else t[0])
    return typo


def _check_build(path: str, cls: type, value: typing.Any) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # moved fields, a carrier outside the band
        try:
            config = build(cls, value, path)
        except (ValueError, TypeError) as exc:
            message = str(exc)
            assert message.startswith((path + ".", path + " ")), message
            return
    assert isinstance(config, cls)


@pytest.mark.parametrize("path, cls", CONFIGS, ids=[p for p, _ in CONFIGS])
@given(data=st.data())
def test_build_gives_a_config_or_an_error_naming_the_field_path(path, cls, data):
    _check_build(path, cls, data.draw(config_dicts(cls)))


@pytest.mark.parametrize("path, cls", CONFIGS, ids=[p for p, _ in CONFIGS])
def test_numpy_scalars_build_the_config_python_numbers_build(path, cls):
    """Every numeric default given as a numpy scalar of the same value builds an equal config."""
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        default = getattr(cls(), f.name)
        if hints[f.name] is float:
            value = np.float64(default)
        elif hints[f.name] is int:
            value = np.int64(default)
        else:
            continue
        assert build(cls, {f.name: value}, path) == cls(), f.name


#: the float fields of SlamConfig at magnitudes 1e-3 .. 1e20 or 1e150 .. 1e308 (where squares overflow), one to
#: three at once
SLAM_MAGNITUDES = st.dictionaries(
    st.sampled_from(sorted(f.name for f in dataclasses.fields(SlamConfig) if isinstance(f.default, float))),
    st.one_of(st.integers(-3, 20), st.integers(150, 308)).map(lambda k: 10.0**k), min_size=1, max_size=3)


@given(value=st.one_of(SLAM_MAGNITUDES, config_dicts(SlamConfig)))
def test_a_built_slam_config_runs_finite(value, monkeypatch_limit):
    """What the builder accepts, the filter runs: three cycles of a small cloud give a finite pose
    (the noise settings without an upper bound built, then overflowed in the first cycle)."""
    from slam.core.rbpf import RBPFSlam

    try:
        config = build(SlamConfig, value, "slam")
    except (ValueError, TypeError):
        return
    slam = RBPFSlam(config, np.random.default_rng(0))
    points = np.array([[10.0, 5.0, 0.0, 1.0], [20.0, -5.0, 0.0, 1.0], [15.0, 8.0, 0.0, 1.0]])
    with np.errstate(all="ignore"):
        for k in range(3):
            est = slam.update(points - [0.5 * k, 0.0, 0.0, 0.0], np.array([0.5, 0.0, 0.0]), 0.2)
    assert np.all(np.isfinite(est.pose)), (value, est.pose)


@pytest.fixture(scope="module")
def monkeypatch_limit():
    """A 64 MiB memory limit: the filter runs at most ~1e6 particle-slots per example."""
    mp = pytest.MonkeyPatch()
    mp.setenv("RHS_SLAM_MEMORY_LIMIT", "64M")
    yield
    mp.undo()


def test_none_for_a_group_is_its_default():
    assert build(RadarConfig, {"waveform": None, "rhs": None}, "radar") == RadarConfig()


# --------------------------------------------------------------------------- gym.make of highway-env keys
HW_KEYS = {
    "lanes_count": st.one_of(st.integers(-2, 30), JUNK),
    "vehicles_count": st.one_of(st.integers(-1, 600), JUNK),
    "duration": st.one_of(st.floats(-1, 5000), JUNK),
    "policy_frequency": st.one_of(st.sampled_from([1, 3, 5, 15, 0.7, 4, 0]), JUNK),
    "simulation_frequency": st.one_of(st.sampled_from([5, 15, 30, 2.5, 0]), JUNK),
    "ego_spacing": st.one_of(st.floats(-1, 200), JUNK),
    "vehicles_density": st.one_of(st.floats(-1, 200), JUNK),
    "scaling": st.one_of(st.floats(-1, 2000), st.sampled_from([1e-9, 1e-3, 0.01]), JUNK),
    "screen_width": st.one_of(st.integers(-1, 5000), JUNK),
    "centering_position": st.one_of(st.lists(st.floats(-1, 2), max_size=3), JUNK),
    "reward_speed_range": st.one_of(st.lists(st.floats(-10, 200), max_size=3), JUNK),
    "initial_lane_id": st.one_of(st.integers(-2, 5), JUNK),
    "action": st.one_of(st.fixed_dictionaries({"type": st.sampled_from(
        ["DiscreteMetaAction", "ContinuousAction", "DiscreteAction", "MultiAgentAction", "Bogus"])}), JUNK),
    "observation": st.one_of(st.fixed_dictionaries({"type": st.sampled_from(
        ["Kinematics", "OccupancyGrid", "KinematicsGoal", "ExitObservation", "Bogus"])}), JUNK),
    "manual_control": st.one_of(st.booleans(), JUNK),
    "landmarks": st.one_of(config_dicts(LandmarkConfig), JUNK),
}


@given(kw=st.lists(st.sampled_from(sorted(HW_KEYS)), min_size=1, max_size=3, unique=True).flatmap(
    lambda ks: st.fixed_dictionaries({k: HW_KEYS[k] for k in ks})))
def test_highway_keys_give_an_env_or_an_error_naming_a_key(kw):
    """Made, reset and stepped, with finite observations and reward; or refused naming a given key."""
    base = {"vehicles_count": 2, "lanes_count": 2, "duration": 0.4}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            env = gym.make("rhs-highway-v0", **{**base, **kw})
        except (ValueError, TypeError) as exc:
            message = str(exc).split(" was raised from the environment creator")[0]
            assert any(k in message for k in kw), message
            return
        try:
            obs, _ = env.reset(seed=0)
            obs, reward, *_ = env.step(env.action_space.sample())
            assert math.isfinite(float(reward))
            assert all(np.all(np.isfinite(np.asarray(v, dtype=float))) for v in
                       (obs.values() if isinstance(obs, dict) else obs if isinstance(obs, tuple) else [obs]))
        finally:
            env.close()
