"""``rhs-slam demo``: one SLAM-in-the-loop episode with the shipped policy.

Drives the default env (``rhs-highway-slam-v0``) with the shipped policy, :data:`agents.SHIPPED_POLICY`
(``agents/data/shipped.zip``; its record names the experiment it came from) (``--policy FILE`` for another zip, ``--policy random`` for a
uniformly random policy, ``--policy constant:4`` for one action at every step), on the env kwargs saved beside the policy
(``--env-kwargs`` is merged over them, see :mod:`agents.evaluate`). Shows a
per-step progress bar, prints the return, collision, mean speed and SLAM errors
(position and heading RMSE over the episode, final map RMSE) as JSON, and writes
``OUT/trajectory_map.png`` (:func:`plot_demo`: three snapshots of the radar point
cloud and the estimated map around the car, and the position error over time
against the filter's own 2-sigma band), ``OUT/demo.json`` and, with
``--animation``, ``OUT/episode.gif`` of the rendered episode (radar points, true
and estimated trajectory and map drawn over the road, a legend strip below);
``--video PATH`` (``.gif``, or ``.mp4`` with the ``video`` extra) writes it through
:class:`rhs_env.video.RecordEpisodeVideo`, with the SLAM health and position error in a status strip.
Each file is written atomically (:mod:`rhs_common.output_files`). Ctrl-C (SIGINT) during the
episode or while the outputs are written ends it with one line on stderr and exit status 130:
``OUT/demo.json`` then says what was done (the steps driven) with ``"partial": true`` and the
files of a previous run are left as they were; before the episode starts nothing is written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from agents import SHIPPED_POLICY
from agents.evaluate import (
    DEFAULT_ENV,
    episode_steps,
    json_default,
    load_policy,
    make_env,
    parse_env_kwargs,
    plot_summary,
    resolve_env,
    run_episode,
)

__all__ = ["GIF_LEGEND", "configure", "plot_demo", "run", "with_legend"]

#: GIF legend: the colours drawn over highway-env's frame (rhs_env.wrappers, slam.gym.wrappers, rhs_env.envs)
GIF_LEGEND = (
    ((255, 40, 40), "radar points"),
    ((60, 220, 60), "true landmarks"),
    ((30, 30, 30), "true trajectory"),
    ((255, 140, 0), "SLAM trajectory + map"),
    ((50, 200, 0), "ego car"),
)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--env", default=None, help=f"env id (default: the policy's, else {DEFAULT_ENV})")
    parser.add_argument(
        "--policy", default=str(SHIPPED_POLICY), help="SB3 zip, 'random', 'constant:ACTION', 'idm', 'headway[:K]' or "
        "'lookahead[:K]' (default: shipped)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--env-kwargs", default=None, help="JSON dict passed to gym.make, merged over the policy's saved env kwargs"
    )
    parser.add_argument("--out", default="rhs_slam_demo", help="output directory (default: ./rhs_slam_demo)")
    parser.add_argument("--animation", action="store_true", help="also write episode.gif of the rendered frames")
    parser.add_argument("--fps", type=float, default=5.0, help="GIF frame rate (default 5 = real time)")
    parser.add_argument("--video", default=None, metavar="PATH",
                        help="also write the episode as a .gif or .mp4 (radar points, SLAM estimate and health)")


def run(args: argparse.Namespace) -> int:
    import rhs_env  # noqa: F401
    from rhs_common.validation import check_output_path
    from rhs_env.video import RecordEpisodeVideo, check_video_path

    env = None
    try:
        check_output_path("--out", args.out, directory=True)
        if not 0 <= args.seed < 2**63:
            raise ValueError(f"--seed must be an integer in [0, 2**63), got {args.seed}")
        if not 0.1 <= args.fps <= 100:
            raise ValueError(f"--fps must be in [0.1, 100], got {args.fps}")
        env_id, env_kwargs = resolve_env(args.policy, args.env, parse_env_kwargs(args.env_kwargs))
        if args.video is not None:
            check_video_path("--video", args.video)
        if args.animation or args.video is not None:
            env_kwargs.setdefault("render_mode", "rgb_array")
        env = make_env(env_id, env_kwargs)
        if args.video is not None:
            env = RecordEpisodeVideo(env, args.video, fps=args.fps)
        policy = load_policy(args.policy, env, args.seed)
    except (ValueError, TypeError, FileNotFoundError, json.JSONDecodeError) as exc:
        print(f"rhs-slam demo: error: {exc}", file=sys.stderr)
        if env is not None:
            env.close()
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frames: list | None = [] if args.animation else None
    trace: list = []
    slam = _show_landmarks(env)
    print(f"rhs-slam demo: one episode of {env_id} (seed {args.seed}) with policy {args.policy}", file=sys.stderr)
    summary: dict = {
        "env_id": env_id,
        "env_kwargs": {k: v for k, v in env_kwargs.items() if k != "render_mode"},
        "policy": str(args.policy),
        "seed": args.seed,
    }
    try:
        return _episode_and_outputs(args, env, policy, out, summary, frames, trace, slam)
    except KeyboardInterrupt:
        return _interrupted(out, summary, trace, episode_steps(env))


def _interrupted(out: Path, summary: dict, trace: list, total_steps: int | None) -> int:
    """Ctrl-C: ``OUT/demo.json`` says what was done, marked ``"partial": true``; exit 130 (128 + SIGINT)."""
    import signal

    from rhs_common.output_files import write_text_atomic

    done = "steps" in summary  # the episode had finished: the figure or the GIF was being written
    if not done:
        summary["steps"] = max(len(trace) - 1, 0)
    summary.update(partial=True, interrupted="SIGINT")
    write_text_atomic(out / "demo.json", json.dumps(summary, indent=2, default=json_default))
    what = "while writing the outputs" if done else f"after {summary['steps']} of {total_steps or '?'} steps"
    print(f"rhs-slam demo: interrupted (Ctrl-C) {what}; wrote {out / 'demo.json'} marked \"partial\": true",
          file=sys.stderr)
    return 128 + int(signal.SIGINT)


def _episode_and_outputs(args, env, policy, out: Path, summary: dict, frames, trace: list, slam: bool) -> int:
    """Drive the episode, then write the figure, the GIF and ``demo.json`` (each atomically), filling ``summary``."""
    from tqdm.auto import tqdm

    from rhs_common.output_files import atomic_output, write_text_atomic

    env_id = summary["env_id"]
    try:
        with tqdm(total=episode_steps(env), desc="demo", unit="step") as bar:
            result = run_episode(env, policy, args.seed, frames=frames, trace=trace, bar=bar)
    finally:
        env.close()
    summary.update({
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
    })
    figure = out / "trajectory_map.png"
    print(f"rhs-slam demo: writing {figure}", file=sys.stderr)
    with atomic_output(figure) as tmp:
        if slam:
            plot_demo(trace, env_id, args.seed, tmp, dt=1.0 / float(env.unwrapped.config["policy_frequency"]))
        else:
            plot_summary({"env_id": env_id, "runs": [result]}, tmp)
    summary["figure"] = str(figure)
    if args.video is not None:  # written by RecordEpisodeVideo when the episode ended
        summary["video"] = str(args.video)
    if frames:
        from PIL import Image  # pillow comes with matplotlib

        frames = [f for f in frames if isinstance(f, np.ndarray) and f.ndim == 3]
        if frames:
            gif = out / "episode.gif"
            print(f"rhs-slam demo: writing {gif} ({len(frames)} frames)", file=sys.stderr)
            images = [with_legend(Image.fromarray(np.asarray(f, dtype=np.uint8))) for f in frames]
            duration = max(20, round(1000.0 / max(args.fps, 0.1)))
            with atomic_output(gif) as tmp:
                images[0].save(tmp, save_all=True, append_images=images[1:], duration=duration, loop=0)
            summary["animation"] = str(gif)
    summary["partial"] = False
    write_text_atomic(out / "demo.json", json.dumps(summary, indent=2, default=json_default))
    print(json.dumps(summary, indent=2, default=json_default))
    return 0


def _show_landmarks(env) -> bool:
    """Ask a SLAM env's :class:`slam.gym.metrics_info.SlamMetricsInfo` for the landmark maps in ``info``."""
    import gymnasium as gym

    from slam.gym.metrics_info import SlamMetricsInfo

    e = env
    while isinstance(e, gym.Wrapper):
        if isinstance(e, SlamMetricsInfo):
            e.landmarks_in_info = True
            return True
        e = e.env
    return False


