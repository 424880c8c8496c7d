"""Low-SNR SLAM: RHS against the phased array with the slot-summed and the footprint detector.

``python scripts/low_snr_slam.py [--seeds 100 101 102] [--rcs 0.005] [--cycles 50] [--out-dir results]``

One ``rhs-paper-v0`` episode (the paper's Fig. 5c scene, IDLE driving, default
radar at 30 dBm, ICP registration) per antenna, detector and seed, with the
obstacles' RCS ``--rcs`` m^2 (default 0.005: 30 dB below the scene's 5 m^2, the
low-SNR case). Vehicle ATE: position RMSE of the SLAM pose over the cycles
(map frame = start pose, no alignment); also the final error, the map matched /
missed / spurious counts (Hungarian, 2 m gate) and the points per cycle. Writes
``low_snr_slam.json`` (every episode, with the provenance of
``rhs_studies.kit.provenance.write_json``: commit, command line, config, and the
fingerprint of the finished run) and ``.md``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from rhs_studies.kit.episodes import POLICY_HZ, drive
from rhs_studies.kit.provenance import write_json
from rhs_studies.kit.seeds import seed_set

ANTENNAS = ("rhs", "phased")
DETECTORS = ("summed", "footprint")


def run_episode(antenna: str, detector: str, seed: int, a: argparse.Namespace) -> dict:
    """One episode; returns the vehicle errors, map counts and points per cycle."""
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids)

    env = gym.make("rhs-paper-v0", antenna=antenna, registration=a.registration, duration=a.cycles / POLICY_HZ,
                   obstacle_rcs_m2=a.rcs, radar={"link": {"tx_power_dbm": a.power}, "detection": {"statistic": detector}})
    t0 = time.perf_counter()
    steps = drive(env, seed)[1:]
    env.close()
    info = steps[-1][1]
    true = np.asarray([i["true_pose"] for _, i in steps])
    est = np.asarray([i["estimated_pose"] for _, i in steps])
    npts = [int(np.sum(o["points_mask"])) for o, _ in steps]
    err = np.hypot(est[:, 0] - true[:, 0], est[:, 1] - true[:, 1])
    return {"antenna": antenna, "detector": detector, "seed": int(seed), "cycles": len(true),
            "ate_m": float(np.sqrt(np.mean(err ** 2))), "final_error_m": float(err[-1]),
            "map_matched": int(info["map_matched"]), "map_missed": int(info["map_missed"]),
            "map_spurious": int(info["map_spurious"]), "points_per_cycle": float(np.mean(npts)),
            "wall_s": time.perf_counter() - t0}


def summary(rows: list[dict]) -> dict:
    """Mean / std of the ATE per (antenna, detector) and the RHS / phased ratio per detector."""
    out: dict = {}
    for d in DETECTORS:
        for ant in ANTENNAS:
            v = [r["ate_m"] for r in rows if r["antenna"] == ant and r["detector"] == d]
            m = [r["map_matched"] for r in rows if r["antenna"] == ant and r["detector"] == d]
            p = [r["points_per_cycle"] for r in rows if r["antenna"] == ant and r["detector"] == d]
            if v:
                out[f"{ant}/{d}"] = {"ate_mean_m": float(np.mean(v)), "ate_std_m": float(np.std(v)),
                                     "ate_median_m": float(np.median(v)), "matched_mean": float(np.mean(m)),
                                     "points_per_cycle": float(np.mean(p)), "n": len(v)}
        if f"rhs/{d}" in out and f"phased/{d}" in out:
            out[f"ratio_rhs_over_phased/{d}"] = out[f"rhs/{d}"]["ate_mean_m"] / out[f"phased/{d}"]["ate_mean_m"]
    return out


def markdown(res: dict) -> str:
    s = res["summary"]
    c = res["config"]
    lines = [f"Low-SNR SLAM on `rhs-paper-v0`: obstacle RCS {c['rcs']:g} m^2 (30 dB below 5 m^2), "
             f"{c['power']:g} dBm, {c['registration']} registration, {c['cycles']} cycles, seeds "
             f"{', '.join(map(str, c['seeds_done']))} (`{' '.join(res['provenance']['command'])}`, commit "
             f"{res['provenance']['commit'][:10]}).", "",
             "| detector | antenna | vehicle ATE (m), mean ± std | median | obstacles matched (of 5) | points / cycle |",
             "|---|---|---:|---:|---:|---:|"]
    for d in DETECTORS:
        for ant in ANTENNAS:
            k = f"{ant}/{d}"
            if k in s:
                v = s[k]
                lines.append(f"| {d} | {ant} | {v['ate_mean_m']:.2f} ± {v['ate_std_m']:.2f} | {v['ate_median_m']:.2f} | "
                             f"{v['matched_mean']:.1f} | {v['points_per_cycle']:.1f} |")
    lines.append("")
    for d in DETECTORS:
        if f"ratio_rhs_over_phased/{d}" in s:
            lines.append(f"RHS / phased ATE ratio, {d} detector: {s[f'ratio_rhs_over_phased/{d}']:.2f} (target <= 1.5).")
    return "\n".join(lines) + "\n"


def fingerprint() -> list[float]:
    """Small config: one 8-cycle RHS episode per detector at the low RCS (seed 0): vehicle errors and map counts."""
    a = argparse.Namespace(rcs=0.005, power=30.0, cycles=8, registration="icp")
    out: list[float] = []
    for d in DETECTORS:
        r = run_episode("rhs", d, 0, a)
        out += [r["ate_m"], r["final_error_m"], r["map_matched"], r["map_spurious"], r["points_per_cycle"]]
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, nargs="+", default=seed_set("low_snr_slam").seeds[:3])
    p.add_argument("--rcs", type=float, default=0.005, help="obstacle RCS, m^2")
    p.add_argument("--power", type=float, default=30.0, help="Tx power, dBm")
    p.add_argument("--cycles", type=int, default=50)
    p.add_argument("--registration", default="icp")
    p.add_argument("--antennas", nargs="+", default=list(ANTENNAS), choices=ANTENNAS)
    p.add_argument("--detectors", nargs="+", default=list(DETECTORS), choices=DETECTORS)
    p.add_argument("--out-dir", default="results")
    a = p.parse_args(argv)
    started = time.time()
    rows: list[dict] = []
    for seed in a.seeds:
        for d in a.detectors:
            for ant in a.antennas:
                r = run_episode(ant, d, seed, a)
                rows.append(r)
                print(f"seed {seed} {d:9s} {ant:6s} ATE {r['ate_m']:.3f} m, final {r['final_error_m']:.2f} m, "
                      f"matched {r['map_matched']}, {r['points_per_cycle']:.1f} pts, {r['wall_s']:.0f} s", flush=True)
        write(a, rows, started, argv, final=False)  # after every seed: an interrupted run keeps the seeds it finished
    print(markdown(write(a, rows, started, argv, final=True)))
    return 0


def write(a: argparse.Namespace, rows: list[dict], started: float, argv: list[str], final: bool) -> dict:
    """JSON and markdown of the episodes so far (``config.seeds_done`` lists the finished seeds).

    Only the finished run records its fingerprint: a partial file reads as unverified.
    """
    done = sorted({r["seed"] for r in rows})
    config = {**vars(a), "seeds_done": done}
    res = {"config": config, "episodes": rows, "summary": summary(rows)}
    out = Path(a.out_dir)
    res["provenance"] = write_json(out / "low_snr_slam.json", res, __file__, config, started,
                                   fingerprint_fn=fingerprint if final else None, argv=argv)  # fmt: skip
    (out / "low_snr_slam.md").write_text(markdown(res))
    return res


if __name__ == "__main__":
    sys.exit(main())
