"""Behaviour cloning from Minari datasets written by ``rhs-slam record``, and its paired test against a policy.

Fits a stable-baselines3 ``ActorCriticPolicy`` (the DAgger students' network: the env's entry of
``agents/hyperparams/dagger.yml``, its ``epochs``, ``batch_size``, ``learning_rate`` and
``class_weight_power``; fresh weights) by weighted maximum likelihood (:func:`agents.algos.imitation.fit`) of the
datasets' labels at their observations (``--dataset-id`` takes one or more datasets of the same env):

* ``--labels expert`` (default): the headway expert's ``infos["expert_action"]`` at every state;
* ``--labels actions``: the recorded ``actions`` at every state;
* ``--labels decisions``: the recorded actions at the driving policy's decision steps only (every
  ``k``-th step from the reset, ``k`` the ``decision_interval`` of ``--like``): what a policy that decides every
  k steps chose (behind its shield, as recorded). States without a label (-1) are left out.

``--like POLICY`` drives the clone as ``POLICY`` is driven: its JSON's ``decision_interval``,
``decision_mode`` and ``shield`` are copied into the clone's JSON. Writes ``OUT/model.zip`` with the JSON beside
it (``algo: dagger``, the env ``--eval-env`` with the dataset's kwargs and ``--eval-env-kwargs`` over them), so
``rhs-slam evaluate --policy OUT/model.zip`` and ``rhs-slam demo`` drive it. With ``--eval-episodes N`` it is
also driven on seeds ``--eval-seed``, ``+ 1``, ... (mean return, crashes, Minari's normalised score where the
dataset has reference scores); with ``--compare POLICY`` that policy is driven on the same seeds and the
summary gets the paired return difference (clone - policy, t interval) and the ratio of the mean returns
with its paired bootstrap interval (seeds resampled together). The compared policy's runs are cached in
``OUT/compare_runs.json`` (reused when the policy, env, kwargs and seeds match; ``--compare-only`` drives and
caches them without any training). ``--results PATH`` writes the summary with provenance
(:func:`rhs_studies.kit.provenance.write_json`) and a Markdown table beside it.

    MINARI_DATASETS_PATH=data python scripts/bc_from_dataset.py --dataset-id rhs-slam/highway-slam/headway-v0 \\
        --out runs/bc --eval-episodes 20 --eval-seed 1000
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from agents.algos.imitation import DaggerConfig, Dataset, agreement, fit

__all__ = ["FIT_FIELDS", "LABELS", "LIKE_FIELDS", "ArrayDataset", "clone", "compare_runs", "env_of", "evaluate_clone",
           "label_rows", "load_samples", "main", "paired_ratio", "parse_args", "write_markdown"]

#: the fields of :class:`agents.algos.imitation.DaggerConfig` that the supervised fit reads
FIT_FIELDS = ("epochs", "batch_size", "learning_rate", "class_weight_power")
#: the label choices (the module docstring)
LABELS = ("expert", "actions", "decisions")
#: the fields of ``--like``'s JSON that say how it is driven (copied into the clone's JSON)
LIKE_FIELDS = ("decision_interval", "decision_mode", "shield")


class ArrayDataset(Dataset):
    """A :class:`agents.algos.imitation.Dataset` over arrays already stacked (the dataset's observations)."""

    def __init__(self, obs: Any, actions: np.ndarray) -> None:
        super().__init__()
        self._obs, self._actions = obs, np.asarray(actions, dtype=np.int64)

    def __len__(self) -> int:
        return len(self._actions)

    def arrays(self) -> tuple[Any, np.ndarray]:
        return self._obs, self._actions


def label_rows(ep: Any, labels: str, every: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The rows of one episode to learn from and their labels.

    Args:
        ep: a Minari episode (``T`` actions, ``T + 1`` observations and infos).
        labels: one of :data:`LABELS`.
        every: for ``"decisions"``, the decision interval ``k``: rows ``0, k, 2k, ... < T``.

    Returns:
        The row indices (into the first ``T`` observations) and their int64 labels (rows labelled -1 left out).
    """
    n = len(ep.actions)
    if labels == "expert":
        if ep.infos is None or "expert_action" not in ep.infos:
            raise ValueError(f"episode {ep.id} has no infos['expert_action']: record it with rhs-slam record")
        y = np.asarray(ep.infos["expert_action"][:n], dtype=np.int64)
    else:
        y = np.asarray(ep.actions, dtype=np.int64).reshape(n)
    rows = np.arange(n)
    if labels == "decisions":
        rows = rows[::every]
    keep = y[rows] >= 0
    return rows[keep], y[rows][keep]


def load_samples(datasets: Any, labels: str = "expert", every: int = 1) -> tuple[Any, np.ndarray]:
    """The labelled (observation, action) pairs of every episode of one or more Minari datasets.

    Args:
        datasets: a :class:`minari.MinariDataset` written by ``rhs-slam record``, or a list of them.
        labels: one of :data:`LABELS` (the module docstring).
        every: the decision interval of ``"decisions"`` (>= 1).

    Returns:
        The observations (a dict of arrays, one row per labelled state) and the labels, int64.
    """
    if labels not in LABELS:
        raise ValueError(f"labels must be one of {LABELS}, got {labels!r}")
    if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or not 1 <= every <= 1000:
        raise ValueError(f"the decision interval must be an integer in [1, 1000], got {every!r}")
    obs_parts: list[Any] = []
    label_parts = []
    for dataset in datasets if isinstance(datasets, (list, tuple)) else [datasets]:
        for ep in dataset.iterate_episodes():
            rows, y = label_rows(ep, labels, int(every))
            o = ep.observations
            obs_parts.append({k: np.asarray(v)[rows] for k, v in o.items()} if isinstance(o, dict)
                             else np.asarray(o)[rows])
            label_parts.append(y)
    y_all = np.concatenate(label_parts) if label_parts else np.zeros(0, np.int64)
    if len(y_all) == 0:
        raise ValueError("the dataset has no labelled state (every expert_action is -1: use --labels actions)")
    if isinstance(obs_parts[0], dict):
        return {k: np.concatenate([p[k] for p in obs_parts]) for k in obs_parts[0]}, y_all
    return np.concatenate(obs_parts), y_all


def env_of(dataset) -> tuple[str, dict[str, Any]]:
    """The env id and kwargs the dataset was recorded on (its env spec)."""
    spec = dataset.spec.env_spec
    if spec is None:
        raise ValueError("the dataset has no env spec: record it with rhs-slam record")
    return spec.id, dict(spec.kwargs)


def _like(policy: str | Path | None) -> dict[str, Any]:
    """The :data:`LIKE_FIELDS` of ``policy``'s JSON (``{}`` for None)."""
    if policy is None:
        return {}
    from agents.evaluate import policy_metadata

    meta = policy_metadata(policy, required=True)
    return {k: meta[k] for k in LIKE_FIELDS if meta.get(k) is not None}


def clone(datasets: Any, out: str | Path, labels: str = "expert", epochs: int | None = None, seed: int = 0,
          torch_threads: int | None = 1, like: str | Path | None = None, eval_env: str | None = None,
          eval_env_kwargs: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
    """Fit the student on ``datasets`` and save it to ``out/model.zip`` (+ its JSON).

    Args:
        datasets: a Minari dataset of ``rhs-slam record`` or a list of them (recorded on one env).
        out: output folder.
        labels: see :func:`load_samples` (``"decisions"`` takes the decision interval of ``like``).
        epochs: passes over the data (default: the DAgger hyperparameters' ``epochs``).
        seed: torch and shuffling seed.
        torch_threads: torch's intra-op threads (None: torch's default).
        like: a policy whose decision interval, decision mode and shield the clone is driven with.
        eval_env: the env id written in the clone's JSON (default: the datasets').
        eval_env_kwargs: kwargs over the datasets' in the clone's JSON.

    Returns:
        The SB3 model and the summary written beside it.
    """
    import torch

    import rhs_env  # noqa: F401  (registers the ids the dataset's spec names)
    from agents.algos.threads import limit_threads

    datasets = list(datasets) if isinstance(datasets, (list, tuple)) else [datasets]
    envs = {json.dumps(env_of(d), sort_keys=True, default=str) for d in datasets}
    if len(envs) != 1:
        raise ValueError(f"the datasets were recorded on different envs: {sorted(envs)}")
    env_id, env_kwargs = env_of(datasets[0])
    driven = _like(like)
    every = int(driven.get("decision_interval", 1)) if labels == "decisions" else 1
    if labels == "decisions" and like is None:
        raise ValueError("--labels decisions needs --like POLICY (its decision_interval)")
    obs, y = load_samples(datasets, labels, every)
    limit_threads(torch_threads)
    torch.manual_seed(seed)
    t0 = time.perf_counter()
    # the hyperparameters of the env the clone drives (a fast variant's dataset: the exact id's entry)
    model, config, loss, train_agreement = _fit(datasets[0], eval_env or env_id, obs, y, epochs, seed)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model.save(out / "model.zip")
    summary = {
        "algo": "dagger", "env_id": eval_env or env_id, "env_kwargs": {**env_kwargs, **(eval_env_kwargs or {})},
        "dataset_env_id": env_id, "dataset_ids": [d.spec.dataset_id for d in datasets], "labels": labels,
        "label_every": every, **driven, "like": None if like is None else str(like), "samples": int(len(y)),
        "label_counts": np.bincount(y, minlength=5).tolist(),
        "episodes": int(sum(d.total_episodes for d in datasets)), "steps": int(sum(d.total_steps for d in datasets)),
        "bc": {k: v for k, v in asdict(config).items() if k in FIT_FIELDS},
        "seed": seed, "final_loss": loss, "train_agreement": train_agreement,
        "wall_s": round(time.perf_counter() - t0, 2), "model": str(out / "model.zip"),
    }
    (out / "model.json").write_text(json.dumps(summary, indent=2))
    return model, summary


def _fit(dataset: Any, env_id: str, obs: Any, y: np.ndarray, epochs: int | None, seed: int) -> tuple[Any, ...]:
    """A fresh DAgger-student network fitted to ``(obs, y)``: (model, config, last loss, train agreement)."""
    import torch
    from stable_baselines3 import PPO

    from agents.algos.hyperparams import run_settings

    run = run_settings("dagger", env_id, 1, 1, None, None)
    config = DaggerConfig(**{k: run.hp[k] for k in FIT_FIELDS if k in run.hp})
    if epochs is not None:
        config = replace(config, epochs=epochs)
    rng = np.random.default_rng(seed)
    import gymnasium as gym

    spec_id, spec_kwargs = env_of(dataset)  # the spaces only (recover_environment also compares wrapper specs)
    env = gym.make(spec_id, **spec_kwargs)
    try:
        model = PPO(run.policy, env, seed=seed, device="cpu", verbose=0, policy_kwargs=run.hp.get("policy_kwargs") or {})
        optimizer = torch.optim.Adam(model.policy.parameters(), lr=config.learning_rate)
        loss = fit(model, ArrayDataset(obs, y), config, rng, optimizer)
        return model, config, loss, agreement(model, obs, y)
    finally:
        env.close()


def _drive(policy: str | Path, env_id: str, env_kwargs: dict[str, Any], seeds: list[int]) -> list[dict[str, Any]]:
    """``policy``'s greedy episodes on ``seeds`` (seed, return, crashed, mean speed)."""
    from agents.evaluate import load_policy, make_env, run_episode

    env = make_env(env_id, env_kwargs, landmarks_in_info=False)
    try:
        policy_obj = load_policy(policy, env, seeds[0])
        runs = []
        for s in seeds:
            r = run_episode(env, policy_obj, s)
            runs.append({"seed": s, "return": float(r["return"]), "crashed": bool(r["crashed"]), "steps": int(r["steps"]),
                         "mean_speed": r["mean_speed"], "position_rmse_m": r["position_rmse_m"],
                         "shield_overrides": r["shield_overrides"]})
            print(f"bc_from_dataset: {Path(str(policy)).name} seed {s}: return {r['return']:.2f}"
                  f"{' (crashed)' if r['crashed'] else ''}", file=sys.stderr, flush=True)
        return runs
    finally:
        env.close()


def evaluate_clone(model_path: str | Path, datasets: Any, episodes: int, seed: int) -> dict[str, Any]:
    """Drive the saved student ``episodes`` episodes (seeds ``seed``, ...) on its JSON's env: its runs, mean return,
    crashes and Minari's normalised score (of the first dataset's reference scores, where it has them)."""
    import minari

    from agents.evaluate import resolve_env

    env_id, env_kwargs = resolve_env(model_path)
    runs = _drive(model_path, env_id, env_kwargs, list(range(seed, seed + episodes)))
    returns = np.array([r["return"] for r in runs])
    first = datasets[0] if isinstance(datasets, (list, tuple)) else datasets
    out: dict[str, Any] = {"env_id": env_id, "env_kwargs": env_kwargs, "eval_seeds": [seed, seed + episodes - 1],
                           "mean_return": float(returns.mean()), "crashes": int(sum(r["crashed"] for r in runs)),
                           "runs": runs}
    if first.storage.metadata.get("ref_max_score") is not None:
        out["normalized_score"] = float(np.mean(minari.get_normalized_score(first, returns)))
    return out


def compare_runs(policy: str | Path, env_id: str, env_kwargs: dict[str, Any], seeds: list[int],
                 cache: Path) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """``policy``'s runs on ``seeds``, from ``cache`` when it holds the same policy, env, kwargs and seeds.

    Returns:
        The runs and the cache's record (where and when they were driven, by which commit).
    """
    from rhs_studies.kit.provenance import git_state

    key = {"policy": str(policy), "env_id": env_id, "env_kwargs": env_kwargs, "seeds": seeds}
    _wait_for(cache.with_name(cache.name + ".lock"))
    if cache.exists():
        saved = json.loads(cache.read_text())
        if json.loads(json.dumps(saved.get("key"))) == json.loads(json.dumps(key, default=str)):
            return saved["runs"], {k: v for k, v in saved.items() if k != "runs"}
    t0 = time.time()
    runs = _drive(policy, env_id, env_kwargs, seeds)
    record = {"key": key, "driven_at_unix": round(t0), "wall_s": round(time.time() - t0, 1), "git": git_state()}
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_text(json.dumps({**record, "runs": runs}, indent=1, default=str))
    return runs, record


def _wait_for(lock: Path, timeout_s: float = 4 * 3600.0, poll_s: float = 10.0) -> None:
    """Wait while ``lock`` exists (another process still driving the compared policy into the cache), at most
    ``timeout_s``; then a ``ValueError`` naming it."""
    deadline = time.time() + timeout_s
    if lock.exists():
        print(f"bc_from_dataset: waiting for {lock} to go (its runs are being driven)", file=sys.stderr, flush=True)
    while lock.exists():
        if time.time() > deadline:
            raise ValueError(f"{lock} is still there after {timeout_s:.0f} s: delete it if no run drives that cache")
        time.sleep(poll_s)


def paired_ratio(a: list[float], b: list[float], reps: int = 10_000, seed: int = 0,
                 level: float = 0.95) -> dict[str, float]:
    """``mean(a) / mean(b)`` over paired samples (the same seeds) and its paired percentile bootstrap interval.

    The pairs are resampled together (index ``i`` drawn with replacement ``n`` times), so what the two share on a
    seed cancels as in a paired difference: ratio ``r = sum(a_i) / sum(b_i)`` over the drawn indices.

    Args:
        a: the clone's returns, one per seed.
        b: the reference policy's returns on the same seeds.
        reps: bootstrap resamples.
        seed: the resampling seed.
        level: the interval's coverage.

    Returns:
        ``ratio``, ``low``, ``high`` and ``n``.
    """
    x, z = np.asarray(a, float), np.asarray(b, float)
    if x.shape != z.shape or x.size < 2:
        raise ValueError(f"paired samples of the same length >= 2 needed, got {x.size} and {z.size}")
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, x.size, size=(reps, x.size))
    ratios = x[idx].sum(axis=1) / z[idx].sum(axis=1)
    lo, hi = np.quantile(ratios, [(1 - level) / 2, (1 + level) / 2])
    return {"ratio": float(x.sum() / z.sum()), "low": float(lo), "high": float(hi), "n": int(x.size)}


def _comparison(clone_runs: list[dict[str, Any]], ref_runs: list[dict[str, Any]], goal: float) -> dict[str, Any]:
    """The paired difference and ratio of the clone's returns to the reference's, and the goal's verdict."""
    from rhs_common.stats import paired_difference, wilson_interval

    by_seed = {r["seed"]: r["return"] for r in ref_runs}
    a = [r["return"] for r in clone_runs if r["seed"] in by_seed]
    b = [by_seed[r["seed"]] for r in clone_runs if r["seed"] in by_seed]
    d = paired_difference(a, b)
    ratio = paired_ratio(a, b)
    n = len(ref_runs)
    crashes = int(sum(r["crashed"] for r in ref_runs))
    return {"reference_mean_return": float(np.mean(b)), "clone_mean_return": float(np.mean(a)),
            "difference": {"mean": d.mean, "low": d.low, "high": d.high, "n": d.n},
            "ratio": ratio, "goal_ratio": goal, "meets_goal": bool(ratio["ratio"] >= goal),
            "meets_goal_at_interval_low": bool(ratio["low"] >= goal),
            "reference_crashes": crashes, "reference_crash_wilson": list(wilson_interval(crashes, n))}


def write_markdown(path: Path, summary: dict[str, Any]) -> None:
    """The summary as a short Markdown table (the docs page's numbers)."""
    ev, cmp_ = summary["evaluation"], summary["comparison"]
    ref = summary["compare"]
    lines = [
        f"Behaviour cloning of `{Path(ref['policy']).name}` from {summary['steps']} recorded steps "
        f"({summary['episodes']} episodes of `{summary['dataset_env_id']}`, datasets {', '.join(summary['dataset_ids'])}), "
        f"labels `{summary['labels']}` ({summary['samples']} samples), evaluated on `{ev['env_id']}`, "
        f"seeds {ev['eval_seeds'][0]}-{ev['eval_seeds'][1]} (paired).",
        "",
        "| policy | mean return | crashes | ",
        "|---|---|---|",
        f"| reference (`{Path(ref['policy']).name}`) | {cmp_['reference_mean_return']:.2f} | "
        f"{cmp_['reference_crashes']} / {cmp_['ratio']['n']} |",
        f"| clone | {cmp_['clone_mean_return']:.2f} | {ev['crashes']} / {cmp_['ratio']['n']} |",
        "",
        f"Paired difference (clone - reference): {cmp_['difference']['mean']:+.2f} "
        f"[{cmp_['difference']['low']:+.2f}, {cmp_['difference']['high']:+.2f}] (95 % t). "
        f"Ratio of mean returns: {cmp_['ratio']['ratio']:.3f} [{cmp_['ratio']['low']:.3f}, {cmp_['ratio']['high']:.3f}] "
        f"(95 % paired bootstrap); goal >= {cmp_['goal_ratio']}: "
        f"{'met' if cmp_['meets_goal'] else 'not met'} (interval low {'above' if cmp_['meets_goal_at_interval_low'] else 'below'} it).",
        f"Training: {summary['bc']}, final loss {summary['final_loss']:.3f}, agreement with the labels "
        f"{summary['train_agreement']:.3f}, {summary['wall_s']:.0f} s.",
    ]
    path.write_text("\n".join(lines) + "\n")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset-id", required=True, nargs="+", help="Minari id(s) (under $MINARI_DATASETS_PATH or --datasets)")
    ap.add_argument("--datasets", default=None, help="Minari datasets folder (default: $MINARI_DATASETS_PATH)")
    ap.add_argument("--out", required=True, help="folder for model.zip, model.json and compare_runs.json")
    ap.add_argument("--labels", choices=LABELS, default="expert")
    ap.add_argument("--like", default=None, help="policy zip whose decision interval, mode and shield the clone takes")
    ap.add_argument("--epochs", type=int, default=None, help="passes over the data (default: dagger.yml's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--eval-env", default=None, help="env id the clone is driven on (default: the datasets')")
    ap.add_argument("--eval-env-kwargs", default=None, help="JSON dict over the datasets' env kwargs for driving")
    ap.add_argument("--eval-episodes", type=int, default=0, help="episodes to drive the student after (0: none)")
    ap.add_argument("--eval-seed", type=int, default=1000, help="seed of the first evaluation episode")
    ap.add_argument("--seed-set", default=None, help="the seed ledger's set the evaluation seeds must lie in")
    ap.add_argument("--compare", default=None, help="policy driven on the same seeds for the paired comparison")
    ap.add_argument("--compare-only", action="store_true", help="drive and cache --compare's runs only")
    ap.add_argument("--goal-ratio", type=float, default=0.95, help="the clone's mean return over --compare's, goal")
    ap.add_argument("--results", default=None, help="write the summary with provenance here (+ .md beside it)")
    return ap.parse_args(argv)


def _check(args: argparse.Namespace) -> None:
    """``ValueError`` naming the flag for counts, seeds and combinations out of range."""
    from rhs_studies.kit.seeds import check_fresh, seed_set

    if args.epochs is not None and not 1 <= args.epochs <= 1000:
        raise ValueError(f"--epochs must be in [1, 1000], got {args.epochs}")
    if not 0 <= args.eval_episodes <= 10_000:
        raise ValueError(f"--eval-episodes must be in [0, 10000], got {args.eval_episodes}")
    if (args.compare or args.compare_only or args.results) and args.eval_episodes < 2:
        raise ValueError("--compare, --compare-only and --results need --eval-episodes >= 2")
    if args.compare_only and not args.compare:
        raise ValueError("--compare-only needs --compare POLICY")
    if args.results and not args.compare:
        raise ValueError("--results needs --compare POLICY (the paired comparison it reports)")
    seeds = list(range(args.eval_seed, args.eval_seed + args.eval_episodes))
    if args.seed_set is not None:
        s = seed_set(args.seed_set)
        if seeds and not (seeds[0] in s and seeds[-1] in s):
            raise ValueError(f"--eval-seed {args.eval_seed} + {args.eval_episodes} episodes leave the seed set "
                             f"{s.name} ({s.first}-{s.last})")
        check_fresh(seeds, "bc_from_dataset's evaluation", allow=[s.name])


def _eval_target(args: argparse.Namespace, datasets: list[Any]) -> tuple[str, dict[str, Any]]:
    """The env id and kwargs the clone and the compared policy are driven on."""
    env_id, env_kwargs = env_of(datasets[0])
    extra = json.loads(args.eval_env_kwargs) if args.eval_env_kwargs else {}
    if not isinstance(extra, dict):
        raise TypeError(f"--eval-env-kwargs must be a JSON object, got {args.eval_env_kwargs!r}")
    return args.eval_env or env_id, {**env_kwargs, **extra}


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Train (unless ``--compare-only``), evaluate and compare as the flags say; the summary."""
    import minari

    _check(args)
    datasets = [minari.load_dataset(i) for i in args.dataset_id]
    env_id, env_kwargs = _eval_target(args, datasets)
    seeds = list(range(args.eval_seed, args.eval_seed + args.eval_episodes))
    out = Path(args.out)
    if args.compare_only:
        runs, record = compare_runs(args.compare, env_id, env_kwargs, seeds, out / "compare_runs.json")
        return {"compare": record, "mean_return": float(np.mean([r["return"] for r in runs]))}
    extra = json.loads(args.eval_env_kwargs) if args.eval_env_kwargs else {}
    _, summary = clone(datasets, out, args.labels, args.epochs, args.seed, like=args.like, eval_env=args.eval_env,
                       eval_env_kwargs=extra)
    if args.eval_episodes:
        summary["evaluation"] = evaluate_clone(out / "model.zip", datasets, args.eval_episodes, args.eval_seed)
    if args.compare:
        runs, record = compare_runs(args.compare, env_id, env_kwargs, seeds, out / "compare_runs.json")
        summary["compare"] = {**record, "policy": str(args.compare), "runs": runs}
        summary["comparison"] = _comparison(summary["evaluation"]["runs"], runs, args.goal_ratio)
    (out / "model.json").write_text(json.dumps(summary, indent=2, default=str))
    return summary


def main(argv: list[str] | None = None) -> int:
    import os

    started = time.time()
    args = parse_args(argv)
    try:
        import minari  # noqa: F401
    except ImportError:
        print('bc_from_dataset: error: needs minari: pip install -c constraints/base.txt -e ".[dataset]"', file=sys.stderr)
        return 2
    if args.datasets is not None:
        os.environ["MINARI_DATASETS_PATH"] = str(Path(args.datasets).resolve())
    try:
        summary = run(args)
    except (ValueError, TypeError, FileNotFoundError, json.JSONDecodeError) as exc:
        print(f"bc_from_dataset: error: {exc}", file=sys.stderr)
        return 2
    if args.results and not args.compare_only:
        from rhs_studies.kit.provenance import write_json

        path = Path(args.results)
        write_json(path, summary, "scripts/bc_from_dataset.py", vars(args), started, argv=argv)
        write_markdown(path.with_suffix(".md"), summary)
    print(json.dumps({k: v for k, v in summary.items() if k not in ("evaluation", "compare")}, indent=2, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
