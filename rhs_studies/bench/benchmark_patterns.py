#!/usr/bin/env python
"""Time the pattern-library build of an M=60, 1-degree radar (90 grids) per method.

The radar is the default one with the surface-wave index ``--refractive-index`` (default
1.70: no shipped library, so nothing is cached or shipped for it; the build is what a user
with that radar waits for). ``benchmark_patterns()`` returns a JSON-able dict (also
callable from scripts/benchmark.py): wall-clock and CPU seconds (parent + worker
processes) of a full ``fast`` build, and of the ``sdr`` baseline on an evenly spaced subset
of grids, extrapolated linearly to all grids (marked ``"extrapolated": true``). Each entry
also carries worst / median PSLR and the worst pointing error.

``fast_vs_previous``: the fast method with today's settings and with the settings it
shipped with before (``PREVIOUS_FAST``: two phase-sweep alternations, full rho search for
every phase, tol 1e-6, SOCP gap 1e-6, no fine-grid cap check) on the same evenly spaced
theta >= 0 grids, back to back in one run: the speed ratio holds on a busy machine where
absolute times do not.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from rhs_env.array_models import RHSConfig, ScanConfig
from rhs_env.patterns.fast import FastSettings, build_fast
from rhs_env.patterns.metrics import pattern_report
from rhs_env.patterns.sdr import SDRSettings, build_sdr


def _cpu() -> float:
    a = resource.getrusage(resource.RUSAGE_SELF)
    b = resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


PREVIOUS_FAST: dict[str, Any] = {"sweep_iters": 2, "sweep_evals": 8, "tol": 1e-6, "socp_tol": 1e-6, "cap_refine": 0,
                                  "max_sidelobe_db": -16.5}


def _time(fn, config: RHSConfig, scan: ScanConfig, settings, workers: int, angles: np.ndarray) -> dict:
    c0, t0 = _cpu(), time.perf_counter()
    tx, rx, _ = fn(config, scan, settings, workers=workers, angles_deg=angles)
    wall, cpu = time.perf_counter() - t0, _cpu() - c0
    rep = pattern_report(config, tx, rx, angles).summary()
    return {"grids": int(angles.size), "wall_s": wall, "cpu_s": cpu, "worst_pslr_db": rep["worst_pslr_db"],
            "median_pslr_db": rep["median_pslr_db"], "worst_pointing_error_deg": rep["worst_pointing_error_deg"],
            "median_mainlobe_gain_db": rep["median_mainlobe_gain_db"]}


def fast_vs_previous(config: RHSConfig, scan: ScanConfig, workers: int, grids: int) -> dict:
    """Today's fast settings against ``PREVIOUS_FAST`` on ``grids`` evenly spaced theta >= 0 grids, back to back."""
    pos = scan.angles_deg[scan.angles_deg >= 0]
    angles = pos[np.unique(np.round(np.linspace(0, pos.size - 1, min(grids, pos.size))).astype(int))]
    prev = _time(build_fast, config, scan, FastSettings(**PREVIOUS_FAST), workers, angles)
    now = _time(build_fast, config, scan, FastSettings(), workers, angles)
    return {"angles_deg": angles.tolist(), "previous": prev, "now": now, "previous_settings": PREVIOUS_FAST,
            "wall_ratio": prev["wall_s"] / now["wall_s"], "cpu_ratio": prev["cpu_s"] / now["cpu_s"]}


def benchmark_patterns(grid_deg: float = 1.0, workers: int = 2, sdr_grids: int = 10,
                       methods: tuple[str, ...] = ("fast", "sdr"), refractive_index: float = 1.70,
                       ratio_grids: int = 10) -> dict:
    """Build times of an unshipped library with each method (SDR on ``sdr_grids`` grids, extrapolated)
    and, with ``ratio_grids > 0``, the speed ratio of the fast method against its previous settings."""
    config, scan = RHSConfig(refractive_index=refractive_index), ScanConfig(grid_deg=grid_deg)
    out: dict = {"elements": config.elements, "refractive_index": refractive_index, "grid_deg": grid_deg,
                 "slots": scan.slots, "workers": workers, "load_average_1_5_15_start": list(os.getloadavg())}
    if "fast" in methods and ratio_grids > 0:
        out["fast_vs_previous"] = fast_vs_previous(config, scan, workers, ratio_grids)
    if "fast" in methods:
        r = _time(build_fast, config, scan, FastSettings(), workers, scan.angles_deg)
        out["fast"] = {**r, "extrapolated": False, "build_s": r["wall_s"]}
    if "sdr" in methods:
        idx = np.unique(np.round(np.linspace(0, scan.slots - 1, min(sdr_grids, scan.slots))).astype(int))
        r = _time(build_sdr, config, scan, SDRSettings(), workers, scan.angles_deg[idx])
        scale = scan.slots / idx.size
        out["sdr"] = {**r, "extrapolated": bool(idx.size < scan.slots), "build_s": r["wall_s"] * scale,
                      "note": f"measured on {idx.size} evenly spaced grids, build_s scaled by {scale:.2f}"}
    out["load_average_1_5_15_end"] = list(os.getloadavg())
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--grid-deg", type=float, default=1.0)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--sdr-grids", type=int, default=10)
    p.add_argument("--refractive-index", type=float, default=1.70, help="surface-wave index n (1.70: not shipped)")
    p.add_argument("--ratio-grids", type=int, default=10,
                   help="grids timed with today's and the previous fast settings back to back (0: skip)")
    p.add_argument("--methods", nargs="+", default=["fast", "sdr"], choices=["fast", "sdr"])
    p.add_argument("--out", type=Path, default=None, help="JSON output")
    a = p.parse_args(argv)
    res = benchmark_patterns(a.grid_deg, a.workers, a.sdr_grids, tuple(a.methods), a.refractive_index, a.ratio_grids)
    res["command"] = " ".join(["python scripts/benchmark_patterns.py", *(sys.argv[1:] if argv is None else argv)])
    text = json.dumps(res, indent=2)
    print(text)
    if a.out is not None:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
