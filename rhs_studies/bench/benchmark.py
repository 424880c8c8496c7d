"""Speed of every stage of rhs-slam, in one run, as JSON (never in timed tests).

Speeds are reported as ratios measured side by side in the same run (a busy
machine slows both sides alike); the load average is recorded at the start of
every section and printed beside it. Sections (``--sections``, default all):

* ``envs``: steps per second of ``rhs-highway-v0``, ``rhs-highway-radar-v0`` and
  ``rhs-highway-slam-v0`` (and the radar and SLAM envs on the numpy reference kernels),
  stepped round-robin in blocks (``--block`` steps each in turn) on the same seeds and
  actions, with the radar's time per stage (synthesis, range/CFAR, OMP) and the SLAM's
  time per stage (registration, association, RBPF) at 100 particles, each stage before
  (numpy kernels) and after (compiled); goals: radar >= 0.75x and SLAM >= 0.67x the base
  env's steps/s, each ratio with its 95 % bootstrap interval over the blocks (:func:`ratio_interval`);
  ``--env-runs`` runs (default 3) in fresh processes, pooled (:func:`bench_envs_runs`: one
  process's ratio moves between processes by more than its own interval);
* ``start``: seconds to the first step of ``rhs-highway-slam-v0`` in a new process (imports,
  make, reset, one step) with an empty kernel cache (cold, goal <= 30 s) and with the cache (warm,
  goal <= 5 s), the median of ``--start-repeats`` runs (each run's seconds beside it: one cold start
  moves by several seconds with the machine's state);
* ``floor``: what the IQ path costs before any processing, per 4-radar scan: the
  noise of its 4 I C N samples (a scan of an empty scene) and their range FFT; the range
  path's (``fidelity="range"``) noise spectrum of the same empty scan; set
  beside the radar budget that the ``envs`` goals leave (radar <= base step x
  (1 / 0.75 - 1) + the base step's Kinematics observation, which the radar and SLAM envs skip;
  radar + SLAM <= base step x (1 / 0.67 - 1) + that observation);
* ``load``: steady under load, the radar env's steps/s with one other busy
  process (a CPU spin loop) against quiet, with single-threaded BLAS in the step
  (the default) and with the process's own BLAS threads (``blas_threads=None``);
  goal >= 0.85x;
* ``vec``: the radar env in ``SubprocVecEnv`` with 2 workers against 1 (total
  env steps/s); goal >= 1.8x; beside it the machine's own two-process scaling, the same
  ratio for a pure-Python loop that shares nothing (:func:`machine_scaling`): the ceiling
  a shared virtual machine gives any two processes;
* ``radar``: one 4-radar scan of a typical scene (scripts/benchmark_radar.py),
  both synthesis fidelities;
* ``patterns``: time to build the dtheta = 1 deg default library with each
  method (scripts/benchmark_patterns.py; SDR on a subset, extrapolated);
* ``traffic``: the traffic alone, steps per second of highway-env's ``highway-fast-v0``, ``rhs-highway-v0``
  stepped by highway-env (``sim="highway-env"``, the default) and by the compiled core (``sim="compiled"``,
  :mod:`rhs_env.traffic`), round-robin on the same seeds and actions, with their default (Kinematics)
  observation and with none (the radar and SLAM envs replace it); and the compiled core's first-step seconds
  in a fresh process with an empty kernel cache (compile) and with the cache (load);
* ``training``: PPO training steps/s with 2 subprocess envs on
  ``rhs-highway-slam-v0`` against ``rhs-highway-v0`` at the steady rate (from the second rollout on),
  with each run's start-up seconds beside it; goal >= 0.7x.
* ``vec_native``: the native vector env (``vectorization_mode="vector_entry_point"``) of 8
  ``rhs-highway-slam-fast-v0`` against one such env and gymnasium's ``SyncVectorEnv`` of 8, round-robin in
  one process, with the machine's two-process scaling as the ceiling; goal >= 1.4x one env.
* ``targets``: the speed targets against highway-env's own ``highway-fast-v0`` in one process, round-robin on
  the same actions, warm kernels (:func:`bench_targets`): the default SLAM env (goal >= 1.5x) and the fast one
  (goal >= 6x), with each env's step split into traffic, radar, SLAM and the rest, and each stage's floor beside
  it (the compiled traffic core's and the SLAM's compiled kernels' own time, the radar's sample floor from the
  ``floor`` section). With ``training`` and ``vec_native`` in the same run, all the speed targets are shown
  together (``training`` also trains PPO on ``rhs-highway-slam-fast-v0``: goal >= 5x PPO on the exact SLAM env).

    python scripts/benchmark.py --sections targets vec_native training   # the speed targets, one run

    python scripts/benchmark.py --out results/benchmark.json      # also writes results/benchmark.md
    python scripts/benchmark.py --sections envs load vec --steps 30   # keeps the other sections of --out
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from rhs_studies.kit.provenance import command_line, write_json

ROOT = Path(__file__).resolve().parents[2]

SECTIONS = ("envs", "start", "floor", "load", "vec", "radar", "patterns", "traffic", "training", "vec_native",
            "targets")
GOALS = {"radar_env_over_base": 0.75, "slam_env_over_base": 0.67, "loaded_over_quiet": 0.85,
         "two_workers_over_one": 1.8, "ppo_slam_over_base": 0.7, "vec_workers_over_single": 1.4,
         "slam_over_highway_fast": 1.5, "slam_fast_over_highway_fast": 6.0, "ppo_fast_native_over_exact": 5.0}
START_GOALS_S = {"cold_s": 30.0, "warm_s": 5.0}  # first step of a new user: empty kernel cache / warm cache
LIBRARY_GOAL_S = 30.0  # the fast M = 60, 1-degree library, 2 workers, every grid pointing within half a grid


def _mean_times(dicts: list[dict]) -> dict:
    keys = sorted({k for d in dicts for k in d})
    return {k: float(np.mean([d.get(k, 0.0) for d in dicts])) * 1e3 for k in keys}


#: the envs of the ``envs`` section: (label, id, kwargs beside the radar grid); the last two are the
#: numpy reference kernels of the same envs (the per-stage "before" of the compiled kernels)
ENV_RUNS: tuple[tuple[str, str, dict[str, str] | None], ...] = (
    ("rhs-highway-v0", "rhs-highway-v0", None),
    ("rhs-highway-radar-v0", "rhs-highway-radar-v0", {}),
    ("rhs-highway-slam-v0", "rhs-highway-slam-v0", {}),
    ("rhs-highway-radar-v0 (numpy kernels)", "rhs-highway-radar-v0", {"kernels": "numpy"}),
    ("rhs-highway-slam-v0 (numpy kernels)", "rhs-highway-slam-v0", {"kernels": "numpy"}),
)
#: the envs every run of the ``envs`` section steps, pooled over runs (:func:`pool_env_runs`)
POOLED_ENVS = ("rhs-highway-v0", "rhs-highway-radar-v0", "rhs-highway-slam-v0")


def _kinematics_observation_ms(env, repeats: int = 20) -> float:
    """Median ms of the base env's own observation (highway-env's Kinematics table, pandas).

    The base step pays it; the radar and SLAM envs replace it by a null observation
    (:data:`rhs_env.registration.NULL_OBSERVATION`), so their radar stages have that much more room.
    """
    obs_type = env.unwrapped.observation_type
    times = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        obs_type.observe()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times[1:]))


def bench_envs(steps: int, seed: int, grid_deg: float, block: int = 5, numpy_kernels: bool = True) -> dict:
    """Steps/s of the three highway ids (and the radar / SLAM envs on the numpy kernels) on the same actions.

    The envs step round-robin, ``block`` steps each in turn (a load drift slows every env alike, as
    the ``load`` section does); the load average is recorded at the start and the end. Also the
    base env's Kinematics observation time (:func:`_kinematics_observation_ms`) and, with
    ``numpy_kernels``, each radar / SLAM stage before (``kernels="numpy"``) and after (compiled).
    """
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids)
    from rhs_common.jit import watch_compiles
    from slam.gym.precompile import workload

    workload()  # every kernel compiled or loaded before the clock runs (some first run only once landmarks match)
    load_start = [round(x, 2) for x in os.getloadavg()]
    runs = [r for r in ENV_RUNS if numpy_kernels or "numpy" not in r[0]]
    envs: dict[str, dict[str, Any]] = {}  # label -> env, seconds and steps timed, stage times per step
    actions = np.random.default_rng(seed).choice([1, 1, 1, 3, 4], size=max(steps, 2 * block))
    for label, env_id, kernels in runs:
        kwargs: dict[str, Any] = {} if kernels is None else {"radar": {"scan": {"grid_deg": grid_deg}, **kernels},
                                             "stage_times_in_info": True}
        if kernels and env_id.startswith("rhs-highway-slam"):
            kwargs["slam"] = dict(kernels)
        env = gym.make(env_id, **kwargs)
        env.reset(seed=seed)
        # warm-up, untimed: the first steps build caches (steering rows, FFT plans) and load or compile the
        # kernels (some run only once the SLAM has matched landmarks)
        for a in actions[: 2 * block]:
            _, _, term, trunc, _ = env.step(int(a))
            if term or trunc:
                env.reset(seed=seed)
        envs[label] = {"env": env, "dt": 0.0, "n": 0, "radar": [], "slam": [], "blocks": []}
    actions = actions[:steps]
    with watch_compiles() as compiled:
        for lo in range(0, steps, block):
            for rec in envs.values():
                _time_block(rec, actions[lo: lo + block], seed)
    out: dict = {"block_steps": block, "load_average_start": load_start, "kernels_compiled_while_timed": sorted(compiled),
                 "blocks_s": {label: [round(t, 6) for t in rec["blocks"]] for label, rec in envs.items()
                              if label in POOLED_ENVS}}
    if compiled:  # a compile inside a timed block would be counted as a step's cost
        print(f"benchmark: warning: kernels compiled while timed: {sorted(compiled)}", file=sys.stderr)
    out["kinematics_observation_ms"] = _kinematics_observation_ms(envs["rhs-highway-v0"]["env"])
    for label, rec in envs.items():
        rec["env"].close()
        n, dt = rec["n"], rec["dt"]
        out[label] = {"steps": n, "steps_per_s": n / dt, "ms_per_step": 1e3 * dt / n,
                      "radar_stage_ms": _mean_times(rec["radar"]) if rec["radar"] else None,
                      "slam_stage_ms": _mean_times(rec["slam"]) if rec["slam"] else None}
    out["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    _ratios(out)
    if numpy_kernels:
        for kind in ("radar", "slam"):
            ref = out[f"rhs-highway-{kind}-v0 (numpy kernels)"]
            out[f"{kind}_env_over_base_numpy_kernels"] = ref["steps_per_s"] / out["rhs-highway-v0"]["steps_per_s"]
        out["stages_before_after"] = stages_before_after(out)
    return out


def _ratios(out: dict) -> None:
    """Set ``out``'s added ms and env / base ratios from its three envs' ms per step and blocks."""
    base = out["rhs-highway-v0"]["ms_per_step"]
    for kind, env_id in (("radar", "rhs-highway-radar-v0"), ("radar_slam", "rhs-highway-slam-v0")):
        out[f"{kind}_added_ms"] = out[env_id]["ms_per_step"] - base
        out[f"{kind}_added_over_base"] = out[f"{kind}_added_ms"] / base
    blocks = out["blocks_s"]
    for kind in ("radar", "slam"):
        env_id = f"rhs-highway-{kind}-v0"
        out[f"{kind}_env_over_base"] = out[env_id]["steps_per_s"] / out["rhs-highway-v0"]["steps_per_s"]
        out[f"{kind}_env_over_base_ci"] = ratio_interval(np.asarray(blocks["rhs-highway-v0"]), np.asarray(blocks[env_id]))


def bench_envs_runs(steps: int, seed: int, grid_deg: float, block: int = 5, runs: int = 3) -> dict:
    """:func:`bench_envs` in ``runs`` fresh processes, one after another, pooled.

    One process's ratio moves between processes by more than its block interval shows (the base
    env's interpreter-bound step moved 25-29 ms between runs on one machine while the compiled
    radar moved less), so the headline pools them: steps/s and stage times over every run's timed
    steps, each ratio ``sum(base blocks) / sum(env blocks)`` over every run, and its 95 % interval
    from a two-level bootstrap (runs, then the blocks within each, :func:`ratio_interval`). The
    first run also steps the numpy kernels (the stage table's "before"); ``runs`` lists each run's
    ratios, ms per step and load.
    """
    results = []
    for i in range(runs):
        code = (f"import json; from rhs_studies.bench.benchmark import bench_envs; print('RESULT ' + json.dumps(bench_envs("
                f"{steps}, {seed}, {grid_deg}, block={block}, numpy_kernels={i == 0})))")
        done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=False)
        line = next((ln for ln in done.stdout.splitlines() if ln.startswith("RESULT ")), None)
        if done.returncode or line is None:
            raise RuntimeError(f"benchmark: envs run {i + 1} of {runs} failed:\n{done.stderr[-3000:]}")
        results.append(json.loads(line[len("RESULT "):]))
        print(f"benchmark: envs run {i + 1}/{runs}: radar {results[-1]['radar_env_over_base']:.3f} x, "
              f"SLAM {results[-1]['slam_env_over_base']:.3f} x", file=sys.stderr)
    return pool_env_runs(results)


def pool_env_runs(results: list[dict]) -> dict:
    """The first run's record (its numpy-kernel envs and stage table) with the three envs pooled over ``results``
    (see :func:`bench_envs_runs`)."""
    out = dict(results[0])
    for env_id in POOLED_ENVS:
        recs = [r[env_id] for r in results]
        n, dt = sum(r["steps"] for r in recs), sum(r["steps"] * r["ms_per_step"] / 1e3 for r in recs)
        stages = {k: ([r[k] for r in recs if r[k]] or None) for k in ("radar_stage_ms", "slam_stage_ms")}
        out[env_id] = {"steps": n, "steps_per_s": n / dt, "ms_per_step": 1e3 * dt / n,
                       **{k: (v if v is None else {s: float(np.mean([d.get(s, 0.0) for d in v])) for s in v[0]})
                          for k, v in stages.items()}}
    out["blocks_s"] = {env_id: [t for r in results for t in r["blocks_s"][env_id]] for env_id in POOLED_ENVS}
    _ratios(out)
    if len(results) > 1:
        for kind in ("radar", "slam"):
            env_id = f"rhs-highway-{kind}-v0"
            out[f"{kind}_env_over_base_ci"] = ratio_interval_runs([np.asarray(r["blocks_s"]["rhs-highway-v0"]) for r in results],
                                                                  [np.asarray(r["blocks_s"][env_id]) for r in results])
    out["runs"] = [{"radar_env_over_base": r["radar_env_over_base"], "slam_env_over_base": r["slam_env_over_base"],
                    "base_ms_per_step": r["rhs-highway-v0"]["ms_per_step"], "load_average_start": r["load_average_start"]}
                   for r in results]
    if "stages_before_after" in results[0]:
        out["stages_before_after"] = stages_before_after(out)
    return out


def _time_block(rec: dict[str, Any], actions: np.ndarray, seed: int) -> None:
    """Step ``rec["env"]`` through ``actions``, one timed block (resets on episode end): its seconds, steps and stage times
    into ``rec``."""
    env = rec["env"]
    t0 = time.perf_counter()
    for a in actions:
        _, _, term, trunc, info = env.step(int(a))
        rec["n"] += 1
        if "slam_stage_times" in info:
            rec["slam"].append(info["slam_stage_times"])
        if "radar_stage_times" in info:
            rec["radar"].append(info["radar_stage_times"])
        if term or trunc:
            env.reset(seed=seed + rec["n"])
    rec["blocks"].append(time.perf_counter() - t0)
    rec["dt"] += rec["blocks"][-1]


def ratio_interval(base_blocks: np.ndarray, env_blocks: np.ndarray, resamples: int = 2000, seed: int = 0) -> list[float]:
    """95 % bootstrap interval of ``sum(base) / sum(env)`` (the env's steps/s over the base's) over the round-robin
    blocks, resampled in pairs (a block of each env ran back to back: the load both saw is shared)."""
    rng = np.random.default_rng(seed)
    pick = rng.integers(0, base_blocks.size, (resamples, base_blocks.size))
    ratios = base_blocks[pick].sum(axis=1) / env_blocks[pick].sum(axis=1)
    return [round(float(x), 4) for x in np.percentile(ratios, [2.5, 97.5])]


def stages_before_after(envs: dict) -> dict:
    """``{stage: {"numpy": ms, "compiled": ms}}`` of the SLAM env's radar and SLAM stages (``radar.`` / ``slam.`` prefixed)."""
    table = {}
    for kind in ("radar", "slam"):
        before = envs["rhs-highway-slam-v0 (numpy kernels)"].get(f"{kind}_stage_ms") or {}
        after = envs["rhs-highway-slam-v0"].get(f"{kind}_stage_ms") or {}
        for stage in sorted(set(before) | set(after)):
            table[f"{kind}.{stage}"] = {"numpy": before.get(stage, float("nan")), "compiled": after.get(stage, float("nan"))}
    return table


#: the cold / warm start of a new user: imports, gym.make, reset and one step of the SLAM env
START_CODE = """
import time
t0, c0 = time.perf_counter(), time.process_time()
import gymnasium as gym
import rhs_env  # noqa: F401
env = gym.make("rhs-highway-slam-v0")
env.reset(seed=0)
env.step(1)
from rhs_common.jit import compile_stats
print(time.perf_counter() - t0, time.process_time() - c0, len(compile_stats()["kernels"]))
"""


def bench_start(repeats: int = 1) -> dict:
    """Seconds to the first step of ``rhs-highway-slam-v0`` in a fresh process, cold (an empty kernel cache) and warm.

    Each run is a subprocess with ``NUMBA_CACHE_DIR`` set to a new temporary directory (cold: every
    kernel compiles, the SLAM env's background compile on: :mod:`slam.gym.precompile`), then the same directory
    again (warm: loaded from the cache) once the background compile has ended (``background_runs_s``: when its lock
    went, seconds from the cold process' start; it compiles the one-call OMP last, after the cold first step).
    ``*_s`` is the time inside the process (imports + make + reset + step), ``*_process_s`` the whole process.
    ``next_*``: a process started as soon as the cold one ended (the background compile may still run: a new user's
    second run); ``cpu_runs_s``: each process' own CPU seconds (the host's load inflates wall time, not these);
    ``kernels_compiled``: the project's kernels each process compiled (:func:`rhs_common.jit.compile_stats`).
    """
    import tempfile

    out: dict = {"load_average_start": [round(x, 2) for x in os.getloadavg()]}
    cold: list[float] = []
    warm: list[float] = []
    cold_p: list[float] = []
    warm_p: list[float] = []
    background: list[float] = []
    nxt: list[float] = []
    cpu: dict[str, list[float]] = {"cold": [], "next": [], "warm": []}
    compiled: dict[str, list[int]] = {"cold": [], "next": [], "warm": []}
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as cache:
            env = {**os.environ, "NUMBA_CACHE_DIR": cache, "OMP_NUM_THREADS": "1", "RHS_SLAM_BACKGROUND_COMPILE": "1",
                   "RHS_SLAM_QUIET": "1"}
            # cold; next: started as the cold one ends (its background compile may still run); warm: after it ended
            for kind, inside, whole in (("cold", cold, cold_p), ("next", nxt, []), ("warm", warm, warm_p)):
                t0 = time.perf_counter()
                res = subprocess.run([sys.executable, "-c", START_CODE], cwd=ROOT, env=env, capture_output=True,
                                     text=True, check=True)
                whole.append(time.perf_counter() - t0)
                wall, cpu_s, n = res.stdout.strip().splitlines()[-1].split()
                inside.append(float(wall))
                cpu[kind].append(round(float(cpu_s), 2))
                compiled[kind].append(int(n))
                if kind == "cold":
                    t_cold = t0
                if kind == "next":
                    background.append(_wait_for_background_compile(Path(cache), t_cold))
    out.update(next_s=float(np.median(nxt)), next_runs_s=[round(v, 2) for v in nxt], cpu_runs_s=cpu,
               kernels_compiled=compiled)
    out.update(cold_s=float(np.median(cold)), warm_s=float(np.median(warm)), cold_process_s=float(np.median(cold_p)),
               warm_process_s=float(np.median(warm_p)), repeats=repeats, cold_runs_s=[round(v, 2) for v in cold],
               warm_runs_s=[round(v, 2) for v in warm], background_runs_s=[round(v, 2) for v in background])
    out["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    return out


#: the envs of the ``traffic`` section: (label, id, kwargs); "bare": no base observation (the radar / SLAM envs')
TRAFFIC_RUNS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("highway-fast-v0", "highway-fast-v0", {}),
    ("rhs-highway-v0 (highway-env)", "rhs-highway-v0", {}),
    ("rhs-highway-v0 (compiled)", "rhs-highway-v0", {"sim": "compiled"}),
    ("rhs-highway-v0 bare (highway-env)", "bare", {}),
    ("rhs-highway-v0 bare (compiled)", "bare", {"sim": "compiled"}),
)
#: a new process: time make + reset + the first step of the compiled env (its kernels compile or load there), after
#: the imports (wall and CPU seconds)
TRAFFIC_START_CODE = """
import time, rhs_env, gymnasium as gym
t0, c0 = time.perf_counter(), time.process_time()
env = gym.make("rhs-highway-v0", sim="compiled"); env.reset(seed=0); env.step(1)
print(time.perf_counter() - t0, time.process_time() - c0)
"""


def _make_traffic_env(env_id: str, kwargs: dict[str, Any]):
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids)

    if env_id == "bare":
        from rhs_env.envs import RHSHighwayEnv
        from rhs_env.registration import NULL_OBSERVATION

        return RHSHighwayEnv(config={"observation": dict(NULL_OBSERVATION), **kwargs})
    if env_id == "highway-fast-v0":
        import highway_env  # noqa: F401  (registers highway-fast-v0)
    return gym.make(env_id, **kwargs)


