"""Paper Fig. 5b: point-cloud RMSE vs number of RHS elements M, for dtheta = 1..5 deg.

For every (M, dtheta) the default radar (RHS patterns from the library of that
configuration, built into the cache on first use by
:func:`rhs_env.patterns.library.get_library`) scans random static-landmark
scenes (10-60 m, RCS 5 m^2, ego at 20 m/s); the SPEC 9 metrics give the RMSE
of matched points (gate 1 m), also over the isolated targets only (no other
target within 2 m in range for the same radar), whose error is the
estimator's and reads against the CRB. Beside it: the same-cost phased array (round(M / 6)
elements) and, for both antennas, the Cramer-Rao bound of the cross-range error,
``sqrt(mean R^2 CRB(theta))`` over the same targets (:func:`rhs_env.point_cloud.angle_crb`
of each radar: the swept-beam Fisher information of the angle over the I slots).
The ratio CRB(phased) / CRB(RHS) is the angular advantage the larger aperture buys.
Writes ``results/fig5b.{png,json,md}``; the JSON carries provenance and the
fingerprint of :func:`fingerprint` (see ``rhs_studies/kit/provenance.py``).

    OMP_NUM_THREADS=1 python scripts/fig5b_pointcloud_vs_elements.py [--elements 20 40 60 80 100]
        [--grids 1 2 3 4 5] [--cycles 5] [--out results/fig5b]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from rhs_env.array_models import RHSConfig, ScanConfig
from rhs_env.radar import RadarConfig, RadarSystem
from rhs_studies.kit.episodes import landmark_scene
from rhs_studies.kit.provenance import write_json
from rhs_studies.kit.seeds import first


def evaluate(cfg: RadarConfig, cycles: int, seed: int) -> dict:
    """RMSE (all matched targets and isolated ones), median error, detection rate, false points, CRB.

    A target is *isolated* when no other target seen by the same radar lies
    within 2 m in range (no range-bin sharing): its error is the estimator's,
    comparable with the CRB; the others add the resolution limit.
    """
    radar = RadarSystem(cfg, np.random.default_rng(seed))
    scene_rng = np.random.default_rng(seed + 1)
    err: list[float] = []
    iso: list[float] = []
    det: list[float] = []
    false_pts: list[float] = []
    crb: list[float] = []
    for _ in range(cycles):
        scene = landmark_scene(scene_rng, radar)
        cloud = radar.scan(scene)
        vis = radar.visible(scene)
        view = vis.any(axis=0)
        m = radar.metrics(cloud, scene, gate_m=1.0)
        det.append(m["detection_rate"])
        false_pts.append(m["false_points"])
        rng_m, ang, _ = radar.radar_frame(scene.xy)
        if len(cloud):
            d = np.hypot(*(scene.xy[:, None, :] - cloud.xy[None, :, :]).transpose(2, 0, 1)).min(axis=1)
        else:
            d = np.full(len(scene), np.inf)
        for k in np.flatnonzero(view):
            r = int(np.flatnonzero(vis[:, k])[0])
            if d[k] > 1.0:
                continue
            err.append(d[k])
            others = np.flatnonzero(vis[r])
            others = others[others != k]
            if not np.any(np.abs(rng_m[r, others] - rng_m[r, k]) < 2.0):
                iso.append(d[k])
        rr, kk = np.nonzero(vis)
        for r in np.unique(rr):
            sel = kk[rr == r]
            c = radar.angle_crb(ang[r, sel], rng_m[r, sel], 5.0, radar=r)
            crb.extend(rng_m[r, sel] ** 2 * c)
    err_m, iso_m = np.asarray(err), np.asarray(iso)
    return {
        "rmse_m": float(np.sqrt(np.mean(err_m ** 2))) if err_m.size else float("nan"),
        "median_error_m": float(np.median(err_m)) if err_m.size else float("nan"),
        "rmse_isolated_m": float(np.sqrt(np.mean(iso_m ** 2))) if iso_m.size else float("nan"),
        "n_isolated": int(iso_m.size),
        "detection_rate": float(np.mean(det)),
        "false_points_per_cycle": float(np.mean(false_pts)),
        "crb_cross_range_m": float(np.sqrt(np.mean(crb))) if crb else float("nan"),
    }


def run_config(elements: int, grid_deg: float, cycles: int, seed: int) -> dict:
    """One (M, dtheta) point: the RHS and the same-cost phased array on the same scenes."""
    rhs, scan = RHSConfig(elements=int(elements)), ScanConfig(grid_deg=float(grid_deg))
    res_rhs = evaluate(RadarConfig(antenna="rhs", rhs=rhs, scan=scan), cycles, seed)
    res_pa = evaluate(RadarConfig(antenna="phased", rhs=rhs, scan=scan), cycles, seed)
    return {"elements": int(elements), "grid_deg": float(grid_deg), "phased_elements": max(2, round(elements / 6)),
            "rhs": res_rhs, "phased": res_pa}


def fingerprint() -> list[float]:
    """The numbers of one cycle at M=60, dtheta=5 deg (shipped library), seed 0: seconds."""
    row = run_config(60, 5.0, 1, 0)
    return [row[a][k] for a in ("rhs", "phased") for k in sorted(row[a])]


def plot(rows: list[dict], grids: list[float], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5))
    colors = plt.cm.viridis(np.linspace(0, 0.9, len(grids)))
    for g, col in zip(grids, colors):
        r = [x for x in rows if x["grid_deg"] == g]
        ms = [x["elements"] for x in r]
        ax.plot(ms, [x["rhs"]["rmse_m"] for x in r], "o-", color=col, label=f"RHS, d$\\theta$={g:g}°")
        ax.plot(ms, [x["rhs"]["rmse_isolated_m"] for x in r], "^-.", color=col, alpha=0.8,
                label=f"RHS isolated targets, d$\\theta$={g:g}°")
        ax.plot(ms, [x["phased"]["rmse_m"] for x in r], "s--", color=col, alpha=0.6,
                label=f"phased (M/6), d$\\theta$={g:g}°")
        ax.plot(ms, [x["rhs"]["crb_cross_range_m"] for x in r], ":", color=col, lw=2, alpha=0.9,
                label=f"CRB (RHS), d$\\theta$={g:g}°")
        ax.plot(ms, [x["phased"]["crb_cross_range_m"] for x in r], "x:", color=col, alpha=0.6,
                label=f"CRB (phased), d$\\theta$={g:g}°")
    ax.set_yscale("log")
    ax.set_xlabel("number of RHS elements M (phased array: M/6)")
    ax.set_ylabel("point-cloud RMSE (m)")
    ax.set_title("Point-cloud error vs RHS elements (landmarks 10-60 m)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def markdown(rows: list[dict], cycles: int, seed: int) -> str:
    md = [
        f"Random static-landmark scenes 10-60 m, RCS 5 m^2, {cycles} cycles per point, seed {seed}; "
        "RMSE of points matched within 1 m; *isolated*: no other target within 2 m in range; "
        "CRB: cross-range Cramer-Rao bound of each antenna over the same targets; CRB ratio: phased / RHS.",
        "",
        "| dtheta (deg) | M | RHS RMSE (m) | RHS isolated (m) | RHS CRB (m) | RHS detection | RHS false pts/cycle "
        "| phased elements | phased RMSE (m) | phased isolated (m) | phased CRB (m) | phased detection "
        "| phased false pts/cycle | CRB ratio |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for x in rows:
        r, q = x["rhs"], x["phased"]
        md.append(
            f"| {x['grid_deg']:g} | {x['elements']} | {r['rmse_m']:.3f} | {r['rmse_isolated_m']:.3f} "
            f"| {r['crb_cross_range_m']:.4f} | {r['detection_rate']:.3f} | {r['false_points_per_cycle']:.2f} "
            f"| {x['phased_elements']} | {q['rmse_m']:.3f} | {q['rmse_isolated_m']:.3f} "
            f"| {q['crb_cross_range_m']:.4f} | {q['detection_rate']:.3f} | {q['false_points_per_cycle']:.2f} "
            f"| {q['crb_cross_range_m'] / r['crb_cross_range_m']:.2f} |"
        )
    return "\n".join(md) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--elements", type=int, nargs="+", default=[20, 40, 60, 80, 100])
    p.add_argument("--grids", type=float, nargs="+", default=[1.0, 2.0, 3.0, 4.0, 5.0])
    p.add_argument("--cycles", type=int, default=5)
    p.add_argument("--seed", type=int, default=first("scenes"))
    p.add_argument("--out", default="results/fig5b")
    p.add_argument("--render-only", action="store_true",
                   help="redraw the PNG and the table from the existing JSON (no scans; the JSON is unchanged)")
    a = p.parse_args(argv)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if a.render_only:
        res = json.loads(out.with_suffix(".json").read_text())
        for r in res["rows"]:  # files from before the phased element count was stored
            r.setdefault("phased_elements", max(2, round(r["elements"] / 6)))
        plot(res["rows"], sorted({r["grid_deg"] for r in res["rows"]}), out.with_suffix(".png"))
        out.with_suffix(".md").write_text(markdown(res["rows"], res["cycles"], res["seed"]))
        print(f"redrew {out.with_suffix('.png')} and {out.with_suffix('.md')} from {out.with_suffix('.json')}")
        return 0
    started = time.time()
    rows = []
    todo = [(m, g) for g in a.grids for m in a.elements]
    for n, (m, g) in enumerate(todo):
        t0 = time.perf_counter()
        rows.append(run_config(m, g, a.cycles, a.seed))
        r, q = rows[-1]["rhs"], rows[-1]["phased"]
        print(f"[{n + 1}/{len(todo)}] M={m:3d} dtheta={g:g} deg: RHS RMSE {r['rmse_m']:.3f} m "
              f"(isolated {r['rmse_isolated_m']:.3f}, det {r['detection_rate']:.2f}, CRB {r['crb_cross_range_m']:.4f} m), "
              f"phased RMSE {q['rmse_m']:.3f} m (isolated {q['rmse_isolated_m']:.3f}, CRB {q['crb_cross_range_m']:.4f} m)"
              f"  ({time.perf_counter() - t0:.0f} s)", flush=True)
    plot(rows, a.grids, out.with_suffix(".png"))
    out.with_suffix(".md").write_text(markdown(rows, a.cycles, a.seed))
    write_json(out.with_suffix(".json"), {"figure": "5b", "rows": rows, "cycles": a.cycles, "seed": a.seed},
               __file__, a, started, fingerprint, argv)
    print(f"wrote {out.with_suffix('.png')} and {out.with_suffix('.json')} in {time.time() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
