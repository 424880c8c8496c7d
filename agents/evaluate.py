"""Evaluate a driving policy with SLAM in the loop (``rhs-slam evaluate``).

Runs ``episodes`` episodes on seeds ``seed, seed + 1, ...`` (so two policies
evaluated with the same seed meet the same traffic) and reports, as mean and
standard deviation over episodes: return, collision rate, mean speed, and, on
envs with the SLAM wrapper, the position RMSE of the estimated trajectory
(sqrt of the mean squared per-step position error) and the final map RMSE.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

SHIPPED_POLICY = Path(__file__).parent / "data" / "ppo_rhs_highway_slam.zip"


class RandomPolicy:
    """Uniformly random actions from the env's action space (seeded)."""

    def __init__(self, action_space, seed: int = 0):
        self.space = action_space
        self.space.seed(seed)

    def predict(self, obs, deterministic: bool = True):
        return self.space.sample(), None


def load_policy(policy: str | Path, env=None, seed: int = 0):
    """``"random"``, or a stable-baselines3 zip (PPO or DQN, detected from the file)."""
    if str(policy) == "random":
        if env is None:
            raise ValueError("a random policy needs the env for its action space")
        return RandomPolicy(env.action_space, seed)
    path = Path(policy)
    if not path.exists():
        raise FileNotFoundError(f"policy file not found: {path}")
    from stable_baselines3 import DQN, PPO

    errors = []
    for cls in (PPO, DQN):
        try:
            return cls.load(path, device="cpu")
        except Exception as exc:  # wrong algorithm class for this zip: try the next one
            errors.append(f"{cls.__name__}: {exc}")
    raise ValueError(f"{path} is not a PPO or DQN model ({'; '.join(errors)})")


def _stats(values: list[float]) -> dict[str, float | None]:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if v.size == 0:
        return {"mean": None, "std": None}
    return {"mean": float(v.mean()), "std": float(v.std())}


def run_episode(env, policy, seed: int, deterministic: bool = True, frames: list | None = None) -> dict[str, Any]:
    """One episode; returns its return, crash flag, mean speed, SLAM errors and the trajectories."""
    obs, info = env.reset(seed=seed)
    total, steps, speeds, pos_err2 = 0.0, 0, [], []
    true_xy, est_xy = [], []
    crashed, done = False, False
    while not done:
        action, _ = policy.predict(obs, deterministic=deterministic)
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        steps += 1
        crashed = crashed or bool(info.get("crashed", False))
        speeds.append(float(info.get("speed", np.nan)))
        if "position_error_m" in info:
            pos_err2.append(float(info["position_error_m"]) ** 2)
            true_xy.append(np.asarray(info["true_pose"][:2], dtype=float).tolist())
            est_xy.append(np.asarray(info["estimated_pose"][:2], dtype=float).tolist())
        if frames is not None:
            frames.append(env.render())
        done = terminated or truncated
    return {
        "seed": seed,
        "return": total,
        "steps": steps,
        "crashed": crashed,
        "mean_speed": float(np.nanmean(speeds)) if speeds else None,
        "position_rmse_m": float(np.sqrt(np.mean(pos_err2))) if pos_err2 else None,
        "map_rmse_m": info.get("map_rmse_m"),
        "true_xy": true_xy,
        "estimated_xy": est_xy,
        "landmarks_true": np.asarray(info.get("true_landmarks", np.zeros((0, 2)))).tolist(),
        "landmarks_est": np.asarray(info.get("estimated_landmarks", np.zeros((0, 2)))).tolist(),
    }


def evaluate(
    policy: str | Path,
    env_id: str,
    episodes: int = 5,
    seed: int = 0,
    env_kwargs: dict | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Evaluate ``policy`` on ``episodes`` seeded episodes of ``env_id``; returns the JSON-ready summary."""
    import gymnasium as gym
    from tqdm.auto import tqdm

    import rhs_env  # noqa: F401

    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    env = gym.make(env_id, **(env_kwargs or {}))
    model = load_policy(policy, env, seed)
    runs = [run_episode(env, model, seed + k) for k in tqdm(range(episodes), desc="evaluate", disable=not progress)]
    env.close()
    summary = {
        "policy": str(policy),
        "env_id": env_id,
        "episodes": episodes,
        "seed": seed,
        "return": _stats([r["return"] for r in runs]),
        "collision_rate": float(np.mean([r["crashed"] for r in runs])),
        "mean_speed_mps": _stats([r["mean_speed"] for r in runs]),
        "position_rmse_m": _stats([r["position_rmse_m"] for r in runs]),
        "map_rmse_m": _stats([r["map_rmse_m"] for r in runs]),
        "episode_length": _stats([r["steps"] for r in runs]),
        "runs": runs,
    }
    return summary


def plot_summary(summary: dict[str, Any], path: str | Path) -> None:
    """Per-episode returns and, when available, the first episode's true vs estimated trajectory and map."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = summary["runs"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    axes[0].bar(range(len(runs)), [r["return"] for r in runs], color=["C3" if r["crashed"] else "C0" for r in runs])
    axes[0].set(xlabel="episode", ylabel="return", title=f"{summary['env_id']}: return (red = crashed)")
    r0 = runs[0]
    if r0["true_xy"]:
        t, e = np.asarray(r0["true_xy"]), np.asarray(r0["estimated_xy"])
        axes[1].plot(t[:, 0], t[:, 1], "k-", label="true trajectory")
        axes[1].plot(e[:, 0], e[:, 1], "C1--", label="estimated trajectory")
        lt, le = np.asarray(r0["landmarks_true"]), np.asarray(r0["landmarks_est"])
        if lt.size:
            axes[1].plot(lt[:, 0], lt[:, 1], "ks", ms=4, mfc="none", label="true landmarks")
        if le.size:
            axes[1].plot(le[:, 0], le[:, 1], "C1x", ms=4, label="estimated landmarks")
        axes[1].set(xlabel="x (m)", ylabel="y (m)", title="episode 1: trajectory and map (map frame)")
        axes[1].legend(fontsize=8)
    else:
        axes[1].axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--policy", default=str(SHIPPED_POLICY), help="SB3 zip, or 'random' (default: shipped policy)")
    parser.add_argument("--env", default="rhs-highway-slam-v0")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--env-kwargs", default="{}", help="JSON dict passed to gym.make")
    parser.add_argument("--out", required=True, help="output JSON file")
    parser.add_argument("--figure", default=None, help="output PNG (default: next to --out)")
    parser.add_argument("--no-progress", action="store_true")


def run(args: argparse.Namespace) -> int:
    try:
        env_kwargs = json.loads(args.env_kwargs)
        if not isinstance(env_kwargs, dict):
            raise ValueError("--env-kwargs must be a JSON object")
        summary = evaluate(args.policy, args.env, args.episodes, args.seed, env_kwargs, not args.no_progress)
    except (ValueError, FileNotFoundError, json.JSONDecodeError) as exc:
        print(f"rhs-slam evaluate: error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(summary, indent=2))
    plot_summary(summary, args.figure or out.with_suffix(".png"))
    brief = {k: v for k, v in summary.items() if k != "runs"}
    print(json.dumps(brief, indent=2))
    return 0
