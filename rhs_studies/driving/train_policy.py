"""Train the driving policies and record how they were made.

``--algo dagger`` (default): DAgger students of the privileged
:class:`agents.policies.expert.HeadwayDriver` (:mod:`agents.algos.imitation`,
``agents/hyperparams/dagger.yml``):

* ``agents/data/dagger_rhs_highway_slam.zip``: on ``rhs-highway-slam-v0`` (point
  cloud + SLAM estimate), SLAM in the loop at every step: the shipped policy
  (``rhs-slam demo``);
* ``agents/data/dagger_rhs_highway_truth.zip``: the same algorithm,
  hyperparameters and env steps on ``rhs-highway-v0`` (ground-truth Kinematics);
* ``--only truth_all_around``: on a Kinematics observation of 8 vehicles, behind
  as well (``agents/data/truth/``); ``--only slam_rhs slam_phased dense dense_phased``:
  the antenna study of ``evaluate_policies.py`` (``agents/data/antenna/``).

``--algo ppo`` trains PPO (``agents/hyperparams/ppo.yml``) into
``ppo_rhs_highway_{slam,truth}.zip``, the PPO rows of the policies table.

Every policy's env gets ``--env-kwargs`` (default :data:`FINE_SPEEDS`: highway-env's
meta-actions with target speeds down to 10 m/s, so that the expert, and its students,
can slow behind a leader slower than 20 m/s); the radar targets add ``--slam-env-kwargs``.

Each zip gets a JSON beside it (env id, ``env_kwargs``, timesteps, wall time,
hyperparameters) that ``rhs-slam evaluate`` / ``rhs-slam demo`` read to rebuild
the env the policy was trained on. ``results/train_policy.json`` records both
runs (timesteps, wall time, steps/s, machine). TensorBoard logs, checkpoints,
monitor CSVs and evaluations stay in ``--work-dir`` (default ``runs/policies``,
not shipped).

    OMP_NUM_THREADS=1 python scripts/train_policy.py                  # the shipped DAgger policies
    python scripts/train_policy.py --only slam_rhs slam_phased dense dense_phased   # the antenna study
    python scripts/train_policy.py --only slam --timesteps 20000 --n-envs 2
    python scripts/train_policy.py --slam-env-kwargs '{"radar": {"scan": {"grid_deg": 5}}}'

``--continue-from DIR`` continues each DAgger student from its zip under DIR
(``agents.algos.imitation``, continuation: ``agents/hyperparams/dagger_continue.yml``,
beta_0 < 1, fresh data on the student's own states) into ``--data-dir``; its
record keeps the parent and the total budget (``total_timesteps``):

    python scripts/train_policy.py --continue-from agents/data --only slam truth --data-dir runs/continued

``--resume`` goes on from the state a stopped or killed run left in ``--work-dir``
(DAgger: after its last finished round, :func:`agents.algos.imitation.load_round_state`), so a
student longer than a session is trained in pieces; rerun the same command with it:

    python scripts/train_policy.py --only dense dense_phased --resume

``--adopt RECORD`` ships what a run with its own ``--data-dir`` / ``--record`` made (a long run kept
apart until it finished): each entry of RECORD (``--only``: those policies) has its zip and metadata
copied to where this script ships them (:func:`target_path`) and its record merged into ``--record``,
with ``run`` naming the command and commit that made it. Nothing is trained:

    python scripts/train_policy.py --adopt runs/antenna_dense/train_policy.json --only dense dense_phased

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

from rhs_studies.kit.driving import (
    ALGOS,
    ANTENNA_STUDY,
    DATA,
    FINE_SPEEDS,
    SHIPPED,
    SLAM_ENV_KWARGS,
    SLAM_ID,
    TARGETS,
    target_path,
)
from rhs_studies.kit.provenance import provenance, write_json
from rhs_studies.kit.seeds import first

ROOT = Path(__file__).resolve().parents[2]


def target_env_kwargs(name: str, slam_kwargs: dict, env_kwargs: dict | None = None) -> dict:
    """``env_kwargs`` (every target's: ``--env-kwargs``), then for a radar target ``--slam-env-kwargs`` with the
    target's radar settings merged into its ``radar`` dict, for a ground-truth one its own observation kwargs."""
    base, radar = dict(env_kwargs or {}), TARGETS[name][1]
    if radar is None:
        return {**base, **(TARGETS[name][2] if len(TARGETS[name]) > 2 else {})}
    merged = {**base, **slam_kwargs}
    return {**merged, "radar": {**(slam_kwargs.get("radar") or {}), **radar}} if radar else merged


MAX_BYTES = 1_000_000
CONTINUE_YAML = ROOT / "agents" / "hyperparams" / "dagger_continue.yml"


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
    from slam.core.cnn_registration import DEFAULT_WEIGHTS

    return {"path": str(Path(DEFAULT_WEIGHTS).relative_to(ROOT)), "exists": Path(DEFAULT_WEIGHTS).exists()}


def train_one(name: str, args: argparse.Namespace, env_kwargs: dict) -> dict:
    from agents.algos.train import metadata_path, train

    env_id = TARGETS[name][0]
    target = target_path(args.algo, name, Path(args.data_dir))
    work = Path(args.work_dir) / f"{args.algo}_{name}"
    if work.exists() and not args.resume:
        shutil.rmtree(work)
    print(
        f"train_policy: {name}: {args.algo} on {env_id}, {args.timesteps} steps, {args.n_envs} envs -> {target}",
        file=sys.stderr,
    )
    t0 = time.perf_counter()
    summary = train(
        args.algo,
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
        hyperparams=args.hyperparams,
        init_policy=None if args.continue_from is None else target_path(args.algo, name, Path(args.continue_from)),
        resume=args.resume,
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
        "total_wall_time_s": round(total, 1),  # this process, setup and evaluations included (a resumed run: its part)
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


def adopt(source: Path, names: list[str] | None, algo: str, record_path: Path, data_dir: Path = DATA,
          argv: list[str] | None = None) -> list[str]:
    """Copy the policies recorded in the train_policy record ``source`` (``names``: only these) to ``data_dir``
    and merge their entries into ``record_path``, each with ``run`` (command, commit, start: the entry's own, stamped
    by its training run, else the source's provenance); returns the keys adopted. ``ValueError`` for a name the
    source has not, or a zip missing."""
    from agents.algos.train import metadata_path

    src = _read_record(source)
    prov = src.get("provenance") or {}
    keys = [f"{algo}_{n}" for n in names] if names else [k for k in src if k.startswith(f"{algo}_")]
    missing = [k for k in keys if k not in src]
    if missing or not keys:
        raise ValueError(f"--adopt: {source} has no entries {missing or keys} (it has {sorted(src)})")
    record = _read_record(record_path)
    for key in keys:
        entry, name = dict(src[key]), key[len(algo) + 1 :]
        zip_path = Path(entry["model"]) if Path(entry["model"]).is_absolute() else ROOT / entry["model"]
        if not zip_path.exists():
            raise ValueError(f"--adopt: {key}: no policy at {zip_path}")
        target = target_path(algo, name, data_dir)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(zip_path, target)
        meta = json.loads(metadata_path(zip_path).read_text())
        metadata_path(target).write_text(json.dumps({**meta, "model": _display(target)}, indent=2) + "\n")
        entry["model"] = _display(target)
        entry.setdefault("run", _run_of(prov))  # an entry stamped by its own training run keeps that
        record[key] = entry
        print(f"train_policy: adopted {key}: {zip_path} -> {target}", file=sys.stderr)
    record.setdefault("machine", src.get("machine"))
    record.pop("provenance", None)
    config = {"adopt": _display(source), "only": names, "algo": algo, "data_dir": _display(data_dir)}
    write_json(record_path, record, __file__, config, time.time(), argv=argv)
    return keys


def _run_of(prov: dict) -> dict:
    """The run that made an entry: command, commit and start of the provenance block ``prov``."""
    return {k: prov[k] for k in ("commit", "command", "started_utc") if k in prov}


def _read_record(path: Path) -> dict:
    """The training record; entries of before the algorithms were named (``slam``, ``truth``) were PPO's."""
    record = json.loads(path.read_text()) if path.exists() else {}
    for old in ("slam", "truth"):
        if old in record:
            record.setdefault(f"ppo_{old}", record.pop(old))
    return record


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algo", choices=ALGOS, default="dagger", help="dagger (default, shipped) or ppo (ablation)")
    ap.add_argument("--only", nargs="+", choices=tuple(TARGETS), default=None,
                    help=f"train these policies only (default: {' '.join(SHIPPED)}; the antenna study: "
                    f"{' '.join(ANTENNA_STUDY)})")
    ap.add_argument(
        "--timesteps", type=int, default=None, help="env steps per policy (default: n_timesteps of the algo's YAML)"
    )
    ap.add_argument("--n-envs", type=int, default=2, help="subprocess envs (default 2)")
    ap.add_argument("--seed", type=int, default=first("training"))
    ap.add_argument("--slam-env-kwargs", default=json.dumps(SLAM_ENV_KWARGS),
                    help="JSON env kwargs of the radar / SLAM policies' envs (saved with them; default: %(default)s)")
    ap.add_argument("--env-kwargs", default=json.dumps(FINE_SPEEDS),
                    help="JSON env kwargs of every policy's env, under the radar ones (default: %(default)s; "
                    "'{}': highway-env's action set, target speeds [20, 25, 30])")
    ap.add_argument("--eval-freq", type=int, default=5000, help="env steps between evaluations (0: none)")
    ap.add_argument("--eval-episodes", type=int, default=2)
    ap.add_argument("--checkpoint-freq", type=int, default=5000)
    ap.add_argument("--ship", choices=("final", "best"), default="final", help="which model to ship")
    ap.add_argument("--work-dir", default=str(ROOT / "runs" / "policies"))
    ap.add_argument("--data-dir", default=str(DATA), help="where the policy zips go (default: agents/data)")
    ap.add_argument("--hyperparams", default=None,
                    help="zoo-style YAML (default: agents/hyperparams/ALGO.yml; with --continue-from: dagger_continue.yml)")
    ap.add_argument("--continue-from", default=None,
                    help="dagger: continue every student from its zip in this data dir (e.g. agents/data)")
    ap.add_argument("--resume", action="store_true",
                    help="go on from each policy's state in --work-dir (DAgger: the last finished round; PPO: the "
                    "latest checkpoint) instead of starting over: a long student trained over several sessions")
    ap.add_argument("--record", default=str(ROOT / "results" / "train_policy.json"))
    ap.add_argument("--adopt", default=None, metavar="RECORD",
                    help="train nothing: ship the policies of another run's record (--only: these) into --data-dir "
                    "and merge their entries into --record")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    started = time.time()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if args.adopt is not None:
        try:
            adopt(Path(args.adopt), args.only, args.algo, Path(args.record), Path(args.data_dir), argv)
        except ValueError as exc:
            ap.error(str(exc))
        return 0

    slam_kwargs, env_kwargs = json.loads(args.slam_env_kwargs), json.loads(args.env_kwargs)
    for flag, value in (("--slam-env-kwargs", slam_kwargs), ("--env-kwargs", env_kwargs)):
        if not isinstance(value, dict):
            ap.error(f"{flag} must be a JSON object")
    if args.continue_from is not None:
        if args.algo != "dagger":
            ap.error("--continue-from continues DAgger students (--algo dagger)")
        args.hyperparams = args.hyperparams or str(CONTINUE_YAML)
    if args.timesteps is None:
        from agents.algos.train import load_hyperparams

        args.timesteps = int(load_hyperparams(args.algo, SLAM_ID, args.hyperparams)["n_timesteps"])
    record_path = Path(args.record)
    machine, weights = _machine(), _registration_weights()
    for name in args.only or SHIPPED:
        meta = train_one(name, args, target_env_kwargs(name, slam_kwargs, env_kwargs))
        record = _read_record(record_path)  # now: another run (--only) may have written its entry meanwhile
        record["machine"], record["registration_weights"] = machine, weights
        record[f"{args.algo}_{name}"] = {
            k: meta[k]
            for k in ("env_id", "env_kwargs", "timesteps", "n_envs", "seed", "wall_time_s", "total_wall_time_s",
                      "steps_per_s", "hyperparams", "recent_episodes", "best_eval_mean_return", "shipped",
                      "model", "zip_bytes", "algo", "iterations", "init_policy", "total_timesteps",
                      "resumed_from_round", "untimed_rounds")
            if k in meta
        }  # fmt: skip
        # the entry keeps the run that made it; the record's provenance is the latest run's (a later --only run)
        record[f"{args.algo}_{name}"]["run"] = _run_of(provenance(__file__, args, started, argv))
        record.pop("provenance", None)  # the record of this run's (training itself: no fingerprint, minutes long)
        write_json(record_path, record, __file__, args, started, argv=argv)
    print(json.dumps(record, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