def bench_traffic(steps: int, seed: int, block: int = 5) -> dict:
    """Steps/s of :data:`TRAFFIC_RUNS`, round-robin in blocks of ``block`` steps on the same actions and seeds;
    the compiled core's ratios with their 95 % intervals (:func:`ratio_interval`); its compile / load seconds."""
    import tempfile
    import warnings

    out: dict[str, Any] = {"load_average_start": [round(x, 2) for x in os.getloadavg()]}
    actions = np.random.default_rng(seed).integers(0, 5, size=steps)
    recs = {label: {"env": _make_traffic_env(i, kw), "n": 0, "blocks": [], "dt": 0.0, "slam": [], "radar": []}
            for label, i, kw in TRAFFIC_RUNS}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for rec in recs.values():
            rec["env"].reset(seed=seed)
            _time_block(rec, actions[:block], seed)  # warm (the compiled core's kernels load or compile here)
            rec.update(n=0, blocks=[], dt=0.0)
            rec["env"].reset(seed=seed)
        for start in range(0, steps, block):
            for rec in recs.values():
                _time_block(rec, actions[start:start + block], seed)
    for label, rec in recs.items():
        out[label] = {"steps_per_s": rec["n"] / rec["dt"], "ms_per_step": 1e3 * rec["dt"] / rec["n"]}
        rec["env"].close()
    blocks = {label: np.asarray(rec["blocks"]) for label, rec in recs.items()}
    for name, env, base in (("compiled_over_highway_env", "rhs-highway-v0 (compiled)", "rhs-highway-v0 (highway-env)"),
                            ("compiled_over_highway_fast", "rhs-highway-v0 (compiled)", "highway-fast-v0"),
                            ("bare_compiled_over_highway_env", "rhs-highway-v0 bare (compiled)",
                             "rhs-highway-v0 bare (highway-env)"),
                            ("bare_compiled_over_highway_fast", "rhs-highway-v0 bare (compiled)", "highway-fast-v0")):
        out[name] = out[env]["steps_per_s"] / out[base]["steps_per_s"]
        out[f"{name}_ci"] = ratio_interval(blocks[base], blocks[env])
    with tempfile.TemporaryDirectory() as cache:
        env_vars = {**os.environ, "NUMBA_CACHE_DIR": cache, "OMP_NUM_THREADS": "1"}
        for key in ("first_step_compile_s", "first_step_cached_s"):
            res = subprocess.run([sys.executable, "-c", TRAFFIC_START_CODE], cwd=ROOT, env=env_vars,
                                 capture_output=True, text=True, check=True)
            wall, cpu = res.stdout.strip().splitlines()[-1].split()
            out[key], out[key[:-2] + "_cpu_s"] = float(wall), float(cpu)
    out["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    return out


def _md_traffic(result: dict) -> list[str]:
    t = result["traffic"]
    lines = [f"| traffic alone (round-robin, load {t['load_average_start'][0]:.1f}) | steps/s | ms/step |",
             "|---|---:|---:|"]
    lines += [f"| {label} | {t[label]['steps_per_s']:.1f} | {t[label]['ms_per_step']:.2f} |"
              for label, _, _ in TRAFFIC_RUNS if label in t]
    ci = t["compiled_over_highway_env_ci"]
    bare = t["bare_compiled_over_highway_env_ci"]
    lines += ["", f"The compiled core (`sim=\"compiled\"`): {t['compiled_over_highway_env']:.1f} x highway-env's "
              f"steps/s on `rhs-highway-v0` (95 % [{ci[0]:.1f}, {ci[1]:.1f}]), {t['compiled_over_highway_fast']:.1f} x "
              f"`highway-fast-v0`; without the Kinematics observation {t['bare_compiled_over_highway_env']:.0f} x "
              f"(95 % [{bare[0]:.0f}, {bare[1]:.0f}]) and {t['bare_compiled_over_highway_fast']:.0f} x "
              "`highway-fast-v0`. Its make + reset + first step in a new process: "
              f"{t['first_step_compile_s']:.1f} s ({t.get('first_step_compile_cpu_s', float('nan')):.1f} s of CPU) "
              "with an empty kernel cache (compile), "
              f"{t['first_step_cached_s']:.2f} s with the cache.", ""]
    return lines


def _wait_for_background_compile(cache: Path, t0: float, timeout_s: float = 600.0) -> float:
    """Wait until no background-compile lock is left under ``cache``; the seconds from ``t0`` when it went."""
    from rhs_common.jit import COMPILE_LOCK

    deadline = time.perf_counter() + timeout_s
    while any(cache.rglob(COMPILE_LOCK)) and time.perf_counter() < deadline:
        time.sleep(0.1)
    return time.perf_counter() - t0


def _steps_per_s(env, steps: int, seed: int) -> float:
    """Env steps per second over ``steps`` steps of a fixed action sequence (resets on episode end)."""
    actions = np.random.default_rng(seed).choice([1, 1, 1, 3, 4], size=steps)
    env.reset(seed=seed)
    t0 = time.perf_counter()
    for n, a in enumerate(actions):
        _, _, term, trunc, _ = env.step(int(a))
        if term or trunc:
            env.reset(seed=seed + n + 1)
    return steps / (time.perf_counter() - t0)


def bench_floor(grid_deg: float, seed: int, repeats: int = 30) -> dict:
    """Median ms per 4-radar scan of the IQ path's data-size floor: noise synthesis and range FFT.

    ``synthesis_noise_ms``: :meth:`RadarSystem.synthesize` of an empty scene (every one of the
    4 I C N samples gets CN(0, sigma_n^2) noise and nothing else); ``range_fft_ms``: the
    windowed, zero-padded range FFT of those samples. Every IQ scan (the default fidelity) pays
    both before detection. ``range_noise_ms``: the same empty scene on the range path
    (``fidelity="range"``, :meth:`RadarSystem.synthesize_spectrum`: the searched bins' noise, drawn
    at half rate), that path's floor.
    """
    from rhs_env.array_models import ScanConfig
    from rhs_env.radar import RadarConfig, RadarSystem
    from rhs_env.scatterers import Scatterers

    cfg = RadarConfig(scan=ScanConfig(grid_deg=grid_deg), fidelity="iq")
    radar = RadarSystem(cfg, np.random.default_rng(seed))
    direct = RadarSystem(replace(cfg, fidelity="range"), np.random.default_rng(seed))
    empty = Scatterers(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0, int), np.zeros(0, bool))
    noise, fft, spectrum = [], [], []
    for _ in range(repeats + 1):  # the two paths in turn: load slows both alike
        t0 = time.perf_counter()
        y = radar.synthesize(empty)
        t1 = time.perf_counter()
        radar.range_spectrum(y)
        t2 = time.perf_counter()
        direct.synthesize_spectrum(empty)
        noise.append(t1 - t0)
        fft.append(t2 - t1)
        spectrum.append(time.perf_counter() - t2)
    wf = cfg.waveform
    return {"samples_per_scan": 4 * cfg.scan.slots * wf.chirps_per_slot * wf.samples, "repeats": repeats,
            "synthesis_noise_ms": 1e3 * float(np.median(noise[1:])), "range_fft_ms": 1e3 * float(np.median(fft[1:])),
            "floor_ms": 1e3 * float(np.median(noise[1:]) + np.median(fft[1:])),
            "range_noise_ms": 1e3 * float(np.median(spectrum[1:]))}


