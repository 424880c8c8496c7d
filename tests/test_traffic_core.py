"""The compiled traffic core (``sim="compiled"``) against highway-env, its oracle: the same scene, the same actions.

The full alignment (50 seeds x 200 steps) is ``scripts/traffic_alignment.py``; here a few short episodes per
scene, the option's validation, the write-back the radar and users read, and the scenes the core refuses.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import rhs_env  # noqa: F401  (registers the ids)
from rhs_env.traffic import core, npmath
from rhs_env.traffic.alignment import align_episode, make_scene
from rhs_env.traffic.engine import UnsupportedScene

#: tolerances of the alignment (positions m, speeds m/s, rewards)
POSITION_TOL, SPEED_TOL, REWARD_TOL = 1e-6, 1e-6, 1e-9
#: whether the kernels compute numpy's numbers to the bit here (rhs_env.traffic.npmath): then the alignment is exact
BIT_EXACT = npmath.USE_SVML and npmath.numpy_dot_is_fma()


@pytest.mark.parametrize(("scene", "seeds"), [("highway", (0, 1, 2)), ("dense", (3,)), ("paper", (4,))])
def test_alignment_with_highway_env(scene, seeds):
    """The same lane changes, crashes and terminations; positions, speeds and rewards to the tolerances."""
    for seed in seeds:
        r = align_episode(scene, seed, 60)
        assert r.agrees, r
        assert r.terminated_at == r.terminated_at_compiled
        assert r.max_position_diff_m <= POSITION_TOL and r.max_speed_diff_mps <= SPEED_TOL, r
        assert r.max_reward_diff <= REWARD_TOL, r
        assert r.lane_changes > 0  # the episode exercised MOBIL / the ego's lane changes
        if BIT_EXACT:
            assert r.max_position_diff_m == r.max_speed_diff_mps == r.max_reward_diff == 0.0, r


def test_npmath_computes_numpys_numbers():
    """arcsin, arctan, tan and power as numpy's scalar ufuncs give them (SVML where numpy uses it), the 2-vector dot
    as numpy's BLAS; sin, cos and sqrt, which the kernels take from numba, too."""
    from rhs_common.jit import njit

    rng = np.random.default_rng(3)
    x = np.concatenate([rng.uniform(-1.6, 1.6, 4000), rng.normal(0.0, 1e-3, 1000), [0.0, -0.0, 1.0, -1.0, 0.5]])
    unit = np.clip(x, -1.0, 1.0)
    pairs = [(npmath.arcsin, np.arcsin, unit), (npmath.arctan, np.arctan, x), (npmath.tan, np.tan, x),
             (njit(lambda v: np.sin(v), cache=False), np.sin, x), (njit(lambda v: np.cos(v), cache=False), np.cos, x),
             (njit(lambda v: np.sqrt(v), cache=False), np.sqrt, np.abs(x))]
    for mine, theirs, values in pairs:
        differ = [v for v in values.tolist() if mine(v) != theirs(v)]
        assert not differ, (theirs.__name__, differ[:3])
    base, exponent = np.abs(x[:2000]) * 1.5, rng.uniform(3.5, 4.5, 2000)
    assert all(npmath.power(a, b) == np.power(a, b) for a, b in zip(base.tolist(), exponent.tolist(), strict=True))
    if npmath.numpy_dot_is_fma():
        a, b = rng.normal(0, 1e3, (2000, 2)), rng.normal(0, 1, (2000, 2))
        assert all(npmath.dot2(u[0], u[1], w[0], w[1]) == np.dot(u, w) for u, w in zip(a, b, strict=True))
        assert all(np.sqrt(npmath.dot2(u[0], u[1], u[0], u[1])) == np.linalg.norm(u) for u in a)


def test_crashes_align():
    """An episode with crashes (the ego's random actions run into traffic): the same crash flags and impacts."""
    r = align_episode("highway", 0, 40)
    assert r.terminated_at > 0 and r.crashed_vehicles >= 2, r  # seed 0 crashes at step 21 (highway-env's run)
    assert r.agrees and r.terminated_at == r.terminated_at_compiled, r


