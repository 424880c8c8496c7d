"""Speed of every stage of rhs-slam, in one run, as JSON (never in timed tests).

Sections (``--sections``, default all):

* ``envs``: steps per second of ``rhs-highway-v0``, ``rhs-highway-radar-v0`` and
  ``rhs-highway-slam-v0`` measured back to back on the same seeds and actions,
  with the radar's time per stage (synthesis, range/CFAR, OMP) and the SLAM's
  time per stage (registration, association, RBPF) at 100 particles;
* ``radar``: one 4-radar scan of a typical scene (scripts/benchmark_radar.py);
* ``patterns``: time to build the dtheta = 1 deg default library with each
  method (scripts/benchmark_patterns.py; SDR on a subset, extrapolated);
* ``training``: PPO training steps per second with 1 and 2 subprocess envs.

    python scripts/benchmark.py --out results/benchmark.json      # also writes results/benchmark.md
    python scripts/benchmark.py --sections envs --steps 20   # keeps the other sections of --out
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))
SECTIONS = ("envs", "radar", "patterns", "training")


def _mean_times(dicts: list[dict]) -> dict:
    keys = sorted({k for d in dicts for k in d})
    return {k: float(np.mean([d.get(k, 0.0) for d in dicts])) * 1e3 for k in keys}


def bench_envs(steps: int, seed: int, grid_deg: float) -> dict:
    """Steps/s of the three highway ids on identical seeds and action sequences."""
    import gymnasium as gym

    import rhs_env  # noqa: F401

    out = {}
    radar = {"scan": {"grid_deg": grid_deg}}
    for env_id, kwargs in (
        ("rhs-highway-v0", {}),
        ("rhs-highway-radar-v0", {"radar": radar, "stage_times_in_info": True}),
        ("rhs-highway-slam-v0", {"radar": radar, "stage_times_in_info": True}),
    ):
        env = gym.make(env_id, **kwargs)
        env.reset(seed=seed)
        actions = np.random.default_rng(seed).choice([1, 1, 1, 3, 4], size=steps)
        radar_times, slam_times = [], []
        t0 = time.perf_counter()
        n = 0
        for a in actions:
            _, _, term, trunc, info = env.step(int(a))
            n += 1
            if "slam_stage_times" in info:
                slam_times.append(info["slam_stage_times"])
            if "radar_stage_times" in info:
                radar_times.append(info["radar_stage_times"])
            if term or trunc:
                env.reset(seed=seed + n)
        dt = time.perf_counter() - t0
        env.close()
        out[env_id] = {
            "steps": n,
            "steps_per_s": n / dt,
            "ms_per_step": 1e3 * dt / n,
            "radar_stage_ms": _mean_times(radar_times) if radar_times else None,
            "slam_stage_ms": _mean_times(slam_times) if slam_times else None,
        }
    base = out["rhs-highway-v0"]["ms_per_step"]
    out["radar_added_ms"] = out["rhs-highway-radar-v0"]["ms_per_step"] - base
    out["radar_slam_added_ms"] = out["rhs-highway-slam-v0"]["ms_per_step"] - base
    out["radar_added_over_base"] = out["radar_added_ms"] / base
    out["radar_slam_added_over_base"] = out["radar_slam_added_ms"] / base
    return out


def bench_training(timesteps: int, seed: int) -> dict:
    """PPO steps/s on rhs-highway-slam-v0 with 1 and 2 subprocess envs."""
    import tempfile

    from agents.train import train

    out = {}
    for n_envs in (1, 2):
        with tempfile.TemporaryDirectory() as tmp:
            s = train("ppo", "rhs-highway-slam-v0", timesteps, tmp, seed=seed, n_envs=n_envs,
                      eval_freq=10**9, checkpoint_freq=10**9, progress=False)
        out[f"n_envs_{n_envs}"] = {"timesteps": s["timesteps"], "steps_per_s": s["steps_per_s"], "wall_s": s["wall_time_s"]}
    return out


def _fmt(d: dict | None) -> str:
    return ", ".join(f"{k} {v:.1f}" for k, v in (d or {}).items()) or "-"


def markdown(result: dict) -> str:
    """The README table of a benchmark result."""
    runs = result.get("section_runs", {})
    when = "; ".join(f"{k} {v['date']}, load {v['load_average'][0]:.1f}" for k, v in runs.items())
    lines = [f"Measured by `python scripts/benchmark.py` on {result['machine']['cpus']} CPU cores "
             + (f"(per section: {when})." if when else f"(load average at start {result['machine']['load_average']})."),
             ""]
    if "envs" in result:
        e = result["envs"]
        lines += ["| env (default radar, dtheta = %g deg) | steps/s | ms/step | radar stages (ms) | SLAM stages (ms) |"
                  % result["settings"]["grid_deg"], "|---|---:|---:|---|---|"]
        for env_id in ("rhs-highway-v0", "rhs-highway-radar-v0", "rhs-highway-slam-v0"):
            r = e[env_id]
            lines.append(f"| `{env_id}` | {r['steps_per_s']:.1f} | {r['ms_per_step']:.1f} | "
                         f"{_fmt(r['radar_stage_ms'])} | {_fmt(r['slam_stage_ms'])} |")
        lines += ["", f"The radar adds {e['radar_added_ms']:.1f} ms per step ({e['radar_added_over_base']:.2f} x the "
                  f"base step), radar + SLAM {e['radar_slam_added_ms']:.1f} ms ({e['radar_slam_added_over_base']:.2f} x).", ""]
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
        lines.append("")
    if "training" in result:
        lines += ["| PPO on `rhs-highway-slam-v0` | steps/s |", "|---|---:|"]
        for k, r in result["training"].items():
            lines.append(f"| {k.replace('n_envs_', '')} subprocess env(s) | {r['steps_per_s']:.1f} |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sections", nargs="+", choices=SECTIONS, default=list(SECTIONS))
    ap.add_argument("--steps", type=int, default=40, help="env steps per id (envs section)")
    ap.add_argument("--grid-deg", type=float, default=1.0)
    ap.add_argument("--train-steps", type=int, default=1024, help="PPO timesteps per setting (training section)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmark.json"))
    args = ap.parse_args(argv)

    result: dict = {
        "machine": {
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "load_average": [round(x, 2) for x in os.getloadavg()],
        },
        "settings": vars(args),
    }
    if "envs" in args.sections:
        print("benchmark: envs ...", file=sys.stderr)
        result["envs"] = bench_envs(args.steps, args.seed, args.grid_deg)
    if "radar" in args.sections:
        print("benchmark: radar ...", file=sys.stderr)
        from benchmark_radar import benchmark_radar

        result["radar"] = {a: benchmark_radar(antenna=a, grid_deg=args.grid_deg) for a in ("rhs", "phased")}
    if "patterns" in args.sections:
        print("benchmark: patterns ...", file=sys.stderr)
        from benchmark_patterns import benchmark_patterns

        result["patterns"] = benchmark_patterns(grid_deg=1.0)
    if "training" in args.sections:
        print("benchmark: training ...", file=sys.stderr)
        result["training"] = bench_training(args.train_steps, args.seed)
    out = Path(args.out)
    # sections not run now are kept from an existing file, with when and under what load they ran
    previous = json.loads(out.read_text()) if out.exists() else {}
    runs = previous.get("section_runs", {})
    for sec in SECTIONS:
        if sec in args.sections:
            runs[sec] = {"date": time.strftime("%Y-%m-%d %H:%M"), "load_average": result["machine"]["load_average"]}
        elif sec in previous:
            result[sec] = previous[sec]
            runs.setdefault(sec, {"date": "an earlier run",
                                  "load_average": previous.get("machine", {}).get("load_average", [float("nan")])})
    result["section_runs"] = {k: runs[k] for k in SECTIONS if k in runs}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2, default=float))
    out.with_suffix(".md").write_text(markdown(result) + "\n")
    print(json.dumps(result, indent=2, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