def radar_budget(result: dict) -> dict | None:
    """The radar's time per scan that the envs goals allow, beside the floor (None without both sections).

    Radar env >= g_r x the base env's steps/s means ``base - obs + radar <= base / g_r``, i.e.
    radar <= base ms x (1 / g_r - 1) + obs, with obs the Kinematics observation that the base step
    pays and the radar and SLAM envs skip; SLAM env >= g_s x means radar + SLAM <= base ms x (1 / g_s - 1) + obs,
    i.e. radar <= that minus the SLAM stages.
    """
    if "envs" not in result or "floor" not in result:
        return None
    e = result["envs"]
    base = e["rhs-highway-v0"]["ms_per_step"]
    obs = float(e.get("kinematics_observation_ms", 0.0))
    slam = sum((e["rhs-highway-slam-v0"].get("slam_stage_ms") or {}).values())
    radar_ms = base * (1 / GOALS["radar_env_over_base"] - 1) + obs
    radar_slam_ms = base * (1 / GOALS["slam_env_over_base"] - 1) + obs
    return {"base_ms_per_step": base, "kinematics_observation_ms": obs, "radar_budget_ms": radar_ms,
            "radar_slam_budget_ms": radar_slam_ms, "slam_stages_ms": slam,
            "radar_budget_with_slam_ms": radar_slam_ms - slam, "floor_ms": result["floor"]["floor_ms"]}


