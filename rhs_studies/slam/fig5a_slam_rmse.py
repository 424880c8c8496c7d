"""Paper Fig. 5a: vehicle and obstacle (map) RMSE of SLAM on ``rhs-paper-v0``, per antenna scheme.

For each antenna (default: the paper's three schemes ``rhs``, the same-cost
``phased`` array and ``random`` patterns), each transmit power of the SNR sweep
and each seed, one SLAM-in-the-loop episode of the paper's Fig. 5c scene (five
obstacles, the vehicle drives 60 m straight ahead in 50 cycles at 5 Hz):

* vehicle RMSE: position RMSE of the SLAM pose over the 50 cycles (map frame = start
  pose, no alignment; the reset cycle, which is the origin by definition, is left out);
* obstacle RMSE: the final map against the five obstacles, Hungarian one-to-one
  matching within ``--map-gate`` m (SPEC 9), plus the matched / missed / spurious counts.

**SNR sweep**: ``tx_power_dbm`` in ``--powers`` (default 30, 20, 10, 0, -10 dBm; 30 dBm
is the default radar) with the noise figure held at ``--noise-figure`` (default 10 dB):
the echo SNR moves 1:1 with the transmit power in dB, down to where detection fails
(the map misses obstacles, the pose is lost). Everything else is the default radar
(60-element RHS, 1-degree beam grid).

**Statistics**: ``--seeds`` episodes (default 20) per antenna and power; each cell
reports the mean, the sample standard deviation (ddof = 1) and the 95 % confidence
interval of the mean from Student's t with n - 1 degrees of freedom,
``mean +- t_{0.975, n-1} s / sqrt(n)`` (none for a single seed). Episodes whose map
matched nothing have no obstacle RMSE and are counted as unmatched.

**Long runs**: every finished episode is appended to ``<out-dir>/fig5a.partial.json``;
``--resume`` skips the episodes already there (same settings), so an interrupted
sweep continues where it stopped. ``--workers N`` runs episodes in N processes.

The paper's claim, "RHS about a third of the phased array's error", is written beside
the measured ratio ``RMSE(antenna) / RMSE(phased)`` (means over seeds) for every power.

Outputs (``--out-dir``, default ``results/``): ``fig5a.png``, ``fig5a.json`` (every
episode and the aggregates), ``fig5a.md`` (the README table).

    OMP_NUM_THREADS=1 python scripts/fig5a_slam_rmse.py [--seeds 20] [--antennas rhs phased random]
        [--powers 30 20 10 0 -10] [--registration cnn|icp|odometry] [--out-dir results] [--quick]
        [--workers 2] [--resume]

``--quick`` is a smoke run for tests: 1 seed, 30 dBm, the 5-degree grid, 10 cycles.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from rhs_common.stats import format_record, mean_interval
from rhs_studies.kit.episodes import ANTENNAS, add_episode_args, paper_slam_episode, start_study
from rhs_studies.kit.pool import map_jobs
from rhs_studies.kit.provenance import jsonable, write_json

PAPER_RATIO = 1.0 / 3.0  # "RHS about a third of the phased array's error"
PAPER_CLAIM = "RHS about a third of the phased array's error (ratio ~0.33)"


def aggregate(
    episodes: list[dict], antennas: list[str], powers: list[float]
) -> list[dict]:
    rows = []
    for p in powers:
        for a in antennas:
            eps = [e for e in episodes if e["antenna"] == a and e["tx_power_dbm"] == p]
            if not eps:
                continue
            rows.append(
                {
                    "antenna": a,
                    "tx_power_dbm": p,
                    "seeds": len(eps),
                    "vehicle_rmse_m": mean_interval([e["vehicle_rmse_m"] for e in eps]).to_dict(),
                    "obstacle_rmse_m": mean_interval([e["obstacle_rmse_m"] for e in eps]).to_dict(),
                    "heading_rmse_rad": mean_interval([e["heading_rmse_rad"] for e in eps]).to_dict(),
                    "map_matched_mean": float(np.mean([e["map_matched"] for e in eps])),
                    "map_missed_mean": float(np.mean([e["map_missed"] for e in eps])),
                    "map_spurious_mean": float(
                        np.mean([e["map_spurious"] for e in eps])
                    ),
                }
            )
    return rows


def ratios(rows: list[dict]) -> list[dict]:
    """``mean RMSE(antenna) / mean RMSE(phased)`` at each power (vehicle and obstacle)."""
    out = []
    for r in rows:
        if r["antenna"] == "phased":
            continue
        ref = next(
            (
                q
                for q in rows
                if q["antenna"] == "phased" and q["tx_power_dbm"] == r["tx_power_dbm"]
            ),
            None,
        )
        if ref is None:
            continue
        item = {"antenna": r["antenna"], "tx_power_dbm": r["tx_power_dbm"]}
        for key in ("vehicle_rmse_m", "obstacle_rmse_m"):
            num, den = r[key]["mean"], ref[key]["mean"]
            item[key[: -len("_m")] + "_ratio"] = (
                None if num is None or not den else float(num / den)
            )
        out.append(item)
    return out


def _ratio_txt(x) -> str:
    return "n/a" if x is None else f"{x:.2f}"


def markdown(result: dict) -> str:
    s = result["settings"]
    lines = [
        (
            f"SLAM on `rhs-paper-v0` (paper Fig. 5c scene, {s['cycles']} cycles), {s['registration']} registration, "
            f"{s['elements']}-element RHS, {s['grid_deg']:g}-degree beam grid, noise figure {s['noise_figure_db']:g} dB; "
            f"mean and 95 % confidence interval of the mean (Student's t, ddof=1) over {len(s['seeds'])} seed(s). "
            f"Vehicle RMSE: position RMSE over the cycles; obstacle RMSE: "
            f"final map, Hungarian matching within {s['map_gate_m']:g} m. Ratio: mean RMSE / mean RMSE of the "
            f"same-cost phased array (paper: {PAPER_CLAIM})."
        ),
        "",
        (
            "| Tx power (dBm) | antenna | vehicle RMSE (m) | obstacle RMSE (m) | matched / missed / spurious | "
            "vehicle ratio to phased | obstacle ratio to phased |"
        ),
        "|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in result["rows"]:
        q = next(
            (
                x
                for x in result["ratios"]
                if x["antenna"] == r["antenna"]
                and x["tx_power_dbm"] == r["tx_power_dbm"]
            ),
            None,
        )
        vr = (
            "1 (reference)"
            if r["antenna"] == "phased"
            else _ratio_txt(q and q["vehicle_rmse_ratio"])
        )
        orr = (
            "1 (reference)"
            if r["antenna"] == "phased"
            else _ratio_txt(q and q["obstacle_rmse_ratio"])
        )
        lines.append(
            f"| {r['tx_power_dbm']:g} | {r['antenna']} | {format_record(r['vehicle_rmse_m'])} | {format_record(r['obstacle_rmse_m'])} | "
            f"{r['map_matched_mean']:.1f} / {r['map_missed_mean']:.1f} / {r['map_spurious_mean']:.1f} | {vr} | {orr} |"
        )
    rhs = [x for x in result["ratios"] if x["antenna"] == "rhs"]
    lines.append("")
    if rhs:
        meas = ", ".join(
            f"{_ratio_txt(x['vehicle_rmse_ratio'])} at {x['tx_power_dbm']:g} dBm"
            for x in rhs
        )
        lines.append(
            f"Paper: vehicle RMSE ratio RHS / phased ≈ {PAPER_RATIO:.2f}. Measured: {meas}."
        )
    else:
        lines.append(
            "Paper: vehicle RMSE ratio RHS / phased ≈ 0.33. Measured: n/a (rhs or phased not in this run)."
        )
    return "\n".join(lines) + "\n"


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    antennas = list(dict.fromkeys(r["antenna"] for r in rows))
    powers = sorted({r["tx_power_dbm"] for r in rows})
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    width = 0.8 / max(len(antennas), 1)
    x = np.arange(len(powers))
    colors = {
        "rhs": "tab:red",
        "phased": "tab:blue",
        "random": "tab:gray",
        "hologram": "tab:orange",
    }
    for ax, key, title in (
        (axes[0], "vehicle_rmse_m", "vehicle (position) RMSE"),
        (axes[1], "obstacle_rmse_m", "obstacle (map) RMSE"),
    ):
        for k, a in enumerate(antennas):
            m, s = [], []
            for p in powers:
                r = next(
                    (q for q in rows if q["antenna"] == a and q["tx_power_dbm"] == p),
                    None,
                )
                st = r[key] if r else {"mean": None, "std": None}
                m.append(np.nan if st["mean"] is None else st["mean"])
                s.append(0.0 if st.get("ci95_half_width") is None else st["ci95_half_width"])
            xs = x + (k - (len(antennas) - 1) / 2) * width
            ax.bar(xs, m, width, yerr=s, capsize=3, label=a, color=colors.get(a))
            for xi, mi in zip(xs, m):
                if not np.isfinite(mi):  # nothing matched within the gate
                    ax.annotate(
                        "n/a",
                        (xi, 0),
                        xytext=(0, 3),
                        textcoords="offset points",
                        ha="center",
                        fontsize=7,
                    )
        finite = [q[key]["mean"] for q in rows if q[key]["mean"]]
        if (
            finite and max(finite) / min(finite) > 30
        ):  # e.g. a lost track next to cm-level errors
            ax.set_yscale("log")
        ax.set_xticks(x, [f"{p:g} dBm" for p in powers])
        ax.set_xlabel(
            f"Tx power (noise figure {result['settings']['noise_figure_db']:g} dB)"
        )
        ax.set_ylabel("RMSE (m)")
        ax.set_title(title)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend()
    rhs = [q for q in result["ratios"] if q["antenna"] == "rhs"]
    meas = (
        ", ".join(
            f"{_ratio_txt(q['vehicle_rmse_ratio'])} @ {q['tx_power_dbm']:g} dBm"
            for q in rhs
        )
        or "n/a"
    )
    fig.suptitle(
        f"Fig. 5a: SLAM on rhs-paper-v0 ({result['settings']['registration']} registration, "
        f"{len(result['settings']['seeds'])} seeds, 95% CI). Paper: RHS/phased ≈ 0.33; measured vehicle ratio: {meas}",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--seeds", type=int, default=20, help="number of seeds (0 .. N-1), default 20"
    )
    p.add_argument(
        "--antennas", nargs="+", default=["rhs", "phased", "random"], choices=ANTENNAS
    )
    p.add_argument(
        "--powers",
        type=float,
        nargs="+",
        default=[30.0, 20.0, 10.0, 0.0, -10.0],
        help="Tx power sweep (dBm), default 30 20 10 0 -10",
    )
    p.add_argument("--workers", type=int, default=1, help="episodes run in this many processes")
    p.add_argument("--resume", action="store_true", help="skip episodes already in <out-dir>/fig5a.partial.json")
    add_episode_args(p, "tiny run for tests: 1 seed, 30 dBm, 5-degree grid, 10 cycles")
    a = p.parse_args(argv)
    if a.quick:
        a.seeds, a.powers, a.grid_deg, a.cycles = 1, [30.0], 5.0, 10
    if a.seeds < 1 or a.cycles < 1:
        p.error("--seeds and --cycles must be at least 1")
    return a


def episode_settings(a: argparse.Namespace) -> dict:
    """What every episode of a run shares (a partial file is resumed only under the same settings)."""
    return {"noise_figure_db": a.noise_figure, "registration": a.registration, "grid_deg": a.grid_deg,
            "elements": a.elements, "cycles": a.cycles, "map_gate_m": a.map_gate}


def run_jobs(jobs: list[tuple], a: argparse.Namespace, partial: Path, done: list[dict]) -> list[dict]:
    """Run the (antenna, power, seed) ``jobs`` (in ``a.workers`` processes), saving each episode to ``partial``."""
    from tqdm import tqdm

    episodes = list(done)
    bar = tqdm(total=len(jobs), desc="fig5a episodes", unit="ep", disable=a.no_progress)

    def save(ep: dict) -> None:
        episodes.append(ep)
        partial.write_text(json.dumps({"settings": episode_settings(a), "episodes": episodes}, default=jsonable))
        bar.update(1)

    map_jobs(paper_slam_episode, [(ant, s, p, a) for ant, p, s in jobs], a.workers, on_result=save)
    bar.close()
    return episodes


def fingerprint() -> list[float]:
    """RHS and phased episodes of the quick config (5-degree grid, 30 dBm, seed 0), 6 cycles: seconds."""
    a = parse_args(["--quick", "--cycles", "6", "--no-progress"])
    a.cycles = 6
    out = []
    for ant in ("rhs", "phased"):
        ep = paper_slam_episode(ant, 0, 30.0, a)
        out += [ep[k] for k in ("vehicle_rmse_m", "final_position_error_m", "heading_rmse_rad", "obstacle_rmse_m",
                                "map_matched", "map_spurious")]
    return out


def main(argv: list[str] | None = None) -> int:
    a, started, out = start_study(parse_args, argv)
    antennas = list(dict.fromkeys(a.antennas))
    powers = list(dict.fromkeys(a.powers))
    jobs = [(ant, p, s) for p in powers for ant in antennas for s in range(a.seeds)]
    partial = out / "fig5a.partial.json"
    done = []
    if a.resume and partial.exists():
        prev = json.loads(partial.read_text())
        if prev.get("settings") == jsonable(episode_settings(a)):
            want = set(jobs)
            done = [e for e in prev["episodes"] if (e["antenna"], e["tx_power_dbm"], e["seed"]) in want]
            have = {(e["antenna"], e["tx_power_dbm"], e["seed"]) for e in done}
            jobs = [j for j in jobs if j not in have]
            print(f"fig5a: resuming, {len(done)} episode(s) done, {len(jobs)} to run", file=sys.stderr)
        else:
            print("fig5a: partial file has other settings; starting afresh", file=sys.stderr)
    t0 = time.perf_counter()
    try:
        episodes = run_jobs(jobs, a, partial, done)
    except ValueError as exc:  # bad radar settings, a refused pattern library, ...
        print(f"fig5a: error: {exc}", file=sys.stderr)
        return 2
    order = {j: k for k, j in enumerate((ant, p, s) for p in powers for ant in antennas for s in range(a.seeds))}
    episodes.sort(key=lambda e: order[(e["antenna"], e["tx_power_dbm"], e["seed"])])
    rows = aggregate(episodes, antennas, powers)
    stage = {}
    for ant in antennas:
        eps = [e for e in episodes if e["antenna"] == ant]
        stage[ant] = {k: float(np.mean([e["slam_stage_times_ms"][k] for e in eps]))
                      for k in eps[0]["slam_stage_times_ms"]}
    result = {
        "figure": "5a",
        "env": "rhs-paper-v0",
        "paper_claim": PAPER_CLAIM,
        "paper_ratio": PAPER_RATIO,
        "snr_sweep": f"tx_power_dbm in {powers} with noise_figure_db = {a.noise_figure:g} (SNR moves 1:1 with Tx power in dB)",
        "settings": {"antennas": antennas, "powers_dbm": powers, "seeds": list(range(a.seeds)),
                     "quick": bool(a.quick), **episode_settings(a)},
        "rows": rows,
        "ratios": ratios(rows),
        "slam_stage_times_ms": stage,
        "episodes": episodes,
        "wall_s": time.perf_counter() - t0,
        "episode_s_mean": float(np.mean([e["wall_s"] for e in episodes])),
    }
    (out / "fig5a.md").write_text(markdown(result))
    plot(result, out / "fig5a.png")
    write_json(out / "fig5a.json", result, __file__, a, started, fingerprint, argv)
    partial.unlink(missing_ok=True)
    print(markdown(result))
    print(f"wrote {out / 'fig5a.png'}, {out / 'fig5a.json'}, {out / 'fig5a.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
