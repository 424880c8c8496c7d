"""``rhs-slam patterns``: build or load a holographic pattern library and report it per grid.

Example::

    rhs-slam patterns --elements 60 --grid-deg 1 --method fast --out lib.npz --json report.json

Refused before any work, with one line naming the option: a radar without sidelobes (too few elements for the
grid), the same element as Tx and Rx feed, an SDR build larger than the machine's memory. Ctrl-C stops a build at
once (its worker processes too) with one line; a library is written only once every grid is built, so nothing
partial is left behind.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
from pathlib import Path
from typing import Any

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--elements", "-M", type=int, default=60, help="elements per RHS, M (default 60)")
    parser.add_argument("--grid-deg", type=float, default=1.0, help="angular grid width in degrees (default 1)")
    parser.add_argument("--sector-deg", type=float, default=90.0, help="scanned sector in degrees (default 90)")
    parser.add_argument("--spacing-wl", type=float, default=0.25, help="element spacing in wavelengths (default 0.25)")
    parser.add_argument("--refractive-index", type=float, default=math.sqrt(3.0),
                        help="surface-wave refractive index n (default sqrt(3))")
    parser.add_argument("--tx-feed", type=int, default=0, help="Tx feed element index (default 0)")
    parser.add_argument("--rx-feed", type=int, default=-1, help="Rx feed element index (default -1: last)")
    parser.add_argument("--method", choices=("fast", "sdr"), default="fast",
                        help="fast: alternating SOCPs (default); sdr: the paper's SDR baseline (slow)")
    parser.add_argument("--workers", type=int, default=2, help="worker processes for building (default 2)")
    parser.add_argument("--load", type=Path, default=None, help="report an existing library file instead")
    parser.add_argument("--out", type=Path, default=None, help="write the library .npz here")
    parser.add_argument("--json", type=Path, default=None, help="write the per-grid report JSON here")
    parser.add_argument("--no-cache", action="store_true", help="always build (do not use shipped/cached)")
    parser.add_argument("--quiet", action="store_true", help="no per-grid table, no progress bar")


def _table(rows: list[dict[str, float]]) -> str:
    lines = [f"{'angle deg':>10} {'gain dB':>9} {'PSLR dB':>9} {'point err deg':>14}"]
    for r in rows:
        lines.append(
            f"{r['angle_deg']:10.2f} {r['mainlobe_gain_db']:9.2f} {r['pslr_db']:9.2f} {r['pointing_error_deg']:14.3f}"
        )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Build or load the library ``args`` describe and print its report (exit status: 0, 2 on an error, 130 on
    Ctrl-C)."""
    try:
        return _run(args)
    except KeyboardInterrupt:
        print("rhs-slam patterns: interrupted (Ctrl-C); nothing was written (a library is saved only once every "
              "grid is built)", file=sys.stderr)
        return 128 + int(signal.SIGINT)


def _write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (temp file then rename: an interrupt leaves the old file or none)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _run(args: argparse.Namespace) -> int:
    from rhs_common.validation import check_output_path
    from rhs_env.array_models import RHSConfig, ScanConfig
    from rhs_env.patterns.library import build_library, estimate_build_s, get_library, load
    from rhs_env.patterns.metrics import pattern_report

    try:
        for name, path in (("--out", args.out), ("--json", args.json)):
            if path is not None:
                check_output_path(name, path)
        if args.load is not None:
            lib = load(args.load)
            config = lib.rhs_config()
            scan = lib.scan_config()
        else:
            config = RHSConfig(
                elements=args.elements,
                spacing_wl=args.spacing_wl,
                refractive_index=args.refractive_index,
                tx_feed=args.tx_feed,
                rx_feed=args.rx_feed,
            )
            scan = ScanConfig(grid_deg=args.grid_deg, sector_deg=args.sector_deg)
            if args.workers < 1:
                raise ValueError(f"workers must be >= 1, got {args.workers}")
            if not args.quiet:
                estimate = estimate_build_s(config, scan, args.method, args.workers)
                print(f"rhs-slam patterns: {scan.slots} grids, M={config.elements}; a build (when not shipped or "
                      f"cached) takes about {estimate:.0f} s on 2 cores", file=sys.stderr)
            if args.no_cache:
                lib = build_library(config, scan, args.method, workers=args.workers, progress=not args.quiet)
            else:
                lib = get_library(config, scan, args.method, workers=args.workers, progress=not args.quiet,
                                  max_build_s=None)
        if args.out is not None:
            lib.save(args.out)
        settings = lib.config.get("settings", {})
        rep = pattern_report(config, lib.tx, lib.rx, lib.angles_deg, oversample=settings.get("oversample", 4.0))
    except (ValueError, OSError) as exc:
        print(f"rhs-slam patterns: error: {exc}", file=sys.stderr)
        return 2
    summary = rep.summary()
    if not args.quiet:
        print(_table(rep.rows()))
    print(
        f"{summary['grids']} grids, method {lib.config.get('method')}: worst PSLR {summary['worst_pslr_db']:.2f} dB, "
        f"median PSLR {summary['median_pslr_db']:.2f} dB, median main-lobe gain "
        f"{summary['median_mainlobe_gain_db']:.2f} dB, worst pointing error {summary['worst_pointing_error_deg']:.3f} deg"
    )
    if lib.path is not None:
        print(f"library: {lib.path}")
    if args.json is not None:
        out: dict[str, Any] = {"config": lib.config, "hash": lib.hash, "summary": summary, "grids": rep.rows(),
                               "library": str(lib.path) if lib.path else None}
        try:
            _write_text(args.json, json.dumps(out, indent=2))
        except OSError as exc:
            print(f"rhs-slam patterns: error: cannot write {args.json}: {exc}", file=sys.stderr)
            return 2
    return 0