def bench_load(steps: int, seed: int, grid_deg: float) -> dict:
    """Radar env steps/s quiet and with one busy process (a spin loop), for blas_threads 1 and None."""
    import subprocess

    import gymnasium as gym

    import rhs_env  # noqa: F401

    out: dict[str, Any] = {}
    for threads in (1, None):
        env = gym.make("rhs-highway-radar-v0", radar={"scan": {"grid_deg": grid_deg}}, blas_threads=threads)
        _steps_per_s(env, 3, seed)  # warm-up
        quiet = _steps_per_s(env, steps, seed)
        busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        try:
            time.sleep(0.5)
            loaded = _steps_per_s(env, steps, seed)
        finally:
            busy.kill()
            busy.wait()
        env.close()
        out[f"blas_threads_{threads}"] = {"quiet_steps_per_s": quiet, "loaded_steps_per_s": loaded,
                                          "loaded_over_quiet": loaded / quiet}
    out["loaded_over_quiet"] = out["blas_threads_1"]["loaded_over_quiet"]
    return out


def _make_radar_env(grid_deg: float):
    import gymnasium as gym

    import rhs_env  # noqa: F401

    return gym.make("rhs-highway-radar-v0", radar={"scan": {"grid_deg": grid_deg}})


#: untimed steps of every SubprocVecEnv worker before the ``vec`` section's clock runs
VEC_WARMUP_STEPS = 20


def bench_vec(steps: int, seed: int, grid_deg: float) -> dict:
    """Total env steps/s of the radar env in SubprocVecEnv with 1 and 2 workers (same steps per worker).

    Each worker first steps ``VEC_WARMUP_STEPS`` untimed: a new process loads its cached kernels on their first
    call, some only once the scene reaches them (seconds, once per process), which is start-up, not the rate.
    """
    import functools

    from stable_baselines3.common.vec_env import SubprocVecEnv

    out: dict[str, Any] = {}
    for n in (1, 2):
        venv = SubprocVecEnv([functools.partial(_make_radar_env, grid_deg) for _ in range(n)])
        venv.seed(seed)
        venv.reset()
        rng = np.random.default_rng(seed)
        for _ in range(VEC_WARMUP_STEPS):
            venv.step(rng.choice([1, 3, 4], size=n))
        t0 = time.perf_counter()
        for _ in range(steps):
            venv.step(rng.choice([1, 1, 1, 3, 4], size=n))
        dt = time.perf_counter() - t0
        venv.close()
        out[f"workers_{n}"] = {"steps_per_s": n * steps / dt, "steps_per_worker": steps}
    out["two_workers_over_one"] = out["workers_2"]["steps_per_s"] / out["workers_1"]["steps_per_s"]
    out["machine_scaling"] = machine_scaling()
    return out


#: the ``vec_native`` section's envs and id (the fast SLAM env: the goal's "8 fast envs") and the worker processes
#: of its multi-core contender (the goal's "2 cores")
VEC_NATIVE_ENVS = 8
VEC_NATIVE_ID = "rhs-highway-slam-fast-v0"
VEC_NATIVE_WORKERS = 2


