#!/usr/bin/env python
"""Build the shipped pattern libraries (or a small config for tests) with the fast method.

Default: M=60, d=lambda/4, n=sqrt(3), feeds 0 / M-1, sector 90 deg, grids 1, 2, 5 deg, into
``rhs_env/patterns/data/``. Prints the build time and worst/median PSLR per library and
writes a JSON summary (``--json``).

    python scripts/build_patterns.py                       # shipped libraries
    python scripts/build_patterns.py --elements 16 --grids 10 --out-dir /tmp/x   # small
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

from rhs_env.array_models import RHSConfig, ScanConfig
from rhs_env.patterns.library import DATA_DIR, build_library, write_checksums
from rhs_env.patterns.metrics import pattern_report
from rhs_studies.kit.provenance import write_json

CAP_TOL_DB = 0.01  # a grid counts as over the sidelobe cap when its fine-grid PSLR exceeds it by more


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--elements", type=int, default=60)
    p.add_argument("--spacing-wl", type=float, default=0.25)
    p.add_argument("--refractive-index", type=float, default=math.sqrt(3.0))
    p.add_argument("--sector-deg", type=float, default=90.0)
    p.add_argument("--grids", type=float, nargs="+", default=[1.0, 2.0, 5.0], help="grid widths in degrees")
    p.add_argument("--method", choices=("fast", "sdr"), default="fast")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out-dir", type=Path, default=DATA_DIR)
    p.add_argument("--json", type=Path, default=None, help="summary JSON (build times, PSLR)")
    p.add_argument("--quiet", action="store_true")
    a = p.parse_args(argv)
    started = time.time()
    try:
        config = RHSConfig(elements=a.elements, spacing_wl=a.spacing_wl, refractive_index=a.refractive_index)
        scans = [ScanConfig(grid_deg=g, sector_deg=a.sector_deg) for g in a.grids]
    except ValueError as exc:
        print(f"build_patterns: error: {exc}", file=sys.stderr)
        return 2
    summary = []
    for scan in scans:
        t0 = time.perf_counter()
        lib = build_library(config, scan, a.method, workers=a.workers, progress=not a.quiet)
        dt = time.perf_counter() - t0
        name = f"rhs_m{config.elements}_grid{scan.grid_deg:g}deg_{a.method}.npz"
        path = lib.save(a.out_dir / name)
        full = pattern_report(config, lib.tx, lib.rx, lib.angles_deg)
        rep = full.summary()
        cap = lib.config["settings"].get("max_sidelobe_db")
        over = [] if cap is None else [float(x) for x in full.angle_deg[full.pslr_db > cap + CAP_TOL_DB]]
        row = {"file": path.name, "grid_deg": scan.grid_deg, "build_s": dt, **rep, "cap_db": cap,
               "grids_over_cap": over, "load_average_1_5_15": list(os.getloadavg())}
        summary.append(row)
        print(
            f"{name}: {dt:.1f} s, worst PSLR {rep['worst_pslr_db']:.2f} dB, median PSLR "
            f"{rep['median_pslr_db']:.2f} dB, worst pointing {rep['worst_pointing_error_deg']:.3f} deg",
            flush=True,
        )
    write_checksums(a.out_dir)  # the sha256 every shipped file is checked against when loaded
    if a.json is not None:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        write_json(a.json, {"libraries": summary, "method": a.method, "rhs": config.to_dict()}, __file__, a, started,
                   fingerprint, argv)
        a.json.with_suffix(".md").write_text(markdown(summary, config, a.method, a.workers) + "\n")
    return 0


def fingerprint() -> list[float]:
    """The fast method on two grids of a 12-element RHS (15-degree grid): patterns and their report, seconds."""
    import numpy as np

    from rhs_env.patterns.fast import FastSettings, build_fast

    config, scan = RHSConfig(elements=12), ScanConfig(grid_deg=15.0)
    angles = scan.angles_deg[[0, scan.slots // 2]]
    tx, rx, _ = build_fast(config, scan, FastSettings(), workers=1, angles_deg=angles)
    rep = pattern_report(config, tx, rx, angles).summary()
    return [*np.ravel(tx), *np.ravel(rx), *(rep[k] for k in sorted(rep))]


def markdown(summary: list[dict], config: RHSConfig, method: str, workers: int) -> str:
    """Table of the built libraries (written next to ``--json`` as ``.md``)."""
    lines = [(f"Libraries built by `python scripts/build_patterns.py` ({method} method, M={config.elements}, "
              f"{workers} workers); two-way PSLR and pointing over every grid of each library."), "",
             ("| dtheta deg | grids | build s | worst PSLR dB | median PSLR dB | median main-lobe gain dB | "
              "worst pointing deg | grids over the sidelobe cap |"), "|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in summary:
        over = ", ".join(f"{x:g}" for x in r["grids_over_cap"]) or "none"
        lines.append(f"| {r['grid_deg']:g} | {r['grids']} | {r['build_s']:.1f} | {r['worst_pslr_db']:.2f} | "
                     f"{r['median_pslr_db']:.2f} | {r['median_mainlobe_gain_db']:.2f} | "
                     f"{r['worst_pointing_error_deg']:.2f} | {len(r['grids_over_cap'])}/{r['grids']} ({over}) |")
    caps = sorted({r["cap_db"] for r in summary if r["cap_db"] is not None})
    if caps:
        load = ", ".join(f"{x:.1f}" for x in summary[-1]["load_average_1_5_15"])
        lines += ["", (f"Sidelobe cap {', '.join(f'{c:g}' for c in caps)} dB (FastSettings.max_sidelobe_db), "
                       "checked on the PSLR report's fine grid (cap_refine); a grid is over it when its PSLR "
                       f"exceeds it by more than {CAP_TOL_DB} dB. Build times are wall clock on a shared 2-core "
                       f"machine (load average at the end: {load}).")]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
