"""The SLAM's error metrics the studies share: the pose NEES and its chi-square band, KITTI's segment drift.

* :func:`pose_nees`: the 3-dof normalised estimation error squared ``e^T P^-1 e`` of a pose (x, y, heading);
* :func:`nees_interval`: the chi-square band it falls in with probability ``level`` for a consistent filter;
* :func:`segment_drift`, :func:`pooled_drift`: KITTI's odometry metric (the relative-pose error over path
  segments of 100-800 m, in % of the length and deg / 100 m), pooled over episodes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: KITTI's segment lengths (m)
DRIFT_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
#: real-data radar odometry drift (%, KITTI's metric): DRO (Boreas), CFEAR (Oxford / MulRan / Boreas range)
DRO_DRIFT_PCT = 0.18
CFEAR_DRIFT_PCT = (0.61, 1.76)


def nees_interval(dof: int = 3, level: float = 0.95) -> tuple[float, float]:
    """The two-sided ``level`` interval of the chi-square distribution with ``dof`` degrees of freedom."""
    from scipy import stats

    return float(stats.chi2.ppf((1 - level) / 2, dof)), float(stats.chi2.ppf((1 + level) / 2, dof))


#: std floors (m, m, rad): a collapsed particle set divides by nothing
NEES_FLOOR = np.array([1e-3, 1e-3, 1e-4])


def pose_nees(err_xy: np.ndarray, err_heading: float, std: np.ndarray, cov: np.ndarray | None = None) -> float:
    """3-dof NEES ``e^T P^-1 e``: with ``cov`` (3, 3) the reported pose covariance (``slam_pose_cov``: the
    particles plus the shared drift; its heading error and the cross-track error it drove are correlated),
    else ``P = diag(std^2)`` (``std`` (3,): x, y (m), heading (rad)). The diagonal is floored at
    ``NEES_FLOOR^2``, and raised to ``std^2`` (while lost ``slam_pose_std`` admits the loss)."""
    e = np.array([err_xy[0], err_xy[1], err_heading])
    var = np.maximum(np.square(np.asarray(std, dtype=float)), NEES_FLOOR**2)
    if cov is None:
        return float(np.sum(e * e / var))
    P = np.array(cov, dtype=float).reshape(3, 3)
    P[np.diag_indices(3)] = np.maximum(np.diag(P), var)
    return float(e @ np.linalg.solve(P, e))


def segment_drift(est: np.ndarray, true: np.ndarray, lengths: tuple[float, ...]) -> dict[str, list[float]]:
    """KITTI's odometry error over path segments: per length ``L``, every start cycle ``i`` whose path (true
    positions) reaches ``L`` at a cycle ``j``; the error of the relative motion ``(T_i^-1 T_j)`` of ``est``
    against ``true``: its translation over ``L`` and its rotation over ``L``.

    Args:
        est: (T, 3) estimated poses (x, y, heading), m and rad.
        true: (T, 3) true poses.
        lengths: segment lengths, m.

    Returns:
        ``{str(L): [sum of translation errors / L, sum of rotation errors / L (rad/m), segments]}``: sums, so
        that episodes pool by adding them (KITTI averages over every segment).
    """
    from rhs_common.geometry import rotation, wrap_angle

    est, true = np.asarray(est, dtype=float).reshape(-1, 3), np.asarray(true, dtype=float).reshape(-1, 3)
    dist = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(true[:, :2], axis=0).T))])
    out: dict[str, list[float]] = {}
    for length in lengths:
        t_sum = r_sum = 0.0
        n = 0
        for i in range(len(true)):
            j = int(np.searchsorted(dist, dist[i] + length))
            if j >= len(true):
                break
            rel = []
            for p in (true, est):
                rel.append(np.array([*(rotation(-p[i, 2]) @ (p[j, :2] - p[i, :2])), wrap_angle(p[j, 2] - p[i, 2])]))
            d_t = rotation(-rel[0][2]) @ (rel[1][:2] - rel[0][:2])
            t_sum += float(np.hypot(*d_t)) / length
            r_sum += abs(float(wrap_angle(rel[1][2] - rel[0][2]))) / length
            n += 1
        out[f"{length:g}"] = [t_sum, r_sum, n]
    return out


def pooled_drift(runs: list[dict[str, Any]], lengths: tuple[float, ...]) -> dict[str, Any]:
    """Translational drift (%) and rotational drift (deg / 100 m) pooled over every segment of ``lengths`` in
    ``runs`` (their ``drift`` sums, :func:`segment_drift`), with the segment count and the lengths that had one."""
    keys = [f"{length:g}" for length in lengths]
    t = sum(r["drift"][k][0] for r in runs for k in keys if k in r["drift"])
    rot = sum(r["drift"][k][1] for r in runs for k in keys if k in r["drift"])
    n = sum(int(r["drift"][k][2]) for r in runs for k in keys if k in r["drift"])
    have = [k for k in keys if any(int(r["drift"].get(k, [0, 0, 0])[2]) for r in runs)]
    return {"translation_pct": 100 * t / n if n else None, "rotation_deg_per_100m": float(np.degrees(rot / n)) * 100
            if n else None, "segments": n, "lengths_m": have}


__all__ = ["CFEAR_DRIFT_PCT", "DRIFT_LENGTHS_M", "DRO_DRIFT_PCT", "NEES_FLOOR", "nees_interval", "pooled_drift", "pose_nees",
           "segment_drift"]