def with_legend(image):
    """``image`` with a white strip below it holding the colour legend (never over the road)."""
    from PIL import Image, ImageDraw

    w, h = image.size
    row_h, pad = 16, 6
    per_row = max(1, w // 150)
    rows = -(-len(GIF_LEGEND) // per_row)
    out = Image.new("RGB", (w, h + rows * row_h + pad), "white")
    out.paste(image.convert("RGB"), (0, 0))
    draw = ImageDraw.Draw(out)
    for k, (color, text) in enumerate(GIF_LEGEND):
        x = 8 + (k % per_row) * (w // per_row)
        y = h + pad // 2 + (k // per_row) * row_h
        draw.ellipse([x, y + 3, x + 9, y + 12], fill=color)
        draw.text((x + 14, y + 1), text, fill=(0, 0, 0))
    return out


def _to_map(points_v: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Vehicle-frame points -> map frame at ``pose`` (x, y, heading)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.c_[pose[0] + c * points_v[:, 0] - s * points_v[:, 1], pose[1] + s * points_v[:, 0] + c * points_v[:, 1]]


def plot_demo(trace: list, env_id: str, seed: int, path: str | Path, dt: float, snapshots: int = 3) -> None:
    """The demo figure: what the radar sees, what the SLAM builds, and how far it is off.

    Top row, at ``snapshots`` instants (equal axes, map frame):
    the radar point cloud of that cycle placed with the SLAM pose, the estimated map
    (all landmarks so far), the true landmarks seen so far, the true and estimated
    trajectory up to that instant (120 x 60 m window, 84 m ahead of the car). Bottom: the position error ``||p_hat - p||`` over
    time against the filter's own 2-sigma band ``2 sqrt(sx^2 + sy^2)`` (``slam_pose_std``
    of ``info``, else ``pose_std`` of the observation): dead reckoning between landmark fixes
    drifts, and the band says how much drift the filter admits to; the track health
    (``slam_health``, right axis) and the cycles the filter says it is lost (``slam_lost``,
    shaded). Legends sit outside the axes.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    obs = [o for o, _ in trace]
    info = [i for _, i in trace]
    true_p = np.array([np.asarray(i["true_pose"], float) for i in info])
    est_p = np.array([np.asarray(i["estimated_pose"], float) for i in info])
    err = np.array([float(i["position_error_m"]) for i in info])
    # the filter's std: the info's slam_pose_std (which admits a loss) where the env reports it, else pose_std
    band = np.array([2.0 * float(np.hypot(*np.asarray(i.get("slam_pose_std", o["pose_std"]), float)[:2]))
                     for o, i in zip(obs, info)])
    health = np.array([float(i.get("slam_health", np.nan)) for i in info])
    lost = np.array([bool(i.get("slam_lost", False)) for i in info])
    t = dt * np.arange(len(trace))
    picks = np.unique(np.linspace(len(trace) // snapshots, len(trace) - 1, snapshots).round().astype(int))
    fig = plt.figure(figsize=(5.2 * len(picks), 6.4))
    grid = fig.add_gridspec(2, len(picks), height_ratios=[1.0, 1.0])
    half = 60.0
    for col, k in enumerate(picks):
        ax = fig.add_subplot(grid[0, col])
        lt = np.asarray(info[k].get("true_landmarks", np.zeros((0, 2))), float).reshape(-1, 2)
        le = np.asarray(info[k].get("estimated_landmarks", np.zeros((0, 2))), float).reshape(-1, 2)
        pts = np.asarray(obs[k]["points"], float)[np.asarray(obs[k]["points_mask"]) > 0][:, :2]
        ax.plot(true_p[: k + 1, 0], true_p[: k + 1, 1], "k-", lw=1.5, label="true trajectory")
        ax.plot(est_p[: k + 1, 0], est_p[: k + 1, 1], "--", color="C1", lw=1.5, label="SLAM trajectory")
        ax.plot(lt[:, 0], lt[:, 1], "s", ms=7, mfc="none", mec="0.35", label="true landmarks (seen)")
        ax.plot(le[:, 0], le[:, 1], "x", ms=7, color="C1", mew=2, label="SLAM map")
        if len(pts):
            mp = _to_map(pts, est_p[k])
            ax.plot(mp[:, 0], mp[:, 1], ".", ms=4, color="C3", label="radar points (this cycle)")
        ax.plot(*est_p[k, :2], "o", color="C1", ms=8)
        ax.set_xlim(est_p[k, 0] - 0.6 * half, est_p[k, 0] + 1.4 * half)  # more room ahead
        ax.set_ylim(est_p[k, 1] - half / 2, est_p[k, 1] + half / 2)
        ax.set_aspect("equal")
        ax.set(xlabel="x (m, map frame)", title=f"t = {t[k]:.1f} s: error {err[k]:.2f} m")
        if col == 0:
            ax.set_ylabel("y (m)")
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=len(labels), frameon=False, fontsize=9)
    ax = fig.add_subplot(grid[1, :])
    ax.fill_between(t, 0.0, band, color="C0", alpha=0.2, lw=0, label="filter's 2-sigma (slam_pose_std)")
    ax.plot(t, err, "C3-", lw=1.5, label="position error ||p_hat - p||")
    if lost.any():
        ax.fill_between(t, 0.0, 1.0, where=lost, transform=ax.get_xaxis_transform(), color="C3", alpha=0.12, lw=0,
                        label="filter says lost (slam_lost)")
    if np.isfinite(health).any():
        hx = ax.twinx()
        hx.plot(t, health, "C2-", lw=1.0, alpha=0.8)
        hx.set(ylim=(0.0, 1.05), ylabel="track health (green)")
    for k in picks:
        ax.axvline(t[k], color="0.6", lw=0.8, ls=":")
    ax.set(xlabel="time (s)", ylabel="m", xlim=(0, t[-1] if len(t) > 1 else 1.0), ylim=(0, None),
           title=f"{env_id}, seed {seed}: position error against the filter's own uncertainty "
           f"(final {err[-1]:.2f} m over {np.hypot(*(true_p[-1, :2] - true_p[0, :2])):.0f} m driven)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.05 if np.isfinite(health).any() else 1.005, 1.0), fontsize=9,
              frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(path, dpi=100)
    plt.close(fig)
