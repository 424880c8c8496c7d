"""The table of bad inputs: every case is refused at the door with an error that names the field.

One parametrized test, one case per row: ``(case, kind, input, expected error, fragment)``.
Kinds: ``make`` (``gym.make(id, **kwargs)``), ``action`` (``env.step(action)`` on
``rhs-highway-v0``), ``cli`` (``rhs-slam ...``: exit status 2 and one line on stderr
naming the field, no traceback). The fragments are the field names (and, for bounds,
the bound), so a message that stops naming them fails here.
"""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pytest

import rhs_env  # noqa: F401
from rhs_slam.cli import main

HW, RADAR, SLAM, PAPER = "rhs-highway-v0", "rhs-highway-radar-v0", "rhs-highway-slam-v0", "rhs-paper-v0"
SCENE = {"targets": [[20.0, 0.0, 5.0]], "antenna": "hologram"}
SCENARIO = {"landmarks": [[10.0, 5.0]], "poses": [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], "antenna": "hologram",
            "grid_deg": 5.0, "registration": "odometry", "particles": 5}
BAD_OUT = "/proc/rhs-slam-no-such-dir/out.json"  # cannot be created, even by root

CASES = [
    # ---- wrong types: TypeError naming the field (numbers as strings used to pass and fail deep inside)
    ("tx_power as string", "make", (RADAR, {"radar": {"link": {"tx_power_dbm": "20"}}}), TypeError,
     "radar.link.tx_power_dbm"),
    ("grid_deg as string", "make", (RADAR, {"radar": {"scan": {"grid_deg": "5"}}}), TypeError, "radar.scan.grid_deg"),
    ("radar not a dict", "make", (RADAR, {"radar": 5}), TypeError, "radar"),
    ("stage_times as string", "make", (RADAR, {"stage_times_in_info": "yes"}), TypeError, "stage_times_in_info"),
    ("scatterers flag as int", "make", (RADAR, {"scatterers_in_info": 1}), TypeError, "scatterers_in_info"),
    ("max_points as float", "make", (RADAR, {"max_points": 1.5}), TypeError, "max_points"),
    ("particles as float", "make", (SLAM, {"slam": {"n_particles": 10.0}}), TypeError, "slam.n_particles"),
    ("landmark rcs as string", "make", (HW, {"landmarks": {"rcs_m2": "5"}}), TypeError, "landmarks.rcs_m2"),
    ("duration as string", "make", (HW, {"duration": "40"}), TypeError, "duration"),
    ("reward as None", "make", (HW, {"collision_reward": None}), TypeError, "collision_reward"),
    ("bool key as string", "make", (HW, {"offroad_terminal": "no"}), TypeError, "offroad_terminal"),
    ("config as list", "make", (HW, {"config": [1]}), TypeError, "config"),
    ("icp as list", "make", (SLAM, {"icp": [1]}), TypeError, "icp"),
    # ---- values out of range, with the bound in the message
    ("render_mode bogus", "make", (HW, {"render_mode": "bogus"}), ValueError, "render_mode must be one of"),
    ("grid 0.01 deg (4500 slots)", "make", (RADAR, {"radar": {"scan": {"grid_deg": 0.01}}}), ValueError,
     "grid_deg must be in [0.25, 90.0]"),
    ("a million elements", "make", (RADAR, {"radar": {"rhs": {"elements": 10**6}}}), ValueError,
     "radar.rhs.elements must be in [2, 4096]"),
    ("10 million particles", "make", (SLAM, {"slam": {"n_particles": 10**7}}), ValueError,
     "slam.n_particles must be in [1, 100000]"),
    ("duration 1e9 s", "make", (HW, {"duration": 1e9}), ValueError, "duration must be in (0.0, 3600.0]"),
    ("landmark rcs 1e300", "make", (HW, {"landmarks": {"rcs_m2": 1e300}}), ValueError,
     "landmarks.rcs_m2 must be in (0.0, 10000.0]"),
    ("vehicle rcs 1e300", "make", (RADAR, {"scatter": {"vehicle_rcs_m2": 1e300}}), ValueError,
     "scatter.vehicle_rcs_m2 must be in (0.0, 10000.0]"),
    ("obstacle rcs 1e300", "make", (PAPER, {"obstacle_rcs_m2": 1e300}), ValueError,
     "obstacle_rcs_m2 must be in (0.0, 10000.0]"),
    ("a million vehicles", "make", (HW, {"vehicles_count": 10**6}), ValueError, "vehicles_count must be in [0, 500]"),
    ("no points", "make", (RADAR, {"max_points": 0}), ValueError, "max_points must be in [1, 65536]"),
    ("pfa NaN", "make", (RADAR, {"radar": {"detection": {"pfa": math.nan}}}), ValueError,
     "radar.detection.pfa must be a finite"),
    ("max range inf", "make", (RADAR, {"radar": {"max_range_m": math.inf}}), ValueError, "radar.max_range_m"),
    ("delta_m inf", "make", (SLAM, {"slam": {"delta_m": math.inf}}), ValueError, "slam.delta_m must be a finite"),
    ("screen 1e9 px", "make", (HW, {"screen_width": 10**9}), ValueError, "screen_width must be in [1, 4096]"),
    ("map gate negative", "make", (SLAM, {"map_gate_m": -1.0}), ValueError, "map_gate_m"),
    ("unknown radar field", "make", (RADAR, {"radar": {"bogus": 1}}), ValueError, "'bogus'"),
    ("nested typo", "make", (RADAR, {"radar": {"scan": {"grid_dge": 5}}}), ValueError, "'grid_dge'"),
    ("unknown env key", "make", (HW, {"lanes_cnt": 3}), ValueError, "'lanes_cnt'"),
    ("unknown registration", "make", (SLAM, {"registration": "xyz"}), ValueError, "registration must be one of"),
    ("unknown antenna", "make", (RADAR, {"antenna": "horn"}), ValueError, "antenna must be one of"),
    # ---- noise settings that overflowed, allocations that exhausted memory (bounds and up-front estimates)
    ("measurement floor 1e200", "make", (SLAM, {"slam": {"measurement_floor_m": 1e200}}), ValueError,
     "slam.measurement_floor_m must be in [0.0, 1000.0]"),
    ("accel std 1e300", "make", (SLAM, {"slam": {"accel_std_mps2": 1e300}}), ValueError,
     "slam.accel_std_mps2 must be in [0.0, 1000.0]"),
    ("gate 1e308", "make", (SLAM, {"slam": {"gate_mahalanobis": 1e308}}), ValueError,
     "slam.gate_mahalanobis must be in (0.0, 1000.0]"),
    ("trans std 1e300", "make", (SLAM, {"slam": {"trans_std_m": 1e300}}), ValueError,
     "slam.trans_std_m must be in [0.0, 1000.0]"),
    ("range std 1e300", "make", (SLAM, {"slam": {"range_std_m": 1e300}}), ValueError, "slam.range_std_m"),
    ("integer past the float range", "make", (SLAM, {"slam": {"delta_m": 10**400}}), ValueError, "slam.delta_m"),
    ("1e5 particles x 5000 slots", "make", (SLAM, {"slam": {"n_particles": 100_000, "max_landmarks": 5000}}),
     ValueError, "slam.n_particles x max_landmarks = 100000 x 5000"),
    ("1e8 samples per chirp", "make", (RADAR, {"radar": {"waveform": {"sample_rate_hz": 1e10, "chirp_s": 1e-2}}}),
     ValueError, "RHS_SLAM_MEMORY_LIMIT"),
    ("scaling 1e-9 px/m", "make", (HW, {"scaling": 1e-9, "render_mode": "rgb_array"}), ValueError,
     "scaling must be in [0.01, 1000.0]"),
    ("reward 1e308", "make", (HW, {"high_speed_reward": 1e308}), ValueError, "high_speed_reward must be in"),
    # ---- settings that contradict each other or cannot apply
    ("normalised reward of an empty range", "make", (HW, {"collision_reward": 0.5}), ValueError,
     "collision_reward < high_speed_reward + right_lane_reward"),
    ("icp with odometry", "make", (SLAM, {"registration": "odometry", "icp": {"max_iterations": 5}}), ValueError,
     "registration='odometry' does not use it"),
    ("slam min range past the radar's", "make", (SLAM, {"slam": {"min_range_m": 500.0}}), ValueError,
     "radar.max_range_m=100"),
    ("slam min range 1e9", "make", (SLAM, {"slam": {"min_range_m": 1e9}}), ValueError, "slam.min_range_m"),
    ("carrier 1 Hz", "make", (RADAR, {"radar": {"rhs": {"carrier_hz": 1.0}}}), ValueError, "radar.rhs.carrier_hz"),
    ("MultiAgentAction", "make", (HW, {"action": {"type": "MultiAgentAction"}}), ValueError,
     "action.type must be one of 'ContinuousAction', 'DiscreteAction', 'DiscreteMetaAction'"),
    ("KinematicsGoal observation", "make", (HW, {"observation": {"type": "KinematicsGoal"}}), ValueError,
     "observation.type"),
    ("Kinematics on a SLAM env", "make", (SLAM, {"observation": {"type": "Kinematics"}}), ValueError,
     "rhs-highway-v0"),
    ("Kinematics on a radar env via config", "make", (RADAR, {"config": {"observation": {"type": "Kinematics"}}}),
     ValueError, "observation="),
    ("paper obstacle on the start", "make", (PAPER, {"obstacles": [[1.0, 37.0]]}), ValueError, "obstacles[0]"),
    ("10000 paper obstacles", "make", (PAPER, {"obstacles": [[float(i % 300), 10.0] for i in range(10_000)]}),
     ValueError, "at most 1000"),
    ("manual control without a window", "make", (HW, {"manual_control": True}), ValueError, "render_mode='human'"),
    ("manual control, rgb_array", "make", (HW, {"manual_control": True, "render_mode": "rgb_array"}), ValueError,
     "manual_control"),
    # ---- invalid actions: the error names the action space
    ("action 7", "action", 7, ValueError, "action space Discrete(5)"),
    ("action -1", "action", -1, ValueError, "action space Discrete(5)"),
    ("action 'a'", "action", "a", TypeError, "action space Discrete(5)"),
    ("action 2-element array", "action", np.array([1, 2]), TypeError, "action space Discrete(5)"),
    ("action NaN", "action", math.nan, TypeError, "action space Discrete(5)"),
    ("action None", "action", None, TypeError, "action space Discrete(5)"),
    ("action 2.5", "action", 2.5, TypeError, "action space Discrete(5)"),
    ("action True", "action", True, TypeError, "action space Discrete(5)"),
    # ---- the command line: exit 2, one line naming the field, before any work
    ("scan --seed -1", "cli", ["scan", "SCENE", "--out", "OUT", "--seed", "-1"], SystemExit, "--seed"),
    ("scan rcs 1e300", "cli", ["scan", {**SCENE, "targets": [[20.0, 0.0, 1e300], [25.0, 1.0, 5.0]]}, "--out", "OUT"],
     SystemExit, "rcs_m2 must be in [0, 10000]"),
    ("scan grid 0.01", "cli", ["scan", "SCENE", "--out", "OUT", "--grid-deg", "0.01"], SystemExit, "grid_deg"),
    ("scan 1e6 targets", "cli", ["scan", {"targets": [[20.0, 0.0, 5.0]] * 10_001}, "--out", "OUT"], SystemExit,
     "at most 10000"),
    ("scan unwritable out", "cli", ["scan", "SCENE", "--out", BAD_OUT], SystemExit, "--out"),
    ("scenario 1e9 m jump", "cli", ["scenario", {**SCENARIO, "poses": [[0, 0, 0], [1e9, 0, 0]]}, "--out", "OUT"],
     SystemExit, "within +-1e+06 m"),
    ("scenario 1 km jump in a cycle", "cli", ["scenario", {**SCENARIO, "poses": [[0, 0, 0], [1e3, 0, 0]]}, "--out",
                                              "OUT"], SystemExit, "100 m/s"),
    ("scenario grid 0.001", "cli", ["scenario", {**SCENARIO, "grid_deg": 0.001}, "--out", "OUT"], SystemExit,
     "grid_deg must be in [0.25"),
    ("scenario particles string", "cli", ["scenario", {**SCENARIO, "particles": "5"}, "--out", "OUT"], SystemExit,
     "'particles'"),
    ("scenario unwritable out", "cli", ["scenario", SCENARIO, "--out", BAD_OUT], SystemExit, "--out"),
    ("train unwritable out", "cli", ["train", "--env", HW, "--out", BAD_OUT], SystemExit, "--out"),
    ("train n_envs 10**6", "cli", ["train", "--env", HW, "--out", "OUTDIR", "--n-envs", "1000000"], SystemExit,
     "n_envs must be in [1, 256]"),
    ("train seed -1", "cli", ["train", "--env", HW, "--out", "OUTDIR", "--seed", "-1"], SystemExit, "seed"),
    ("demo unwritable out", "cli", ["demo", "--out", BAD_OUT], SystemExit, "--out"),
    ("demo kwarg type", "cli", ["demo", "--out", "OUTDIR", "--env-kwargs", '{"radar": {"link": {"tx_power_dbm": "20"}}}'],
     SystemExit, "radar.link.tx_power_dbm"),
    ("evaluate kwarg type", "cli", ["evaluate", "--out", "OUT", "--env-kwargs", '{"max_points": 1.5}'], SystemExit,
     "max_points"),
    ("demo seed -1", "cli", ["demo", "--out", "OUTDIR", "--seed", "-1"], SystemExit, "--seed"),
    ("evaluate unwritable out", "cli", ["evaluate", "--out", BAD_OUT], SystemExit, "--out"),
    ("evaluate 0 episodes", "cli", ["evaluate", "--out", "OUT", "--episodes", "0"], SystemExit, "--episodes"),
    ("patterns unwritable out", "cli", ["patterns", "--grid-deg", "5", "--out", BAD_OUT], SystemExit, "--out"),
    ("patterns grid 0.01", "cli", ["patterns", "--grid-deg", "0.01", "--quiet"], SystemExit, "grid_deg"),
]


