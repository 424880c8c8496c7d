"""Paper Fig. 5c: true and estimated trajectory and obstacle map on the paper scenario (``rhs-paper-v0``).

One SLAM-in-the-loop episode (default: the RHS antenna, seed 0, 30 dBm): the vehicle
starts at (0, 37.5) m heading +x and drives about 60 m in 50 cycles past the five
obstacles at (10, 65), (25, 10), (30, 65), (35, 10), (50, 65) m. The figure is drawn
in the paper's (world) frame: the true and the estimated trajectory, the true
obstacles and the estimated map, and, faintly, every radar point of the run placed
with the true pose. The estimated map is the SLAM's full map; each obstacle is
matched one-to-one to an estimated landmark (Hungarian, within ``--map-gate`` m).

Outputs (``--out-dir``, default ``results/``): ``fig5c.png``, ``fig5c.json``
(trajectories, maps, matches, errors), ``fig5c.md`` (the README table).

    OMP_NUM_THREADS=1 python scripts/fig5c_trajectory_map.py [--antenna rhs] [--seed 0]
        [--registration cnn|icp|odometry] [--out-dir results] [--quick]

``--quick`` is a smoke run for tests: the 5-degree grid and 10 cycles.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from rhs_common.geometry import wrap_angle
from rhs_studies.kit.episodes import ANTENNAS, add_episode_args, drive, make_paper_env, start_study
from rhs_studies.kit.provenance import write_json
from rhs_studies.kit.seeds import first


def run(args: argparse.Namespace) -> dict:
    from tqdm import tqdm

    from slam.core.metrics import map_metrics
    from slam.core.registration import apply_motion
    from slam.gym.wrappers import SlamObservation

    env = make_paper_env(args, args.antenna, args.tx_power)
    slam = env
    while not isinstance(slam, SlamObservation):
        slam = slam.env
    t0 = time.perf_counter()
    bar = tqdm(total=args.cycles, desc="fig5c cycles", unit="cycle", disable=args.no_progress)
    trace = drive(env, args.seed, bar=bar)
    bar.close()
    origin = np.asarray(slam.origin, dtype=float)  # world pose of the map frame (the start pose)
    env.close()
    info = trace[-1][1]
    true = np.asarray([i["true_pose"] for _, i in trace], float)
    est = np.asarray([i["estimated_pose"] for _, i in trace], float)
    std = np.asarray([o["pose_std"] for o, _ in trace], float)
    clouds = []
    for o, i in trace:  # every scan's points in the world frame
        pts = o["points"][o["points_mask"] > 0, :2].astype(float)
        if len(pts):
            clouds.append(apply_motion(pts, np.asarray(i["world_pose"], dtype=float)))

    to_world = lambda xy: apply_motion(np.asarray(xy, float).reshape(-1, 2), origin)
    true_lm = np.asarray(info["true_landmarks"], float).reshape(-1, 2)
    est_lm = np.asarray(info["estimated_landmarks"], float).reshape(-1, 2)
    mm = map_metrics(est_lm, true_lm, float(args.map_gate))
    matches = []
    tw, ew = to_world(true_lm), to_world(est_lm)
    pairs = {int(t): int(e) for e, t in np.asarray(mm["pairs"]).reshape(-1, 2)}
    for k in range(len(true_lm)):
        e = pairs.get(k)
        matches.append(
            {
                "true_xy": tw[k].round(4).tolist(),
                "estimated_xy": None if e is None else ew[e].round(4).tolist(),
                "error_m": None if e is None else float(np.hypot(*(est_lm[e] - true_lm[k]))),
            }
        )
    pos_err = np.hypot(est[1:, 0] - true[1:, 0], est[1:, 1] - true[1:, 1])
    head_err = wrap_angle(est[1:, 2] - true[1:, 2])
    world_heading = lambda p: wrap_angle(p[:, 2] + origin[2])
    cloud = np.concatenate(clouds) if clouds else np.zeros((0, 2))
    return {
        "figure": "5c",
        "env": "rhs-paper-v0",
        "frame": "world (paper) frame: x along the road, y up; the map frame is the start pose",
        "settings": {
            "antenna": args.antenna,
            "seed": int(args.seed),
            "registration": args.registration,
            "tx_power_dbm": float(args.tx_power),
            "noise_figure_db": float(args.noise_figure),
            "grid_deg": float(args.grid_deg),
            "elements": int(args.elements),
            "cycles": int(len(true) - 1),
            "map_gate_m": float(args.map_gate),
            "quick": bool(args.quick),
        },
        "start_pose_world": origin.round(6).tolist(),
        "true_trajectory": np.column_stack([to_world(true[:, :2]), world_heading(true)]).round(4).tolist(),
        "estimated_trajectory": np.column_stack([to_world(est[:, :2]), world_heading(est)]).round(4).tolist(),
        "pose_std": std.round(5).tolist(),
        "true_obstacles": tw.round(4).tolist(),
        "estimated_map": ew.round(4).tolist(),
        "matches": matches,
        "vehicle_rmse_m": float(np.sqrt(np.mean(pos_err**2))) if len(pos_err) else None,
        "final_position_error_m": float(pos_err[-1]) if len(pos_err) else None,
        "heading_rmse_rad": float(np.sqrt(np.mean(head_err**2))) if len(head_err) else None,
        "obstacle_rmse_m": None if not np.isfinite(mm["rmse"]) else float(mm["rmse"]),
        "map_matched": int(mm["matched"]),
        "map_missed": int(mm["missed"]),
        "map_spurious": int(mm["spurious"]),
        "radar_points": len(cloud),
        "_cloud": cloud,  # for the plot only
        "wall_s": time.perf_counter() - t0,
    }


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 6))
    cloud = result["_cloud"]
    if len(cloud):
        ax.scatter(cloud[:, 0], cloud[:, 1], s=2, c="0.75", label="radar points (true pose)", zorder=1)
    t, e = (np.asarray(result["true_trajectory"]), np.asarray(result["estimated_trajectory"]))
    ax.plot(t[:, 0], t[:, 1], "k-", lw=2, label="true trajectory", zorder=3)
    ax.plot(e[:, 0], e[:, 1], "--", color="tab:orange", lw=2, label="estimated trajectory", zorder=4)
    ob = np.asarray(result["true_obstacles"]).reshape(-1, 2)
    em = np.asarray(result["estimated_map"]).reshape(-1, 2)
    ax.scatter(ob[:, 0], ob[:, 1], s=120, marker="s", facecolors="none", edgecolors="k", lw=1.5, label="true obstacles", zorder=5)
    if len(em):
        ax.scatter(em[:, 0], em[:, 1], s=40, marker="x", c="tab:red", label="estimated map", zorder=6)
    for m in result["matches"]:
        if m["estimated_xy"] is not None:
            ax.plot([m["true_xy"][0], m["estimated_xy"][0]], [m["true_xy"][1], m["estimated_xy"][1]], "r-", lw=0.8)
    s = result["settings"]
    ov = result["obstacle_rmse_m"]
    ax.set_title(
        f"Fig. 5c: {s['antenna']} antenna, seed {s['seed']}, {s['registration']} registration, {s['cycles']} cycles\n"
        f"vehicle RMSE {result['vehicle_rmse_m']:.2f} m, obstacle RMSE "
        f"{'n/a' if ov is None else f'{ov:.2f} m'} ({result['map_matched']}/{len(ob)} matched, "
        f"{result['map_spurious']} spurious)",
        fontsize=10,
    )
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def markdown(result: dict) -> str:
    s = result["settings"]
    f = lambda x, d=2: "n/a" if x is None else f"{x:.{d}f}"
    lines = [
        (
            f"One episode of `rhs-paper-v0` ({s['antenna']} antenna, seed {s['seed']}, "
            f"{s['registration']} registration, {s['cycles']} cycles, {s['tx_power_dbm']:g} dBm, "
            f"{s['grid_deg']:g}-degree grid), world frame."
        ),
        "",
        "| vehicle RMSE (m) | final position error (m) | heading RMSE (deg) | obstacle RMSE (m) | matched / missed / spurious |",
        "|---:|---:|---:|---:|---:|",
        (
            f"| {f(result['vehicle_rmse_m'])} | {f(result['final_position_error_m'])} | "
            f"{f(None if result['heading_rmse_rad'] is None else math.degrees(result['heading_rmse_rad']))} | "
            f"{f(result['obstacle_rmse_m'])} | {result['map_matched']} / {result['map_missed']} / "
            f"{result['map_spurious']} |"
        ),
        "",
        "| true obstacle (m) | estimated (m) | error (m) |",
        "|---|---|---:|",
    ]
    for m in result["matches"]:
        est = "missed" if m["estimated_xy"] is None else f"({m['estimated_xy'][0]:.2f}, {m['estimated_xy'][1]:.2f})"
        lines.append(f"| ({m['true_xy'][0]:.1f}, {m['true_xy'][1]:.1f}) | {est} | {f(m['error_m'])} |")
    return "\n".join(lines) + "\n"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--antenna", choices=ANTENNAS, default="rhs")
    p.add_argument("--seed", type=int, default=first("scenes"))
    p.add_argument("--tx-power", type=float, default=30.0, help="Tx power (dBm)")
    add_episode_args(p, "tiny run for tests: 5-degree grid, 10 cycles")
    a = p.parse_args(argv)
    if a.quick:
        a.grid_deg, a.cycles = 5.0, 10
    if a.cycles < 1 or a.seed < 0:
        p.error("--cycles must be at least 1 and --seed non-negative")
    return a


def fingerprint() -> list[float]:
    """The quick config (RHS, seed 0, 5-degree grid), 6 cycles: both trajectories and the map errors."""
    a = parse_args(["--quick", "--no-progress"])
    a.cycles = 6
    r = run(a)
    errs = [m["error_m"] for m in r["matches"]]
    return [*np.ravel(r["estimated_trajectory"]), *np.ravel(r["true_trajectory"]), *errs, r["map_spurious"]]


def main(argv: list[str] | None = None) -> int:
    a, started, out = start_study(parse_args, argv)
    try:
        result = run(a)
    except ValueError as exc:
        print(f"fig5c: error: {exc}", file=sys.stderr)
        return 2
    plot(result, out / "fig5c.png")
    result.pop("_cloud")
    (out / "fig5c.md").write_text(markdown(result))
    write_json(out / "fig5c.json", result, __file__, a, started, fingerprint, argv)
    print(markdown(result))
    print(f"wrote {out / 'fig5c.png'}, {out / 'fig5c.json'}, {out / 'fig5c.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
