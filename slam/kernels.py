"""Compiled kernels of the SLAM (numba): the RBPF's Mahalanobis association and the ICP's nearest neighbours.

Each kernel computes what the numpy reference computes (:func:`slam.association.mahalanobis_associate`
with the distances of :meth:`slam.rbpf.RBPFSlam._associate`; ``cKDTree.query`` in
:class:`slam.registration.ICPRegistration`), with the same variable names and floating-point
order, per particle instead of on P x M x L tensors. ``SlamConfig(kernels="numpy")``
(``gym.make(..., slam={"kernels": "numpy"})``) selects the reference; the costs of numba are
listed in :mod:`rhs_env.kernels`.
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import njit

__all__ = ["mahalanobis_association", "nearest_neighbours"]

NEW = -1  # slam.association.NEW
DROPPED = -2  # slam.association.DROPPED


@njit
def mahalanobis_association(obs_map: np.ndarray, a00: np.ndarray, a01: np.ndarray, a11: np.ndarray,
                            mean: np.ndarray, cov: np.ndarray, active: np.ndarray, used: np.ndarray,
                            gate2: float, new_gate2: float, rounds: int) -> np.ndarray:
    """Gated mutual-nearest association per particle on the squared Mahalanobis distances (P, M) -> sub-index.

    For particle p, observation m (map frame ``obs_map[p, m]``, covariance ``A = [[a00, a01], [a01, a11]]``)
    and used landmark slot ``l = used[q]`` (mean mu, covariance Lambda):
    ``S = A + Lambda``, ``S^-1 = [[s11, -s01], [-s01, s00]] / max(det S, 1e-300)``, ``nu = z - mu``,

        d2 = i00 nx nx + 2 i01 nx ny + i11 ny ny     (inf for an inactive landmark).

    Then :func:`slam.association.mahalanobis_associate`: ``rounds`` rounds accepting the pairs that are each
    other's nearest among the free observations and landmarks within ``gate2``; a free observation
    is DROPPED when some landmark is within ``new_gate2``, else NEW. Returns idx (P, M) into ``used``.
    """
    n_p, n_m = a00.shape
    n_l = used.size
    idx = np.full((n_p, n_m), NEW, np.int64)
    cost = np.empty((n_m, n_l))
    near = np.empty(n_m, np.bool_)
    best_l = np.empty(n_m, np.int64)
    best_c = np.empty(n_m)
    best_m = np.empty(n_l, np.int64)
    best_mc = np.empty(n_l)
    for p in range(n_p):
        for m in range(n_m):
            lowest = np.inf
            for q in range(n_l):
                l = used[q]
                if not active[p, l]:
                    cost[m, q] = np.inf
                    continue
                s00 = a00[p, m] + cov[p, l, 0, 0]
                s01 = a01[p, m] + cov[p, l, 0, 1]
                s11 = a11[p, m] + cov[p, l, 1, 1]
                det = max(s00 * s11 - s01 * s01, 1e-300)
                i00, i01, i11 = s11 / det, -s01 / det, s00 / det
                nx = obs_map[p, m, 0] - mean[p, l, 0]
                ny = obs_map[p, m, 1] - mean[p, l, 1]
                d2 = i00 * nx * nx + 2.0 * i01 * nx * ny + i11 * ny * ny
                lowest = min(lowest, d2)
                cost[m, q] = d2 if d2 <= gate2 else np.inf
            near[m] = lowest <= new_gate2
        for _ in range(rounds):
            for m in range(n_m):  # argmin over landmarks (first of equal minima, as np.argmin)
                best_l[m], best_c[m] = 0, cost[m, 0]
                for q in range(1, n_l):
                    if cost[m, q] < best_c[m]:
                        best_l[m], best_c[m] = q, cost[m, q]
            for q in range(n_l):  # argmin over observations
                best_m[q], best_mc[q] = 0, cost[0, q]
                for m in range(1, n_m):
                    if cost[m, q] < best_mc[q]:
                        best_m[q], best_mc[q] = m, cost[m, q]
            found = False
            for m in range(n_m):
                if np.isfinite(best_c[m]) and best_m[best_l[m]] == m:
                    idx[p, m] = best_l[m]
                    found = True
                    for q in range(n_l):
                        cost[m, q] = np.inf
                    for k in range(n_m):
                        cost[k, best_l[m]] = np.inf
            if not found:
                break
        for m in range(n_m):
            if idx[p, m] == NEW and near[m]:
                idx[p, m] = DROPPED
    return idx


@njit
def nearest_neighbours(query: np.ndarray, ref: np.ndarray, upper_bound: float) -> tuple[np.ndarray, np.ndarray]:
    """``cKDTree(ref).query(query, k=1, distance_upper_bound=upper_bound)`` by brute force (small clouds).

    ``d_q = min_r sqrt((x_q - x_r)^2 + (y_q - y_r)^2)`` and its index (the first of equal distances);
    ``(inf, len(ref))`` where no point is nearer than ``upper_bound``.
    """
    n_q, n_r = query.shape[0], ref.shape[0]
    d = np.full(n_q, np.inf)
    j = np.full(n_q, n_r, np.int64)
    for q in range(n_q):
        best = np.inf
        arg = n_r
        for r in range(n_r):
            dx = query[q, 0] - ref[r, 0]
            dy = query[q, 1] - ref[r, 1]
            d2 = dx * dx + dy * dy
            if d2 < best:
                best, arg = d2, r
        dist = np.sqrt(best)
        if dist < upper_bound:
            d[q], j[q] = dist, arg
    return d, j
