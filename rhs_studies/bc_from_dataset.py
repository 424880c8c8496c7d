"""Behaviour cloning from a Minari dataset written by ``rhs-slam record``.

Fits a stable-baselines3 ``ActorCriticPolicy`` (the DAgger students' network: the env's entry of
``agents/hyperparams/dagger.yml``, its ``epochs``, ``batch_size``, ``learning_rate`` and
``class_weight_power``) by weighted maximum likelihood (:func:`agents.imitation.fit`) of the
dataset's labels at its observations: the headway expert's ``infos["expert_action"]`` (default)
or the recorded ``actions`` (``--labels actions``). States without a label (-1) are left out.
Writes ``OUT/model.zip`` with the JSON beside it (env id and kwargs of the dataset, ``algo: dagger``),
so ``rhs-slam evaluate --policy OUT/model.zip`` and ``rhs-slam demo`` drive it; with
``--eval-episodes N`` it is also driven here on seeds ``--eval-seed``, ``+ 1``, ... and the summary
gets the mean return and the normalised score (``minari.get_normalized_score``, where the dataset has
reference scores).

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

from agents.imitation import DaggerConfig, Dataset, agreement, fit

#: the fields of :class:`agents.imitation.DaggerConfig` that the supervised fit reads
FIT_FIELDS = ("epochs", "batch_size", "learning_rate", "class_weight_power")


class ArrayDataset(Dataset):
    """A :class:`agents.imitation.Dataset` over arrays already stacked (the dataset's observations)."""

    def __init__(self, obs: Any, actions: np.ndarray) -> None:
        super().__init__()
        self._obs, self._actions = obs, np.asarray(actions, dtype=np.int64)

    def __len__(self) -> int:
        return len(self._actions)

    def arrays(self) -> tuple[Any, np.ndarray]:
        return self._obs, self._actions


def load_samples(dataset, labels: str = "expert") -> tuple[Any, np.ndarray]:
    """The labelled (observation, action) pairs of every episode of a Minari ``dataset``.

    Args:
        dataset: a :class:`minari.MinariDataset` written by ``rhs-slam record``.
        labels: ``"expert"`` (the headway expert's ``infos["expert_action"]``) or ``"actions"`` (what was driven).

    Returns:
        The observations (a dict of arrays, one row per labelled state) and the labels, int64.
    """
    if labels not in ("expert", "actions"):
        raise ValueError(f"labels must be 'expert' or 'actions', got {labels!r}")
    obs_parts: list[Any] = []
    label_parts = []
    for ep in dataset.iterate_episodes():
        n = len(ep.actions)
        if labels == "expert":
            if ep.infos is None or "expert_action" not in ep.infos:
                raise ValueError(f"episode {ep.id} has no infos['expert_action']: record it with rhs-slam record")
            y = np.asarray(ep.infos["expert_action"][:n], dtype=np.int64)
        else:
            y = np.asarray(ep.actions, dtype=np.int64).reshape(n)
        keep = y >= 0
        o = ep.observations
        obs_parts.append({k: np.asarray(v[:n])[keep] for k, v in o.items()} if isinstance(o, dict) else np.asarray(o[:n])[keep])
        label_parts.append(y[keep])
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


def clone(dataset, out: str | Path, labels: str = "expert", epochs: int | None = None, seed: int = 0,
          torch_threads: int | None = 1) -> tuple[Any, dict[str, Any]]:
    """Fit the student on ``dataset`` and save it to ``out/model.zip`` (+ its JSON).

    Args:
        dataset: a Minari dataset of ``rhs-slam record``.
        out: output folder.
        labels: see :func:`load_samples`.
        epochs: passes over the data (default: the DAgger hyperparameters' ``epochs``).
        seed: torch and shuffling seed.
        torch_threads: torch's intra-op threads (None: torch's default).

    Returns:
        The SB3 model and the summary written beside it.
    """
    import torch
    from stable_baselines3 import PPO

    import rhs_env  # noqa: F401  (registers the ids the dataset's spec names)
    from agents.run_setup import limit_threads, run_settings

    env_id, env_kwargs = env_of(dataset)
    obs, y = load_samples(dataset, labels)
    run = run_settings("dagger", env_id, 1, 1, None, None)
    config = DaggerConfig(**{k: run.hp[k] for k in FIT_FIELDS if k in run.hp})
    if epochs is not None:
        config = replace(config, epochs=epochs)
    limit_threads(torch_threads)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    env = dataset.recover_environment()
    t0 = time.perf_counter()
    try:
        model = PPO(run.policy, env, seed=seed, device="cpu", verbose=0, policy_kwargs=run.hp.get("policy_kwargs") or {})
        optimizer = torch.optim.Adam(model.policy.parameters(), lr=config.learning_rate)
        data = ArrayDataset(obs, y)
        loss = fit(model, data, config, rng, optimizer)
        train_agreement = agreement(model, obs, y)
    finally:
        env.close()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model.save(out / "model.zip")
    summary = {
        "algo": "dagger", "env_id": env_id, "env_kwargs": env_kwargs, "dataset_id": dataset.spec.dataset_id,
        "labels": labels, "samples": int(len(y)), "episodes": int(dataset.total_episodes),
        "bc": {k: v for k, v in asdict(config).items() if k in FIT_FIELDS},
        "seed": seed, "final_loss": loss, "train_agreement": train_agreement,
        "wall_s": round(time.perf_counter() - t0, 2), "model": str(out / "model.zip"),
    }
    (out / "model.json").write_text(json.dumps(summary, indent=2))
    return model, summary


def evaluate_clone(model_path: str | Path, dataset, episodes: int, seed: int) -> dict[str, Any]:
    """Drive the saved student ``episodes`` episodes (seeds ``seed``, ...): mean return, crashes, normalised score."""
    import minari

    from agents.evaluate import load_policy, make_env, resolve_env, run_episode

    env_id, env_kwargs = resolve_env(model_path)
    env = make_env(env_id, env_kwargs)
    try:
        policy = load_policy(model_path, env, seed)
        runs = [run_episode(env, policy, seed + k) for k in range(episodes)]
    finally:
        env.close()
    returns = np.array([r["return"] for r in runs])
    out: dict[str, Any] = {"eval_seeds": [seed, seed + episodes - 1], "mean_return": float(returns.mean()),
                           "crashes": int(sum(r["crashed"] for r in runs))}
    if dataset.storage.metadata.get("ref_max_score") is not None:
        out["normalized_score"] = float(np.mean(minari.get_normalized_score(dataset, returns)))
    return out


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset-id", required=True, help="Minari id (under $MINARI_DATASETS_PATH or --datasets)")
    ap.add_argument("--datasets", default=None, help="Minari datasets folder (default: $MINARI_DATASETS_PATH)")
    ap.add_argument("--out", required=True, help="folder for model.zip and model.json")
    ap.add_argument("--labels", choices=("expert", "actions"), default="expert")
    ap.add_argument("--epochs", type=int, default=None, help="passes over the data (default: dagger.yml's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--eval-episodes", type=int, default=0, help="episodes to drive the student after (0: none)")
    ap.add_argument("--eval-seed", type=int, default=1000, help="seed of the first evaluation episode")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    import os

    args = parse_args(argv)
    try:
        import minari
    except ImportError:
        print('bc_from_dataset: error: needs minari: pip install -c constraints/base.txt -e ".[dataset]"', file=sys.stderr)
        return 2
    if args.datasets is not None:
        os.environ["MINARI_DATASETS_PATH"] = str(Path(args.datasets).resolve())
    try:
        if args.epochs is not None and not 1 <= args.epochs <= 1000:
            raise ValueError(f"--epochs must be in [1, 1000], got {args.epochs}")
        if not 0 <= args.eval_episodes <= 10_000:
            raise ValueError(f"--eval-episodes must be in [0, 10000], got {args.eval_episodes}")
        dataset = minari.load_dataset(args.dataset_id)
        _, summary = clone(dataset, args.out, args.labels, args.epochs, args.seed)
    except (ValueError, FileNotFoundError) as exc:
        print(f"bc_from_dataset: error: {exc}", file=sys.stderr)
        return 2
    if args.eval_episodes:
        summary["evaluation"] = evaluate_clone(Path(args.out) / "model.zip", dataset, args.eval_episodes, args.eval_seed)
        (Path(args.out) / "model.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
