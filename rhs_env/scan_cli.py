"""``rhs-slam scan SCENE.json --out CLOUD.json``: one radar cycle on targets from a file.

Scene (vehicle frame, the ego at the origin heading +x; ``examples/scene.json`` in the repository is one)::

    {"targets": [[x, y, rcs_m2], ...],          # or [x, y, rcs_m2, vx, vy] (relative velocity, m/s)
     "occluders": [[x0, y0, x1, y1], ...],      # optional opaque segments
     "antenna": "rhs" | "phased" | "random" | "hologram",   # optional, default rhs
     "seed": 0}                                  # optional, default 0

Output: ``{"points": [[x, y, radial_velocity, amplitude], ...], "radar": [...],
"stage_times": {...}, "antenna": ..., "seed": ...}``. A malformed scene is
refused with a one-line message on stderr naming the file and exit status 2: bytes that are
not UTF-8, nesting, integers of many digits, keys given twice, a path that is not a regular
file or over the size limit (:mod:`rhs_common.input_files`), strings or booleans where numbers go,
values out of their bounds. ``--out`` may not be the scene itself nor a named pipe or device; it is
written atomically (:mod:`rhs_common.output_files`): a failed run leaves the previous file whole.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from rhs_common.input_files import InputError, read_json
from rhs_common.output_files import check_output_file, write_text_atomic
from rhs_env.array_models import ANTENNA_KINDS

__all__ = ["MAX_COORD_M", "MAX_RCS_M2", "MAX_SPEED_MPS", "MAX_TARGETS", "SceneError", "configure", "parse_scene", "run"]

#: bounds that keep one scan's work and arithmetic finite: an RCS of 1e300 m^2 overflows the
#: echo power (and its sidelobes wipe out every other target); 10 000 targets is ~100x a highway scene
MAX_RCS_M2 = 1e4
MAX_TARGETS = 10_000
MAX_COORD_M = 1e4
MAX_SPEED_MPS = 1e3


class SceneError(ValueError):
    """A scene file that cannot be used (message is shown to the user)."""


def _finite_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def parse_scene(data: Any) -> dict:
    """Validate a scene dict; returns targets (K, 3|5), occluders (S, 4), antenna, seed."""
    if not isinstance(data, dict):
        raise SceneError("scene must be a JSON object with a 'targets' list")
    unknown = set(data) - {"targets", "occluders", "antenna", "seed"}
    if unknown:
        raise SceneError(f"unknown scene key(s): {', '.join(sorted(unknown))} "
                         "(allowed: targets, occluders, antenna, seed)")
    if "targets" not in data:
        raise SceneError("scene is missing the 'targets' key ([[x, y, rcs_m2], ...])")
    targets = data["targets"]
    if not isinstance(targets, list):
        raise SceneError("'targets' must be a list of [x, y, rcs_m2] rows")
    if len(targets) > MAX_TARGETS:
        raise SceneError(f"'targets' must have at most {MAX_TARGETS} rows, got {len(targets)}")
    rows = []
    for n, row in enumerate(targets):
        if not isinstance(row, list) or len(row) not in (3, 5):
            raise SceneError(f"targets[{n}] must be [x, y, rcs_m2] or [x, y, rcs_m2, vx, vy], got {row!r}")
        if not all(_finite_number(v) for v in row):
            raise SceneError(f"targets[{n}] must hold finite numbers, got {row!r}")
        if not 0 <= row[2] <= MAX_RCS_M2:
            raise SceneError(f"targets[{n}] rcs_m2 must be in [0, {MAX_RCS_M2:g}] m^2, got {row[2]!r}")
        if max(abs(row[0]), abs(row[1])) > MAX_COORD_M:
            raise SceneError(f"targets[{n}] x, y must be within +-{MAX_COORD_M:g} m, got {row[:2]!r}")
        if len(row) == 5 and max(abs(row[3]), abs(row[4])) > MAX_SPEED_MPS:
            raise SceneError(f"targets[{n}] vx, vy must be within +-{MAX_SPEED_MPS:g} m/s, got {row[3:]!r}")
        rows.append([float(v) for v in row] + ([0.0, 0.0] if len(row) == 3 else []))
    occ = data.get("occluders", [])
    if not isinstance(occ, list):
        raise SceneError("'occluders' must be a list of [x0, y0, x1, y1] segments")
    if len(occ) > MAX_TARGETS:
        raise SceneError(f"'occluders' must have at most {MAX_TARGETS} rows, got {len(occ)}")
    segs = []
    for n, row in enumerate(occ):
        if not isinstance(row, list) or len(row) != 4 or not all(_finite_number(v) for v in row):
            raise SceneError(f"occluders[{n}] must be [x0, y0, x1, y1] with finite numbers, got {row!r}")
        segs.append([float(v) for v in row])
    antenna = data.get("antenna", "rhs")
    if antenna not in ANTENNA_KINDS:
        raise SceneError(f"unknown antenna {antenna!r} (allowed: {', '.join(ANTENNA_KINDS)})")
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
        raise SceneError(f"'seed' must be an integer in [0, 2**63), got {seed!r}")
    return {"targets": np.array(rows, float).reshape(-1, 5), "occluders": np.array(segs, float).reshape(-1, 4),
            "antenna": antenna, "seed": seed}


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", type=Path, help="scene JSON: {\"targets\": [[x, y, rcs_m2], ...], ...}")
    parser.add_argument("--out", type=Path, required=True, help="output JSON with the point cloud")
    parser.add_argument("--antenna", choices=ANTENNA_KINDS, default=None, help="override the scene's antenna")
    parser.add_argument("--seed", type=int, default=None, help="override the scene's seed")
    parser.add_argument("--grid-deg", type=float, default=1.0, help="beam grid dtheta in degrees (default 1)")


def _fail(msg: str) -> int:
    print(f"rhs-slam scan: error: {msg}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    if args.seed is not None and not 0 <= args.seed < 2**63:
        return _fail(f"--seed must be an integer in [0, 2**63), got {args.seed}")
    try:
        check_output_file("--out", args.out, inputs=[("the scene", args.scene)])
    except (TypeError, ValueError) as exc:
        return _fail(str(exc))
    try:
        data = read_json(args.scene)
    except InputError as exc:
        return _fail(str(exc))
    try:
        scene = parse_scene(data)
    except SceneError as exc:
        return _fail(f"{args.scene}: {exc}")
    antenna = args.antenna or scene["antenna"]
    seed = scene["seed"] if args.seed is None else args.seed

    from rhs_env.array_models import ScanConfig
    from rhs_env.radar import RadarConfig, RadarSystem
    from rhs_env.scatterers import Occluders, Scatterers

    try:
        cfg = RadarConfig(antenna=antenna, scan=ScanConfig(grid_deg=args.grid_deg))
        rng = np.random.default_rng(seed)
        radar = RadarSystem(cfg, rng)
    except (TypeError, ValueError) as exc:
        return _fail(str(exc))
    t = scene["targets"]
    k = t.shape[0]
    scat = Scatterers(t[:, :2], t[:, 3:5], t[:, 2], np.arange(k), np.all(t[:, 3:5] == 0, axis=1))
    seg = scene["occluders"]
    occ = Occluders(seg.reshape(-1, 2, 2), np.full(seg.shape[0], -1)) if seg.shape[0] else None
    cloud = radar.scan(scat, occ)
    out = {
        "points": [[float(v) for v in row] for row in cloud.points],
        "radar": [int(r) for r in cloud.radar],
        "antenna": antenna,
        "seed": seed,
        "stage_times": {k2: float(v) for k2, v in cloud.stage_times.items()},
    }
    try:
        write_text_atomic(args.out, json.dumps(out) + "\n")
    except OSError as exc:
        return _fail(f"cannot write {args.out}: {exc.strerror or exc}")
    print(f"{len(cloud)} points from {k} targets ({antenna}, seed {seed}) -> {args.out}")
    return 0
