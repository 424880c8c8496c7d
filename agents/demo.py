"""``rhs-slam demo``: one SLAM-in-the-loop episode with the shipped policy.

Drives the default env (``rhs-highway-slam-v0``) with the policy shipped in
``agents/data`` (``--policy FILE`` for another zip, ``--policy random`` for a
uniformly random policy, ``--policy constant:4`` for one action at every step), on the env kwargs saved beside the policy
(``--env-kwargs`` is merged over them, see :mod:`agents.evaluate`). Prints the
return, collision, mean speed and SLAM errors (position and heading RMSE over
the episode, final map RMSE) as JSON, and writes ``OUT/trajectory_map.png``
(true and estimated trajectory and map, position error over time),
``OUT/demo.json`` and, with ``--animation``, ``OUT/episode.gif`` of the rendered
episode (radar points, true and estimated trajectory and map drawn over the road).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from agents.evaluate import (
    DEFAULT_ENV,
    SHIPPED_POLICY,
    _json_default,
    load_policy,
    parse_env_kwargs,
    plot_summary,
    resolve_env,
    run_episode,
)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--env", default=None, help=f"env id (default: the policy's, else {DEFAULT_ENV})")
    parser.add_argument(
        "--policy", default=str(SHIPPED_POLICY), help="SB3 zip, 'random' or 'constant:ACTION' (default: shipped)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--env-kwargs", default=None, help="JSON dict passed to gym.make, merged over the policy's saved env kwargs"
    )
    parser.add_argument("--out", default="rhs_slam_demo", help="output directory (default: ./rhs_slam_demo)")
    parser.add_argument("--animation", action="store_true", help="also write episode.gif of the rendered frames")
    parser.add_argument("--fps", type=float, default=5.0, help="GIF frame rate (default 5 = real time)")


def run(args: argparse.Namespace) -> int:
    import gymnasium as gym
    import numpy as np

    import rhs_env  # noqa: F401

    from rhs_common.validation import check_output_path

    env = None
    try:
        check_output_path("--out", args.out, directory=True)
        if not 0 <= args.seed < 2**63:
            raise ValueError(f"--seed must be an integer in [0, 2**63), got {args.seed}")
        if not 0.1 <= args.fps <= 100:
            raise ValueError(f"--fps must be in [0.1, 100], got {args.fps}")
        env_id, env_kwargs = resolve_env(args.policy, args.env, parse_env_kwargs(args.env_kwargs))
        if args.animation:
            env_kwargs.setdefault("render_mode", "rgb_array")
        try:
            env = gym.make(env_id, **env_kwargs)
        except TypeError as exc:
            raise ValueError(f"bad env kwargs for {env_id}: {exc}") from None
        policy = load_policy(args.policy, env, args.seed)
    except (ValueError, FileNotFoundError, json.JSONDecodeError) as exc:
        print(f"rhs-slam demo: error: {exc}", file=sys.stderr)
        if env is not None:
            env.close()
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frames: list | None = [] if args.animation else None
    print(f"rhs-slam demo: one episode of {env_id} (seed {args.seed}) with policy {args.policy}", file=sys.stderr)
    try:
        result = run_episode(env, policy, args.seed, frames=frames)
    finally:
        env.close()
    summary = {
        "env_id": env_id,
        "env_kwargs": {k: v for k, v in env_kwargs.items() if k != "render_mode"},
        "policy": str(args.policy),
        "seed": args.seed,
        "return": result["return"],
        "steps": result["steps"],
        "crashed": result["crashed"],
        "collisions": int(result["crashed"]),
        "mean_speed_mps": result["mean_speed"],
        "position_rmse_m": result["position_rmse_m"],
        "final_position_error_m": result["final_position_error_m"],
        "heading_rmse_rad": result["heading_rmse_rad"],
        "map_rmse_m": result["map_rmse_m"],
        "map_matched": result["map_matched"],
        "map_missed": result["map_missed"],
        "map_spurious": result["map_spurious"],
    }
    figure = out / "trajectory_map.png"
    plot_summary({"env_id": env_id, "runs": [result]}, figure)
    summary["figure"] = str(figure)
    if frames:
        from PIL import Image  # pillow comes with matplotlib

        frames = [f for f in frames if isinstance(f, np.ndarray) and f.ndim == 3]
        if frames:
            gif = out / "episode.gif"
            images = [Image.fromarray(np.asarray(f, dtype=np.uint8)) for f in frames]
            duration = max(20, round(1000.0 / max(args.fps, 0.1)))
            images[0].save(gif, save_all=True, append_images=images[1:], duration=duration, loop=0)
            summary["animation"] = str(gif)
    (out / "demo.json").write_text(json.dumps(summary, indent=2, default=_json_default))
    print(json.dumps(summary, indent=2, default=_json_default))
    return 0