def bench_vec_native(steps: int, seed: int, block: int = 5, n: int = VEC_NATIVE_ENVS,
                     env_id: str = VEC_NATIVE_ID, workers: int = VEC_NATIVE_WORKERS) -> dict:
    """Env steps/s of the native vector env, in one process and in ``workers`` worker processes, against one env
    and gymnasium's ``SyncVectorEnv``.

    The native env in this process (``gym.make_vec(env_id, n, vectorization_mode="vector_entry_point")``), the
    same with ``workers=workers`` (:mod:`rhs_env.vector_workers`; this process waits while they step),
    ``SyncVectorEnv`` of ``n`` and one env take turns, ``block`` vector steps each (the single env: ``block * n``
    steps), after one untimed block each, for ``steps`` env steps each in all; the machine's two-process scaling
    (:func:`machine_scaling`) is the ceiling beside them.

    Args:
        steps: env steps per contender (rounded up to whole blocks).
        seed: reset seed and action seed.
        block: vector steps per turn.
        n: envs of the vector envs.
        env_id: the id.
        workers: worker processes of the multi-core contender.

    Returns:
        Steps/s per contender, ``vec_native_over_single`` (one process) and ``vec_workers_over_single`` (the
        workers) with their 95 % block-bootstrap intervals, ``sync_over_single`` and ``machine_scaling``.
    """
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids)

    single = gym.make(env_id)
    vecs = {"native": gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point"),
            "workers": gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", workers=workers),
            "sync": gym.make_vec(env_id, num_envs=n, vectorization_mode="sync")}
    single.reset(seed=seed)
    single.action_space.seed(seed)
    for v in vecs.values():
        v.reset(seed=seed)
        v.action_space.seed(seed)

    def run_single() -> float:
        t0 = time.perf_counter()
        for _ in range(block * n):
            _, _, term, trunc, _ = single.step(single.action_space.sample())
            if term or trunc:
                single.reset()
        return time.perf_counter() - t0

    def run_vec(v: Any) -> float:
        t0 = time.perf_counter()
        for _ in range(block):
            v.step(v.action_space.sample())
        return time.perf_counter() - t0

    run_single()
    for v in vecs.values():
        run_vec(v)
    times: dict[str, list[float]] = {"single": [], "native": [], "workers": [], "sync": []}
    for _ in range(max(1, -(-steps // (block * n)))):
        times["single"].append(run_single())
        for name, v in vecs.items():
            times[name].append(run_vec(v))
    single.close()
    for v in vecs.values():
        v.close()
    env_steps = block * n * len(times["single"])
    out: dict[str, Any] = {"env_id": env_id, "num_envs": n, "workers": workers, "env_steps_each": env_steps,
                           **{f"{k}_steps_per_s": env_steps / sum(t) for k, t in times.items()}}
    out["vec_native_over_single"] = out["native_steps_per_s"] / out["single_steps_per_s"]
    out["vec_native_over_single_ci"] = ratio_interval(np.array(times["single"]), np.array(times["native"]))
    out["vec_workers_over_single"] = out["workers_steps_per_s"] / out["single_steps_per_s"]
    out["vec_workers_over_single_ci"] = ratio_interval(np.array(times["single"]), np.array(times["workers"]))
    out["sync_over_single"] = out["sync_steps_per_s"] / out["single_steps_per_s"]
    out["machine_scaling"] = machine_scaling()
    return out


def _md_vec_native(r: dict) -> list[str]:
    """The ``vec_native`` section's line."""
    ci = r["vec_native_over_single_ci"]
    line = (f"Native vector env (`vectorization_mode=\"vector_entry_point\"`), {r['num_envs']} x `{r['env_id']}`: "
            f"in one process {r['native_steps_per_s']:.1f} env steps/s against one env's "
            f"{r['single_steps_per_s']:.1f} ({r['vec_native_over_single']:.2f} x [95 % {ci[0]:.2f}, {ci[1]:.2f}]: "
            "its envs in turn on one core)")
    if "vec_workers_over_single" in r:
        wi = r["vec_workers_over_single_ci"]
        line += (f"; with `workers={r['workers']}` {r['workers_steps_per_s']:.1f} ({r['vec_workers_over_single']:.2f} x "
                 f"[95 % {wi[0]:.2f}, {wi[1]:.2f}], goal >= {GOALS['vec_workers_over_single']} x)")
    line += (f"; gymnasium's SyncVectorEnv {r['sync_steps_per_s']:.1f} ({r['sync_over_single']:.2f} x). The ceiling, "
             f"the machine's two-process scaling: {r['machine_scaling']['two_over_one_median']:.2f} x.")
    return [line, ""]


#: the ``targets`` section's envs: (label, id, kwargs); ``highway-fast-v0`` is the yardstick of every ratio
TARGET_RUNS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("highway-fast-v0", "highway-fast-v0", {}),
    ("rhs-highway-slam-v0", "rhs-highway-slam-v0", {"stage_times_in_info": True}),
    ("rhs-highway-slam-fast-v0", "rhs-highway-slam-fast-v0", {"stage_times_in_info": True}),
    ("rhs-highway-radar-fast-v0", "rhs-highway-radar-fast-v0", {"stage_times_in_info": True}),
    ("rhs-highway-v0 bare (compiled)", "bare", {"sim": "compiled"}),
)
#: the ratios of the ``targets`` section: goal key -> the env over ``highway-fast-v0``
TARGET_RATIOS = {"slam_over_highway_fast": "rhs-highway-slam-v0", "slam_fast_over_highway_fast": "rhs-highway-slam-fast-v0"}


class _KernelClock:
    """Seconds spent inside chosen compiled kernels: each ``module.name`` is replaced by a timing wrapper while the
    clock is open (the callers look the kernels up on their module at call time), restored on exit."""

    def __init__(self, targets: dict[str, list[tuple[Any, str]]]) -> None:
        self.targets = targets
        self.seconds = dict.fromkeys(targets, 0.0)
        self._saved: list[tuple[Any, str, Any]] = []

    def __enter__(self) -> _KernelClock:
        for stage, items in self.targets.items():
            for module, name in items:
                fn = getattr(module, name)
                self._saved.append((module, name, fn))
                setattr(module, name, self._timed(stage, fn))
        return self

    def _timed(self, stage: str, fn: Any) -> Any:
        def timed(*args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds[stage] += time.perf_counter() - t0
        return timed

    def __exit__(self, *exc: Any) -> None:
        for module, name, fn in reversed(self._saved):
            setattr(module, name, fn)
        self._saved.clear()


def _kernel_targets() -> dict[str, list[tuple[Any, str]]]:
    """The compiled kernels whose own time is a stage's floor: the traffic core's step, the SLAM's kernels."""
    import slam.core.kernels as slam_kernels
    from rhs_env.traffic import core

    names = [n for n in slam_kernels.__all__ if callable(getattr(slam_kernels, n))]
    return {"traffic": [(core, "simulate")], "slam": [(slam_kernels, n) for n in names]}


def _stage_split(rec: dict[str, Any]) -> dict[str, float]:
    """ms per step of an env's radar and SLAM stages (from its step infos) and of the rest of its step."""
    n = max(rec["n"], 1)
    radar = 1e3 * sum(d.get("total", 0.0) for d in rec["radar"]) / n
    slam = 1e3 * sum(sum(d.values()) for d in rec["slam"]) / n
    step = 1e3 * rec["dt"] / n
    return {"step_ms": step, "radar_ms": radar, "slam_ms": slam, "traffic_and_rest_ms": step - radar - slam}


def _kernel_floors(recs: dict[str, dict[str, Any]], steps: int, seed: int) -> dict[str, dict[str, float]]:
    """ms per step inside the compiled traffic core and SLAM kernels of each env, over ``steps`` untimed steps."""
    floors = {}
    actions = np.random.default_rng(seed + 1).choice([1, 1, 1, 3, 4], size=steps)
    for label, rec in recs.items():
        if label == "highway-fast-v0":
            continue
        clock = _KernelClock(_kernel_targets())
        probe = {**rec, "n": 0, "dt": 0.0, "blocks": [], "radar": [], "slam": []}
        with clock:
            _time_block(probe, actions, seed)
        floors[label] = {f"{k}_kernels_ms": 1e3 * v / steps for k, v in clock.seconds.items()}
    return floors


def bench_targets(steps: int, seed: int, block: int = 5, floor_steps: int = 40) -> dict:
    """The speed targets against highway-env's ``highway-fast-v0``, round-robin in this process, warm.

    :data:`TARGET_RUNS` step ``block`` steps each in turn on the same actions (a load drift slows every env alike)
    after one untimed warm-up block each (and every SLAM kernel compiled or loaded first,
    :func:`slam.gym.precompile.workload`). Each env's step is split into its radar and SLAM stages (its
    ``stage_times_in_info``) and the rest (traffic, wrappers, metrics). Floors beside them, from ``floor_steps``
    further untimed steps: the time inside the compiled traffic core (:func:`rhs_env.traffic.core.simulate`) and
    inside the SLAM's compiled kernels (:mod:`slam.core.kernels`), the arithmetic those stages cannot go below
    as written; the rest of a stage is interpreter work around them. ``rhs-highway-radar-fast-v0`` (no SLAM) and
    the bare compiled traffic (no observation) are the fast SLAM env's floors without its SLAM and radar.

    Args:
        steps: timed env steps per env (rounded up to whole blocks).
        seed: reset and action seed.
        block: steps per turn.
        floor_steps: untimed steps per env of the kernel-floor pass.

    Returns:
        Steps/s, ms per step and the stage split per env; :data:`TARGET_RATIOS` with their 95 % block-bootstrap
        intervals (:func:`ratio_interval`); ``floors`` per env; the load average at the start and the end.
    """
    import warnings

    from rhs_common.jit import watch_compiles
    from slam.gym.precompile import workload

    workload()
    out: dict[str, Any] = {"block_steps": block, "load_average_start": [round(x, 2) for x in os.getloadavg()]}
    actions = np.random.default_rng(seed).choice([1, 1, 1, 3, 4], size=max(steps, block))
    recs = {label: {"env": _make_traffic_env(i, kw), "n": 0, "blocks": [], "dt": 0.0, "slam": [], "radar": []}
            for label, i, kw in TARGET_RUNS}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for rec in recs.values():
            rec["env"].reset(seed=seed)
            _time_block(rec, actions[:2 * block], seed)
            rec.update(n=0, blocks=[], dt=0.0, slam=[], radar=[])
            rec["env"].reset(seed=seed)
        with watch_compiles() as compiled:
            for lo in range(0, steps, block):
                for rec in recs.values():
                    _time_block(rec, actions[lo:lo + block], seed)
        out["kernels_compiled_while_timed"] = sorted(compiled)
        floors = _kernel_floors(recs, floor_steps, seed)
    for label, rec in recs.items():
        out[label] = {"steps": rec["n"], "steps_per_s": rec["n"] / rec["dt"], **_stage_split(rec),
                      "floors": floors.get(label, {})}
        rec["env"].close()
    base = recs["highway-fast-v0"]
    for key, label in TARGET_RATIOS.items():
        out[key] = out[label]["steps_per_s"] / out["highway-fast-v0"]["steps_per_s"]
        out[f"{key}_ci"] = ratio_interval(np.asarray(base["blocks"]), np.asarray(recs[label]["blocks"]))
    out["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    return out


def _md_targets(result: dict) -> list[str]:
    """The ``targets`` section's table, its ratios and the floors."""
    t = result["targets"]
    lines = [f"| against `highway-fast-v0` (one process, round-robin, warm; load {t['load_average_start'][0]:.1f}) "
             "| steps/s | ms/step | radar (ms) | SLAM (ms) | traffic + rest (ms) | floors: traffic core / SLAM kernels "
             "(ms) |", "|---|---:|---:|---:|---:|---:|---|"]
    for label, _, _ in TARGET_RUNS:
        if label not in t:
            continue
        r, f = t[label], t[label].get("floors", {})
        fl = (f"{f['traffic_kernels_ms']:.2f} / {f['slam_kernels_ms']:.2f}" if f else "-")
        lines.append(f"| {label} | {r['steps_per_s']:.1f} | {r['step_ms']:.2f} | {r['radar_ms']:.2f} | "
                     f"{r['slam_ms']:.2f} | {r['traffic_and_rest_ms']:.2f} | {fl} |")
    parts = []
    for key, label in TARGET_RATIOS.items():
        ci = t[f"{key}_ci"]
        parts.append(f"`{label}` {t[key]:.2f} x `highway-fast-v0` (95 % [{ci[0]:.2f}, {ci[1]:.2f}], goal >= "
                     f"{GOALS[key]:g} x)")
    lines += ["", "; ".join(parts) + ". The floors are the time inside the compiled traffic core and inside the "
              "SLAM's compiled kernels per step: what those stages cost as arithmetic; the rest of each stage is "
              "interpreter work around them."]
    if t.get("kernels_compiled_while_timed"):
        lines[-1] += f" Kernels compiled while timed (counted as step time): {', '.join(t['kernels_compiled_while_timed'])}."
    if "floor" in result:
        f = result["floor"]
        lines[-1] += (f" The exact radar's sample floor (noise + range FFT of every IQ sample): {f['floor_ms']:.1f} ms "
                      "per scan; the fast radar synthesises no sample.")
    return lines + [""]


#: the work of :func:`machine_scaling`: an integer sum in the interpreter (no memory traffic, no shared state)
SPIN_CODE = "import time\nt = time.perf_counter()\ns = 0\nfor i in range(8_000_000):\n    s += i\nprint(time.perf_counter() - t)"


def machine_scaling(repeats: int = 5) -> dict[str, Any]:
    """Two processes of :data:`SPIN_CODE` at once against one alone, ``repeats`` times in turn: the
    throughput ratio ``2 t_1 / max(t_2a, t_2b)`` of work that shares nothing, its median and range."""

    def run(n: int) -> list[float]:
        procs = [subprocess.Popen([sys.executable, "-c", SPIN_CODE], stdout=subprocess.PIPE, text=True) for _ in range(n)]
        return [float(p.communicate()[0]) for p in procs]

    ratios = []
    for _ in range(repeats):
        one = run(1)[0]
        ratios.append(2 * one / max(run(2)))
    return {"two_over_one_median": float(np.median(ratios)), "two_over_one_runs": [round(r, 3) for r in ratios]}


#: the ``training`` section's ids: the SLAM env, the base env (the ``ppo_slam_over_base`` goal) and the fast SLAM env
#: (``ppo_fast_over_exact``: its PPO steps/s over the exact SLAM env's, default threads only)
TRAINING_IDS = ("rhs-highway-slam-v0", "rhs-highway-v0", "rhs-highway-slam-fast-v0")
#: the ``training`` section's PPO on the fast SLAM env through the native vector env: envs and worker processes
#: (``ppo_fast_native_over_exact``: its steady rate over the exact SLAM env's with 2 subprocess envs)
NATIVE_PPO_ENVS, NATIVE_PPO_WORKERS = 8, 2


def _fast_hyperparams(folder: str) -> Path:
    """A PPO hyperparameter file in ``folder`` whose fast-SLAM-env entry is the shipped SLAM env's (the same spaces:
    the fast variant changes the radar only), so the two envs train with the same settings."""
    import yaml

    from agents.algos.hyperparams import HYPERPARAMS_DIR
    from rhs_common.input_files import read_yaml

    table = read_yaml(HYPERPARAMS_DIR / "ppo.yml")
    path = Path(folder) / "ppo_fast.yml"
    path.write_text(yaml.safe_dump({TRAINING_IDS[2]: table[TRAINING_IDS[0]]}))
    return path


def bench_training(timesteps: int, seed: int, repeats: int = 3) -> dict:
    """PPO steps/s with 2 subprocess envs on rhs-highway-slam-v0 and on rhs-highway-v0.

    The speed that hours of training run at is the steady rate: env steps per second from the second
    rollout to the end (:class:`agents.algos.callbacks.PhaseTimer`); the ratio goal is on it. The one-off cost of a
    run is reported beside it: ``startup_s``, the whole run's wall time (vector env with its workers and
    kernel warm-up, model, learning) less its timesteps at the steady rate; the first run in the process (the
    SLAM env with ``update_threads_auto``) also carries the process's one-time costs (imports, the forkserver with
    its preloaded modules, the first kernel-cache loads: ~12 s against ~3-4 s for a later run, load ~1). Each env
    id runs with the default (the learner's one torch thread throughout) and with ``update_threads="auto"``
    (the updates also take the cores of the waiting env workers: faster on a quiet machine, much slower on a
    busy one, see :func:`agents.algos.threads.update_threads_for`), the four runs in turn, ``repeats`` rounds: one
    run's steady rate moved by ~15 % between runs, so each rate is pooled over the rounds (their steps over their
    time: the harmonic mean of the rounds' rates, each round having the same steps), and each round's ratio is kept
    (``ratio_runs``). With the default threads, PPO also trains on ``rhs-highway-slam-fast-v0`` in each round:
    ``ppo_fast_over_exact`` is its pooled steady rate over the exact SLAM env's (each round's in
    ``ppo_fast_over_exact_runs``). Last in each round, PPO trains on the fast SLAM env the way its users would on
    2 cores: :data:`NATIVE_PPO_ENVS` envs in the native vector env with :data:`NATIVE_PPO_WORKERS` worker processes
    (``train(..., native_workers=...)``; ``native``); ``ppo_fast_native_over_exact`` is its pooled steady rate over
    the exact SLAM env's with 2 subprocess envs (the goal's "today's PPO on the SLAM env").
    """
    import tempfile

    from agents.algos.train import train

    rounds: dict[str, dict[str, list[dict]]] = {}
    for _ in range(repeats):
        for label, threads in (("update_threads_auto", "auto"), ("default", None)):
            for env_id in TRAINING_IDS if label == "default" else TRAINING_IDS[:2]:
                with tempfile.TemporaryDirectory() as tmp:
                    s = train("ppo", env_id, timesteps, tmp, seed=seed, n_envs=2, eval_freq=10**9,
                              checkpoint_freq=10**9, progress=False, update_threads=threads,
                              hyperparams=_fast_hyperparams(tmp) if env_id == TRAINING_IDS[2] else None)
                rounds.setdefault(label, {}).setdefault(env_id, []).append(_training_record(s, 2))
        with tempfile.TemporaryDirectory() as tmp:  # as many rollouts as the 2-env runs: a steady rate to compare
            s = train("ppo", TRAINING_IDS[2], timesteps * NATIVE_PPO_ENVS // 2, tmp, seed=seed, n_envs=NATIVE_PPO_ENVS,
                      eval_freq=10**9, checkpoint_freq=10**9, progress=False, update_threads=None,
                      hyperparams=_fast_hyperparams(tmp), native_workers=NATIVE_PPO_WORKERS)
        rounds.setdefault("native", {}).setdefault(TRAINING_IDS[2], []).append(
            {**_training_record(s, NATIVE_PPO_ENVS), "workers": NATIVE_PPO_WORKERS})
    native_runs = rounds.pop("native")
    out: dict[str, Any] = {"repeats": repeats}
    for label, by_env in rounds.items():
        out[label] = {env_id: _pooled_training(runs) for env_id, runs in by_env.items()}
        slam, base = out[label]["rhs-highway-slam-v0"], out[label]["rhs-highway-v0"]
        out[label]["ppo_slam_over_base"] = slam["steady_steps_per_s"] / base["steady_steps_per_s"]
        out[label]["ppo_slam_over_base_learn_wall"] = slam["steps_per_s_learn"] / base["steps_per_s_learn"]
        out[label]["ratio_runs"] = [round(a["steady_steps_per_s"] / b["steady_steps_per_s"], 3)
                                    for a, b in zip(by_env["rhs-highway-slam-v0"], by_env["rhs-highway-v0"])]
    for env_id in TRAINING_IDS:
        out[env_id] = out["default"][env_id]
    out["ppo_slam_over_base"] = out["default"]["ppo_slam_over_base"]
    fast, exact = out["default"][TRAINING_IDS[2]], out["default"]["rhs-highway-slam-v0"]
    out["ppo_fast_over_exact"] = fast["steady_steps_per_s"] / exact["steady_steps_per_s"]
    out["ppo_fast_over_exact_runs"] = [round(a["steady_steps_per_s"] / b["steady_steps_per_s"], 3) for a, b in
                                       zip(rounds["default"][TRAINING_IDS[2]], rounds["default"]["rhs-highway-slam-v0"])]
    native = out["native"] = {TRAINING_IDS[2]: _pooled_training(native_runs[TRAINING_IDS[2]])}
    native[TRAINING_IDS[2]]["workers"] = NATIVE_PPO_WORKERS
    out["ppo_fast_native_over_exact"] = native[TRAINING_IDS[2]]["steady_steps_per_s"] / exact["steady_steps_per_s"]
    out["ppo_fast_native_over_exact_runs"] = [round(a["steady_steps_per_s"] / b["steady_steps_per_s"], 3) for a, b in
                                              zip(native_runs[TRAINING_IDS[2]], rounds["default"]["rhs-highway-slam-v0"])]
    return out


def _training_record(summary: dict, n_envs: int) -> dict:
    """One PPO run of :func:`bench_training` from its ``train`` summary: the steady rate (the whole run's when it
    had no steady phase), the rollouts' collect / update split, and the start-up (wall time less the steps at the
    steady rate)."""
    t = summary["timing"]
    whole = t["setup_s"] + t["learn_s"]
    steady = t["steady_steps_per_s"] or summary["steps_per_s"]
    return {"n_envs": n_envs, "timesteps": summary["timesteps"], "update_threads": t["update_threads"],
            "steady_steps_per_s": steady, "steps_per_s_learn": summary["steps_per_s"],
            "steady_collect_s_per_rollout": t["steady_collect_s_per_rollout"],
            "steady_update_s_per_rollout": t["steady_update_s_per_rollout"],
            "setup_s": t["setup_s"], "learn_s": t["learn_s"], "whole_run_s": round(whole, 3),
            "startup_s": round(whole - summary["timesteps"] / steady, 3)}


def _pooled_training(runs: list[dict]) -> dict:
    """One env id's PPO runs pooled: rates as the harmonic mean (equal steps per run), times as the mean, and each
    run's steady rate (``steady_runs``)."""

    def harmonic(key: str) -> float:
        return float(len(runs) / sum(1.0 / r[key] for r in runs))

    pooled = {k: runs[0][k] for k in ("n_envs", "timesteps", "update_threads")}
    pooled.update({k: harmonic(k) for k in ("steady_steps_per_s", "steps_per_s_learn")})
    for k in ("steady_collect_s_per_rollout", "steady_update_s_per_rollout", "setup_s", "learn_s", "whole_run_s",
              "startup_s"):
        vals = [r[k] for r in runs if r[k] is not None]
        pooled[k] = round(float(np.mean(vals)), 3) if vals else None
    pooled["steady_runs"] = [round(r["steady_steps_per_s"], 2) for r in runs]
    return pooled


def _fmt(d: dict | None) -> str:
    return ", ".join(f"{k} {v:.1f}" for k, v in (d or {}).items()) or "-"


def _md_envs(result: dict) -> list[str]:
    e = result["envs"]
    grid = result["settings"]["grid_deg"]
    load = "".join(f", load {e[k][0]:.1f}" for k in ("load_average_start",) if k in e)
    lines = [f"| env (default radar, dtheta = {grid:g} deg; round-robin{load}) | steps/s | ms/step | radar stages (ms) "
             "| SLAM stages (ms) |", "|---|---:|---:|---|---|"]
    for env_id, _, _ in ENV_RUNS:
        if env_id not in e:
            continue
        r = e[env_id]
        lines.append(f"| `{env_id}` | {r['steps_per_s']:.1f} | {r['ms_per_step']:.1f} | "
                     f"{_fmt(r['radar_stage_ms'])} | {_fmt(r['slam_stage_ms'])} |")
    lines += ["", f"The radar adds {e['radar_added_ms']:.1f} ms per step ({e['radar_added_over_base']:.2f} x the "
              f"base step), radar + SLAM {e['radar_slam_added_ms']:.1f} ms ({e['radar_slam_added_over_base']:.2f} x)."]
    if "radar_env_over_base" in e:
        before = (f" (numpy kernels: radar {e['radar_env_over_base_numpy_kernels']:.2f} x, SLAM "
                  f"{e['slam_env_over_base_numpy_kernels']:.2f} x)" if "radar_env_over_base_numpy_kernels" in e else "")
        ci = {k: (f" [{e[f'{k}_env_over_base_ci'][0]:.3f}, {e[f'{k}_env_over_base_ci'][1]:.3f}]"
                  if f"{k}_env_over_base_ci" in e else "") for k in ("radar", "slam")}
        lines.append(f"Steps/s over the base env: radar {e['radar_env_over_base']:.3f} x{ci['radar']} (goal >= "
                     f"{GOALS['radar_env_over_base']}), SLAM {e['slam_env_over_base']:.3f} x{ci['slam']} (goal >= "
                     f"{GOALS['slam_env_over_base']}){before}"
                     + ("; in brackets the 95 % bootstrap interval over the round-robin blocks" if ci["radar"] else "")
                     + (" of every run (runs resampled, then blocks)." if ci["radar"] and e.get("runs") else "."))
    if len(e.get("runs") or []) > 1:
        runs = e["runs"]
        lines.append(f"Pooled over {len(runs)} runs in fresh processes, one after another; each run's radar / SLAM "
                     "ratio (base ms per step, load): "
                     + "; ".join(f"{r['radar_env_over_base']:.3f} / {r['slam_env_over_base']:.3f} "
                                 f"({r['base_ms_per_step']:.1f} ms, {r['load_average_start'][0]:.1f})" for r in runs)
                     + ". The stage table's numpy column comes from the first run.")
    if "stages_before_after" in e:
        lines += ["", "| stage of the SLAM env's step | numpy kernels (ms) | compiled (ms) |", "|---|---:|---:|"]
        for stage, v in e["stages_before_after"].items():
            lines.append(f"| {stage} | {v['numpy']:.2f} | {v['compiled']:.2f} |")
    return [*lines, ""]


def _md_start(result: dict) -> list[str]:
    st = result["start"]
    return [f"First step of `rhs-highway-slam-v0` in a new process (imports, make, reset, one step; load "
            f"{st['load_average_start'][0]:.1f}): {st['cold_s']:.1f} s with an empty kernel cache (goal <= "
            f"{START_GOALS_S['cold_s']:g} s), {st['warm_s']:.1f} s with the cache (goal <= {START_GOALS_S['warm_s']:g} s); "
            f"whole processes {st['cold_process_s']:.1f} s / {st['warm_process_s']:.1f} s"
            + (f"; median of {st['repeats']} (cold: {', '.join(f'{v:.1f}' for v in st['cold_runs_s'])} s)."
               if st.get("repeats", 1) > 1 and "cold_runs_s" in st else ".")
            + (" The cold process' background compile ended "
               f"{', '.join(f'{v:.1f}' for v in st['background_runs_s'])} s after that process started (it compiles "
               "the one-call OMP last: the first scans run its Python body on the compiled stages, the same numbers)."
               if st.get("background_runs_s") else "")
            + (f" A second process started as the cold one ended (its background compile still running): "
               f"{st['next_s']:.1f} s ({', '.join(f'{v:.1f}' for v in st['next_runs_s'])} s). CPU seconds per process "
               f"(cold / next / warm): {_cpu_triples(st['cpu_runs_s'])}; kernels compiled: "
               f"{_cpu_triples(st['kernels_compiled'])}." if "next_s" in st else ""), ""]


def _cpu_triples(d: dict[str, list]) -> str:
    """``a / b / c`` per repeat of the start section's cold, next and warm processes, ``;``-separated."""
    return "; ".join(" / ".join(f"{v:g}" for v in vals) for vals in zip(d["cold"], d["next"], d["warm"]))


def _md_ratios(result: dict) -> list[str]:
    lines = []
    if "load" in result:
        ld = result["load"]
        lines += ["| radar env, one other busy process | quiet steps/s | loaded steps/s | loaded / quiet |",
                  "|---|---:|---:|---:|"]
        for k in ("blas_threads_1", "blas_threads_None"):
            r = ld[k]
            lines.append(f"| `blas_threads={k.rsplit('_', 1)[1]}` | {r['quiet_steps_per_s']:.1f} | "
                         f"{r['loaded_steps_per_s']:.1f} | {r['loaded_over_quiet']:.2f} |")
        lines += [f"Goal: loaded / quiet >= {GOALS['loaded_over_quiet']} with the default (single-threaded BLAS).", ""]
    if "vec" in result:
        v = result["vec"]
        lines += [f"SubprocVecEnv, radar env: 1 worker {v['workers_1']['steps_per_s']:.1f} steps/s, 2 workers "
                  f"{v['workers_2']['steps_per_s']:.1f} steps/s: {v['two_workers_over_one']:.2f} x (goal >= "
                  f"{GOALS['two_workers_over_one']})"
                  + (f"; the machine's own two-process scaling in the same section (a pure-Python loop, "
                     f"{len(v['machine_scaling']['two_over_one_runs'])} tries): median "
                     f"{v['machine_scaling']['two_over_one_median']:.2f} x (range "
                     f"{min(v['machine_scaling']['two_over_one_runs']):.2f}-{max(v['machine_scaling']['two_over_one_runs']):.2f})"
                     if "machine_scaling" in v else "") + ".", ""]
    if "training" in result and "ppo_slam_over_base" in result["training"]:
        t = result["training"]
        if "default" in t:
            lines += ["| PPO, 2 subprocess envs | update threads | steady steps/s | collect / update per rollout (s) "
                      "| start-up (s) |", "|---|---:|---:|---|---:|"]
            for label in ("default", "update_threads_auto"):
                for k in (i for i in TRAINING_IDS if i in t[label]):
                    r = t[label][k]
                    lines.append(f"| `{k}` | {r['update_threads'] or 1} | {r['steady_steps_per_s']:.1f} | "
                                 f"{r['steady_collect_s_per_rollout']:.2f} / {r['steady_update_s_per_rollout']:.2f} | "
                                 f"{r['startup_s']:.1f} |")
            rounds = (f" Pooled over {t['repeats']} rounds of the four runs (steady rates: harmonic mean); each "
                      f"round's ratio: {', '.join(f'{x:.2f}' for x in t['default']['ratio_runs'])} (auto: "
                      f"{', '.join(f'{x:.2f}' for x in t['update_threads_auto']['ratio_runs'])})."
                      if t.get("repeats", 1) > 1 else "")
            lines += [f"PPO on the SLAM env over the base env, steady rate: {t['ppo_slam_over_base']:.3f} x (goal >= "
                      f"{GOALS['ppo_slam_over_base']}; with update_threads='auto': "
                      f"{t['update_threads_auto']['ppo_slam_over_base']:.3f} x). Start-up: the run's wall time less its "
                      "steps at the steady rate." + rounds, ""]
            if "ppo_fast_over_exact" in t:
                text = (f"PPO on the fast SLAM env over the exact SLAM env, steady rate, 2 subprocess envs each: "
                        f"{t['ppo_fast_over_exact']:.2f} x (each round: "
                        f"{', '.join(f'{x:.2f}' for x in t['ppo_fast_over_exact_runs'])}).")
                if "ppo_fast_native_over_exact" in t:
                    r = t["native"][TRAINING_IDS[2]]
                    split = (f"{r['steady_collect_s_per_rollout']:.2f} / {r['steady_update_s_per_rollout']:.2f} s"
                             if r["steady_collect_s_per_rollout"] is not None else "-")
                    text += (f" The fast env's PPO with {r['n_envs']} envs in the native vector env on {r['workers']} "
                             f"worker processes: {r['steady_steps_per_s']:.1f} steps/s (collect / update per rollout "
                             f"{split}), "
                             f"{t['ppo_fast_native_over_exact']:.2f} x the exact env's with 2 subprocess envs (goal >= "
                             f"{GOALS['ppo_fast_native_over_exact']:g}; each round: "
                             f"{', '.join(f'{x:.2f}' for x in t['ppo_fast_native_over_exact_runs'])}).")
                lines[-1:-1] = [text]
        else:
            lines += ["| PPO, 2 subprocess envs | steps/s |", "|---|---:|"]
            lines += [f"| `{k}` | {t[k]['steps_per_s']:.1f} |" for k in ("rhs-highway-slam-v0", "rhs-highway-v0")]
            lines += [f"PPO on the SLAM env over the base env: {t['ppo_slam_over_base']:.2f} x (goal >= "
                      f"{GOALS['ppo_slam_over_base']}).", ""]
    return lines


def markdown(result: dict) -> str:
    """The README tables of a benchmark result."""
    runs = result.get("section_runs", {})
    when = "; ".join(f"{k} {v['date']}, load {v['load_average'][0]:.1f}" for k, v in runs.items())
    lines = [f"Measured by `python scripts/benchmark.py` on {result['machine']['cpus']} CPU cores "
             + (f"(per section: {when})." if when else f"(load average at start {result['machine']['load_average']})."),
             ""]
    if "envs" in result:
        lines += _md_envs(result)
    if "start" in result:
        lines += _md_start(result)
    budget = radar_budget(result)
    if budget is not None:
        f = result["floor"]
        lines += [f"The IQ path's floor per 4-radar scan ({f['samples_per_scan']} samples): noise "
                  f"{f['synthesis_noise_ms']:.1f} ms + range FFT {f['range_fft_ms']:.1f} ms = {f['floor_ms']:.1f} ms, "
                  "before detection and OMP"
                  + (f"; the range path's (`fidelity=\"range\"`: the searched bins' noise drawn directly, at half rate) "
                     f"{f['range_noise_ms']:.1f} ms" if "range_noise_ms" in f else "")
                  + f". The goals leave the radar {budget['radar_budget_ms']:.1f} ms "
                  f"(radar env >= {GOALS['radar_env_over_base']} x) and {budget['radar_budget_with_slam_ms']:.1f} ms "
                  f"beside the SLAM's {budget['slam_stages_ms']:.1f} ms (SLAM env >= {GOALS['slam_env_over_base']} x) "
                  f"of a {budget['base_ms_per_step']:.1f} ms base step"
                  + (f" (the radar and SLAM envs skip its {budget['kinematics_observation_ms']:.1f} ms Kinematics "
                     "observation)" if budget.get("kinematics_observation_ms") else "") + ".", ""]
    lines += _md_ratios(result)
    if "traffic" in result:
        lines += _md_traffic(result)
    if "targets" in result:
        lines += _md_targets(result)
    if "vec_native" in result:
        lines += _md_vec_native(result["vec_native"])
    if "radar" in result:
        lines += ["| one 4-radar scan, typical scene | synthesis (ms) | range/CFAR (ms) | OMP (ms) | total (ms) |",
                  "|---|---:|---:|---:|---:|"]
        for ant, r in result["radar"].items():
            st = r["stage_ms_median"]
            lines.append(f"| {ant} | {st.get('synthesis', float('nan')):.1f} | {st.get('range_cfar', float('nan')):.1f} "
                         f"| {st.get('omp', float('nan')):.1f} | {st.get('total', float('nan')):.1f} |")
        lines.append("")
    if "patterns" in result:
        p = result["patterns"]
        n = f", n = {p['refractive_index']:g}" if "refractive_index" in p else ""
        lines += [f"| pattern library (M = 60, dtheta = 1 deg{n}, 2 workers) | build time (s) |", "|---|---:|"]
        for m in ("fast", "sdr"):
            if m in p:
                note = f" ({p[m]['note']})" if p[m].get("extrapolated") else ""
                lines.append(f"| {m}{note} | {p[m]['build_s']:.1f} |")
        if "fast_vs_previous" in p:
            v = p["fast_vs_previous"]
            lines.append(f"| fast, previous settings / today's on the same {len(v['angles_deg'])} grids (ratio) | "
                         f"{v['wall_ratio']:.2f} x wall, {v['cpu_ratio']:.2f} x CPU |")
        g = result.get("goals", {}).get("library_build_s")
        if g:
            lines.append(f"Goal: the fast library in <= {g['goal']:g} s with every grid pointing within half a grid: "
                         f"{'met' if g['met'] else 'NOT met'} ({g['value']:.1f} s, worst pointing "
                         f"{g['worst_pointing_error_deg']:.2f} deg, worst two-way PSLR {g['worst_pslr_db']:.2f} dB).")
        lines.append("")
    return "\n".join(lines)


def ratio_interval_runs(base_runs: list[np.ndarray], env_runs: list[np.ndarray], resamples: int = 2000,
                        seed: int = 0) -> list[float]:
    """95 % two-level bootstrap interval of ``sum(base) / sum(env)`` over several runs' round-robin blocks: runs
    resampled with replacement, then each picked run's blocks in pairs (:func:`ratio_interval`), so a spread
    between runs widens the interval as the spread between blocks does."""
    rng = np.random.default_rng(seed)
    ratios = np.empty(resamples)
    for i in range(resamples):
        base = env = 0.0
        for r in rng.integers(0, len(base_runs), len(base_runs)):
            pick = rng.integers(0, base_runs[r].size, base_runs[r].size)
            base += base_runs[r][pick].sum()
            env += env_runs[r][pick].sum()
        ratios[i] = base / env
    return [round(float(x), 4) for x in np.percentile(ratios, [2.5, 97.5])]


def _run_section(sec: str, args: argparse.Namespace) -> dict:
    if sec == "envs":
        if args.env_runs > 1:
            return bench_envs_runs(args.steps, args.seed, args.grid_deg, block=args.block, runs=args.env_runs)
        return bench_envs(args.steps, args.seed, args.grid_deg, block=args.block)
    if sec == "start":
        return bench_start(args.start_repeats)
    if sec == "floor":
        return bench_floor(args.grid_deg, args.seed)
    if sec == "load":
        return bench_load(args.steps, args.seed, args.grid_deg)
    if sec == "vec":
        return bench_vec(args.steps, args.seed, args.grid_deg)
    if sec == "vec_native":
        return bench_vec_native(args.steps, args.seed, block=args.block)
    if sec == "radar":
        from rhs_studies.bench.benchmark_radar import benchmark_radar

        return {f"{a}_{f}": benchmark_radar(antenna=a, grid_deg=args.grid_deg, fidelity=f)
                for a in ("rhs", "phased") for f in ("iq", "range")}
    if sec == "patterns":
        from rhs_studies.bench.benchmark_patterns import benchmark_patterns

        return benchmark_patterns(grid_deg=1.0)
    if sec == "traffic":
        return bench_traffic(args.steps, args.seed, block=args.block)
    if sec == "targets":
        return bench_targets(args.steps, args.seed, block=args.block)
    return bench_training(args.train_steps, args.seed, args.train_repeats)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sections", nargs="+", choices=SECTIONS, default=list(SECTIONS))
    ap.add_argument("--steps", type=int, default=300, help="env steps per measurement (envs, load, vec)")
    ap.add_argument("--block", type=int, default=5, help="steps of one env before the next one's turn (envs)")
    ap.add_argument("--env-runs", type=int, default=3,
                    help="envs: runs in fresh processes, pooled (1: one run in this process)")
    ap.add_argument("--grid-deg", type=float, default=1.0)
    ap.add_argument("--train-steps", type=int, default=1024, help="PPO timesteps per env id (training section)")
    ap.add_argument("--train-repeats", type=int, default=3,
                    help="training: rounds of the four PPO runs, pooled")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--start-repeats", type=int, default=3,
                    help="cold and warm starts measured (start section; the median is the result)")
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmark.json"))
    args = ap.parse_args(argv)
    if args.start_repeats < 1:
        ap.error("--start-repeats must be at least 1")
    if args.env_runs < 1:
        ap.error("--env-runs must be at least 1")
    if args.train_repeats < 1:
        ap.error("--train-repeats must be at least 1")
    # the timed sections share no core with a background kernel compile (slam.gym.precompile); the start
    # section's processes measure it as a new user meets it (bench_start switches it back on there). The
    # caller's setting is restored at the end (a test calling main() would otherwise leave it off for the rest)
    from rhs_common.jit import BACKGROUND_SWITCH

    before = os.environ.get(BACKGROUND_SWITCH)
    os.environ[BACKGROUND_SWITCH] = "0"
    try:
        return _run_sections(args, argv)
    finally:
        if before is None:
            os.environ.pop(BACKGROUND_SWITCH, None)
        else:
            os.environ[BACKGROUND_SWITCH] = before


def _run_sections(args: argparse.Namespace, argv: list[str] | None) -> int:
    """The sections of ``args`` run and written (:func:`main`)."""
    started = time.time()
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    result: dict = {
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "platform": platform.platform(),
                    "load_average": [round(x, 2) for x in os.getloadavg()]},
        "settings": vars(args), "commit": commit, "command": " ".join(command_line(__file__)),
    }
    out = Path(args.out)
    # sections not run now are kept from an existing file, with when and under what load they ran
    previous = json.loads(out.read_text()) if out.exists() else {}
    runs = previous.get("section_runs", {})
    for sec in SECTIONS:
        if sec in args.sections:
            load = [round(x, 2) for x in os.getloadavg()]
            print(f"benchmark: {sec} (load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}) ...", file=sys.stderr)
            result[sec] = _run_section(sec, args)
            runs[sec] = {"date": time.strftime("%Y-%m-%d %H:%M"), "load_average": load, "commit": commit}
        elif sec in previous:
            result[sec] = previous[sec]
            runs.setdefault(sec, {"date": "an earlier run",
                                  "load_average": previous.get("machine", {}).get("load_average", [float("nan")])})
    result["section_runs"] = {k: runs[k] for k in SECTIONS if k in runs}
    result["goals"] = _goals(result)
    result["radar_budget"] = radar_budget(result)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json(out, result, __file__, args, started, argv=argv)  # timings: provenance, no fingerprint
    out.with_suffix(".md").write_text(markdown(result) + "\n")
    print(json.dumps(result, indent=2, default=float))
    for k, g in result["goals"].items():
        ci = f" [95 % {g['ci'][0]:.3f}, {g['ci'][1]:.3f}]" if "ci" in g else ""
        print(f"{k}: {g['value']:.3f}{ci} (goal {g.get('sense', '>=')} {g['goal']}) {'met' if g['met'] else 'NOT met'}",
              file=sys.stderr)
    return 0


def _goals(result: dict) -> dict:
    """Each speed ratio present in the result, its goal and whether it is met."""
    found: dict[str, dict[str, Any]] = {}
    for sec in ("envs", "load", "vec", "training", "vec_native", "targets"):
        for k, goal in GOALS.items():
            if k in result.get(sec, {}):
                v = float(result[sec][k])
                found[k] = {"value": v, "goal": goal, "met": v >= goal}
                if f"{k}_ci" in result[sec]:  # the 95 % interval over the round-robin blocks
                    found[k]["ci"] = result[sec][f"{k}_ci"]
    for k, goal in START_GOALS_S.items():
        if k in result.get("start", {}):
            v = float(result["start"][k])
            found[f"start_{k}"] = {"value": v, "goal": goal, "sense": "<=", "met": v <= goal}
    fast = result.get("patterns", {}).get("fast")
    if fast and not fast.get("extrapolated"):
        v, pointing_ok = float(fast["build_s"]), fast["worst_pointing_error_deg"] <= 0.5 * result["patterns"]["grid_deg"]
        found["library_build_s"] = {"value": v, "goal": LIBRARY_GOAL_S, "sense": "<=", "met": v <= LIBRARY_GOAL_S and pointing_ok,
                                    "worst_pointing_error_deg": fast["worst_pointing_error_deg"],
                                    "worst_pslr_db": fast["worst_pslr_db"]}
    return found


if __name__ == "__main__":
    sys.exit(main())
