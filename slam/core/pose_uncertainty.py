"""The map drift's per-cycle increment measured from the cycle itself (``pose_covariance="adaptive"``).

:mod:`slam.core.drift` accumulates the map-relative drift that the particles share as a random walk. With
``pose_covariance="drift-constants"`` (:class:`slam.core.pipeline.PipelineConfig`) its increment is a density per
metre driven, measured once on one radar configuration. The adaptive model measures the increment each cycle from
what the filter saw, so it follows the radar that produced the cloud (scan grid, antenna, SNR, landmark density):

1. **Information of the cycle's pose against the map.** Each static point ``p`` (vehicle frame, covariance ``C``
   from the radar's range and angle stds, :func:`slam.core.association.point_covariance`, plus the filter's
   floor) is moved into the map frame with the pose predicted by the cycle's motion, ``m = t + R(th) p``, and
   paired with the landmark ``l`` (covariance ``L``) of the map *before* the cycle's update that is nearest in
   the Mahalanobis distance of ``S = R C R^T + L`` among the 4 nearest, within the 99 % gate; one point per
   landmark (the filter clusters a landmark's points into one observation). The pose is fitted to the pairs
   (Gauss-Newton from the prediction). With ``H = [I_2, dR(th)/dth p]`` the pose information is
   ``J = sum H^T S^-1 H`` (3 x 3, map frame) and ``J^-1`` the covariance of a pose fitted to those landmarks.
2. **The residuals' scale.** ``s^2 = sum r^T S^-1 r / (2 n - 3)`` with ``r = l - m`` at the fitted pose: the
   factor by which the pairs scatter more (or less) than the radar's stated covariances say. The pipeline
   accumulates the chi-square and the degrees of freedom over the map's cycles
   (:attr:`slam.core.pipeline.SlamPipeline.residual_scale`) and scales the whole reported covariance by it:
   on the default 1-degree scan the pairs scatter at ~0.03-0.05 of their stated variance, on the 5-degree grid
   at ~0.4.
3. **The hand-over.** The map drifts because new landmarks are initialised from the current pose: each cycle
   the landmarks born in it (``n_new``) join the ``n_old`` landmarks the cycle matched, and carry the pose's error
   against the old ones into the map. A reference set that renews the fraction ``f = n_new / (n_new + n_old)`` per
   cycle moves by ``f`` times that error; the errors of successive cycles are correlated over the ``1 / f``
   cycles a landmark lives (the same landmarks pin them), so over a landmark's life the set moves by about one
   pose error: the increment per cycle is ``Q = f J^-1`` (map frame).

``Q`` replaces ``G diag(q d) G^T`` in :func:`slam.core.drift.drift_step` (:func:`adaptive_drift_step`); ``F`` still
turns a heading error into cross-track error with the distance driven. The reported covariance is
``s^2 (particles' variances + P)``. No constant of this model is fitted to a drive. A cycle that pins nothing
(fewer than two pairs, or ``J`` singular) holds the last measured ``J^-1``.

Its known limit: an error that persists from scan to scan (the angle quantisation of a coarse scan grid, a
landmark's multipath) moves the landmark and the point alike, so the scan-to-map residuals do not see it and
``s^2`` under-reads it; it shows only as drift. The results page (``docs/results/pose-covariance.md``) measures
where that matters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["CHI2_GATE_2DOF", "CycleInformation", "adaptive_drift_step", "cycle_information"]

#: the 99 % quantile of the chi-square distribution with 2 degrees of freedom: the pairing gate
CHI2_GATE_2DOF = 9.2103
#: a pair's information is only counted with at least this many pairs (a 3-dof pose from 2-d points)
MIN_PAIRS = 2
#: Gauss-Newton steps of the pose fitted to the pairs (from the predicted pose: one step is near the optimum)
GAUSS_NEWTON_STEPS = 2


@dataclass(frozen=True)
class CycleInformation:
    """One cycle's measurement of the pose against the map (module docstring).

    ``cov`` (3, 3): ``J^-1`` (m^2, m rad, rad^2; map frame), or None when the cycle pinned nothing;
    ``scale``: the cycle's ``s^2`` (nan with fewer than 2 pairs); ``n_old``: landmarks paired;
    ``n_new``: landmarks born in the cycle; ``fraction``: ``n_new / (n_new + n_old)`` (0 when both are 0);
    ``chi2``, ``dof``: the residuals' chi-square and its degrees of freedom (0 without a fit); ``fitted`` (3,):
    the pose fitted to the pairs (None without a fit).
    """

    cov: np.ndarray | None
    scale: float
    n_old: int
    n_new: int
    fraction: float
    chi2: float = 0.0
    dof: int = 0
    fitted: np.ndarray | None = None


def cycle_information(
    pose: np.ndarray,
    points: np.ndarray,
    point_cov: np.ndarray,
    landmarks: np.ndarray,
    landmark_cov: np.ndarray,
    new: np.ndarray,
    born: int | None = None,
) -> CycleInformation:
    """Measure the cycle's pose information against the landmarks that existed before it (module docstring).

    Args:
        pose: (3,) the pose ``(x, y, th)`` the pairing starts from (map frame; m, m, rad): the prediction.
        points: (N, >=2) the cycle's static points, x, y in the vehicle frame (m).
        point_cov: (N, 2, 2) their vehicle-frame covariances (m^2).
        landmarks: (L, 2) the map's landmarks (map frame, m).
        landmark_cov: (L, 2, 2) their covariances (m^2).
        new: (L,) bool, the landmarks born in this cycle (left out of the pairing).
        born: the landmarks born in this cycle, reported ones or not (the filter's tentative landmarks);
            None: ``new.sum()``.

    Returns:
        The :class:`CycleInformation` of the cycle.
    """
    new = np.asarray(new, dtype=bool).reshape(-1)
    n_new = int(new.sum()) if born is None else int(born)
    lm = np.asarray(landmarks, dtype=float).reshape(-1, 2)[~new]
    lcov = np.asarray(landmark_cov, dtype=float).reshape(-1, 2, 2)[~new]
    pts = np.asarray(points, dtype=float)
    pts = pts.reshape(-1, pts.shape[-1] if pts.ndim == 2 else 2)[:, :2]
    pcov = np.asarray(point_cov, dtype=float).reshape(-1, 2, 2)
    none = CycleInformation(None, float("nan"), 0, n_new, 1.0 if n_new else 0.0)
    if not len(lm) or not len(pts):
        return none
    pv, target, Si = _pairs(np.asarray(pose, dtype=float).reshape(3), pts, pcov, lm, lcov)
    n_old = len(pv)
    fraction = n_new / (n_new + n_old) if n_new + n_old else 0.0
    if n_old < MIN_PAIRS:
        return CycleInformation(None, float("nan"), n_old, n_new, fraction)
    fit = _fit_pose(np.asarray(pose, dtype=float).reshape(3), pv, target, Si)
    if fit is None:
        return CycleInformation(None, float("nan"), n_old, n_new, fraction)
    pose_fit, J, d2 = fit
    dof = 2 * n_old - 3
    scale = d2 / dof if dof > 0 else float("nan")
    cov = np.linalg.inv(J)
    return CycleInformation(0.5 * (cov + cov.T), scale, n_old, n_new, fraction, d2, max(dof, 0), pose_fit)


def _pairs(
    pose: np.ndarray, pts: np.ndarray, pcov: np.ndarray, lm: np.ndarray, lcov: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each point's landmark (the Mahalanobis-nearest of the 4 nearest, within the gate), one point per landmark:
    the paired points (n, 2) (vehicle frame), their landmarks (n, 2) and ``S^-1`` (n, 2, 2)."""
    x, y, th = (float(v) for v in pose)
    c, s = math.cos(th), math.sin(th)
    R = np.array([[c, -s], [s, c]])
    world = pts @ R.T + np.array([x, y])
    k = min(4, len(lm))
    _, idx = cKDTree(lm).query(world, k=k)
    idx = np.asarray(idx).reshape(len(pts), k)
    S = R[None, None] @ pcov[:, None] @ R.T[None, None] + lcov[idx]  # (N, k, 2, 2)
    r = lm[idx] - world[:, None, :]  # (N, k, 2)
    Sinv = np.linalg.inv(S)
    d2 = np.einsum("nki,nkij,nkj->nk", r, Sinv, r)
    best = np.argmin(d2, axis=1)
    rows = np.arange(len(pts))
    d2b, lmb = d2[rows, best], idx[rows, best]
    ok = d2b <= CHI2_GATE_2DOF
    seen: set[int] = set()
    keep = np.zeros(len(pts), dtype=bool)
    for i in np.argsort(d2b):  # one point per landmark: the closest in Mahalanobis distance
        if ok[i] and int(lmb[i]) not in seen:
            seen.add(int(lmb[i]))
            keep[i] = True
    return pts[keep], lm[lmb[keep]], Sinv[rows, best][keep]


def _fit_pose(
    pose: np.ndarray, pv: np.ndarray, target: np.ndarray, Si: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The pose fitted to the pairs by Gauss-Newton from ``pose``: the fitted pose, its information ``J`` (3, 3)
    at the fit and the residuals' chi-square; None when ``J`` is singular."""
    pose_fit = np.array(pose, dtype=float)
    n = len(pv)
    J = np.zeros((3, 3))
    r = np.zeros((n, 2))
    for _ in range(GAUSS_NEWTON_STEPS + 1):
        c, s = math.cos(pose_fit[2]), math.sin(pose_fit[2])
        R = np.array([[c, -s], [s, c]])
        r = target - (pv @ R.T + pose_fit[:2])
        H = np.zeros((n, 2, 3))
        H[:, 0, 0] = H[:, 1, 1] = 1.0
        H[:, :, 2] = np.column_stack([-s * pv[:, 0] - c * pv[:, 1], c * pv[:, 0] - s * pv[:, 1]])  # d(R p)/dth
        J = np.einsum("nji,njk,nkl->il", H, Si, H)
        if np.linalg.cond(J) > 1e12:
            return None
        pose_fit = pose_fit + np.linalg.solve(J, np.einsum("nji,njk,nk->i", H, Si, r))
    return pose_fit, J, float(np.einsum("ni,nij,nj->", r, Si, r))


def adaptive_drift_step(cov: np.ndarray, heading: float, motion: np.ndarray, increment: np.ndarray) -> np.ndarray:
    """``P' = F P F^T + Q`` (:func:`slam.core.drift.drift_step` with the cycle's measured increment).

    Args:
        cov: (3, 3) the drift covariance before the motion.
        heading: the estimated heading before the motion (rad).
        motion: (3,) ``(dx, dy, dpsi)`` in the previous vehicle frame.
        increment: (3, 3) ``Q`` in the map frame (``f J^-1``).

    Returns:
        A new (3, 3) array.
    """
    m = np.asarray(motion, dtype=float).reshape(3)
    if not np.all(np.isfinite(m)):
        return np.array(cov, dtype=float, copy=True)
    c, s = math.cos(heading), math.sin(heading)
    F = np.array([[1.0, 0.0, -(s * m[0] + c * m[1])], [0.0, 1.0, c * m[0] - s * m[1]], [0.0, 0.0, 1.0]])
    out = F @ np.asarray(cov, dtype=float) @ F.T + np.asarray(increment, dtype=float)
    return 0.5 * (out + out.T)