def test_sim_option_is_validated():
    with pytest.raises(ValueError, match="sim must be one of"):
        gym.make("rhs-highway-v0", sim="fast")
    with pytest.raises(ValueError, match="sim='compiled' needs action.type='DiscreteMetaAction'"):
        gym.make("rhs-highway-v0", sim="compiled", action={"type": "ContinuousAction"})
    with pytest.raises(ValueError, match="other_vehicles_type"):
        gym.make("rhs-highway-v0", sim="compiled", other_vehicles_type="highway_env.vehicle.behavior.LinearVehicle")
    assert gym.make("rhs-highway-v0").unwrapped.config["sim"] == "auto"  # the default: the core where it ports


def test_objects_are_written_back():
    """After a step the vehicle objects hold the stepped state (what the observation, the radar and users read)."""
    env = make_scene("highway", "compiled", vehicles_count=10)
    env.reset(seed=7)
    before = [v.position.copy() for v in env.road.vehicles]
    position_arrays = [v.position for v in env.road.vehicles]
    env.step(1)
    state = env._compiled_traffic().state
    assert state is not None
    for i, v in enumerate(env.road.vehicles):
        assert v.position is position_arrays[i]  # updated in place
        assert not np.array_equal(v.position, before[i])
        assert (v.position[0], v.position[1], v.speed) == (state.f[i, core.X], state.f[i, core.Y], state.f[i, core.V])
        assert v.lane is env.road.network.get_lane(v.lane_index)
    assert env.vehicle.speed_index == state.k[state.ctrl, core.SPEED_INDEX]


def test_swapped_vehicle_repacks():
    """Replacing a vehicle in ``road.vehicles`` (the IDM ego of ``agents.evaluate``) packs the scene again."""
    from highway_env.vehicle.behavior import IDMVehicle

    envs = [make_scene("highway", sim, vehicles_count=10) for sim in ("highway-env", "compiled")]
    for env in envs:
        env.reset(seed=2)
        env.step(1)
        ego = env.vehicle
        idm = IDMVehicle.create_from(ego)
        env.road.vehicles[env.road.vehicles.index(ego)] = idm
        env.controlled_vehicles = [idm]
        env.action_type.controlled_vehicle = idm
        for _ in range(10):
            env.step(3)
    a, b = ([(v.position.copy(), v.speed, v.lane_index[2]) for v in env.road.vehicles] for env in envs)
    for (pa, va, la), (pb, vb, lb) in zip(a, b, strict=True):
        assert la == lb and abs(va - vb) <= SPEED_TOL and np.abs(pa - pb).max() <= POSITION_TOL


def test_unsupported_scene_is_refused():
    from highway_env.vehicle.objects import Obstacle

    env = make_scene("highway", "compiled", vehicles_count=3)
    env.reset(seed=0)
    env.road.objects.append(Obstacle(env.road, [50.0, 0.0]))
    with pytest.raises(UnsupportedScene, match="road objects.*sim='highway-env'"):
        env.step(1)


