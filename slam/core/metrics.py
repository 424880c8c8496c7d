"""SLAM metrics. SI units: m, rad.

- :func:`position_rmse`: ``sqrt(mean_t |p_hat_t - p_t|^2)`` over the run, no
  alignment (the map frame is the start pose).
- :func:`heading_rmse`: ``sqrt(mean_t wrap(th_hat_t - th_t)^2)``.
- :func:`map_metrics`: one-to-one matching of estimated to true landmarks by the
  Hungarian algorithm (``scipy.optimize.linear_sum_assignment``) on the Euclidean
  distance; pairs farther than the gate are not matches. RMSE over matches,
  ``missed`` = true landmarks without a match, ``spurious`` = estimated landmarks
  without a match.
- :func:`landmark_hits` and :func:`matched_fraction`: the map's recall over a
  chosen subset of the true landmarks. Which landmarks count as *seen* is a
  definition the caller states. :class:`slam.gym.metrics_info.SlamMetricsInfo`'s
  ``map_matched`` / ``map_missed`` count every landmark that has been within
  radar range (``max_range_m``, a disc: field of view, traffic occlusion and
  detection ignored). ``scripts/slam_accuracy.py`` also reports the
  **measured** matched fraction: a landmark counts as seen once the radar has
  produced a point within :data:`MEASURED_GATE_M` (1 m) of its true position in
  at least :data:`MEASURED_MIN_SCANS` (2) scans, the number of updates the RBPF
  needs before it reports a landmark (``SlamConfig.min_hits``). A landmark the
  radar never measured (occluded by traffic, detected once at the edge of range)
  cannot be in any map, so it says nothing about the SLAM.

The point-cloud metric (detection rate, RMSE, false points) is
:func:`rhs_env.point_cloud.pointcloud_metrics`, next to the radar that makes the clouds.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from rhs_common.geometry import wrap_angle

__all__ = [
    "position_rmse",
    "heading_rmse",
    "position_errors",
    "map_metrics",
    "landmark_hits",
    "matched_fraction",
    "MEASURED_GATE_M",
    "MEASURED_MIN_SCANS",
]

#: a radar point within this distance (m) of a true landmark measured it (the SLAM's ``cluster_radius_m``)
MEASURED_GATE_M = 1.0
#: scans with such a point before a landmark counts as measured (the RBPF's ``min_hits``)
MEASURED_MIN_SCANS = 2


def position_errors(est: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Per-cycle position error ``|p_hat - p|`` (T,) (m); inputs (T, >=2)."""
    est = np.asarray(est, dtype=float)
    true = np.asarray(true, dtype=float)
    if est.shape[0] != true.shape[0]:
        raise ValueError(f"est and true must have the same length, got {est.shape[0]} and {true.shape[0]}")
    return np.linalg.norm(est[:, :2] - true[:, :2], axis=1)


def position_rmse(est: np.ndarray, true: np.ndarray) -> float:
    """Position RMSE (m) over the run, no alignment; NaN for an empty run."""
    e = position_errors(est, true)
    return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")


def heading_rmse(est: np.ndarray, true: np.ndarray) -> float:
    """Heading RMSE (rad) with wrapped differences; inputs (T, 3) poses or (T,) angles."""
    est = np.asarray(est, dtype=float)
    true = np.asarray(true, dtype=float)
    a = est[:, 2] if est.ndim == 2 else est
    b = true[:, 2] if true.ndim == 2 else true
    if a.shape != b.shape:
        raise ValueError(f"est and true must have the same length, got {a.shape} and {b.shape}")
    d = wrap_angle(a - b)
    return float(np.sqrt(np.mean(d**2))) if d.size else float("nan")


#: above this many estimate x landmark pairs the candidates come from a k-d tree, not the full distance matrix
DENSE_PAIRS = 4096


def _candidates(est: np.ndarray, true: np.ndarray, gate: float) -> tuple[np.ndarray, np.ndarray]:
    """The (est, true) index pairs that may lie within ``gate``: a superset of ``d <= gate`` (the caller computes
    ``d`` and keeps those). Small maps test every pair; a long drive's map (thousands of landmarks with the
    archive) asks a k-d tree, so the cost grows as ``E log T`` rather than ``E T``."""
    reach = gate * (1.0 + 1e-9)
    if len(est) * len(true) <= DENSE_PAIRS:
        dx = est[:, None, 0] - true[None, :, 0]
        dy = est[:, None, 1] - true[None, :, 1]
        rows, cols = np.nonzero(dx * dx + dy * dy <= reach * reach)
        return rows, cols
    pairs = cKDTree(est).sparse_distance_matrix(cKDTree(true), reach, output_type="ndarray")
    return pairs["i"].astype(np.intp), pairs["j"].astype(np.intp)


