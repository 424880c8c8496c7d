"""Planar trajectories in the text formats SLAM evaluation tools read (``evo``, the TUM and KITTI benchmarks).

A trajectory here is ``T`` poses ``(x, y, heading)`` (m, m, rad) in one frame, the SLAM's map frame (the
start pose is the origin), with a time per pose (s: the env's simulated time, one policy period per cycle).

* **TUM** (``*.tum``): one line per pose, ``timestamp tx ty tz qx qy qz qw``; planar, so ``tz = 0`` and the
  quaternion is the rotation about z by the heading, ``(0, 0, sin(h/2), cos(h/2))``.
* **KITTI** (``*.kitti``): one line per pose, the 12 entries of the 3x4 matrix ``[R | t]`` row by row, no
  timestamps (the poses of two files pair by line).

Times and positions are written with 9 decimals (1 nm), rotations with 12: an error metric computed from
the files (``evo_ape``) equals the project's own (:func:`slam.core.metrics.position_rmse`) to far below 1e-6 m.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = [
    "FORMATS",
    "SUFFIXES",
    "yaw_quaternion",
    "quaternion_yaw",
    "tum_text",
    "kitti_text",
    "write_tum",
    "write_kitti",
    "read_tum",
    "read_kitti",
    "write_trajectory_pair",
    "FORMAT_CHOICES",
    "formats_of",
]

#: the formats :func:`write_trajectory_pair` writes
FORMATS = ("tum", "kitti")
#: file suffix per format
SUFFIXES = {"tum": ".tum", "kitti": ".kitti"}
#: the command lines' ``--trajectory-format`` values
FORMAT_CHOICES = ("tum", "kitti", "both")


def formats_of(choice: str) -> tuple[str, ...]:
    """The formats of a ``--trajectory-format`` value (:data:`FORMAT_CHOICES`): ``"both"`` is TUM and KITTI."""
    if choice not in FORMAT_CHOICES:
        raise ValueError(f"--trajectory-format must be one of {', '.join(FORMAT_CHOICES)}, got {choice!r}")
    return FORMATS if choice == "both" else (choice,)


def _poses(poses: np.ndarray, name: str = "poses") -> np.ndarray:
    """``poses`` as a finite (T, 3) float array (ValueError naming ``name`` otherwise)."""
    a = np.asarray(poses, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name} must be a (T, 3) array of x, y, heading, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite (no NaN or inf)")
    return a


def _times(times: np.ndarray, count: int) -> np.ndarray:
    """``times`` as a finite, strictly increasing (T,) array of ``count`` values (ValueError otherwise)."""
    t = np.asarray(times, dtype=float).reshape(-1)
    if t.shape != (count,):
        raise ValueError(f"times must have one entry per pose ({count}), got {t.shape[0]}")
    if not np.all(np.isfinite(t)):
        raise ValueError("times must be finite (no NaN or inf)")
    if count > 1 and not np.all(np.diff(t) > 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise ValueError(f"times must increase strictly (TUM tools pair poses by time), got {t[k - 1]!r} then {t[k]!r}")
    return t


def yaw_quaternion(heading: np.ndarray) -> np.ndarray:
    """Quaternions ``(qx, qy, qz, qw)`` (T, 4) of the rotations about z by ``heading`` (T,) (rad)."""
    h = np.asarray(heading, dtype=float).reshape(-1)
    z = np.zeros_like(h)
    return np.column_stack([z, z, np.sin(h / 2), np.cos(h / 2)])


def quaternion_yaw(q: np.ndarray) -> np.ndarray:
    """Heading (T,) (rad, in (-pi, pi]) of quaternions ``(qx, qy, qz, qw)`` (T, 4): the rotation's yaw."""
    q = np.asarray(q, dtype=float).reshape(-1, 4)
    x, y, z, w = q.T
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def tum_text(times: np.ndarray, poses: np.ndarray) -> str:
    """TUM lines ``timestamp tx ty tz qx qy qz qw`` of planar ``poses`` (T, 3) at ``times`` (T,) (s)."""
    p = _poses(poses)
    t = _times(times, len(p))
    q = yaw_quaternion(p[:, 2])
    return "".join(f"{ti:.9f} {x:.9f} {y:.9f} 0.000000000 " + " ".join(f"{v:.12f}" for v in qi) + "\n"
                   for ti, x, y, qi in zip(t, p[:, 0], p[:, 1], q))


