"""Radar benchmark: time per stage of one four-radar scan on a typical highway scene.

``python scripts/benchmark_radar.py [--antenna rhs] [--repeats 20] [--out results/benchmark_radar.json]``
or ``benchmark_radar()`` from Python. The scene (:func:`rhs_studies.kit.scenes.typical_scene`): about 20
static roadside landmarks (5 m^2) on both road sides and 10 vehicles (boxes
5 m x 2 m, a scattering point at the centre of each face that looks at the ego,
10 m^2 in all per vehicle, moving at relative speeds of a few m/s), with the
vehicle outlines as occluders. Also reports the SPEC 9 point-cloud metrics.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from rhs_env.array_models import ScanConfig
from rhs_env.radar import RadarConfig, RadarSystem
from rhs_studies.kit.episodes import typical_scene
from rhs_studies.kit.provenance import write_json


def benchmark_radar(antenna: str = "rhs", grid_deg: float = 1.0, repeats: int = 20, seed: int = 0,
                    out: str | Path | None = None, fidelity: str | None = None) -> dict:
    """Median time per stage (ms) over ``repeats`` scans and the point-cloud metrics; optional JSON.

    ``fidelity``: the synthesis path (RadarConfig.fidelity; default: the config's default).
    """
    cfg = RadarConfig(antenna=antenna, scan=ScanConfig(grid_deg=grid_deg))
    if fidelity is not None:
        cfg = replace(cfg, fidelity=fidelity)
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    radar = RadarSystem(cfg, rng)
    build_s = time.perf_counter() - t0
    scene, occ = typical_scene(np.random.default_rng(seed + 1))
    radar.scan(scene, occ)  # warm-up
    stages: dict[str, list[float]] = {}
    det, sq, false_pts, npts = [], [], [], []
    for _ in range(repeats):
        cloud = radar.scan(scene, occ)
        for k, v in cloud.stage_times.items():
            stages.setdefault(k, []).append(v)
        m = radar.metrics(cloud, scene, occ, gate_m=1.0, per_object=True)
        det.append(m["detection_rate"])
        sq.extend(m["sq_errors"])
        false_pts.append(m["false_points"])
        npts.append(m["n_points"])
    result = {
        "antenna": antenna,
        "fidelity": cfg.fidelity,
        "grid_deg": grid_deg,
        "slots": cfg.scan.slots,
        "scatterers": len(scene),
        "in_view": int(radar.in_view(scene, occ).sum()),
        "repeats": repeats,
        "build_s": build_s,
        "stage_ms_median": {k: 1e3 * float(np.median(v)) for k, v in stages.items()},
        "detection_rate": float(np.mean(det)),
        "rmse_m": float(np.sqrt(np.mean(sq))) if sq else float("nan"),
        "false_points_per_cycle": float(np.mean(false_pts)),
        "points_per_cycle": float(np.mean(npts)),
        "threads": os.environ.get("OMP_NUM_THREADS", "unset"),
    }
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(result, indent=1))
    return result


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--antenna", default="rhs", choices=["rhs", "phased", "random", "hologram"])
    p.add_argument("--grid-deg", type=float, default=1.0)
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--fidelity", default=None, choices=["iq", "range"])
    p.add_argument("--out", default="results/benchmark_radar.json")
    a = p.parse_args(argv)
    started = time.time()
    res = benchmark_radar(a.antenna, a.grid_deg, a.repeats, fidelity=a.fidelity)
    write_json(a.out, res, __file__, a, started, argv=argv)  # timings: provenance, no fingerprint
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
