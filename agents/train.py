"""Train driving agents with stable-baselines3 (``rhs-slam train``).

PPO or DQN with the hyperparameters of ``agents/hyperparams/<algo>.yml`` for the
env id (rl-baselines3-zoo style), ``SubprocVecEnv`` over ``n_envs`` envs each
wrapped in a ``Monitor`` that logs ``crashed``, TensorBoard logs, an
``EvalCallback`` on a separate env, periodic checkpoints and a progress bar.
Writes ``DIR/model.zip`` (the final policy), ``DIR/best_model.zip``,
``DIR/checkpoints/``, ``DIR/tb/`` and ``DIR/train.json`` (settings and timings).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import yaml

ALGOS = ("ppo", "dqn")
HYPERPARAMS_DIR = Path(__file__).parent / "hyperparams"


def load_hyperparams(algo: str, env_id: str, path: str | Path | None = None) -> dict[str, Any]:
    """Hyperparameters for ``env_id`` from a zoo-style YAML file (default: the shipped one for ``algo``)."""
    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    path = Path(path) if path else HYPERPARAMS_DIR / f"{algo}.yml"
    table = yaml.safe_load(path.read_text())
    if env_id not in table:
        raise ValueError(f"{path} has no hyperparameters for env {env_id!r} (has: {', '.join(table)})")
    return dict(table[env_id])


def _resolve_policy_kwargs(kwargs: dict[str, Any]) -> dict[str, Any]:
    from agents.features import FEATURE_EXTRACTORS

    kwargs = dict(kwargs or {})
    name = kwargs.get("features_extractor_class")
    if isinstance(name, str):
        if name not in FEATURE_EXTRACTORS:
            raise ValueError(f"features_extractor_class must be one of {list(FEATURE_EXTRACTORS)}, got {name!r}")
        kwargs["features_extractor_class"] = FEATURE_EXTRACTORS[name]
    return kwargs


def make_vec_env(env_id: str, n_envs: int, seed: int, env_kwargs: dict | None = None, subprocess: bool = True):
    """``n_envs`` copies of ``env_id`` (``Monitor`` logging ``crashed``), in subprocesses when n_envs > 1."""
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    import rhs_env  # noqa: F401  (registers the ids in this process)

    vec_cls = SubprocVecEnv if (subprocess and n_envs > 1) else DummyVecEnv
    return sb3_make_vec_env(
        env_id,
        n_envs=n_envs,
        seed=seed,
        env_kwargs=env_kwargs or {},
        vec_env_cls=vec_cls,
        vec_env_kwargs={"start_method": "spawn"} if vec_cls is SubprocVecEnv else None,
        monitor_kwargs={"info_keywords": ("crashed",)},
    )


def _progress_callback(total: int):
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm.auto import tqdm

    class TqdmCallback(BaseCallback):
        """Progress bar over environment steps (SB3's own needs the rich package)."""

        def _on_training_start(self) -> None:
            self.bar = tqdm(total=total, desc="train", unit="step")

        def _on_step(self) -> bool:
            self.bar.update(self.training_env.num_envs)
            return True

        def _on_training_end(self) -> None:
            self.bar.close()

    return TqdmCallback()


def train(
    algo: str,
    env_id: str,
    timesteps: int,
    out: str | Path,
    seed: int = 0,
    n_envs: int | None = None,
    hyperparams: str | Path | None = None,
    env_kwargs: dict | None = None,
    eval_freq: int = 2000,
    eval_episodes: int = 3,
    checkpoint_freq: int = 5000,
    progress: bool = True,
) -> dict[str, Any]:
    """Train ``algo`` on ``env_id`` for ``timesteps`` steps; returns the summary written to ``out/train.json``."""
    from stable_baselines3 import DQN, PPO
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback, EvalCallback

    if timesteps < 1:
        raise ValueError(f"timesteps must be >= 1, got {timesteps}")
    hp = load_hyperparams(algo, env_id, hyperparams)
    policy = hp.pop("policy")
    n_envs = int(n_envs or hp.pop("n_envs", 1))
    hp.pop("n_envs", None)
    env_kwargs = {**hp.pop("env_kwargs", {}), **(env_kwargs or {})}
    hp["policy_kwargs"] = _resolve_policy_kwargs(hp.get("policy_kwargs", {}))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)

    venv = make_vec_env(env_id, n_envs, seed, env_kwargs)
    eval_env = make_vec_env(env_id, 1, seed + 10_000, env_kwargs, subprocess=False)
    cls = {"ppo": PPO, "dqn": DQN}[algo]
    model = cls(policy, venv, seed=seed, verbose=0, tensorboard_log=str(out / "tb"), **hp)
    callbacks = [
        EvalCallback(
            eval_env,
            n_eval_episodes=eval_episodes,
            eval_freq=max(1, eval_freq // n_envs),
            best_model_save_path=str(out),
            log_path=str(out / "eval"),
            deterministic=True,
            verbose=0,
        ),
        CheckpointCallback(save_freq=max(1, checkpoint_freq // n_envs), save_path=str(out / "checkpoints")),
    ]
    if progress:
        callbacks.append(_progress_callback(timesteps))
    t0 = time.perf_counter()
    model.learn(total_timesteps=timesteps, callback=CallbackList(callbacks), tb_log_name=algo)
    wall = time.perf_counter() - t0
    model.save(out / "model.zip")
    venv.close()
    eval_env.close()
    summary = {
        "algo": algo,
        "env_id": env_id,
        "timesteps": int(model.num_timesteps),
        "n_envs": n_envs,
        "seed": seed,
        "wall_time_s": round(wall, 1),
        "steps_per_s": round(model.num_timesteps / wall, 2),
        "env_kwargs": env_kwargs,
        "model": str(out / "model.zip"),
    }
    (out / "train.json").write_text(json.dumps(summary, indent=2))
    return summary


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--algo", choices=ALGOS, default="ppo")
    parser.add_argument("--env", default="rhs-highway-slam-v0", help="env id (default: rhs-highway-slam-v0)")
    parser.add_argument("--timesteps", type=int, default=20_000)
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--n-envs", type=int, default=None, help="subprocess envs (default: from the YAML)")
    parser.add_argument("--hyperparams", default=None, help="zoo-style YAML (default: agents/hyperparams/ALGO.yml)")
    parser.add_argument("--env-kwargs", default="{}", help="JSON dict passed to gym.make")
    parser.add_argument("--eval-freq", type=int, default=2000)
    parser.add_argument("--no-progress", action="store_true")


def run(args: argparse.Namespace) -> int:
    import sys

    try:
        env_kwargs = json.loads(args.env_kwargs)
        if not isinstance(env_kwargs, dict):
            raise ValueError("--env-kwargs must be a JSON object")
        summary = train(
            args.algo,
            args.env,
            args.timesteps,
            args.out,
            seed=args.seed,
            n_envs=args.n_envs,
            hyperparams=args.hyperparams,
            env_kwargs=env_kwargs,
            eval_freq=args.eval_freq,
            progress=not args.no_progress,
        )
    except (ValueError, json.JSONDecodeError) as exc:
        print(f"rhs-slam train: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(summary, indent=2))
    return 0