def kitti_text(poses: np.ndarray) -> str:
    """KITTI lines (the 3x4 matrix ``[R | t]`` row by row) of planar ``poses`` (T, 3)."""
    p = _poses(poses)
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    z, o = np.zeros(len(p)), np.ones(len(p))
    rows = np.column_stack([c, -s, z, p[:, 0], s, c, z, p[:, 1], z, z, o, z])
    digits = (12, 12, 12, 9) * 3  # rotation entries, then the translation's, per row of [R | t]
    return "".join(" ".join(f"{v:.{d}f}" for v, d in zip(row, digits)) + "\n" for row in rows)


def write_tum(path: str | Path, times: np.ndarray, poses: np.ndarray) -> Path:
    """Write a TUM file (:func:`tum_text`); returns its path."""
    path = Path(path)
    path.write_text(tum_text(times, poses))
    return path


def write_kitti(path: str | Path, poses: np.ndarray) -> Path:
    """Write a KITTI pose file (:func:`kitti_text`); returns its path."""
    path = Path(path)
    path.write_text(kitti_text(poses))
    return path


def _table(path: str | Path, cols: int) -> np.ndarray:
    """The numeric rows of a whitespace-separated file (``#`` comments skipped), (T, cols)."""
    rows = [line.split() for line in Path(path).read_text().splitlines() if line.strip() and not line.startswith("#")]
    bad = next((n for n, r in enumerate(rows) if len(r) != cols), None)
    if bad is not None:
        raise ValueError(f"{path}: line {bad + 1} has {len(rows[bad])} numbers, expected {cols}")
    return np.asarray(rows, dtype=float).reshape(len(rows), cols)


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A TUM file's times (T,) and planar poses (T, 3) (x, y, yaw; z and the tilt are dropped)."""
    a = _table(path, 8)
    return a[:, 0], np.column_stack([a[:, 1], a[:, 2], quaternion_yaw(a[:, 4:8])])


def read_kitti(path: str | Path) -> np.ndarray:
    """A KITTI pose file's planar poses (T, 3): x, y and the yaw of each 3x4 matrix."""
    a = _table(path, 12)
    return np.column_stack([a[:, 3], a[:, 7], np.arctan2(a[:, 4], a[:, 0])])


def write_trajectory_pair(
    directory: str | Path,
    stem: str,
    times: np.ndarray,
    estimated: np.ndarray,
    true: np.ndarray,
    formats: Sequence[str] = ("tum",),
) -> list[Path]:
    """Write the estimated and the true trajectory of one run as ``<stem>_est<suffix>`` and ``<stem>_gt<suffix>``.

    Args:
        directory: output folder (created when missing).
        stem: file name stem, e.g. ``"seed_0"``.
        times: (T,) strictly increasing times (s), the simulated time of each pose.
        estimated: (T, 3) estimated poses (map frame).
        true: (T, 3) true poses (same frame).
        formats: some of :data:`FORMATS`.

    Returns:
        The paths written, ``est`` before ``gt`` per format.
    """
    unknown = [f for f in formats if f not in FORMATS]
    if unknown or not formats:
        raise ValueError(f"formats must be some of {', '.join(FORMATS)}, got {list(formats)!r}")
    est, gt = _poses(estimated, "estimated"), _poses(true, "true")
    if len(est) != len(gt):
        raise ValueError(f"estimated and true must have the same length, got {len(est)} and {len(gt)}")
    t = _times(times, len(est))
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    for fmt in dict.fromkeys(formats):
        for tag, poses in (("est", est), ("gt", gt)):
            path = out / f"{stem}_{tag}{SUFFIXES[fmt]}"
            paths.append(write_tum(path, t, poses) if fmt == "tum" else write_kitti(path, poses))
    return paths
