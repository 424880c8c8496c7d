"""Env steps/s of the RLlib backend against the number of env runners (needs the [rllib] extra).

For each ``--runners`` value, PPO (``agents/hyperparams/ppo.yml`` entry of ``--env``,
train batch ``n_steps * n_envs`` whatever the runner count) runs ``--iterations``
iterations on a local Ray instance; the rate is env steps over wall time of the
iterations after the first (the first includes actor start-up and warm-up).
An iteration = sampling (parallel over runners) + the PPO update (one learner, in
the driver), so only the sampling part scales. Writes ``--out`` (JSON with commit,
command line, config, per-iteration times).

    . .venv-rllib/bin/activate
    OMP_NUM_THREADS=1 python scripts/benchmark_rllib.py --runners 1 2 --iterations 3
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--env", default="rhs-highway-slam-v0")
    ap.add_argument("--env-kwargs", default='{"radar": {"scan": {"grid_deg": 5}}}')
    ap.add_argument("--runners", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "results" / "rllib_scaling.json"))
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from agents.rllib import init_ray
    from agents.train import load_hyperparams, train_rllib_backend

    env_kwargs = json.loads(args.env_kwargs)
    hp = load_hyperparams("ppo", args.env)
    batch = int(hp["n_steps"]) * int(hp.get("n_envs", 1))
    rows = []
    # one Ray instance for every row (sized for the largest): a restart per row costs start-up time
    init_ray(None, max(args.runners))
    for n in args.runners:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            s = train_rllib_backend(args.env, batch * args.iterations, tmp, env_kwargs=env_kwargs, num_env_runners=n,
                                    eval_freq=0, checkpoint_freq=0, progress=False)  # fmt: skip
            total = time.perf_counter() - t0
        it = s["iterations"]
        later = it[1:] or it
        steps = later[-1]["env_steps"] - (it[0]["env_steps"] if len(it) > 1 else 0)
        rate = steps / sum(r["wall_s"] for r in later)
        rows.append({"num_env_runners": n, "env_steps_per_s": round(rate, 2), "iterations": it,
                     "total_wall_s_incl_actor_start": round(total, 1)})  # fmt: skip
        print(f"runners={n}: {rate:.1f} env steps/s (iterations 2..{len(it)}), {total:.0f} s in all", file=sys.stderr)
    import ray

    ray.shutdown()
    result = {
        "commit": _commit(),
        "command": " ".join([Path(sys.argv[0]).name, *(argv if argv is not None else sys.argv[1:])]),
        "env_id": args.env,
        "env_kwargs": env_kwargs,
        "train_batch": batch,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "load_average_1m_at_end": os.getloadavg()[0]},  # fmt: skip
        "rows": rows,
        "note": "shared, loaded machine: compare the rows with each other, not with other runs",
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps([{k: r[k] for k in ("num_env_runners", "env_steps_per_s")} for r in rows]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