@pytest.fixture(scope="module")
def highway_env():
    env = gym.make(HW, vehicles_count=2, lanes_count=2, duration=2)
    env.reset(seed=0)
    yield env
    env.close()


def _cli_args(args: list, tmp_path) -> list[str]:
    out = []
    for a in args:
        if isinstance(a, dict):  # a scene / scenario document
            p = tmp_path / "doc.json"
            p.write_text(json.dumps(a))
            a = str(p)
        elif a == "SCENE":
            p = tmp_path / "scene.json"
            p.write_text(json.dumps(SCENE))
            a = str(p)
        elif a == "OUT":
            a = str(tmp_path / "out.json")
        elif a == "OUTDIR":
            a = str(tmp_path / "run")
        out.append(a)
    return out


@pytest.mark.parametrize("case, kind, given, error, fragment", CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_refused_naming_the_field(case, kind, given, error, fragment, highway_env, tmp_path, capsys):
    if kind == "make":
        env_id, kwargs = given
        with pytest.raises(error) as exc:
            gym.make(env_id, **kwargs).close()
        assert fragment in str(exc.value), str(exc.value)
    elif kind == "action":
        with pytest.raises(error) as exc:
            highway_env.step(given)
        assert fragment in str(exc.value)
        highway_env.reset(seed=0)
    else:
        code = main(_cli_args(given, tmp_path))
        err = capsys.readouterr().err.strip()
        assert code == 2, err
        assert fragment in err and "Traceback" not in err, err
        assert len(err.splitlines()) == 1, err
        assert not (tmp_path / "out.json").exists()