def map_metrics(est: np.ndarray, true: np.ndarray, gate: float = 2.0) -> dict:
    """Hungarian map matching within ``gate`` (m).

    The assignment maximises the number of pairs within the gate, then minimises the sum of their distances
    ``d_ij = |e_i - t_j|``. Only the pairs within the gate take part, so the problem splits: a pair whose estimate
    and true landmark have no other candidate is matched outright, and the Hungarian algorithm
    (``scipy.optimize.linear_sum_assignment``) solves the rest, the rows and columns that share candidates. The
    result is that of the Hungarian algorithm on the full (E, T) matrix with the out-of-gate pairs priced above
    every in-gate sum, at the cost of the candidates alone (:func:`_candidates`: every pair of a small map, a k-d
    tree's for a long drive's).

    Returns ``dict(rmse, matched, missed, spurious, pairs)``: ``rmse`` over matched
    pairs (NaN when none), ``pairs`` (matched, 2) int array of (est index, true index), sorted by est index.
    """
    if not gate > 0:
        raise ValueError(f"gate must be in (0, inf), got {gate!r}")
    est = np.asarray(est, dtype=float).reshape(-1, 2)
    true = np.asarray(true, dtype=float).reshape(-1, 2)
    ne, nt = len(est), len(true)
    if ne == 0 or nt == 0:
        return dict(rmse=float("nan"), matched=0, missed=nt, spurious=ne, pairs=np.zeros((0, 2), dtype=int))
    r, c = _candidates(est, true, gate)
    d = np.sqrt((est[r, 0] - true[c, 0]) ** 2 + (est[r, 1] - true[c, 1]) ** 2)
    inside = d <= gate
    r, c, d = r[inside], c[inside], d[inside]
    alone = (np.bincount(r, minlength=ne)[r] == 1) & (np.bincount(c, minlength=nt)[c] == 1)
    rows, cols = r[alone], c[alone]
    if not alone.all():  # the candidates that share a row or a column: the Hungarian algorithm on them
        shared_rows, ri = np.unique(r[~alone], return_inverse=True)
        shared_cols, ci = np.unique(c[~alone], return_inverse=True)
        cost = np.full((len(shared_rows), len(shared_cols)), gate * 1e3 + d[~alone].max() * 10 + 1.0)
        cost[ri, ci] = d[~alone]
        hr, hc = linear_sum_assignment(cost)
        ok = cost[hr, hc] <= gate
        rows = np.concatenate([rows, shared_rows[hr[ok]]])
        cols = np.concatenate([cols, shared_cols[hc[ok]]])
    order = np.argsort(rows, kind="stable")
    rows, cols = rows[order], cols[order]
    m = len(rows)
    dist = np.sqrt((est[rows, 0] - true[cols, 0]) ** 2 + (est[rows, 1] - true[cols, 1]) ** 2)
    rmse = float(np.sqrt(np.mean(dist**2))) if m else float("nan")
    return dict(rmse=rmse, matched=m, missed=nt - m, spurious=ne - m, pairs=np.stack([rows, cols], axis=1))


def landmark_hits(points_xy: np.ndarray, landmarks_xy: np.ndarray, gate: float = MEASURED_GATE_M) -> np.ndarray:
    """(K,) bool: some point of the scan (N, 2) lies within ``gate`` (m) of landmark k (K, 2).

    Both in the same frame. Summed over scans it gives the number of scans that
    measured each landmark (the *measured* definition of the module docstring).
    """
    if not gate > 0:
        raise ValueError(f"gate must be in (0, inf), got {gate!r}")
    pts = np.asarray(points_xy, dtype=float).reshape(-1, 2)
    lm = np.asarray(landmarks_xy, dtype=float).reshape(-1, 2)
    if len(pts) == 0 or len(lm) == 0:
        return np.zeros(len(lm), dtype=bool)
    d2 = np.sum((lm[:, None, :] - pts[None, :, :]) ** 2, axis=2)
    return np.asarray(d2.min(axis=1) <= gate * gate, dtype=bool)


def matched_fraction(est: np.ndarray, true: np.ndarray, keep: np.ndarray | None = None, gate: float = 2.0) -> float | None:
    """Fraction of the true landmarks ``true[keep]`` that the map ``est`` matches (Hungarian within ``gate``).

    ``matched / keep.sum()``, the estimated map matched against the kept landmarks only
    (an estimate of a dropped landmark is then spurious, not a match); None when
    nothing is kept.
    """
    true = np.asarray(true, dtype=float).reshape(-1, 2)
    keep = np.ones(len(true), dtype=bool) if keep is None else np.asarray(keep, dtype=bool).reshape(-1)
    if keep.shape != (len(true),):
        raise ValueError(f"keep must have one entry per true landmark ({len(true)}), got {keep.shape}")
    if not keep.any():
        return None
    return map_metrics(est, true[keep], gate)["matched"] / int(keep.sum())
