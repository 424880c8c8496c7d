"""Point-cloud quality of the radar on the Fig. 5b scenes, with 95 % confidence intervals.

Random static-landmark scenes (scripts/fig5b_pointcloud_vs_elements.py: 24
landmarks 10-60 m inside the sectors, RCS 5 m^2, ego at 20 m/s, so every
landmark has a radial velocity), default radar unless told. Per scene: the
detection rate and the false points; per detected landmark: the point error
(m), and the range, angle and Doppler (radial velocity) errors of the point
against the truth seen from its radar (:meth:`rhs_env.radar.RadarSystem.point_errors`).
Means over scenes and RMSEs over targets come with Student-t 95 % intervals
(:mod:`rhs_common.stats`; RMSE: delta method on the mean squared error), so two runs
(before and after a change, or ``--fidelity iq`` against ``range``) compare directly.

    OMP_NUM_THREADS=1 python scripts/radar_quality.py [--scenes 100] [--fidelity range] [--out results/radar_quality.json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from rhs_common.stats import mean_half_record, rmse_interval
from rhs_env.array_models import ScanConfig
from rhs_env.radar import RadarConfig, RadarSystem
from rhs_studies.kit.provenance import command_line, numbers, write_json
from rhs_studies.kit.seeds import first

ROOT = Path(__file__).resolve().parents[2]


def evaluate(cfg: RadarConfig, scenes: int, seed: int, noise_draws: int = 1, scene: Callable | None = None) -> dict:
    """Scan ``scenes`` Fig. 5b scenes with one radar; metrics with 95 % intervals.

    ``scene(rng, radar) -> Scatterers`` draws each scene (default
    :func:`rhs_studies.kit.scenes.landmark_scene`); the radar's generator is seeded ``seed``, the
    scenes' ``seed + 1``.

    ``noise_draws`` > 1 scans the same scenes again with as many independent noise
    realizations (radar generators seeded ``seed``, ``seed + 1000``, ...) and pools
    them: the RMSEs are dominated by a few outlier points (the median error is ~30x
    smaller), so one realization's RMSE moves by more than its delta-method interval
    says, and pooling draws steadies it. The pooled samples share their scenes, so the
    intervals are somewhat narrow for the scene-level means; two configs compared on
    the same scenes and seeds see the same scene effects.
    """
    from rhs_studies.kit.episodes import landmark_scene

    make_scene = landmark_scene if scene is None else scene
    det, false_pts = [], []
    errs: dict[str, list] = {"xy": [], "range": [], "angle": [], "doppler": []}
    for draw in range(noise_draws):
        radar = RadarSystem(cfg, np.random.default_rng(seed + 1000 * draw))
        scene_rng = np.random.default_rng(seed + 1)  # the same scenes in every draw
        for _ in range(scenes):
            sc = make_scene(scene_rng, radar)
            e = radar.point_errors(radar.scan(sc), sc, gate_m=1.0)
            det.append(e["n_detected"] / max(e["n_true"], 1))
            false_pts.append(e["false_points"])
            for k in errs:
                errs[k].append(e[k])
    cat = {k: np.concatenate(v) for k, v in errs.items()}
    return {
        "detection_rate": mean_half_record(det),
        "false_points_per_scan": mean_half_record(false_pts),
        **{name: dict(zip(("rmse", "ci95", "n"), rmse_interval(e))) for name, e in (
            ("point_rmse_m", cat["xy"]), ("range_rmse_m", cat["range"]),
            ("angle_rmse_deg", np.rad2deg(cat["angle"])), ("doppler_rmse_mps", cat["doppler"]))},
    }


def fingerprint() -> list[float | None]:
    """:func:`evaluate` on one scene of the default RHS radar on the 5-degree grid, seed 0: seconds."""
    return numbers(evaluate(RadarConfig(antenna="rhs", scan=ScanConfig(grid_deg=5.0)), 1, 0))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=100)
    p.add_argument("--seed", type=int, default=first("scenes"))
    p.add_argument("--antenna", default="rhs")
    p.add_argument("--grid-deg", type=float, default=1.0)
    p.add_argument("--fidelity", default=None, help="RadarConfig.fidelity (default: the config's default)")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    started = time.time()
    cfg = RadarConfig(antenna=a.antenna, scan=ScanConfig(grid_deg=a.grid_deg))
    if a.fidelity is not None:
        cfg = replace(cfg, fidelity=a.fidelity)
    res = {"metrics": evaluate(cfg, a.scenes, a.seed), "scenes": a.scenes, "seed": a.seed,
           "command": " ".join(command_line(__file__)), "config": cfg.to_dict(),
           "commit": subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                                    text=True).stdout.strip()}
    if a.out:
        write_json(a.out, res, __file__, {**vars(a), "radar": cfg.to_dict()}, started, fingerprint, argv)
    print(json.dumps(res["metrics"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
