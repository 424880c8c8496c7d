#!/usr/bin/env python
"""Time the pattern-library build of the default radar (M=60, 1-degree grid, 90 grids) per method.

``benchmark_patterns()`` returns a JSON-able dict (also callable from scripts/benchmark.py):
wall-clock and CPU seconds (parent + worker processes) of a full ``fast`` build, and of
the ``sdr`` baseline on an evenly spaced subset of grids, extrapolated linearly to all
grids (marked ``"extrapolated": true``). Each entry also carries worst / median PSLR.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

from rhs_env.antenna import RHSConfig, ScanConfig
from rhs_env.patterns.fast import FastSettings, build_fast
from rhs_env.patterns.metrics import pattern_report
from rhs_env.patterns.sdr import SDRSettings, build_sdr


def _cpu() -> float:
    a = resource.getrusage(resource.RUSAGE_SELF)
    b = resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def _time(fn, config: RHSConfig, scan: ScanConfig, settings, workers: int, angles: np.ndarray) -> dict:
    c0, t0 = _cpu(), time.perf_counter()
    tx, rx, _ = fn(config, scan, settings, workers=workers, angles_deg=angles)
    wall, cpu = time.perf_counter() - t0, _cpu() - c0
    rep = pattern_report(config, tx, rx, angles).summary()
    return {"grids": int(angles.size), "wall_s": wall, "cpu_s": cpu, "worst_pslr_db": rep["worst_pslr_db"],
            "median_pslr_db": rep["median_pslr_db"]}


def benchmark_patterns(grid_deg: float = 1.0, workers: int = 2, sdr_grids: int = 10,
                       methods: tuple[str, ...] = ("fast", "sdr")) -> dict:
    """Build times of the default library with each method (SDR on ``sdr_grids`` grids, extrapolated)."""
    config, scan = RHSConfig(), ScanConfig(grid_deg=grid_deg)
    out: dict = {"elements": config.elements, "grid_deg": grid_deg, "slots": scan.slots, "workers": workers}
    if "fast" in methods:
        r = _time(build_fast, config, scan, FastSettings(), workers, scan.angles_deg)
        out["fast"] = {**r, "extrapolated": False, "build_s": r["wall_s"]}
    if "sdr" in methods:
        idx = np.unique(np.round(np.linspace(0, scan.slots - 1, min(sdr_grids, scan.slots))).astype(int))
        r = _time(build_sdr, config, scan, SDRSettings(), workers, scan.angles_deg[idx])
        scale = scan.slots / idx.size
        out["sdr"] = {**r, "extrapolated": bool(idx.size < scan.slots), "build_s": r["wall_s"] * scale,
                      "note": f"measured on {idx.size} evenly spaced grids, build_s scaled by {scale:.2f}"}
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--grid-deg", type=float, default=1.0)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--sdr-grids", type=int, default=10)
    p.add_argument("--methods", nargs="+", default=["fast", "sdr"], choices=["fast", "sdr"])
    p.add_argument("--out", type=Path, default=None, help="JSON output")
    a = p.parse_args(argv)
    res = benchmark_patterns(a.grid_deg, a.workers, a.sdr_grids, tuple(a.methods))
    text = json.dumps(res, indent=2)
    print(text)
    if a.out is not None:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
