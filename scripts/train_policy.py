"""Train the shipped driving policies (PPO) and record how they were made.

* ``agents/data/ppo_rhs_highway_slam.zip``: trained on ``rhs-highway-slam-v0``
  (point cloud + SLAM estimate), SLAM in the loop at every step;
* ``agents/data/ppo_rhs_highway_truth.zip``: the same algorithm, hyperparameters
  (``agents/hyperparams/ppo.yml``) and number of steps on ``rhs-highway-v0``
  (ground-truth Kinematics), for comparison.

Each zip gets a JSON beside it (env id, ``env_kwargs``, timesteps, wall time,
hyperparameters) that ``rhs-slam evaluate`` / ``rhs-slam demo`` read to rebuild
the env the policy was trained on. ``results/train_policy.json`` records both
runs (timesteps, wall time, steps/s, machine). TensorBoard logs, checkpoints,
monitor CSVs and evaluations stay in ``--work-dir`` (default ``runs/policies``,
not shipped).

    OMP_NUM_THREADS=1 python scripts/train_policy.py                  # both policies
    python scripts/train_policy.py --only slam --timesteps 20000 --n-envs 2
    python scripts/train_policy.py --slam-env-kwargs '{"radar": {"scan": {"grid_deg": 5}}}'

``--slam-env-kwargs`` (JSON) trains the SLAM policy on a cheaper configuration
of the same env id; it is saved beside the policy and used by default when the
policy is evaluated or demonstrated.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))
from _provenance import write_json

DATA = ROOT / "agents" / "data"
SLAM_ID, TRUTH_ID = "rhs-highway-slam-v0", "rhs-highway-v0"
TARGETS = {
    "slam": (SLAM_ID, DATA / "ppo_rhs_highway_slam.zip"),
    "truth": (TRUTH_ID, DATA / "ppo_rhs_highway_truth.zip"),
}
MAX_BYTES = 1_000_000


def _machine() -> dict:
    import torch

    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "torch": torch.__version__,
        "load_average_1m_at_start": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
    }


def _registration_weights() -> dict:
    from slam.cnn_registration import DEFAULT_WEIGHTS

    return {"path": str(Path(DEFAULT_WEIGHTS).relative_to(ROOT)), "exists": Path(DEFAULT_WEIGHTS).exists()}


def train_one(name: str, args: argparse.Namespace, env_kwargs: dict) -> dict:
    from agents.train import metadata_path, train

    env_id, target = TARGETS[name]
    target = Path(args.data_dir) / target.name
    work = Path(args.work_dir) / name
    if work.exists():
        shutil.rmtree(work)
    print(
        f"train_policy: {name}: PPO on {env_id}, {args.timesteps} steps, {args.n_envs} envs -> {target}",
        file=sys.stderr,
    )
    t0 = time.perf_counter()
    summary = train(
        "ppo",
        env_id,
        args.timesteps,
        work,
        seed=args.seed,
        n_envs=args.n_envs,
        env_kwargs=env_kwargs,
        eval_freq=args.eval_freq,
        eval_episodes=args.eval_episodes,
        checkpoint_freq=args.checkpoint_freq,
        progress=not args.no_progress,
    )
    total = time.perf_counter() - t0
    source = work / ("best_model.zip" if args.ship == "best" and (work / "best_model.zip").exists() else "model.zip")
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(source, target)
    size = target.stat().st_size
    if size >= MAX_BYTES:
        raise SystemExit(f"train_policy: {target} is {size} bytes, over the {MAX_BYTES} byte limit")
    meta = {
        **summary,
        "shipped": args.ship if source.name != "model.zip" else "final",
        "model": _display(target),
        "total_wall_time_s": round(total, 1),
        "trained_by": "scripts/train_policy.py",
        "zip_bytes": size,
    }
    metadata_path(target).write_text(json.dumps(meta, indent=2) + "\n")
    print(
        json.dumps({k: meta[k] for k in ("env_id", "timesteps", "wall_time_s", "steps_per_s", "zip_bytes")}),
        file=sys.stderr,
    )
    return meta


def _display(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(ROOT))
    except ValueError:
        return str(path)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", choices=tuple(TARGETS), default=None, help="train one policy only")
    ap.add_argument(
        "--timesteps", type=int, default=None, help="env steps per policy (default: n_timesteps of ppo.yml)"
    )
    ap.add_argument("--n-envs", type=int, default=2, help="subprocess envs (default 2)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--slam-env-kwargs", default="{}", help="JSON env kwargs of the SLAM policy's env (saved with it)")
    ap.add_argument("--eval-freq", type=int, default=5000, help="env steps between evaluations (0: none)")
    ap.add_argument("--eval-episodes", type=int, default=2)
    ap.add_argument("--checkpoint-freq", type=int, default=5000)
    ap.add_argument("--ship", choices=("final", "best"), default="final", help="which model to ship")
    ap.add_argument("--work-dir", default=str(ROOT / "runs" / "policies"))
    ap.add_argument("--data-dir", default=str(DATA), help="where the policy zips go (default: agents/data)")
    ap.add_argument("--record", default=str(ROOT / "results" / "train_policy.json"))
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    started = time.time()
    os.environ.setdefault("OMP_NUM_THREADS", "1")

    slam_kwargs = json.loads(args.slam_env_kwargs)
    if not isinstance(slam_kwargs, dict):
        ap.error("--slam-env-kwargs must be a JSON object")
    if args.timesteps is None:
        from agents.train import load_hyperparams

        args.timesteps = int(load_hyperparams("ppo", SLAM_ID)["n_timesteps"])
    record_path = Path(args.record)
    record = json.loads(record_path.read_text()) if record_path.exists() else {}
    record["machine"] = _machine()
    record["registration_weights"] = _registration_weights()
    for name in TARGETS:
        if args.only and name != args.only:
            continue
        meta = train_one(name, args, slam_kwargs if name == "slam" else {})
        record[name] = {
            k: meta[k]
            for k in ("env_id", "env_kwargs", "timesteps", "n_envs", "seed", "wall_time_s", "total_wall_time_s",
                      "steps_per_s", "hyperparams", "recent_episodes", "best_eval_mean_return", "shipped",
                      "model", "zip_bytes")
        }  # fmt: skip
        record.pop("provenance", None)  # the record of this run's (training itself: no fingerprint, minutes long)
        write_json(record_path, record, __file__, args, started, argv=argv)
    print(json.dumps(record, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
