"""CNN vs ICP registration in the SLAM loop on the paper scene (``rhs-paper-v0``).

The held-out pair comparison (``scripts/train_registration.py``) measures one
registration at a time from a noisy prior; this script measures what each does to
the SLAM: for every registration in ``--registrations`` (default ``cnn``, the paper's
network with the shipped weights, ``icp`` and ``odometry``, the motion prior alone:
the Doppler ego velocity times the cycle length) and every seed, one episode of
the paper scene (same episode as Fig. 5a: 50 cycles at 5 Hz, IDLE action, default
radar with ``--antenna`` at ``--tx-power`` dBm). Per registration: vehicle RMSE,
final position error, heading RMSE, obstacle RMSE (Hungarian within ``--map-gate``
m), with mean, sample std and the 95 % t confidence interval over the seeds
(the statistics of ``scripts/fig5a_slam_rmse.py``), and the ratio of means to ICP.

Writes ``<out-dir>/registration_in_loop.{json,md}`` (JSON with provenance and the
fingerprint of :func:`fingerprint`).

    OMP_NUM_THREADS=1 python scripts/registration_in_loop.py [--seeds 10] [--antenna rhs]
        [--registrations cnn icp odometry] [--tx-power 30] [--out-dir results] [--quick]
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys

from rhs_common.stats import format_record, mean_interval
from rhs_studies.kit.episodes import ANTENNAS, add_episode_args, paper_slam_episode, start_study
from rhs_studies.kit.provenance import write_json
from slam.core.registration import REGISTRATIONS

METRICS = ("vehicle_rmse_m", "final_position_error_m", "heading_rmse_rad", "obstacle_rmse_m")


def run(a: argparse.Namespace) -> list[dict]:
    """Every (registration, seed) episode."""
    from tqdm import tqdm

    jobs = [(r, s) for r in a.registrations for s in range(a.seeds)]
    episodes = []
    for reg, seed in tqdm(jobs, desc="registration in the loop", unit="ep", disable=a.no_progress):
        args = copy.copy(a)
        args.registration = reg
        episodes.append({"registration": reg, **paper_slam_episode(a.antenna, seed, a.tx_power, args)})
    return episodes


def summarize(episodes: list[dict], registrations: list[str]) -> list[dict]:
    rows = []
    for reg in registrations:
        eps = [e for e in episodes if e["registration"] == reg]
        rows.append({"registration": reg, "seeds": len(eps), **{m: mean_interval([e[m] for e in eps]).to_dict() for m in METRICS},
                     "map_matched_mean": sum(e["map_matched"] for e in eps) / len(eps),
                     "map_spurious_mean": sum(e["map_spurious"] for e in eps) / len(eps)})
    icp = next((r for r in rows if r["registration"] == "icp"), None)
    for r in rows:
        den = icp and icp["vehicle_rmse_m"]["mean"]
        r["vehicle_rmse_ratio_to_icp"] = r["vehicle_rmse_m"]["mean"] / den if den else None
    return rows


def _scaled(st: dict, k: float) -> dict:
    """The statistics of ``k x`` from those of ``x`` (e.g. radians to degrees)."""
    mul = (lambda v: None if v is None else k * v)
    return {**st, "mean": mul(st["mean"]), "std": mul(st["std"]), "ci95_half_width": mul(st["ci95_half_width"]),
            "ci95": None if st["ci95"] is None else [k * v for v in st["ci95"]]}


def markdown(result: dict) -> str:
    s = result["settings"]
    lines = [
        f"SLAM on `rhs-paper-v0` ({s['cycles']} cycles, {s['antenna']} antenna, {s['tx_power_dbm']:g} dBm, "
        f"{s['grid_deg']:g}-degree grid), each registration on the same {s['seeds']} seed(s); mean and 95 % "
        "confidence interval of the mean (Student's t, ddof=1). `odometry`: the Doppler motion prior alone.",
        "",
        "| registration | vehicle RMSE (m) | final position error (m) | heading RMSE (deg) | obstacle RMSE (m) "
        "| matched / spurious | vehicle RMSE / ICP's |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in result["rows"]:
        head = _scaled(r["heading_rmse_rad"], math.degrees(1.0))
        ratio = r["vehicle_rmse_ratio_to_icp"]
        lines.append(
            f"| {r['registration']} | {format_record(r['vehicle_rmse_m'], 3)} | {format_record(r['final_position_error_m'], 3)} "
            f"| {format_record(head, 3)} | {format_record(r['obstacle_rmse_m'], 3)} | {r['map_matched_mean']:.1f} / "
            f"{r['map_spurious_mean']:.1f} | {'n/a' if ratio is None else f'{ratio:.1f}'} |"
        )
    return "\n".join(lines) + "\n"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=10, help="episodes per registration (seeds 0 .. N-1)")
    p.add_argument("--registrations", nargs="+", choices=REGISTRATIONS, default=["cnn", "icp", "odometry"])
    p.add_argument("--antenna", choices=ANTENNAS, default="rhs")
    p.add_argument("--tx-power", type=float, default=30.0, help="Tx power (dBm), default 30 (the default radar)")
    add_episode_args(p, "tiny run for tests: 1 seed, 5-degree grid, 8 cycles")
    p.add_argument("--render-only", action="store_true", help="rewrite the .md from the existing .json (no runs)")
    a = p.parse_args(argv)
    if a.quick:
        a.seeds, a.grid_deg, a.cycles = 1, 5.0, 8
    if a.seeds < 1 or a.cycles < 1:
        p.error("--seeds and --cycles must be at least 1")
    a.registrations = list(dict.fromkeys(a.registrations))
    return a


def fingerprint() -> list[float]:
    """CNN and ICP episodes of the quick config (seed 0, 6 cycles): seconds."""
    a = parse_args(["--quick", "--registrations", "cnn", "icp", "--no-progress"])
    a.cycles = 6
    return [e[m] for e in run(a) for m in METRICS]


def main(argv: list[str] | None = None) -> int:
    a, started, out = start_study(parse_args, argv)
    if a.render_only:
        md = markdown(json.loads((out / "registration_in_loop.json").read_text()))
        (out / "registration_in_loop.md").write_text(md)
        print(md)
        return 0
    episodes = run(a)
    result = {
        "env": "rhs-paper-v0",
        "settings": {"antenna": a.antenna, "tx_power_dbm": a.tx_power, "seeds": a.seeds, "cycles": a.cycles,
                     "grid_deg": a.grid_deg, "elements": a.elements, "registrations": a.registrations},
        "rows": summarize(episodes, a.registrations),
        "episodes": episodes,
    }
    md = markdown(result)
    (out / "registration_in_loop.md").write_text(md)
    write_json(out / "registration_in_loop.json", result, __file__, a, started, fingerprint, argv)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
