"""The front page's video: one drive of the shipped policy on ``rhs-highway-slam-v0``, as a GIF.

The frames are the env's own rendering (radar points, true and SLAM trajectory, the SLAM map, the
landmarks) with :class:`rhs_env.video.RecordEpisodeVideo`'s legend and status strip (time, return,
speed, SLAM track health, position error against the filter's 2-sigma). Default: seed 0, the first
16 s of the episode (80 cycles at 5 Hz: the env's ``duration`` cut to ``--seconds``), full size, real time.

Outputs (``--out-dir``, default ``results/``): ``episode.gif`` (under 2 MB: README.md and the docs'
front page show it) and ``episode_video.json`` (frames, bytes, the drive's return and SLAM errors,
provenance).

    OMP_NUM_THREADS=1 python scripts/make_video.py [--seed 0] [--seconds 16] [--every 1] [--scale 1.0]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from rhs_studies.kit.episodes import start_study
from rhs_studies.kit.provenance import write_json
from rhs_studies.kit.seeds import first

#: the front page's file must stay small
MAX_BYTES = 2_000_000


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    from agents import SHIPPED_POLICY

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", default=SHIPPED_POLICY, help="policy, as rhs-slam demo takes it (default: shipped)")
    ap.add_argument("--env", default=None, help="env id (default: the policy's)")
    ap.add_argument("--seed", type=int, default=first("scenes"))
    ap.add_argument("--seconds", type=float, default=16.0, help="simulated seconds recorded (the episode's duration)")
    ap.add_argument("--every", type=int, default=1, help="keep every k-th step's frame")
    ap.add_argument("--scale", type=float, default=1.0, help="resize factor of the frames")
    ap.add_argument("--out-dir", default="results")
    return ap.parse_args(argv)


def run(a: argparse.Namespace, out: Path) -> dict[str, Any]:
    """Drive the episode through the recorder; the record of the video and of the drive."""
    from agents.evaluate import is_scripted, load_policy, make_env, resolve_env, run_episode
    from rhs_env.video import RecordEpisodeVideo

    if not 1.0 <= a.seconds <= 600.0:
        raise ValueError(f"--seconds must be in [1, 600], got {a.seconds}")
    env_id, env_kwargs = resolve_env(a.policy, a.env)
    env_kwargs.update(render_mode="rgb_array", duration=a.seconds)
    gif = out / "episode.gif"
    env = RecordEpisodeVideo(make_env(env_id, env_kwargs), gif, every=a.every, scale=a.scale)
    try:
        result = run_episode(env, load_policy(a.policy, env, a.seed), a.seed)
    finally:
        env.close()
    from PIL import Image

    with Image.open(gif) as im:
        frames, size = int(getattr(im, "n_frames", 1)), list(im.size)
    size_bytes = gif.stat().st_size
    if size_bytes > MAX_BYTES:
        print(f"make_video: warning: {gif} is {size_bytes / 1e6:.1f} MB (front page: under {MAX_BYTES / 1e6:.0f} MB); "
              "use --every 2 or --scale 0.75", file=sys.stderr)
    return {
        "env_id": env_id, "env_kwargs": {k: v for k, v in env_kwargs.items() if k != "render_mode"},
        "policy": a.policy if is_scripted(a.policy) else Path(a.policy), "seed": a.seed, "video": str(gif.name),
        "frames": frames, "size_px": size,
        "bytes": size_bytes, "fps": env.fps / env.every,
        **{k: result[k] for k in ("return", "steps", "crashed", "mean_speed", "position_rmse_m",
                                  "final_position_error_m", "map_rmse_m")},
    }


def main(argv: list[str] | None = None) -> int:
    a, started, out = start_study(parse_args, argv)
    try:
        result = run(a, out)
    except (ValueError, FileNotFoundError) as exc:
        print(f"make_video: error: {exc}", file=sys.stderr)
        return 2
    write_json(out / "episode_video.json", result, __file__, a, started, None, argv)
    print(f"wrote {out / 'episode.gif'} ({result['frames']} frames, {result['bytes'] / 1e3:.0f} kB), "
          f"{out / 'episode_video.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
