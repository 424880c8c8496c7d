#!/usr/bin/env python
"""How low can the two-way sidelobes go? The fast method under a sweep of sidelobe caps.

For the default radar (M=60, d=lambda/4, n=sqrt(3), Tx fed at element 0, Rx at M-1) every
grid of the library (``--grid-deg``; with mirror-symmetric feeds only theta >= 0 is solved,
theta < 0 is its mirror image with the same PSLR and gain) is optimised once per cap in
``--caps`` (``FastSettings.max_sidelobe_db``, enforced on the fine grid by ``cap_refine``).
Per grid and cap it records the two-way PSLR and main-lobe gain on the fine grid of
:func:`rhs_env.patterns.metrics.pattern_report`, the P1 margin delta and whether the cap
was met, and the geometry that limits it: the offset of the nearest one-way twin
(``sin theta' = +-2n - sin theta - k lambda/d``, paper eq. 3, visible or not) from the grid
centre in main-lobe half-widths ``hw = lambda/(M d)``.

Writes ``results/patterns_sidelobe_limits.json`` and ``.md``: per cap, the grids that meet
it, the worst / median PSLR and the main-lobe gain it costs against the loosest cap; per
grid, the lowest PSLR reached over all caps (the best this optimiser finds for this
aperture and feed arrangement).

    python scripts/pattern_sidelobe_limits.py                         # default, all grids
    python scripts/pattern_sidelobe_limits.py --elements 16 --grid-deg 10 --caps -12 -16
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from rhs_env.array_models import RHSConfig, ScanConfig
from rhs_env.patterns.fast import FastSettings, build_fast
from rhs_env.patterns.metrics import pattern_report
from rhs_studies.kit.provenance import write_json

ROOT = Path(__file__).resolve().parents[2]

MET_TOL_DB = 0.01  # a cap counts as met when the fine-grid PSLR is within this of it


def twin_offsets_hw(config: RHSConfig, angles_deg: np.ndarray) -> dict[str, np.ndarray]:
    """Offset of the nearest one-way twin of each side from the grid centre, in main-lobe half-widths.

    Twins ``s' = sign 2n - s - k / d`` (sign + for the feed at element 0, - at M-1), over
    ``k`` in -8..8, visible or not; also reported: the nearest twin that lies outside the
    visible region, as its distance past endfire (its main lobe leaks into ``|s| <= 1``
    when that is under one half-width).
    """
    s = np.sin(np.deg2rad(angles_deg))[:, None]
    hw = config.mainlobe_halfwidth
    ks = np.arange(-8, 9)
    out: dict[str, np.ndarray] = {}
    for side, feed in (("tx", config.tx_feed), ("rx", config.rx_feed)):
        sign = 1.0 if feed == 0 else -1.0
        tw = sign * 2.0 * config.refractive_index - s - ks / config.spacing_wl
        out[f"{side}_twin_offset_hw"] = np.min(np.abs(tw - s), axis=1) / hw
        past = np.where(np.abs(tw) > 1.0, np.abs(tw) - 1.0, np.inf)
        out[f"{side}_twin_past_endfire_hw"] = np.min(past, axis=1) / hw
    return out


def sweep(config: RHSConfig, scan: ScanConfig, caps: list[float], workers: int,
          settings: FastSettings, angles: np.ndarray | None = None) -> dict:
    """Optimise the theta >= 0 grids (or ``angles``) once per cap; per-grid rows and per-cap summaries."""
    if angles is None:
        angles = scan.angles_deg[scan.angles_deg >= 0]
    geo = twin_offsets_hw(config, angles)
    rows, per_cap = [], []
    for cap in caps:
        st = FastSettings(**{**settings.to_dict(), "max_sidelobe_db": cap})
        t0 = time.perf_counter()
        tx, rx, infos = build_fast(config, scan, st, workers=workers, angles_deg=angles)
        dt = time.perf_counter() - t0
        rep = pattern_report(config, tx, rx, angles, oversample=st.oversample)
        met = rep.pslr_db <= cap + MET_TOL_DB
        for k, a in enumerate(angles):
            rows.append({"cap_db": cap, "angle_deg": float(a), "pslr_db": float(rep.pslr_db[k]),
                         "mainlobe_gain_db": float(rep.mainlobe_gain_db[k]), "delta": float(rep.delta[k]),
                         "pointing_error_deg": float(rep.pointing_error_deg[k]), "cap_met": bool(met[k]),
                         "capped_on_d": bool(infos[k]["capped"]),
                         **{key: float(v[k]) for key, v in geo.items()}})
        per_cap.append({"cap_db": cap, "build_s": dt, "grids": int(angles.size), "grids_cap_met": int(met.sum()),
                        "worst_pslr_db": float(rep.pslr_db.max()), "median_pslr_db": float(np.median(rep.pslr_db)),
                        "median_mainlobe_gain_db": float(np.median(rep.mainlobe_gain_db)),
                        "min_mainlobe_gain_db": float(rep.mainlobe_gain_db.min()),
                        "worst_pointing_error_deg": float(np.abs(rep.pointing_error_deg).max()),
                        "missed_angles_deg": [float(a) for a in angles[~met]]})
        print(f"cap {cap:g} dB: {int(met.sum())}/{angles.size} grids meet it, worst PSLR "
              f"{rep.pslr_db.max():.2f} dB, median gain {np.median(rep.mainlobe_gain_db):.2f} dB ({dt:.0f} s)",
              flush=True)
    return {"angles_deg": angles.tolist(), "per_cap": per_cap, "grids": rows, **_best(rows, caps)}


def _best(rows: list[dict], caps: list[float]) -> dict:
    """Per grid: the lowest fine-grid PSLR over all caps (pointing within half a grid) and its gain cost."""
    by_angle: dict[float, list[dict]] = {}
    for r in rows:
        by_angle.setdefault(r["angle_deg"], []).append(r)
    best = []
    for a, rs in sorted(by_angle.items()):
        loose = next(r for r in rs if r["cap_db"] == caps[0])
        b = min(rs, key=lambda r: r["pslr_db"])
        best.append({"angle_deg": a, "best_pslr_db": b["pslr_db"], "at_cap_db": b["cap_db"],
                     "gain_cost_db": loose["mainlobe_gain_db"] - b["mainlobe_gain_db"],
                     "rx_twin_offset_hw": b["rx_twin_offset_hw"], "tx_twin_offset_hw": b["tx_twin_offset_hw"],
                     "tx_twin_past_endfire_hw": b["tx_twin_past_endfire_hw"],
                     "rx_twin_past_endfire_hw": b["rx_twin_past_endfire_hw"]})
    worst = max(best, key=lambda r: r["best_pslr_db"])
    return {"best_per_grid": best, "best_achievable_worst_pslr_db": worst["best_pslr_db"],
            "best_achievable_worst_angle_deg": worst["angle_deg"]}


def markdown(res: dict) -> str:
    c = res["config"]
    lines = [(f"Two-way sidelobe caps, fast method, M={c['elements']}, n={c['refractive_index']:.4g}, "
              f"{res['scan']['grid_deg']:g}-degree grids "
              f"({'the listed subset' if res.get('subset') else 'theta >= 0'}; theta < 0 mirrors them), "
              f"`{' '.join(res['provenance']['command'])}`."), "",
             ("| cap dB | grids meeting it | worst PSLR dB | median PSLR dB | median gain dB | min gain dB | "
              "grids missing it (deg) |"), "|---:|---:|---:|---:|---:|---:|---|"]
    for p in res["per_cap"]:
        miss = ", ".join(f"{a:g}" for a in p["missed_angles_deg"]) or "none"
        lines.append(f"| {p['cap_db']:g} | {p['grids_cap_met']}/{p['grids']} | {p['worst_pslr_db']:.2f} | "
                     f"{p['median_pslr_db']:.2f} | {p['median_mainlobe_gain_db']:.2f} | "
                     f"{p['min_mainlobe_gain_db']:.2f} | {miss} |")
    hard = sorted(res["best_per_grid"], key=lambda r: -r["best_pslr_db"])[:6]
    lines += ["", (f"Lowest PSLR reached on every grid over all caps: worst grid "
                   f"{res['best_achievable_worst_angle_deg']:g} deg at {res['best_achievable_worst_pslr_db']:.2f} dB. "
                   "Hardest grids (best PSLR dB over the caps, main-lobe gain it costs against the loosest cap, "
                   "nearest Rx / Tx twin from the grid centre and nearest twin past endfire, in main-lobe "
                   "half-widths):"), ""]
    for r in hard:
        past = min(r["tx_twin_past_endfire_hw"], r["rx_twin_past_endfire_hw"])
        lines.append(f"- {r['angle_deg']:g} deg: {r['best_pslr_db']:.2f} dB (cap {r['at_cap_db']:g}, "
                     f"gain {-r['gain_cost_db']:+.2f} dB); Rx twin {r['rx_twin_offset_hw']:.1f} hw, "
                     f"Tx twin {r['tx_twin_offset_hw']:.1f} hw, a twin {past:.2f} hw past endfire")
    return "\n".join(lines)


def fingerprint() -> list[float]:
    """Small config: M = 16, 10-degree grid, caps -12 / -16 dB, one worker: PSLR, gain and pointing per grid and cap."""
    res = sweep(RHSConfig(elements=16), ScanConfig(grid_deg=10.0), [-12.0, -16.0], 1, FastSettings())
    keys = ("pslr_db", "mainlobe_gain_db", "pointing_error_deg")
    return [float(r[k]) for r in res["grids"] for k in keys if k in r]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--elements", type=int, default=60)
    p.add_argument("--refractive-index", type=float, default=math.sqrt(3.0))
    p.add_argument("--grid-deg", type=float, default=1.0)
    p.add_argument("--caps", type=float, nargs="+", default=[-16.5, -18.0, -20.0, -22.0],
                   help="sidelobe caps in dB, loosest first (the gain cost is against the first)")
    p.add_argument("--angles", type=float, nargs="+", default=None,
                   help="only these grid centres (deg; default every theta >= 0 grid)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, default=ROOT / "results" / "patterns_sidelobe_limits.json")
    a = p.parse_args(argv)
    try:
        config = RHSConfig(elements=a.elements, refractive_index=a.refractive_index)
        scan = ScanConfig(grid_deg=a.grid_deg)
        settings = FastSettings()
        for cap in a.caps:
            FastSettings(max_sidelobe_db=cap)
        angles = None if a.angles is None else np.asarray(a.angles, dtype=float)
        if angles is not None and not np.all(np.isin(np.round(angles, 9), np.round(scan.angles_deg, 9))):
            raise ValueError(f"angles must be grid centres of the {scan.grid_deg:g}-degree scan, got {a.angles}")
    except ValueError as exc:
        print(f"pattern_sidelobe_limits: error: {exc}", file=sys.stderr)
        return 2
    started = time.time()
    res = {"config": config.to_dict(), "scan": scan.to_dict(), "settings": settings.to_dict(), "caps_db": a.caps,
           "subset": a.angles is not None, **sweep(config, scan, a.caps, a.workers, settings, angles),
           "load_average_1_5_15": list(os.getloadavg())}
    res["provenance"] = write_json(a.out, res, __file__, a, started, fingerprint_fn=fingerprint,
                                   argv=sys.argv[1:] if argv is None else argv)  # fmt: skip
    md = markdown(res)
    print(md)
    a.out.with_suffix(".md").write_text(md + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
