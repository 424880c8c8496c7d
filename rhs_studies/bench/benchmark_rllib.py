"""Ray RLlib sampling throughput: PPO steps/s with 1 and 2 env runners, in one run.

    .venv-rllib/bin/python scripts/benchmark_rllib.py [--env rhs-highway-slam-v0] [--iterations 4]
        [--runners 1 2] [--out results/benchmark_rllib.json]

Needs the ``rllib`` extra (its own environment, see docs/installation.md). For each number
of env runners R, ``rhs-slam train --backend rllib`` runs PPO from the shipped
``agents/hyperparams/ppo.yml`` entry (train batch ``n_steps x n_envs`` = 256 env
steps, whatever R) for ``--iterations`` iterations; the first iteration (Ray
actors starting, the env built in each) is reported apart and left out of the
steady-state rate

    steps/s(R) = sum of env steps / sum of wall time over iterations 2..N.

The speed-up is steps/s(2) / steps/s(1). Each iteration samples (R actors in
parallel, one env each) and then updates the policy in the driver: the update
does not scale with R, so the speed-up is below R even on idle cores. The load
average at the start and at the end is recorded beside the figures: on a
2-core machine, a busy neighbour process takes the second runner's core.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from rhs_studies.kit.provenance import write_json

DEFAULT_ENV_KWARGS = {"radar": {"scan": {"grid_deg": 5}}}


def train_batch(env_id: str) -> int:
    """Env steps per PPO iteration of the ``ppo.yml`` entry: ``n_steps * n_envs``."""
    from agents.algos.train import load_hyperparams

    hp = load_hyperparams("ppo", env_id)
    return int(hp["n_steps"]) * int(hp.get("n_envs", 1))


def run_once(env_id: str, runners: int, iterations: int, batch: int, env_kwargs: dict, seed: int) -> dict:
    """Train ``iterations`` PPO iterations with ``runners`` env runners; steps/s excluding the first."""
    from agents.algos.train import train_rllib_backend

    with tempfile.TemporaryDirectory() as out:
        summary = train_rllib_backend(env_id, iterations * batch, out, seed=seed, env_kwargs=env_kwargs,
                                      num_env_runners=runners, checkpoint_freq=0, progress=False)  # fmt: skip
    its = summary["iterations"]
    steady = its[1:] or its
    steps = its[-1]["env_steps"] - (its[0]["env_steps"] if len(its) > 1 else 0)
    wall = sum(r["wall_s"] for r in steady)
    return {
        "runners": runners,
        "iterations": len(its),
        "first_iteration_s": round(its[0]["wall_s"], 2),
        "steady_env_steps": steps,
        "steady_wall_s": round(wall, 2),
        "steps_per_s": round(steps / wall, 2),
        "iteration_wall_s": [round(r["wall_s"], 2) for r in its],
    }


def markdown(res: dict) -> str:
    rows = [f"| {r['runners']} | {r['steps_per_s']:.1f} | {r['first_iteration_s']:.1f} | "
            f"{r['steady_env_steps']} steps in {r['steady_wall_s']:.1f} s |" for r in res["runs"]]  # fmt: skip
    speedup = f"{res['speedup']:.2f}x" if res.get("speedup") is not None else "n/a"
    return "\n".join([
        f"`python scripts/benchmark_rllib.py` (in `.venv-rllib`) on `{res['env_id']}` with env kwargs "
        f"`{json.dumps(res['env_kwargs'])}`, PPO train batch {res['train_batch']} env steps, {res['iterations']} "
        "iterations per row "
        f"(the first, Ray actors starting, left out of steps/s); {res['cpus']} cores, load average "
        f"{res['load_start']:.1f} at the start and {res['load_end']:.1f} at the end.",
        "",
        "| env runners | steps/s | first iteration (s) | steady state |",
        "|---:|---:|---:|---|",
        *rows,
        "",
        f"2 runners / 1 runner: **{speedup}**.",
    ]) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--env", default="rhs-highway-slam-v0")
    ap.add_argument("--env-kwargs", type=json.loads, default=DEFAULT_ENV_KWARGS, help="JSON")
    ap.add_argument("--iterations", type=int, default=4, help="PPO iterations per row (>= 2)")
    ap.add_argument("--runners", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="results/benchmark_rllib.json")
    a = ap.parse_args(argv)
    if a.iterations < 2:
        ap.error(f"--iterations must be >= 2 (the first is left out), got {a.iterations}")
    if any(r < 1 for r in a.runners):
        ap.error(f"--runners must be >= 1, got {a.runners}")
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # before numpy / torch load: one BLAS thread per process
    from agents.algos.rllib import init_ray, require_ray

    require_ray()
    started = time.time()
    load_start = os.getloadavg()[0]
    batch = train_batch(a.env)
    init_ray(None, max(a.runners))  # one Ray instance for every row: a restart per row would cost start-up time
    try:
        runs = [run_once(a.env, r, a.iterations, batch, a.env_kwargs, a.seed) for r in a.runners]
    finally:
        import ray

        ray.shutdown()
    by = {r["runners"]: r["steps_per_s"] for r in runs}
    res = {
        "env_id": a.env, "env_kwargs": a.env_kwargs, "iterations": a.iterations, "train_batch": batch,
        "cpus": os.cpu_count(),
        "load_start": load_start, "load_end": os.getloadavg()[0], "runs": runs,
        "speedup": round(by[2] / by[1], 3) if 1 in by and 2 in by else None,
    }  # fmt: skip
    out = Path(a.out)
    write_json(out, res, __file__, vars(a), started, argv=sys.argv[1:] if argv is None else argv)
    out.with_suffix(".md").write_text(markdown(res))
    print(markdown(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
