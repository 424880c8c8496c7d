"""Radar benchmark: time per stage of one four-radar scan on a typical highway scene.

``python scripts/benchmark_radar.py [--antenna rhs] [--repeats 20] [--out results/benchmark_radar.json]``
or ``benchmark_radar()`` from Python. The scene (:func:`typical_scene`): about 20
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import write_json

from rhs_env.array_models import ScanConfig
from rhs_env.radar import RadarConfig, RadarSystem
from rhs_env.scatterers import Occluders, Scatterers


def typical_scene(rng: np.random.Generator, n_landmarks: int = 20, n_vehicles: int = 10,
                  ego_speed: float = 25.0) -> tuple[Scatterers, Occluders]:
    """Highway scene in the ego frame: landmarks at y = +-(9..12) m, vehicles in 4 lanes (4 m wide)."""
    half = n_landmarks // 2
    lx = np.concatenate([np.linspace(-55, 60, half), np.linspace(-50, 55, n_landmarks - half)])
    lx = lx + rng.uniform(-2, 2, lx.size)
    ly = np.concatenate([rng.uniform(9, 12, half), -rng.uniform(9, 12, n_landmarks - half)])
    l_xy = np.column_stack([lx, ly])
    l_vel = np.tile([-ego_speed, 0.0], (n_landmarks, 1))
    # vehicles in lanes y = -6, -2, 2, 6 (ego in lane y = -2 -> shifted so the ego lane is y = 0)
    lanes = np.array([-4.0, 4.0, 8.0, -8.0 + 4.0])
    vx = rng.uniform(-60, 70, n_vehicles)
    vx = np.where(np.abs(vx) < 8, vx + np.sign(vx + 1e-9) * 10, vx)
    vy = lanes[rng.integers(0, lanes.size, n_vehicles)]
    vrel = rng.uniform(-5, 5, n_vehicles)
    centers = np.column_stack([vx, vy])
    # face centres (front, left, rear, right) and outward normals, heading 0
    off = np.array([[2.5, 0], [0, 1.0], [-2.5, 0], [0, -1.0]])
    faces = centers[:, None, :] + off[None]  # (V, 4, 2)
    facing = np.einsum("vfd,fd->vf", faces, off) < 0  # the face looks at the ego (origin)
    vid = np.repeat(np.arange(n_vehicles), 4).reshape(n_vehicles, 4) + 1000
    nf = np.maximum(facing.sum(1, keepdims=True), 1)
    pts = faces[facing]
    rcs = np.broadcast_to(10.0 / nf, facing.shape)[facing]
    vel = np.column_stack([np.repeat(vrel, 4).reshape(n_vehicles, 4)[facing], np.zeros(pts.shape[0])])
    scat = Scatterers(
        np.vstack([l_xy, pts]), np.vstack([l_vel, vel]), np.concatenate([np.full(n_landmarks, 5.0), rcs]),
        np.concatenate([np.arange(n_landmarks), vid[facing]]),
        np.concatenate([np.ones(n_landmarks, bool), np.zeros(pts.shape[0], bool)]),
    )
    occ = Occluders.from_boxes(centers, np.zeros(n_vehicles), 5.0, 2.0, np.arange(n_vehicles) + 1000)
    return scat, occ


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
