"""Compiled kernels of the radar's processing chain (numba), the numpy code's equations in loops.

Each kernel computes what a numpy function of :mod:`rhs_env.detection` /
:mod:`rhs_env.point_cloud` / :mod:`rhs_env.radar` computes, with its variable names and
in the same floating-point order where the numpy code fixes one (comparisons of
float32 statistics stay float32), so the compiled path reproduces the numpy
reference to round-off. The numpy path stays selectable: ``RadarConfig(kernels="numpy")``
(``gym.make(..., radar={"kernels": "numpy"})``).

Why compiled. The stages work on arrays of 30-300 rows: the numpy reference pays
thousands of interpreter-level calls per scan, several times the arithmetic.
The noise generator stays in numpy (its transcendental functions are SIMD there; numba's
wheels have no SVML).

Costs of the dependency (numba 0.68.1, measured on the development machine, x86-64, Python 3.11):
installed size ~15 MB for numba plus ~130 MB for llvmlite; numba 0.68 supports numpy < 2.5 (each numba
release caps numpy: a numpy newer than the cap waits for a numba release); first compile of
every kernel of this module and :mod:`slam.kernels` ~20 s (once per machine, cached on disk,
:mod:`rhs_common.jit`); loading them from the cache ~0.5 s.
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import njit

__all__ = ["footprint_detections"]


# --------------------------------------------------------------------------- detection
@njit
def footprint_detections(stat: np.ndarray, in_range: np.ndarray, alpha: np.ndarray, floor: np.ndarray,
                         cap: np.ndarray, train_cells: np.ndarray, method: int, rank: int, leak: np.ndarray,
                         margin: float, null: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The detections of :meth:`rhs_env.detection.FootprintDetector.detect` from the statistic T (R, J, K) float32.

    1. peaks: ``T_j(k) > T_j(k - 1)``, ``T_j(k) >= T_j(k + 1)``, ``T_j(k) > alpha_j floor_j`` (float32), k in range;
    2. CFAR: keep ``T_j(k) > alpha_j clip(Z, floor_j, cap_j)``, Z the ``rank``-th smallest training cell
       (``method`` 0, OS), their mean (1, CA), or ``Z = floor_j`` (2, fixed);
    3. window sidelobe on the hypothesis' own line: drop ``T_j(k) < margin max_{k'} T_j(k') leak(|k - k'|)``
       over the detected bins k' of the same radar with ``T_j(k') > T_j(k)``;
    4. union over hypotheses per (radar, bin), ``strength = max_j T_j(k) / floor_j``, sorted by radar then bin;
    5. main lobe: drop a pair within ``null`` bins of a stronger pair of its radar with
       ``strength < margin strength' leak(|k - k'|)``.

    ``train_cells`` (K, 2 train) the training-cell bins of every bin; ``leak`` the window's power-leak envelope.
    Returns rd, kd, strength.
    """
    n_r, n_j, n = stat.shape
    n_leak = leak.size
    lo32 = (alpha * floor).astype(np.float32)
    # 1. local maxima above the lowest threshold, in np.nonzero order (radar, hypothesis, bin);
    # branch-free (each cell written, the count advanced by the test): most cells are no peak
    n_cells = n_r * n_j * n
    cand = np.empty(n_cells + 1, np.int64)
    c = 0
    for rr in range(n_r):
        for jj in range(n_j):
            line = stat[rr, jj]
            base = (rr * n_j + jj) * n
            lo_j = lo32[jj]
            for kk in range(1, n - 1):
                t = line[kk]
                cand[c] = base + kk
                c += (t > line[kk - 1]) & (t >= line[kk + 1]) & (t > lo_j) & in_range[kk]
    # 2. the CFAR threshold at the peaks
    r = np.empty(c, np.int64)
    j = np.empty(c, np.int64)
    k = np.empty(c, np.int64)
    val = np.empty(c)
    m = 0
    n_train = train_cells.shape[1]
    vals = np.empty(n_train)
    for q0 in range(c):
        rr, rest = divmod(cand[q0], n_j * n)
        jj, kk = divmod(rest, n)
        line = stat[rr, jj]
        v = float(line[kk])
        if method == 2:
            thr = alpha[jj] * floor[jj]
        else:
            for q in range(n_train):
                vals[q] = float(line[train_cells[kk, q]])
            if method == 0:  # the rank-th smallest (insertion sort of the few training cells)
                for q in range(1, n_train):
                    x = vals[q]
                    p = q - 1
                    while p >= 0 and vals[p] > x:
                        vals[p + 1] = vals[p]
                        p -= 1
                    vals[p + 1] = x
                z = vals[rank - 1]
            else:
                z = np.mean(vals)
            thr = alpha[jj] * min(max(z, floor[jj]), cap[jj])
        if v > thr:
            r[m], j[m], k[m], val[m] = rr, jj, kk, v
            m += 1
    r, j, k, val = r[:m], j[:m], k[:m], val[:m]
    # 3. window sidelobe of a stronger detected bin of the same radar, on this hypothesis' line
    if m > 1:
        detected = np.zeros((n_r, n), np.bool_)
        for d in range(m):
            detected[r[d], k[d]] = True
        bins = np.empty((n_r, n), np.int64)  # the detected bins of each radar, ascending
        n_bins = np.zeros(n_r, np.int64)
        for rr in range(n_r):
            for kk in range(n):
                if detected[rr, kk]:
                    bins[rr, n_bins[rr]] = kk
                    n_bins[rr] += 1
        keep = np.ones(m, np.bool_)
        for d in range(m):
            worst = 0.0
            for q in range(n_bins[r[d]]):
                kk = bins[r[d], q]
                sv = float(stat[r[d], j[d], kk])
                if sv > val[d]:
                    worst = max(worst, sv * leak[min(abs(k[d] - kk), n_leak - 1)])
            keep[d] = val[d] >= margin * worst
        r, j, k, val = r[keep], j[keep], k[keep], val[keep]
        m = r.size
    # 4. union over hypotheses
    key = r * n + k
    uniq = np.unique(key)
    strength = np.zeros(uniq.size)
    for d in range(m):
        u = np.searchsorted(uniq, key[d])
        strength[u] = max(strength[u], val[d] / floor[j[d]])
    rd, kd = uniq // n, uniq % n
    # 5. inside the window main lobe of a stronger pair (any hypothesis)
    n_d = rd.size
    if n_d > 1:
        keep = np.ones(n_d, np.bool_)
        for a in range(n_d):
            worst = 0.0
            for b in range(n_d):
                dk = abs(kd[a] - kd[b])
                if rd[a] == rd[b] and dk < null and strength[b] > strength[a]:
                    worst = max(worst, strength[b] * leak[min(dk, n_leak - 1)])
            keep[a] = strength[a] >= margin * worst
        rd, kd, strength = rd[keep], kd[keep], strength[keep]
    return rd, kd, strength
