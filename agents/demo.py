"""``rhs-slam demo``: one SLAM-in-the-loop episode with the shipped policy.

Drives the default env (``rhs-highway-slam-v0``) with the policy shipped in
``agents/data`` (a uniformly random policy with ``--policy random``), prints
return, collision and SLAM errors as JSON, and writes the true/estimated
trajectory and map figure (and, with ``--animation``, a GIF of the rendered
episode).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from agents.evaluate import SHIPPED_POLICY, load_policy, plot_summary, run_episode


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--env", default="rhs-highway-slam-v0")
    parser.add_argument("--policy", default=str(SHIPPED_POLICY), help="SB3 zip or 'random' (default: shipped)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--env-kwargs", default="{}", help="JSON dict passed to gym.make")
    parser.add_argument("--out", default="rhs_slam_demo", help="output directory (default: ./rhs_slam_demo)")
    parser.add_argument("--animation", action="store_true", help="also write episode.gif of the rendered frames")


def run(args: argparse.Namespace) -> int:
    import gymnasium as gym
    import numpy as np

    import rhs_env  # noqa: F401

    try:
        env_kwargs = json.loads(args.env_kwargs)
        if not isinstance(env_kwargs, dict):
            raise ValueError("--env-kwargs must be a JSON object")
        if args.animation:
            env_kwargs.setdefault("render_mode", "rgb_array")
        env = gym.make(args.env, **env_kwargs)
        policy = load_policy(args.policy, env, args.seed)
    except (ValueError, FileNotFoundError, json.JSONDecodeError) as exc:
        print(f"rhs-slam demo: error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frames: list | None = [] if args.animation else None
    print(f"rhs-slam demo: one episode of {args.env} (seed {args.seed}) with policy {args.policy}", file=sys.stderr)
    result = run_episode(env, policy, args.seed, frames=frames)
    env.close()
    summary = {
        "env_id": args.env,
        "policy": str(args.policy),
        "seed": args.seed,
        "return": result["return"],
        "steps": result["steps"],
        "crashed": result["crashed"],
        "mean_speed_mps": result["mean_speed"],
        "position_rmse_m": result["position_rmse_m"],
        "map_rmse_m": result["map_rmse_m"],
    }
    figure = out / "trajectory_map.png"
    plot_summary({"env_id": args.env, "runs": [result]}, figure)
    summary["figure"] = str(figure)
    if frames:
        from PIL import Image  # pillow comes with matplotlib

        gif = out / "episode.gif"
        images = [Image.fromarray(np.asarray(f, dtype=np.uint8)) for f in frames]
        images[0].save(gif, save_all=True, append_images=images[1:], duration=200, loop=0)
        summary["animation"] = str(gif)
    (out / "demo.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps(summary, indent=2))
    return 0
