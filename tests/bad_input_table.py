"""The inputs a new user tried, each with the outcome it must have, and a classifier of what happened.

Not a test module itself: ``tests/test_fuzz_inputs.py`` runs every row, and
``python tests/bad_input_table.py`` prints the tally by class (each case in a forked child
with a time limit, so a hang is counted as one instead of stopping the count)::

    tried / clean / accepted / unnamed / traceback / silent / hang / wrongly-rejected

Measured (timeout 240 s, 2-core machine; the 101 rows here plus the 62 of tests/test_bad_inputs.py):
at 493cbf2, 163 / 70 / 21 / 19 / 21 / 27 / 3 / 2; after the input checks, 163 / 134 / 29 / 0 / 0 / 0 / 0 / 0.
(The starting tree is run as ``PYTHONPATH=<its checkout> python tests/bad_input_table.py``.)
The 50 rows added for the bounds, memory estimates, contradictions and env lifecycle (29 here, 21 in
tests/test_bad_inputs.py; timeout 60 s): at 8eb0ff3, 50 / 0 / 3 / 5 / 9 / 26 / 4 / 3; after, 50 / 44 / 6 / 0 / 0 / 0 /
0 / 0 (two reward rows added since: 52 / 46 / 6).

A row is ``Case(name, kind, given, expect, fragments)``:

* ``expect="refuse"``: a clean error whose message holds every fragment (the field, flag or
  file): ``ValueError`` / ``TypeError`` from the library, exit status 2 and one line on stderr
  (no traceback) from the command line. Such a refusal that does not name them is *unnamed*;
  anything else raised is a *traceback*; success is *silent*.
* ``expect="accept"``: works and gives finite numbers (a reset and two steps for an env).
  Refused is *wrongly-rejected*.
* ``expect="note"``: works, and says so: the fragments appear in what it prints (or in the
  warning it gives). Working without the note is *silent*.

Kinds: ``make`` (``gym.make(id, **kw)``, a reset and two steps, a render with a render_mode),
``reset`` (``reset(seed=...)``), ``after_end`` (steps after the episode ended), ``cli``
(``rhs-slam ...`` through :func:`rhs_slam.cli.main`, in-process), ``call`` (a function).
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import signal
import sys
import traceback
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

HW, RADAR, SLAM, PAPER = "rhs-highway-v0", "rhs-highway-radar-v0", "rhs-highway-slam-v0", "rhs-paper-v0"
#: a cheap radar (closed-form hologram, coarse grid) and short episodes: every case runs in seconds
CHEAP_RADAR = {"antenna": "hologram", "scan": {"grid_deg": 5.0}, "rhs": {"elements": 24}}
SMALL = {"vehicles_count": 2, "lanes_count": 2, "duration": 0.4}
PAPER_KW = {"radar": CHEAP_RADAR, "duration": 0.4}
SLAM_KW = {"radar": CHEAP_RADAR, "slam": {"n_particles": 8}, **SMALL}
SCENE = {"targets": [[20.0, 0.0, 5.0]], "antenna": "hologram"}
SCENARIO = {"landmarks": [[10.0, 5.0]], "poses": [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], "antenna": "hologram",
            "grid_deg": 5.0, "registration": "odometry", "particles": 5}
STUDENT = "agents/data/dagger_rhs_highway_truth.zip"  # a DAgger student on rhs-highway-v0, target speeds 10..30
#: a train run of seconds: the ground-truth env, one env, no evaluation or checkpoints
TRAIN_FAST = ["--env", HW, "--timesteps", "64", "--n-envs", "1", "--eval-freq", "0", "--checkpoint-freq", "0", "--no-progress"]

CLASSES = ("tried", "clean", "accepted", "unnamed", "traceback", "silent", "hang", "wrongly-rejected")


@dataclass(frozen=True)
class Case:
    name: str
    kind: str
    given: Any
    expect: str = "refuse"
    fragments: tuple[str, ...] = ()
    files: dict[str, bytes] = field(default_factory=dict)  # name -> content, written into the case's folder


def _deep(n: int) -> bytes:
    return b"[" * n + b"]" * n


def _doc(d: dict) -> bytes:
    return json.dumps(d).encode()


CASES: list[Case] = [
    # ---- highway-env's own config keys, passed through gym.make
    Case("target_speeds empty", "make", (HW, {"action": {"type": "DiscreteMetaAction", "target_speeds": []}}),
         fragments=("action.target_speeds",)),
    Case("target_speeds NaN", "make", (HW, {"action": {"type": "DiscreteMetaAction", "target_speeds": [10, math.nan]}}),
         fragments=("action.target_speeds",)),
    Case("target_speeds decreasing", "make", (HW, {"action": {"type": "DiscreteMetaAction",
                                                               "target_speeds": [30, 20, 10]}}),
         fragments=("action.target_speeds", "increasing")),
    Case("target_speeds as string", "make", (HW, {"action": {"type": "DiscreteMetaAction", "target_speeds": "fast"}}),
         fragments=("action.target_speeds",)),
    Case("target_speeds 1e9 m/s", "make", (HW, {"action": {"type": "DiscreteMetaAction", "target_speeds": [1e9]}}),
         fragments=("action.target_speeds",)),
    Case("target_speeds numpy array", "make", (HW, {"action": {"type": "DiscreteMetaAction",
                                                                "target_speeds": np.array([10.0, 20.0, 30.0])}}),
         "accept"),
    Case("action type bogus", "make", (HW, {"action": {"type": "Bogus"}}), fragments=("action.type",)),
    Case("action not a dict", "make", (HW, {"action": 5}), fragments=("action",)),
    Case("reward_speed_range string", "make", (HW, {"reward_speed_range": "fast"}), fragments=("reward_speed_range",)),
    Case("reward_speed_range reversed", "make", (HW, {"reward_speed_range": [30, 20]}),
         fragments=("reward_speed_range", "increasing")),
    Case("reward_speed_range three numbers", "make", (HW, {"reward_speed_range": [10, 20, 30]}),
         fragments=("reward_speed_range",)),
    Case("reward_speed_range numpy", "make", (HW, {"reward_speed_range": np.array([20.0, 30.0])}), "accept"),
    Case("other_vehicles_type missing", "make", (HW, {"other_vehicles_type": "no.such.Vehicle"}),
         fragments=("other_vehicles_type",)),
    Case("other_vehicles_type not a vehicle", "make", (HW, {"other_vehicles_type": "math.pi"}),
         fragments=("other_vehicles_type",)),
    Case("other_vehicles_type as int", "make", (HW, {"other_vehicles_type": 5}), fragments=("other_vehicles_type",)),
    Case("other_vehicles_type Aggressive", "make",
         (HW, {**SMALL, "other_vehicles_type": "highway_env.vehicle.behavior.AggressiveVehicle"}), "accept"),
    Case("initial_lane_id 99 of 4", "make", (HW, {"initial_lane_id": 99}), fragments=("initial_lane_id", "lanes_count")),
    Case("initial_lane_id -1", "make", (HW, {"initial_lane_id": -1}), fragments=("initial_lane_id",)),
    Case("initial_lane_id 1.5", "make", (HW, {"initial_lane_id": 1.5}), fragments=("initial_lane_id",)),
    Case("initial_lane_id 1 of 2", "make", (HW, {**SMALL, "initial_lane_id": 1}), "accept"),
    Case("initial_lane_id numpy", "make", (HW, {**SMALL, "initial_lane_id": np.int64(0)}), "accept"),
    Case("observation vehicles_count -1", "make", (HW, {"observation": {"type": "Kinematics", "vehicles_count": -1}}),
         fragments=("observation.vehicles_count",)),
    Case("observation vehicles_count 0", "make", (HW, {"observation": {"type": "Kinematics", "vehicles_count": 0}}),
         fragments=("observation.vehicles_count",)),
    Case("observation type bogus", "make", (HW, {"observation": {"type": "Bogus"}}), fragments=("observation.type",)),
    Case("observation features string", "make", (HW, {"observation": {"type": "Kinematics", "features": "x"}}),
         fragments=("observation.features",)),
    Case("observation vehicles_count 3", "make", (HW, {**SMALL, "observation": {"type": "Kinematics",
                                                                                "vehicles_count": 3}}), "accept"),
    Case("centering_position string", "make", (HW, {**SMALL, "centering_position": "x", "render_mode": "rgb_array"}),
         fragments=("centering_position",)),
    Case("centering_position one number", "make", (HW, {"centering_position": [0.3]}),
         fragments=("centering_position",)),
    Case("centering_position NaN", "make", (HW, {"centering_position": [0.3, math.nan]}),
         fragments=("centering_position",)),
    Case("centering_position ok", "make", (HW, {**SMALL, "centering_position": [0.5, 0.5],
                                                 "render_mode": "rgb_array"}), "accept"),
    Case("policy_frequency 0.7", "make", (HW, {"policy_frequency": 0.7}),
         fragments=("policy_frequency", "simulation_frequency")),
    Case("policy_frequency 4 of 15", "make", (HW, {"policy_frequency": 4}),
         fragments=("policy_frequency", "simulation_frequency")),
    Case("policy_frequency 3 of 15", "make", (HW, {**SMALL, "policy_frequency": 3}), "accept"),
    Case("simulation_frequency 2.5 Hz", "make", (HW, {**SMALL, "simulation_frequency": 2.5, "policy_frequency": 2.5}),
         "accept"),
    Case("lanes_count numpy", "make", (HW, {**SMALL, "lanes_count": np.int64(3)}), "accept"),
    Case("duration numpy float32", "make", (HW, {**SMALL, "duration": np.float32(0.4)}), "accept"),
    Case("show_trajectories as string", "make", (HW, {"show_trajectories": "yes"}), fragments=("show_trajectories",)),
    Case("screen_width float", "make", (HW, {"screen_width": 600.5}), fragments=("screen_width",)),
    Case("controlled_vehicles 2", "make", (HW, {**SMALL, "controlled_vehicles": 2}), "accept"),
    # ---- the paper scene's start and obstacles (world frame, m)
    Case("paper start NaN", "make", (PAPER, {**PAPER_KW, "start": [0, math.nan]}), fragments=("start",)),
    Case("paper start y 1e9", "make", (PAPER, {**PAPER_KW, "start": [0, 1e9]}), fragments=("start",)),
    Case("paper start three numbers", "make", (PAPER, {**PAPER_KW, "start": [0, 1, 2]}), fragments=("start",)),
    Case("paper start as string", "make", (PAPER, {**PAPER_KW, "start": "0,37.5"}), fragments=("start",)),
    Case("paper obstacle 1e9 m away", "make", (PAPER, {**PAPER_KW, "obstacles": [[1e9, 1e9]]}),
         fragments=("obstacles",)),
    Case("paper obstacle NaN", "make", (PAPER, {**PAPER_KW, "obstacles": [[10, math.nan]]}), fragments=("obstacles",)),
    Case("paper obstacles flat list", "make", (PAPER, {**PAPER_KW, "obstacles": [10, 65, 25, 10]}),
         fragments=("obstacles", "[x, y]")),
    Case("paper obstacles booleans", "make", (PAPER, {**PAPER_KW, "obstacles": [[True, False]]}),
         fragments=("obstacles",)),
    Case("paper obstacles string", "make", (PAPER, {**PAPER_KW, "obstacles": "none"}), fragments=("obstacles",)),
    Case("paper obstacles moved", "make", (PAPER, {**PAPER_KW, "obstacles": [[20, 45], [40, 30]]}), "accept"),
    Case("paper start moved", "make", (PAPER, {**PAPER_KW, "start": [5.0, 40.0]}), "accept"),
    Case("paper obstacles numpy", "make", (PAPER, {**PAPER_KW, "obstacles": np.array([[20.0, 45.0]])}), "accept"),
    # ---- one value given two ways
    Case("antenna twice, differing", "make", (RADAR, {"antenna": "phased", "radar": {**CHEAP_RADAR, "antenna": "rhs"}}),
         fragments=("antenna", "radar.antenna")),
    Case("antenna twice, equal", "make", (RADAR, {**SMALL, "antenna": "hologram", "radar": CHEAP_RADAR}), "accept"),
    Case("lanes_count twice, differing", "make", (HW, {"config": {"lanes_count": 2}, "lanes_count": 3}),
         fragments=("config", "lanes_count")),
    Case("lanes_count twice, equal", "make", (HW, {**SMALL, "config": {"lanes_count": 2}, "lanes_count": 2}), "accept"),
    # ---- numpy scalars where Python numbers go
    Case("grid_deg float32", "make", (RADAR, {**SMALL, "radar": {"scan": {"grid_deg": np.float32(5.0)}}}), "accept"),
    Case("elements int64", "make", (RADAR, {**SMALL, "radar": {**CHEAP_RADAR, "rhs": {"elements": np.int64(24)}}}),
         "accept"),
    Case("reset seed int64", "reset", (HW, SMALL, np.int64(5)), "accept"),
    Case("reset seed int64 (SLAM env)", "reset", (SLAM, SLAM_KW, np.int64(5)), "accept"),
    Case("reset seed float", "reset", (HW, SMALL, 5.0), fragments=("seed",)),
    # ---- hours of work behind one value
    Case("grid 0.25 deg (360 grids to optimise)", "make", (RADAR, {"radar": {"scan": {"grid_deg": 0.25}}}),
         fragments=("radar.scan.grid_deg", "rhs-slam patterns")),
    Case("4096 elements", "make", (RADAR, {"radar": {"rhs": {"elements": 4096}, "scan": {"grid_deg": 10.0}}}),
         fragments=("radar.rhs.elements", "rhs-slam patterns")),
    Case("4096 elements, hologram", "make", (RADAR, {**SMALL, "radar": {"antenna": "hologram", "rhs": {"elements": 4096},
                                                                      "scan": {"grid_deg": 30.0}}}), "accept"),
    # ---- settings that overflowed or exhausted memory: bounded, estimated up front
    Case("slam measurement_floor_m 1e200", "make", (SLAM, {**SLAM_KW, "slam": {"measurement_floor_m": 1e200}}),
         fragments=("slam.measurement_floor_m",)),
    Case("slam accel_std_mps2 1e300", "make", (SLAM, {**SLAM_KW, "slam": {"accel_std_mps2": 1e300}}),
         fragments=("slam.accel_std_mps2",)),
    Case("slam gate_mahalanobis 1e308", "make", (SLAM, {**SLAM_KW, "slam": {"gate_mahalanobis": 1e308}}),
         fragments=("slam.gate_mahalanobis",)),
    Case("slam trans_std_m 1e300", "make", (SLAM, {**SLAM_KW, "slam": {"trans_std_m": 1e300}}),
         fragments=("slam.trans_std_m",)),
    Case("slam range_std_m 1e300", "make", (SLAM, {**SLAM_KW, "slam": {"range_std_m": 1e300}}),
         fragments=("slam.range_std_m",)),
    Case("slam 100000 particles x 5000 slots", "make",
         (SLAM, {**SLAM_KW, "slam": {"n_particles": 100_000, "max_landmarks": 5000}}),
         fragments=("n_particles x max_landmarks", "GiB", "RHS_SLAM_MEMORY_LIMIT")),
    Case("waveform f_s 1e10 x chirp 1e-2", "make",
         (RADAR, {**SMALL, "radar": {**CHEAP_RADAR, "waveform": {"sample_rate_hz": 1e10, "chirp_s": 1e-2}}}),
         fragments=("radar.waveform.sample_rate_hz x waveform.chirp_s", "GiB", "RHS_SLAM_MEMORY_LIMIT")),
    Case("scaling 1e-9 with rgb_array", "make", (HW, {**SMALL, "scaling": 1e-9, "render_mode": "rgb_array"}),
         fragments=("scaling",)),
    # ---- settings that cannot apply or contradict each other
    Case("icp settings with odometry", "make", (SLAM, {**SLAM_KW, "registration": "odometry",
                                                       "icp": {"max_iterations": 5}}),
         fragments=("icp", "registration='odometry'")),
    Case("slam min_range_m 1e9", "make", (SLAM, {**SLAM_KW, "slam": {"min_range_m": 1e9}}),
         fragments=("slam.min_range_m",)),
    Case("slam min_range_m beyond the radar's max range", "make", (SLAM, {**SLAM_KW, "slam": {"min_range_m": 150.0}}),
         fragments=("slam.min_range_m", "radar.max_range_m")),
    Case("rhs carrier 1 Hz", "make", (RADAR, {**SMALL, "radar": {**CHEAP_RADAR, "rhs": {"elements": 24,
                                                                                       "carrier_hz": 1.0}}}),
         fragments=("radar.rhs.carrier_hz",)),
    Case("rhs tx_feed == rx_feed", "make", (RADAR, {**SMALL, "radar": {**CHEAP_RADAR, "rhs": {"elements": 24,
                                                                                       "tx_feed": 0, "rx_feed": 0}}}),
         fragments=("radar.rhs.tx_feed", "rx_feed", "different")),
    Case("action MultiAgentAction", "make", (HW, {**SMALL, "action": {"type": "MultiAgentAction"}}),
         fragments=("action.type", "DiscreteMetaAction")),
    Case("observation Kinematics on a SLAM env", "make", (SLAM, {**SLAM_KW, "observation": {"type": "Kinematics"}}),
         fragments=("observation", HW)),
    Case("paper obstacle on the ego's start", "make", (PAPER, {**PAPER_KW, "obstacles": [[0.0, 37.5]]}),
         fragments=("obstacles[0]", "start")),
    Case("10000 paper obstacles", "make", (PAPER, {**PAPER_KW, "obstacles": [[float(i % 300), 10.0 + i % 7]
                                                                               for i in range(10_000)]}),
         fragments=("obstacles", "1000")),
    Case("Box action of strings", "call", lambda: _continuous_step(np.array(["0.1", "0.2"])),
         fragments=("action", "Box")),
    Case("Box action float32", "call", lambda: _continuous_step(np.array([0.1, 0.2], np.float32)), "accept"),
    Case("step after close", "call", lambda: _after_close("step"), fragments=("step()", "close()")),
    Case("render after close", "call", lambda: _after_close("render"), fragments=("render()", "close()")),
    Case("reset options [1, 2]", "call", lambda: _reset_with([1, 2]), fragments=("options",)),
    Case("reset options 'x'", "call", lambda: _reset_with("x"), fragments=("options",)),
    Case("reset options unknown key", "call", lambda: _reset_with({"lanes": 2}), fragments=("options", "config")),
    Case("reset options config", "call", lambda: _reset_with({"config": {"lanes_count": 2}}), "accept"),
    Case("render_mode rgb_array_list (gymnasium's frame list)", "make",
         (HW, {**SMALL, "render_mode": "rgb_array_list"}), "accept"),
    Case("manual_control without a display", "make", (HW, {**SMALL, "manual_control": True}),
         fragments=("manual_control",)),
    # ---- what the configs must accept
    Case("blas_threads numpy int", "make", (SLAM, {**SLAM_KW, "blas_threads": np.int64(2)}), "accept"),
    Case("radar waveform None", "make", (RADAR, {**SMALL, "radar": {**CHEAP_RADAR, "waveform": None}}), "accept"),
    Case("ego_spacing 0", "make", (HW, {**SMALL, "ego_spacing": 0}), "accept"),
    # ---- the episode is over
    Case("step after truncated", "after_end", (HW, SMALL, "truncated"), "note", ("reset()", "[1 warnings]")),
    Case("step after terminated", "after_end", (HW, SMALL, "terminated"), "note", ("reset()", "[1 warnings]")),
    # ---- the JSON readers: scan and scenario
    Case("scan invalid UTF-8", "cli", ["scan", "FILE:doc.json", "--out", "OUT"], fragments=("doc.json", "UTF-8"),
         files={"doc.json": b'{"targets": [[20, 0, 5]], "antenna": "holo\xff"}'}),
    Case("scan nested 200000 deep", "cli", ["scan", "FILE:doc.json", "--out", "OUT"], fragments=("doc.json", "nest"),
         files={"doc.json": _deep(200_000)}),
    Case("scan 400-digit integer", "cli", ["scan", "FILE:doc.json", "--out", "OUT"], fragments=("doc.json", "digits"),
         files={"doc.json": b'{"targets": [[' + b"9" * 400 + b', 0, 5]]}'}),
    Case("scan seed 400 digits", "cli", ["scan", "FILE:doc.json", "--out", "OUT"], fragments=("doc.json", "digits"),
         files={"doc.json": b'{"targets": [[20, 0, 5]], "seed": ' + b"1" * 400 + b"}"}),
    Case("scan x as string", "cli", ["scan", "FILE:doc.json", "--out", "OUT"], fragments=("doc.json", "targets[0]"),
         files={"doc.json": _doc({"targets": [["20", 0, 5]]})}),
    Case("scan rcs as boolean", "cli", ["scan", "FILE:doc.json", "--out", "OUT"], fragments=("doc.json", "targets[0]"),
         files={"doc.json": _doc({"targets": [[20, 0, True]]})}),
    Case("scan 1e400", "cli", ["scan", "FILE:doc.json", "--out", "OUT"], fragments=("doc.json", "targets[0]"),
         files={"doc.json": b'{"targets": [[1e400, 0, 5]]}'}),
    Case("scan UTF-8 BOM", "cli", ["scan", "FILE:doc.json", "--out", "OUT"], "accept",
         files={"doc.json": b"\xef\xbb\xbf" + _doc(SCENE)}),
    Case("scan ok", "cli", ["scan", "FILE:doc.json", "--out", "OUT", "--grid-deg", "5"], "accept",
         files={"doc.json": _doc(SCENE)}),
    Case("scenario invalid UTF-8", "cli", ["scenario", "FILE:doc.json", "--out", "OUT"],
         fragments=("doc.json", "UTF-8"), files={"doc.json": b'{"landmarks": [[10, 5]], "antenna": "\xc3\x28"}'}),
    Case("scenario nested 200000 deep", "cli", ["scenario", "FILE:doc.json", "--out", "OUT"],
         fragments=("doc.json", "nest"), files={"doc.json": _deep(200_000)}),
    Case("scenario 400-digit integer", "cli", ["scenario", "FILE:doc.json", "--out", "OUT"],
         fragments=("doc.json", "digits"),
         files={"doc.json": _doc(SCENARIO).replace(b'"particles": 5', b'"particles": ' + b"7" * 400)}),
    Case("scenario landmark as string", "cli", ["scenario", "FILE:doc.json", "--out", "OUT"],
         fragments=("doc.json", "'landmarks'"), files={"doc.json": _doc({**SCENARIO, "landmarks": [["10", 5]]})}),
    Case("scenario pose as boolean", "cli", ["scenario", "FILE:doc.json", "--out", "OUT"],
         fragments=("doc.json", "'poses'"),
         files={"doc.json": _doc({**SCENARIO, "poses": [[0, 0, 0], [True, 0, 0]]})}),
    Case("scenario heading 1e12 rad", "cli", ["scenario", "FILE:doc.json", "--out", "OUT"],
         fragments=("doc.json", "heading"),
         files={"doc.json": _doc({**SCENARIO, "poses": [[0, 0, 0], [1, 0, 1e12]]})}),
    Case("scenario dt as string", "cli", ["scenario", "FILE:doc.json", "--out", "OUT"],
         fragments=("doc.json", "'dt'"), files={"doc.json": _doc({**SCENARIO, "dt": "0.2"})}),
    Case("scenario ok", "cli", ["scenario", "FILE:doc.json", "--out", "OUT", "--no-progress"], "accept",
         files={"doc.json": _doc(SCENARIO)}),
    # ---- the YAML reader (--hyperparams)
    Case("hyperparams malformed YAML", "cli", ["train", *TRAIN_FAST, "--out", "OUTDIR", "--hyperparams",
                                               "FILE:hp.yml"], fragments=("hp.yml",),
         files={"hp.yml": b"rhs-highway-v0: {policy: MlpPolicy, n_steps: [1,\n"}),
    Case("hyperparams invalid UTF-8", "cli", ["train", *TRAIN_FAST, "--out", "OUTDIR", "--hyperparams",
                                              "FILE:hp.yml"], fragments=("hp.yml", "UTF-8"),
         files={"hp.yml": b"rhs-highway-v0:\n  policy: Mlp\xffPolicy\n"}),
    Case("hyperparams nested deep", "cli", ["train", *TRAIN_FAST, "--out", "OUTDIR", "--hyperparams", "FILE:hp.yml"],
         fragments=("hp.yml", "nest"), files={"hp.yml": b"rhs-highway-v0: " + _deep(100_000) + b"\n"}),
    Case("hyperparams 400-digit n_steps", "cli", ["train", *TRAIN_FAST, "--out", "OUTDIR", "--hyperparams",
                                                  "FILE:hp.yml"], fragments=("hp.yml", "n_steps"),
         files={"hp.yml": b"rhs-highway-v0:\n  policy: MlpPolicy\n  n_steps: " + b"9" * 400 + b"\n"}),
    Case("hyperparams n_steps as string", "cli", ["train", *TRAIN_FAST, "--out", "OUTDIR", "--hyperparams",
                                                  "FILE:hp.yml"], fragments=("hp.yml", "n_steps"),
         files={"hp.yml": b"rhs-highway-v0:\n  policy: MlpPolicy\n  n_steps: '128'\n"}),
    Case("hyperparams gamma as boolean", "cli", ["train", *TRAIN_FAST, "--out", "OUTDIR", "--hyperparams",
                                                 "FILE:hp.yml"], fragments=("hp.yml", "gamma"),
         files={"hp.yml": b"rhs-highway-v0:\n  policy: MlpPolicy\n  gamma: yes\n"}),
    Case("hyperparams not a mapping", "cli", ["train", *TRAIN_FAST, "--out", "OUTDIR", "--hyperparams", "FILE:hp.yml"],
         fragments=("hp.yml",), files={"hp.yml": b"- 1\n- 2\n"}),
    # ---- flags
    Case("train --env-kwargs '{bad'", "cli", ["train", *TRAIN_FAST, "--out", "OUTDIR", "--env-kwargs", "{bad"],
         fragments=("--env-kwargs",)),
    Case("evaluate --env-kwargs '{bad'", "cli", ["evaluate", "--out", "OUT", "--env-kwargs", "{bad"],
         fragments=("--env-kwargs",)),
    Case("demo --env-kwargs '{bad'", "cli", ["demo", "--out", "OUTDIR", "--env-kwargs", "{bad"],
         fragments=("--env-kwargs",)),
    Case("evaluate --env-kwargs nested 100000", "cli", ["evaluate", "--out", "OUT", "--env-kwargs",
                                                        '{"a": ' + "[" * 100_000 + "]" * 100_000 + "}"],
         fragments=("--env-kwargs", "nest")),
    Case("train unknown --env", "cli", ["train", "--out", "OUTDIR", "--env", "bogus-v0"],
         fragments=("unknown env id", "rhs-highway-v0")),
    Case("evaluate unknown --env", "cli", ["evaluate", "--out", "OUT", "--env", "bogus-v0"],
         fragments=("unknown env id", "rhs-highway-v0")),
    Case("demo unknown --env", "cli", ["demo", "--out", "OUTDIR", "--env", "bogus-v0"],
         fragments=("unknown env id", "rhs-highway-v0")),
    Case("evaluate 100000 episodes", "cli", ["evaluate", "--out", "OUT", "--episodes", "100000", "--no-progress"],
         fragments=("--episodes", "--yes")),
    Case("train --resume on an empty folder", "cli", ["train", *TRAIN_FAST, "--out", "OUTDIR", "--resume"], fragments=("--resume",)),
    Case("train --algo ppo --timesteps 64", "cli", ["train", *TRAIN_FAST, "--out", "OUTDIR"],
         "note", ("rounded up to 128",)),
    Case("train --init-policy without --env-kwargs", "cli",
         ["train", "--algo", "dagger", *TRAIN_FAST, "--out", "OUTDIR", "--init-policy", STUDENT],
         "note", ("target_speeds",)),
    Case("train --init-policy, other target speeds", "cli",
         ["train", "--algo", "dagger", *TRAIN_FAST, "--out", "OUTDIR", "--init-policy", STUDENT,
          "--env-kwargs", '{"action": {"type": "DiscreteMetaAction", "target_speeds": [5, 10, 15]}}'],
         fragments=("--init-policy", "target_speeds")),
]


# --------------------------------------------------------------------------- running one case
@dataclass
class Outcome:
    ok: bool  # ran to the end without an exception
    message: str = ""  # the error text (exception or stderr)
    clean: bool = False  # a refusal of the accepted form (ValueError / TypeError, or exit 2 on one line)
    text: str = ""  # what it printed or warned (for the notes)
    finite: bool = True


def _finite(value: Any) -> bool:
    if isinstance(value, dict):
        return all(_finite(v) for v in value.values())
    try:
        return bool(np.all(np.isfinite(np.asarray(value, dtype=float))))
    except (TypeError, ValueError):
        return True


def _run_env(env_id: str, kwargs: dict, seed: Any = 0, after_end: str | None = None) -> Outcome:
    import gymnasium as gym

    import rhs_env  # noqa: F401

    env = gym.make(env_id, **kwargs)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            obs, info = env.reset(seed=seed)
            finite = _finite(obs)
            steps = 0
            done = False
            while not done and steps < 2:
                obs, reward, term, trunc, info = env.step(1)
                finite = finite and _finite(obs) and math.isfinite(float(reward))
                steps += 1
                done = term or trunc
                if after_end == "terminated":
                    env.unwrapped.vehicle.crashed = True  # the next step ends the episode as a crash would
            if env.render_mode is not None:
                frame = env.render()
                finite = finite and frame is not None
            if after_end is not None:
                while not done:  # to the end of the episode, then twice beyond it
                    _, _, term, trunc, _ = env.step(1)
                    done = term or trunc
                before = len(caught)
                for _ in range(3):
                    env.step(1)
                warned = [str(w.message) for w in caught[before:]]
                return Outcome(True, text="\n".join(warned) + f"\n[{len(warned)} warnings]", finite=finite)
        return Outcome(True, finite=finite)
    finally:
        env.close()


def _step_with(action: Any) -> Outcome:
    import gymnasium as gym

    import rhs_env  # noqa: F401

    env = gym.make(HW, **SMALL)
    try:
        env.reset(seed=0)
        obs, reward, *_ = env.step(action)
        return Outcome(True, finite=_finite(obs) and math.isfinite(float(reward)))
    finally:
        env.close()


def _continuous_step(action: Any) -> Any:
    """A step of ``rhs-highway-v0`` with the continuous action space (a Box of two numbers)."""
    import gymnasium as gym

    import rhs_env  # noqa: F401

    env = gym.make(HW, **SMALL, action={"type": "ContinuousAction"})
    try:
        env.reset(seed=0)
        return env.step(action)[0]
    finally:
        env.close()


def _after_close(call: str) -> Any:
    """``step`` or ``render`` of an ``rgb_array`` env after its ``close``."""
    import gymnasium as gym

    import rhs_env  # noqa: F401

    env = gym.make(HW, **SMALL, render_mode="rgb_array")
    env.reset(seed=0)
    env.close()
    return env.step(1)[0] if call == "step" else env.render()


def _reset_with(options: Any) -> Any:
    """``reset(seed=0, options=options)`` of ``rhs-highway-v0``."""
    import gymnasium as gym

    import rhs_env  # noqa: F401

    env = gym.make(HW, **SMALL)
    try:
        return env.reset(seed=0, options=options)[0]
    finally:
        env.close()


def table_rows() -> list[Case]:
    """The rows of ``tests/test_bad_inputs.py`` (every one a refusal naming its fragment) as cases."""
    from test_bad_inputs import CASES as ROWS

    kinds = {"make": "make", "action": "action", "cli": "oldcli"}
    return [Case(f"[table] {name}", kinds[kind], given, "refuse", (fragment,)) for name, kind, given, _, fragment in ROWS]


def _cli(args: list[str], folder: Path, files: dict[str, bytes]) -> Outcome:
    from rhs_slam.cli import main

    argv = []
    for a in args:
        if a.startswith("FILE:"):
            name = a[5:]
            (folder / name).write_bytes(files[name])
            a = str(folder / name)
        elif a == "OUT":
            a = str(folder / "out.json")
        elif a == "OUTDIR":
            a = str(folder / "run")
        argv.append(a)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse
            code = exc.code if isinstance(exc.code, int) else 2
    text = err.getvalue().strip()
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if code == 0:
        summary = folder / "run" / "train.json"
        note = summary.read_text() if summary.exists() else ""
        return Outcome(True, text=out.getvalue() + text + note)
    last = lines[-1] if lines else ""
    # a refusal: exit 2, the error on the last line, no traceback (tests/test_fuzz_inputs.py checks one line)
    clean = code == 2 and "Traceback" not in text and "error" in last
    return Outcome(False, message=last, clean=clean, text=text)


def run_case(case: Case, folder: Path) -> Outcome:
    """Run ``case`` once in ``folder`` (a scratch directory); exceptions that are not refusals propagate."""
    try:
        if case.kind == "make":
            env_id, kwargs = case.given
            return _run_env(env_id, kwargs)
        if case.kind == "reset":
            env_id, kwargs, seed = case.given
            return _run_env(env_id, kwargs, seed=seed)
        if case.kind == "after_end":
            env_id, kwargs, how = case.given
            return _run_env(env_id, kwargs, after_end=how)
        if case.kind == "cli":
            return _cli(case.given, folder, case.files)
        if case.kind == "action":  # a step with this action on a fresh rhs-highway-v0
            return _step_with(case.given)
        if case.kind == "oldcli":  # a row of tests/test_bad_inputs.py's table
            from test_bad_inputs import _cli_args

            return _cli([str(a) for a in _cli_args(case.given, folder)], folder, {})
        if case.kind == "call":
            fn: Callable[[], Any] = case.given
            return Outcome(True, finite=_finite(fn()))
    except (ValueError, TypeError) as exc:
        return Outcome(False, message=f"{type(exc).__name__}: {exc}", clean=True)
    except RuntimeError as exc:  # gymnasium's lifecycle errors (rhs_env.envs.EnvClosedError) and a vector env's
        if type(exc).__name__ not in ("EnvClosedError", "WorkerError"):  # dead worker (rhs_env.vector) are refusals
            raise
        return Outcome(False, message=f"{type(exc).__name__}: {exc}", clean=True)
    raise ValueError(f"unknown case kind {case.kind!r}")


def classify(case: Case, outcome: Outcome | None, error: BaseException | None = None) -> str:
    """The class of what happened: clean, accepted, traceback, silent or wrongly-rejected (hang: the caller)."""
    if error is not None:
        return "traceback"
    assert outcome is not None
    # gymnasium appends the kwargs to an error of the env creator: the fragments must be in the error itself
    said = (outcome.text if outcome.ok else outcome.message).split(" was raised from the environment creator")[0]
    named = all(f in said for f in case.fragments)
    if case.expect == "refuse":
        if outcome.ok:
            return "silent"
        if outcome.clean:
            return "clean" if named else "unnamed"
        return "traceback"
    if not outcome.ok:
        return "wrongly-rejected" if outcome.clean else "traceback"
    if not outcome.finite:
        return "silent"
    if case.expect == "note":
        return "accepted" if named else "silent"
    return "accepted"


def expected_class(case: Case) -> str:
    return "clean" if case.expect == "refuse" else "accepted"


# --------------------------------------------------------------------------- the tally
def _child(case: Case, folder: Path, conn) -> None:  # pragma: no cover - runs in a forked child
    os.setpgrp()  # its own process group: a hang is killed with the workers it started
    try:
        outcome = run_case(case, folder)
        conn.send(classify(case, outcome) + "\t" + (outcome.message or outcome.text)[-300:].replace("\n", " | "))
    except BaseException as exc:  # a traceback: anything but a refusal
        conn.send("traceback\t" + "".join(traceback.format_exception_only(type(exc), exc)).strip()[-300:])
    conn.close()


def tally(cases: list[Case], timeout_s: float, verbose: bool = True) -> dict[str, int]:
    """Run every case in a forked child (a hang is killed after ``timeout_s``); counts by class."""
    import multiprocessing
    import tempfile

    ctx = multiprocessing.get_context("fork")
    counts = dict.fromkeys(CLASSES, 0)
    for case in cases:
        with tempfile.TemporaryDirectory() as tmp:
            parent, child = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_child, args=(case, Path(tmp), child))
            proc.start()
            if parent.poll(timeout_s):
                result = parent.recv()
            else:
                result = f"hang\tno result after {timeout_s:g} s"
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.join()
        cls, detail = result.split("\t", 1)
        counts["tried"] += 1
        counts[cls] += 1
        if verbose:
            mark = "  " if cls == expected_class(case) else "!!"
            print(f"{mark} {cls:16s} {case.name}: {detail[:160]}", flush=True)
    return counts


def main(argv: list[str] | None = None) -> int:
    import argparse

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--timeout", type=float, default=90.0, help="seconds before a case counts as a hang")
    p.add_argument("--json", default=None, help="write the counts here")
    p.add_argument("--only", default=None, help="cases whose name contains this")
    p.add_argument("--no-table-rows", action="store_true", help="leave out the rows of tests/test_bad_inputs.py")
    a = p.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import gymnasium  # noqa: F401  (imported once, before the children fork)

    import rhs_env
    import rhs_slam.cli  # noqa: F401

    print(f"rhs_env from {Path(rhs_env.__file__).parent}", flush=True)
    cases = [c for c in CASES + ([] if a.no_table_rows else table_rows()) if a.only is None or a.only in c.name]
    counts = tally(cases, a.timeout)
    print(json.dumps(counts))
    if a.json:
        Path(a.json).write_text(json.dumps(counts, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    os.chdir(Path(__file__).resolve().parents[1])  # the repository root: the student zip path is relative
    sys.exit(main())