def test_kernel_python_body_matches_compiled():
    """The kernels run as Python (``py_func``) give the compiled numbers (the same source covers both)."""
    env = make_scene("highway", "compiled", vehicles_count=12)
    env.reset(seed=5)
    env.step(1)
    s = env._compiled_traffic().state
    args = [a.copy() for a in (s.f, s.k, s.p, s.lanes, s.speeds)]
    core.simulate(*args, 3, 0, core.ACTION_CODES["FASTER"], s.ctrl, 1 / 15)
    python = getattr(core.simulate, "py_func", core.simulate)
    py_args = [a.copy() for a in (s.f, s.k, s.p, s.lanes, s.speeds)]
    python(*py_args, 3, 0, core.ACTION_CODES["FASTER"], s.ctrl, 1 / 15)
    np.testing.assert_allclose(py_args[0], args[0], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(py_args[1], args[1])


def test_benchmark_traffic_section_markdown():
    """scripts/benchmark.py's ``traffic`` section: its table and the ratio line from a result."""
    from rhs_studies import benchmark

    t = {label: {"steps_per_s": 10.0 * (i + 1), "ms_per_step": 100.0 / (i + 1)}
         for i, (label, _, _) in enumerate(benchmark.TRAFFIC_RUNS)}
    t.update(load_average_start=[1.0], compiled_over_highway_env=1.5, compiled_over_highway_env_ci=[1.4, 1.6],
             compiled_over_highway_fast=3.0, bare_compiled_over_highway_env=40.0,
             bare_compiled_over_highway_env_ci=[30.0, 50.0], bare_compiled_over_highway_fast=60.0, first_step_compile_s=9.5,
             first_step_compile_cpu_s=6.0, first_step_cached_s=0.4)
    text = "\n".join(benchmark._md_traffic({"traffic": t}))
    assert "| rhs-highway-v0 bare (compiled) | 50.0 | 20.00 |" in text
    assert "1.5 x highway-env's steps/s" in text and "9.5 s (6.0 s of CPU)" in text
    assert "traffic" in benchmark.SECTIONS


def test_radar_env_sees_the_same_traffic():
    """``rhs-highway-radar-v0`` with ``sim="compiled"``: the same point clouds as on highway-env (the radar reads the
    written-back vehicles)."""
    from conftest import small_env_kwargs

    envs = [gym.make("rhs-highway-radar-v0", sim=sim, vehicles_count=10, **small_env_kwargs(slam=False))
            for sim in ("highway-env", "compiled")]
    for env in envs:
        env.reset(seed=3)
    for t in range(6):
        (a, *_), (b, *_) = (env.step(0 if t == 0 else 3) for env in envs)
        np.testing.assert_allclose(a["points"], b["points"], rtol=0, atol=1e-6)
        np.testing.assert_array_equal(a["points_mask"], b["points_mask"])
    assert envs[1].unwrapped.config["sim"] == "compiled"


def test_ground_truth_observation_and_info_match():
    """``rhs-highway-v0``'s default Kinematics observation and its ``info`` (speed, crash, reward terms, world pose)
    are the same on both sims."""
    envs = [gym.make("rhs-highway-v0", sim=sim, vehicles_count=12) for sim in ("highway-env", "compiled")]
    for env in envs:
        env.reset(seed=11)
    rng = np.random.default_rng(1)
    for _ in range(30):
        action = int(rng.integers(5))
        (oa, ra, ta, ua, ia), (ob, rb, tb, ub, ib) = (env.step(action) for env in envs)
        np.testing.assert_allclose(oa, ob, rtol=0, atol=1e-6)
        assert (ta, ua, ia["crashed"]) == (tb, ub, ib["crashed"]) and abs(ra - rb) <= REWARD_TOL
        assert ia["rewards"].keys() == ib["rewards"].keys()
        for key, value in ia["rewards"].items():
            assert abs(float(value) - ib["rewards"][key]) <= REWARD_TOL, key
        np.testing.assert_allclose(ia["world_pose"], ib["world_pose"], rtol=0, atol=POSITION_TOL)


def test_rendering_frame_by_frame_matches():
    """With a viewer the core steps one frame at a time (highway-env renders the frames in between): the same
    images and state as highway-env."""
    envs = [gym.make("rhs-highway-v0", sim=sim, render_mode="rgb_array", vehicles_count=8)
            for sim in ("highway-env", "compiled")]
    for env in envs:
        env.reset(seed=4)
        env.render()
    for _ in range(3):
        for env in envs:
            env.step(3)
        a, b = (env.render() for env in envs)
        np.testing.assert_array_equal(a, b)
    xa, xb = (np.array([v.position for v in env.unwrapped.road.vehicles]) for env in envs)
    np.testing.assert_allclose(xa, xb, rtol=0, atol=POSITION_TOL)


# ---- the default (sim="auto"): the core on the straight-road ids where it ports the config and the scene
@pytest.fixture(autouse=True)
def _foreground_traffic_compile(monkeypatch):
    """The kernels compile in this process (on a cold cache ``sim="auto"`` would step highway-env's code until a
    background process cached them: tests/test_startup.py covers that)."""
    monkeypatch.setenv("RHS_SLAM_BACKGROUND_COMPILE", "0")


STRAIGHT_ROAD_IDS = ("rhs-highway-v0", "rhs-highway-radar-v0", "rhs-highway-slam-v0", "rhs-highway-radar-fast-v0",
                     "rhs-highway-slam-fast-v0", "rhs-dense-v0", "rhs-paper-v0")


@pytest.mark.parametrize("env_id", STRAIGHT_ROAD_IDS)
def test_straight_road_ids_default_to_the_compiled_core(env_id):
    env = gym.make(env_id)
    try:
        base = env.unwrapped
        assert base.config["sim"] == "auto" and base.traffic_sim == "compiled"
        base.reset(seed=0)  # the scene alone (the radar and SLAM wrappers do not touch the traffic)
        assert base.traffic_sim == "compiled"
        assert gym.make(env_id, sim="highway-env").unwrapped.traffic_sim == "highway-env"
    finally:
        env.close()


def test_other_roads_keep_highway_env():
    env = gym.make("rhs-merge-v0")
    env.reset(seed=0)
    env.step(1)
    assert "sim" not in env.unwrapped.config and env.unwrapped.traffic_sim == "highway-env"


@pytest.mark.parametrize("config", [{"action": {"type": "ContinuousAction"}},
                                    {"other_vehicles_type": "highway_env.vehicle.behavior.LinearVehicle"},
                                    {"controlled_vehicles": 2}])
def test_auto_falls_back_to_highway_env_on_an_unported_config(config):
    """The default takes highway-env's code for a config the core does not port, without an error; the same steps as
    ``sim="highway-env"``."""
    envs = [gym.make("rhs-highway-v0", vehicles_count=8, **config, **sim) for sim in ({}, {"sim": "highway-env"})]
    for env in envs:
        env.reset(seed=1)
        assert env.unwrapped.traffic_sim == "highway-env"
    for _ in range(3):
        action = envs[0].action_space.sample()
        (_, ra, *_), (_, rb, *_) = (env.step(action) for env in envs)
        assert ra == rb
    xa, xb = (np.array([v.position for v in env.unwrapped.road.vehicles]) for env in envs)
    np.testing.assert_array_equal(xa, xb)


def test_auto_falls_back_on_an_unported_scene_and_returns():
    """A road object added mid-episode: ``sim="auto"`` steps the scene with highway-env's code from the (up to date)
    objects, as ``sim="highway-env"`` does, and with the core again once it is gone; ``sim="compiled"`` raises."""
    from highway_env.vehicle.objects import Obstacle

    envs = [make_scene("highway", sim, vehicles_count=10) for sim in ("highway-env", "auto")]
    for env in envs:
        env.reset(seed=6)
        env.step(1)
    assert envs[1].traffic_sim == "compiled"
    for env in envs:
        env.road.objects.append(Obstacle(env.road, env.vehicle.position + np.array([60.0, 0.0])))
    assert envs[1].traffic_sim == "highway-env"
    for action in (3, 1, 0):
        for env in envs:
            env.step(action)
    for env in envs:
        env.road.objects.clear()
    assert envs[1].traffic_sim == "compiled"
    for action in (1, 2, 4):
        (_, ra, ta, *_), (_, rb, tb, *_) = (env.step(action) for env in envs)
        assert abs(ra - rb) <= REWARD_TOL and ta == tb
    a, b = (scene_state(env) for env in envs)
    np.testing.assert_allclose(a, b, rtol=0, atol=POSITION_TOL)


def scene_state(env) -> np.ndarray:
    """Every vehicle's position, heading, speed, lane, target lane, target speed and crash flag."""
    return np.array([[*v.position, v.heading, v.speed, v.lane_index[2], v.target_lane_index[2], v.target_speed,
                      float(v.crashed)] for v in env.unwrapped.road.vehicles])


def test_edits_between_steps_are_stepped_as_highway_env_steps_them():
    """A user's (or a driver's) edits of the vehicles between steps: speed, position, target lane and target speed of
    an IDM vehicle and the ego's target speed are read in before the next step, as highway-env reads them."""
    envs = [make_scene("highway", sim, vehicles_count=10) for sim in ("highway-env", "compiled")]
    for env in envs:
        env.reset(seed=8)
        env.step(1)
        other = env.road.vehicles[3]
        other.speed += 3.0
        other.position[1] += 0.5
        other.target_lane_index = (*other.target_lane_index[:2], (other.target_lane_index[2] + 1) % 4)
        other.target_speed = 27.0
        env.vehicle.target_speed = 21.0
    for action in (1, 1, 3, 1):
        for env in envs:
            env.step(action)
    a, b = (scene_state(env) for env in envs)
    np.testing.assert_allclose(a, b, rtol=0, atol=POSITION_TOL)


@pytest.mark.parametrize("driver", ["headway", "lookahead", "idm"])
def test_drivers_see_the_same_traffic(driver):
    """The privileged drivers of :mod:`agents` read ``env.unwrapped.road`` every step: on the core's written-back
    objects they choose the same actions as on highway-env's, and the scenes stay equal."""
    from agents.evaluate import IDMMobilPolicy
    from agents.policies.expert import HeadwayDriver
    from agents.policies.lookahead import LookaheadDriver

    make = {"headway": HeadwayDriver, "lookahead": LookaheadDriver, "idm": IDMMobilPolicy}[driver]
    envs = [gym.make("rhs-highway-v0", sim=sim, vehicles_count=12) for sim in ("highway-env", "compiled")]
    drivers = [make(env) for env in envs]
    obs = [env.reset(seed=9)[0] for env in envs]
    for _ in range(15):
        actions = [int(np.asarray(d.predict(o)[0])) for d, o in zip(drivers, obs, strict=True)]
        assert actions[0] == actions[1]
        out = [env.step(a) for env, a in zip(envs, actions, strict=True)]
        obs = [o[0] for o in out]
        assert out[0][2] == out[1][2] and abs(out[0][1] - out[1][1]) <= REWARD_TOL
        if out[0][2] or out[0][3]:
            break
    a, b = (scene_state(env) for env in envs)
    np.testing.assert_allclose(a, b, rtol=0, atol=POSITION_TOL)
    assert envs[1].unwrapped.traffic_sim == "compiled"


@pytest.mark.skipif(not npmath.USE_SVML, reason="numpy dispatches to its AVX-512 SVML functions only on AVX-512 CPUs")
def test_a_cache_compiled_with_numpys_avx512_loads_under_a_capped_dispatch(tmp_path):
    """The traffic kernels compiled where numpy dispatches to AVX-512 (they call its SVML functions), then run by a
    process whose numpy is capped at AVX2 (``NPY_DISABLE_CPU_FEATURES``): the second compiles its own kernels
    (:func:`rhs_common.jit.numpy_dispatch_stamp` is in the cache stamp) and steps the same traffic as
    highway-env's numpy there; before, it loaded the first one's kernels and crashed on a null SVML address."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    script = ("import gymnasium as gym, rhs_env\n"
              "env = gym.make('rhs-highway-v0', sim='compiled')\n"
              "env.reset(seed=0)\n"
              "for _ in range(5): env.step(1)\n"
              "print('stepped')\n")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "RHS_SLAM_BACKGROUND_COMPILE": "0", "OMP_NUM_THREADS": "1"}
    root = Path(__file__).resolve().parent.parent
    for extra in ({}, {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"}):
        proc = subprocess.run([sys.executable, "-c", script], cwd=root, env={**env, **extra}, capture_output=True,
                              text=True, timeout=600, check=False)
        assert proc.returncode == 0 and "stepped" in proc.stdout, (extra, proc.returncode, proc.stderr[-2000:])
