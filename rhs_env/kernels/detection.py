"""Compiled detection (numba): the kernels of :class:`rhs_env.detection.FootprintDetector`.

:func:`footprint_statistic` is :meth:`~rhs_env.detection.FootprintDetector.statistic` (the energy of each beam slot
summed over its chirps, then over each hypothesis' footprint slot by slot: 2-4 of the I slots, so ~30x fewer
operations than the dense 0 / 1 product, within 1-2 float32 ulp of it); :func:`footprint_detections` is
:meth:`~rhs_env.detection.FootprintDetector.detect` in one pass (peaks, CFAR test, side-lobe and main-lobe pruning),
its float32 comparisons in float32 as the numpy method makes them, so the same detections.
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import njit

__all__ = ["footprint_detections", "footprint_statistic"]


@njit
def _peaks(stat: np.ndarray, in_range: np.ndarray, lo32: np.ndarray) -> np.ndarray:
    """Flat indices (radar, hypothesis, bin) of ``T_j(k) > T_j(k - 1)``, ``T_j(k) >= T_j(k + 1)``, ``T_j(k) > lo_j``.

    In np.nonzero order. The threshold test first: few cells exceed ``lo_j`` (~1 % of them are peaks on the
    highway scene), so its branch is well predicted and the neighbours are compared only there.
    """
    n_r, n_j, n = stat.shape
    cand = np.empty(n_r * n_j * n + 1, np.int64)
    c = 0
    for rr in range(n_r):
        for jj in range(n_j):
            line = stat[rr, jj]
            base = (rr * n_j + jj) * n
            lo_j = lo32[jj]
            for kk in range(1, n - 1):
                t = line[kk]
                if t > lo_j:
                    if (t > line[kk - 1]) & (t >= line[kk + 1]) & in_range[kk]:
                        cand[c] = base + kk
                        c += 1
    return cand[:c]


@njit
def _cfar_pass(v: float, line: np.ndarray, cells: np.ndarray, method: int, rank: int, alpha: float, floor: float,
               cap: float, vals: np.ndarray) -> bool:
    """``v > alpha clip(Z, floor, cap)``, Z of the training cells ``line[cells]``: their mean (method 1, CA) or
    their rank-th smallest (0, OS).

    OS without sorting: ``f(z) = alpha clip(z, floor, cap)`` is non-decreasing, so ``f(Z)`` is the rank-th
    smallest of the ``f(z_q)`` (the same floating-point operations per value), and ``v > f(Z)`` holds exactly
    when at least ``rank`` of the ``f(z_q)`` are below v.
    """
    n_train = cells.size
    if method == 1:
        for q in range(n_train):
            vals[q] = float(line[cells[q]])
        return v > alpha * min(max(np.mean(vals), floor), cap)
    below = 0
    for q in range(n_train):
        below += alpha * min(max(float(line[cells[q]]), floor), cap) < v
    return below >= rank


@njit
def _sidelobe_keep(stat: np.ndarray, r: np.ndarray, j: np.ndarray, k: np.ndarray, val: np.ndarray,
                   leak: np.ndarray, margin: float) -> np.ndarray:
    """``T_j(k) >= margin max_{k'} T_j(k') leak(|k - k'|)`` over the detected bins k' of the radar with ``T_j(k') > T_j(k)``."""
    n_r, _, n = stat.shape
    m = r.size
    bins = np.empty((n_r, n), np.int64)  # the detected bins of each radar, ascending
    n_bins = np.zeros(n_r, np.int64)
    detected = np.zeros((n_r, n), np.bool_)
    for d in range(m):
        detected[r[d], k[d]] = True
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
                worst = max(worst, sv * leak[min(abs(k[d] - kk), leak.size - 1)])
        keep[d] = val[d] >= margin * worst
    return keep


@njit
def _mainlobe_keep(rd: np.ndarray, kd: np.ndarray, strength: np.ndarray, leak: np.ndarray, margin: float,
                   null: int) -> np.ndarray:
    """``strength >= margin strength' leak(|k - k'|)`` over the stronger pairs of the radar within ``null`` bins."""
    n_d = rd.size
    keep = np.ones(n_d, np.bool_)
    for a in range(n_d):
        worst = 0.0
        for b in range(n_d):
            dk = abs(kd[a] - kd[b])
            if rd[a] == rd[b] and dk < null and strength[b] > strength[a]:
                worst = max(worst, strength[b] * leak[min(dk, leak.size - 1)])
        keep[a] = strength[a] >= margin * worst
    return keep


@njit
def footprint_statistic(f: np.ndarray, slots: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """T (R, J, K) float32 of :meth:`rhs_env.detection.FootprintDetector.statistic`: ``T_rjk = sum_{i in S_j} E_rik``.

    ``E_rik = sum_c re_rick^2 + sum_c im_rick^2`` (float32, the sums over c in order, as the numpy einsum over the
    interleaved view ``f`` (R, I, C, 2 K) float32 of the complex64 spectra), then the footprint ``S_j`` of each
    hypothesis summed slot by slot (``slots[starts[j]:starts[j + 1]]``, ascending) instead of the dense product
    ``F^T E`` with the 0 / 1 footprint matrix: the footprints hold 2-4 of the I slots, so ~30x fewer operations.
    The float32 sums of 2-4 terms in slot order: within 1-2 ulp of the BLAS product (whose order is its own).
    """
    n_r, n_i, n_c, n_b = f.shape
    n_k = n_b // 2
    n_j = starts.size - 1
    e = np.empty((n_i, n_k), np.float32)
    p = np.empty(n_b, np.float32)
    out = np.empty((n_r, n_j, n_k), np.float32)
    for r in range(n_r):
        for i in range(n_i):  # E: re^2 and im^2 summed over the chirps, then added
            for b in range(n_b):
                p[b] = f[r, i, 0, b] * f[r, i, 0, b]
            for c in range(1, n_c):
                for b in range(n_b):
                    p[b] += f[r, i, c, b] * f[r, i, c, b]
            for k in range(n_k):
                e[i, k] = p[2 * k] + p[2 * k + 1]
        for j in range(n_j):
            first = slots[starts[j]]
            for k in range(n_k):
                out[r, j, k] = e[first, k]
            for m in range(starts[j] + 1, starts[j + 1]):
                i = slots[m]
                for k in range(n_k):
                    out[r, j, k] += e[i, k]
    return out


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
    _, n_j, n = stat.shape
    cand = _peaks(stat, in_range, (alpha * floor).astype(np.float32))
    r = np.empty(cand.size, np.int64)
    j = np.empty(cand.size, np.int64)
    k = np.empty(cand.size, np.int64)
    val = np.empty(cand.size)
    vals = np.empty(train_cells.shape[1])
    m = 0
    for flat in cand:
        rr, rest = divmod(flat, n_j * n)
        jj, kk = divmod(rest, n)
        v = float(stat[rr, jj, kk])
        if method == 2:
            hit = v > alpha[jj] * floor[jj]
        else:
            hit = _cfar_pass(v, stat[rr, jj], train_cells[kk], method, rank, alpha[jj], floor[jj], cap[jj], vals)
        if hit:
            r[m], j[m], k[m], val[m] = rr, jj, kk, v
            m += 1
    r, j, k, val = r[:m], j[:m], k[:m], val[:m]
    if m > 1:
        keep = _sidelobe_keep(stat, r, j, k, val, leak, margin)
        r, j, k, val = r[keep], j[keep], k[keep], val[keep]
    n_r = stat.shape[0]
    best = np.zeros(n_r * n)  # max_j T_j / floor_j per (radar, bin); 0: not detected (T > 0 where detected)
    for d in range(r.size):
        best[r[d] * n + k[d]] = max(best[r[d] * n + k[d]], val[d] / floor[j[d]])
    key = np.flatnonzero(best > 0)  # sorted by radar then bin
    strength = best[key]
    rd, kd = key // n, key % n
    if rd.size > 1:
        keep = _mainlobe_keep(rd, kd, strength, leak, margin, null)
        rd, kd, strength = rd[keep], kd[keep], strength[keep]
    return rd, kd, strength
