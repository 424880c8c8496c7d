"""``rhs-slam scenario SCENARIO.json --out RESULT.json``: SLAM on a scripted run.

Input JSON (``examples/scenario.json`` in the repository is one)::

    {"landmarks": [[x, y], ...],          # world frame, m
     "poses": [[x, y, heading], ...],     # true pose per cycle (m, m, rad); the first is the map origin
     "antenna": "rhs",                    # optional: rhs | phased | random | hologram
     "seed": 0,                           # optional
     "dt": 0.2,                           # optional cycle length, s
     "registration": "icp",               # optional: cnn | icp | odometry
     "rcs_m2": 5.0,                       # optional landmark RCS
     "grid_deg": 1.0}                     # optional beam grid

The radar synthesises and processes the echoes of the landmarks seen from each
true pose; the SLAM runs through the same :class:`slam.core.pipeline.SlamPipeline`
as the env. With ``--trajectories DIR`` the estimated and true trajectories are also written as
``DIR/<scenario stem>_est.tum`` and ``_gt.tum`` (``--trajectory-format kitti`` or ``both`` for KITTI's
format; :mod:`slam.core.trajectory_formats`), times ``t * dt``, for ``evo_ape`` / ``evo_traj``; their APE
(no alignment) is ``ate_rmse_m``. Output: ``estimated_poses`` and ``landmarks`` (map frame),
``ate_rmse_m``, ``map_rmse_m`` and the map match counts, written atomically
(:mod:`rhs_common.output_files`); ``--out`` may not be the scenario file itself.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from rhs_common.input_files import read_json
from rhs_common.output_files import check_output_file, write_text_atomic
from rhs_common.validation import check_choice, check_int, check_output_path
from slam.core.trajectory_formats import FORMAT_CHOICES, formats_of

__all__ = [
    "ANTENNAS", "MAX_COORD_M", "MAX_CYCLES", "MAX_DT_S", "MAX_HEADING_RAD", "MAX_LANDMARKS", "MAX_RCS_M2",
    "MAX_SPEED_MPS", "OPTIONAL", "REGISTRATIONS", "configure", "parse_scenario", "run", "run_scripted",
]

OPTIONAL = {"antenna", "seed", "dt", "registration", "rcs_m2", "grid_deg", "particles"}

#: bounds that keep a run finite and physical: cycles and landmarks (work), coordinates,
#: the speed between consecutive poses (a 1e9 m jump is not a drive), cycle length, RCS
MAX_CYCLES = 100_000
MAX_LANDMARKS = 100_000
MAX_COORD_M = 1e6
#: headings may be unwrapped (the turns summed), up to this many radians: 100 000 cycles of 10 s at 1 rad/s
MAX_HEADING_RAD = 1e6
MAX_SPEED_MPS = 100.0
MAX_DT_S = 10.0
MAX_RCS_M2 = 1e4
ANTENNAS = ("rhs", "phased", "random", "hologram")
REGISTRATIONS = ("cnn", "icp", "odometry")


def _array(doc: dict, key: str, cols: int, min_rows: int, max_rows: int) -> np.ndarray:
    """``doc[key]`` as a (rows, cols) float array: a list of rows of ``cols`` numbers each (no strings or
    booleans), finite, x and y within ``MAX_COORD_M``, a third column (headings) within ``MAX_HEADING_RAD``."""
    if key not in doc:
        raise ValueError(f"missing key {key!r}")
    rows = doc[key]
    rows = rows.tolist() if isinstance(rows, np.ndarray) else rows
    shape = f"[{', '.join(['number'] * cols)}]"
    if not isinstance(rows, (list, tuple)):
        raise TypeError(f"{key!r} must be a list of {shape} rows, got {type(rows).__name__}")
    if len(rows) > max_rows:
        raise ValueError(f"{key!r} must have at most {max_rows} rows, got {len(rows)}")
    if len(rows) < min_rows:
        raise ValueError(f"{key!r} needs at least {min_rows} rows, got {len(rows)}")
    for n, row in enumerate(rows):
        if not isinstance(row, (list, tuple)) or len(row) != cols:
            raise ValueError(f"{key!r}[{n}] must be a row of {cols} numbers {shape}, got {row!r}")
        for v in row:
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise TypeError(f"{key!r}[{n}] must hold numbers, got {v!r} ({type(v).__name__}) in {row!r}")
    a = np.asarray(rows, dtype=float).reshape(len(rows), cols)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{key!r} must contain only finite numbers (no NaN or inf)")
    if np.abs(a[:, :2]).max(initial=0.0) > MAX_COORD_M:
        raise ValueError(f"{key!r} x, y must be within +-{MAX_COORD_M:g} m")
    if cols == 3 and np.abs(a[:, 2]).max(initial=0.0) > MAX_HEADING_RAD:
        k = int(np.argmax(np.abs(a[:, 2])))
        raise ValueError(f"{key!r}[{k}] heading must be within +-{MAX_HEADING_RAD:g} rad, got {a[k, 2]:g} (a "
                         "double resolves 1e-10 rad at 1e6 rad, only 1e-4 rad at 1e12)")
    return a


def _number(doc: dict, key: str, default: float, high: float) -> float:
    v = doc.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise TypeError(f"{key!r} must be a number in (0, {high:g}], got {v!r} ({type(v).__name__})")
    if not (math.isfinite(v) and 0 < v <= high):
        raise ValueError(f"{key!r} must be in (0, {high:g}], got {v!r}")
    return float(v)


def _check_speed(poses: np.ndarray, dt: float) -> None:
    """Consecutive poses at most ``MAX_SPEED_MPS * dt`` apart (ValueError naming the first jump)."""
    step = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    bad = np.flatnonzero(step > MAX_SPEED_MPS * dt)
    if bad.size:
        k = int(bad[0]) + 1
        raise ValueError(f"'poses'[{k}] is {step[k - 1]:.4g} m from the previous pose in dt={dt:g} s: at most "
                         f"{MAX_SPEED_MPS:g} m/s x dt = {MAX_SPEED_MPS * dt:g} m per cycle")


def parse_scenario(doc: Any) -> dict[str, Any]:
    """Validate a scenario document; returns the arrays and options (ValueError with a clear message)."""
    if not isinstance(doc, dict):
        raise TypeError("the scenario must be a JSON object with 'landmarks' and 'poses'")
    unknown = sorted(set(doc) - OPTIONAL - {"landmarks", "poses"})
    if unknown:
        raise ValueError(f"unknown key(s) {', '.join(map(repr, unknown))}")
    from rhs_env.array_models import ScanConfig
    from slam.core.rbpf import SlamConfig

    out: dict[str, Any] = {"landmarks": _array(doc, "landmarks", 2, 0, MAX_LANDMARKS),
                           "poses": _array(doc, "poses", 3, 2, MAX_CYCLES)}
    out["antenna"] = doc.get("antenna", "rhs")
    check_choice("'antenna'", out["antenna"], ANTENNAS)
    out["registration"] = doc.get("registration", "icp")
    check_choice("'registration'", out["registration"], REGISTRATIONS)
    seed = doc.get("seed", 0)
    check_int("'seed'", seed, 0, 2**63 - 1)
    out["seed"] = seed
    out["dt"] = _number(doc, "dt", 0.2, MAX_DT_S)
    out["rcs_m2"] = _number(doc, "rcs_m2", 5.0, MAX_RCS_M2)
    out["grid_deg"] = _number(doc, "grid_deg", 1.0, 180.0)
    try:
        ScanConfig(grid_deg=out["grid_deg"])  # the beam-grid bounds (at most MAX_SLOTS slots)
        particles = doc.get("particles", 100)
        SlamConfig(n_particles=particles)
    except (TypeError, ValueError) as exc:
        raise type(exc)(str(exc).replace("n_particles", "'particles'")) from None
    out["particles"] = particles
    _check_speed(out["poses"], out["dt"])
    return out


def run_scripted(
    spec: dict[str, Any],
    progress: bool = False,
    trajectories: str | Path | None = None,
    formats: tuple[str, ...] = ("tum",),
    stem: str = "scenario",
) -> dict[str, Any]:
    """Run the radar + SLAM on a parsed scenario; returns the JSON-ready result.

    Args:
        spec: a scenario from :func:`parse_scenario`.
        progress: show a progress bar.
        trajectories: also write the estimated and true trajectories into this folder
            (:func:`slam.core.trajectory_formats.write_trajectory_pair`, unrounded, times ``t * dt``);
            the result then lists them in ``trajectory_files``.
        formats: their formats, some of ``("tum", "kitti")``.
        stem: their file name stem.

    Returns:
        The JSON-ready result (poses and landmarks rounded to 0.1 mm).
    """
    from rhs_env.array_models import ScanConfig
    from rhs_env.radar import RadarConfig, RadarSystem
    from slam.core.rbpf import SlamConfig
    from slam.core.registration import make_registration
    from slam.core.scenario import run_scenario
    from slam.gym.radar_cloud import RadarCloud

    rng = np.random.default_rng(spec["seed"])
    radar = RadarSystem(RadarConfig(antenna=spec["antenna"], scan=ScanConfig(grid_deg=spec["grid_deg"])), rng)
    cloud = RadarCloud(spec["landmarks"], spec["poses"], spec["dt"], radar, spec["rcs_m2"])
    res = run_scenario(
        spec["landmarks"],
        spec["poses"],
        cloud,
        make_registration(spec["registration"], rng),
        SlamConfig(n_particles=spec["particles"]),
        rng,
        dt=spec["dt"],
        progress=progress,
    )
    nan_to_none = lambda v: None if v is None or not np.isfinite(v) else float(v)
    files = {}
    if trajectories is not None:
        from slam.core.trajectory_formats import write_trajectory_pair

        times = np.arange(len(res["true_poses"])) * spec["dt"]
        paths = write_trajectory_pair(trajectories, stem, times, res["estimated_poses"], res["true_poses"], formats)
        files = {"trajectory_files": [str(p) for p in paths]}
    return {
        "estimated_poses": np.round(res["estimated_poses"], 4).tolist(),
        "true_poses": np.round(res["true_poses"], 4).tolist(),
        "landmarks": np.round(res["landmarks"], 4).tolist(),
        "ate_rmse_m": nan_to_none(res["ate_rmse_m"]),
        "heading_rmse_rad": nan_to_none(res["heading_rmse_rad"]),
        "map_rmse_m": nan_to_none(res["map_rmse_m"]),
        "map_matched": int(res["map_matched"]),
        "map_missed": int(res["map_missed"]),
        "map_spurious": int(res["map_spurious"]),
        "antenna": spec["antenna"],
        "registration": spec["registration"],
        "seed": spec["seed"],
        **files,
    }


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", help="scenario JSON file (landmarks, poses, ...)")
    parser.add_argument("--out", required=True, help="result JSON file")
    parser.add_argument("--trajectories", default=None, metavar="DIR",
                        help="also write the estimated and true trajectories here (<scenario>_est.tum, <scenario>_gt.tum) "
                        "for evo_ape / evo_traj")
    parser.add_argument("--trajectory-format", default="tum", choices=FORMAT_CHOICES,
                        help="format of --trajectories: tum (timestamped), kitti (3x4 matrices) or both (default: tum)")
    parser.add_argument("--no-progress", action="store_true")


def run(args: argparse.Namespace) -> int:
    try:
        check_output_file("--out", args.out, inputs=[("the scenario", args.scenario)])
        if args.trajectories is not None:
            check_output_path("--trajectories", args.trajectories, directory=True)
        doc = read_json(args.scenario)
        try:
            spec = parse_scenario(doc)
        except (TypeError, ValueError) as exc:
            raise type(exc)(f"{args.scenario}: {exc}") from None
        try:
            result = run_scripted(spec, progress=not args.no_progress, trajectories=args.trajectories,
                                  formats=formats_of(args.trajectory_format), stem=Path(args.scenario).stem)
        except FileNotFoundError as exc:  # e.g. the CNN registration weights are not there
            raise ValueError(str(exc)) from None
        try:
            write_text_atomic(args.out, json.dumps(result, indent=1))
        except OSError as exc:
            raise ValueError(f"cannot write {args.out}: {exc.strerror or exc}") from None
    except (TypeError, ValueError) as exc:
        print(f"rhs-slam scenario: error: {exc}", file=sys.stderr)
        return 2
    keys = ("ate_rmse_m", "map_rmse_m", "map_matched", "map_missed", "map_spurious", "trajectory_files")
    print(json.dumps({k: result[k] for k in keys if k in result}))
    return 0
