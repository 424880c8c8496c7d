"""Compiled kernels of the radar's processing chain (numba), the numpy code's equations in loops.

Each kernel computes what a numpy function of :mod:`rhs_env.detection` /
:mod:`rhs_env.point_cloud` / :mod:`rhs_env.radar` computes, with its variable names and
in the same floating-point order where the numpy code fixes one (comparisons of
float32 statistics stay float32), so the compiled path reproduces the numpy
reference to round-off. A few sums run in another order where that is much faster: the footprint
statistic (:func:`footprint_statistic`: each footprint's 2-4 slots instead of a dense 0 / 1 product,
within 1-2 float32 ulp), the least squares' ``A^H A`` and ``A^H y`` (:func:`lstsq`,
:func:`bin_amplitudes`: vectorised sums, ~1e-15 relative), the narrow Doppler searches' DTFT
(:func:`_dtft_row`: float32 sums of the complex64 values, the reference's own precision) and each radar's
tone product (:func:`add_tone_products`: scipy's BLAS adds it into the spectrum, numpy's BLAS forms it in
the reference: float32 round-off); the equivalence tests (same detections and
point count, positions within 1 mm, Doppler within 1 cm/s) and the results' fingerprints hold.
The numpy path stays selectable: ``RadarConfig(kernels="numpy")``
(``gym.make(..., radar={"kernels": "numpy"})``).

Why compiled. The stages work on arrays of 30-300 rows: the numpy reference pays
thousands of interpreter-level calls per scan, several times the arithmetic.
The noise generator stays in numpy (its transcendental functions are SIMD there; numba's
wheels have no SVML).

Costs of the dependency (numba 0.68.1 / llvmlite 0.50, measured on the development machine, x86-64,
Python 3.11, 2 cores shared with other jobs, load average 5-8):

* installed size: numba 33 MB + llvmlite 180 MB (llvmlite carries a static LLVM);
* numpy upper bound: every numba release caps numpy (0.68.1: numpy < 2.6); a numpy newer than the
  cap waits for a numba release (pyproject asks numba >= 0.60, pip picks the one matching numpy);
* no SVML in the wheels: transcendental loops are not vectorised, so the noise generator stays numpy;
* first compile of every kernel here and in :mod:`slam.core.kernels`, once per machine: ~30 s at load 1-3
  with the first one-call OMP (:func:`omp_doppler`, ~24 s of it); a new process then loads them from the
  cache (:mod:`rhs_common.jit`): imports, ``gym.make``, reset and the first step of the SLAM env in a
  new process took 28.8-33.2 s with an empty cache and 1.9-2.1 s with it (load 0.8-2.3; ``python
  scripts/benchmark.py --sections start``; with the OMP as many small kernels: 10.8 s and 1.7 s at load
  1). The OMP's orchestration (:func:`omp_doppler`, :func:`_new_atoms`, :func:`_joint_search`,
  :func:`joint_refine`) is now written as loops: numba's fancy indexing, ``np.where``, array expressions
  and slice assignments from arrays (whose shape-mismatch message compiles numba's string formatting)
  cost seconds of compile each; measured side by side (CPU seconds of that first SLAM-env step, fresh
  cache, load ~9, two runs each): 33.7 s -> 27.4 s, the OMP's share 25.1 s -> 18.5 s (scaled: ~24 s wall
  expected on a quiet machine, from 29.5 s; not yet rerun there). The points of the OMP's output
  (:func:`assemble_points`, :func:`range_offsets`), the line of sight (:func:`line_of_sight`) and the ICP's
  heading search (:func:`slam.core.kernels.icp_search`) add ~2 s to that first compile (0.9 + 0.2 + 0.3 + 0.5 s,
  each alone in a fresh cache; the SLAM env's cold start 24.8 s -> 26.7 s, load ~1.8). On a slower
  machine (AMD EPYC, AVX-512, quiet) the same cold start took 38.6 s; the Doppler fits, the tone products'
  BLAS call and the RBPF's per-pair kernels (:mod:`slam.core.kernels`) add ~2.5 s to it (the Doppler
  fits' RANSAC kernel compiles in 2.0 s: a small QR instead of ``np.linalg.lstsq``, 3.6 s of compile
  alone, and element-wise copies). A SLAM env on an empty cache now compiles on two cores: a background
  process (:mod:`slam.gym.precompile`) takes the kernels the env reaches last (:func:`joint_refine`,
  ``_keep_rows``, the points, the SLAM's) while the env compiles the synthesis, the detector and the OMP's
  search: 45.4 s -> 28.4 s there (median of 3, ``benchmark.py --sections start``; the README's speed page has
  the current run). The scene's vehicle faces (:func:`face_scatterers`, reached first, at ``reset``) add ~0.8 s
  to the env's share. Of the env's share, the one-call OMP's own compile was ~8 s (19.0 s with its callees; 6.1 s
  alone with every callee cached): numba links each callee's code into the caller's module and optimises and
  generates the whole tree again. So on a cold cache the background compiles it last, and until then the env's
  scans run its body (and :func:`joint_refine`'s) in Python on the compiled stages
  (:data:`omp_doppler_tiered`, :class:`rhs_common.jit.Tiered`): the same numbers bit for bit, ~2x the OMP's time
  for the first tens of steps. Vector envs compile once, in the parent
  (``agents.run_setup.make_vec_env``,
  :func:`rhs_common.jit.warm_cache`).
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import Tiered, njit, python_body
from rhs_common.native import matmul_add

__all__ = [
    "PRODUCT_ORDER", "PRODUCT_SERIES_BOUND", "TABLE_WORK_MAX", "TAYLOR_ORDER", "angle_information", "assemble_points",
    "atom_norms", "bin_amplitudes", "doppler_dtft_refine", "face_scatterers", "footprint_detections",
    "footprint_statistic", "gather_bins", "joint_refine", "joint_rho", "line_of_sight", "lstsq", "newton_refine",
    "noise_samples", "noise_uniforms", "omp_doppler", "phasors", "range_offsets", "slot_projection", "slot_sums",
    "taylor_atoms", "taylor_tables", "tone_operands", "tone_spectra",
]


# --------------------------------------------------------------------------- detection
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


# --------------------------------------------------------------------------- atoms (Taylor tables)
#: order of the one-way gains' Taylor series in u = sin(theta): the error term
#: ``(|x - x_c| du)^(N + 1) / (N + 1)!`` is ~1e-19 for the 60-element RHS at the default candidate spacing
#: (at half the candidates, ``oversampling=2``, 2^11 times that; the second derivative ~1e-11 relative, measured)
TAYLOR_ORDER = 10
#: order of the two-way gain's own series, whose exponents span twice the aperture: ~3e-20 for the RHS at the
#: default spacing, its second derivative 6e-15 relative to the direct sums (measured; 8.9e-13 at order 10);
#: 13 x 2 I coefficients read per atom instead of 11 x 4 I
PRODUCT_ORDER = 12
#: the largest remainder bound ``(max |y~| du / 2)^(N + 1) / (N + 1)!`` at which the two-way gain's own series is used
PRODUCT_SERIES_BOUND = 1e-15
#: the most candidates x elements x table columns (I_c M 2 I) a Taylor table is built for: ~4e6 for the default RHS;
#: past it (thousands of elements) the build would take minutes and the atoms come from the direct product
TABLE_WORK_MAX = 1e8


def _series(weights: np.ndarray, xt: np.ndarray, u_c: np.ndarray, order: int) -> np.ndarray:
    """``T[c, n, i] = sum_m weights_mi (j x~_m)^n exp(j x~_m u_c) / n!`` (I_c, N + 1, columns) complex128.

    In blocks of candidates whose temporaries stay near 32 MB (a 4096-element array has ~10^4 candidates).
    """
    fact = np.cumprod(np.concatenate([[1.0], np.arange(1, order + 1)]))
    powers = (1j * xt[None, :]) ** np.arange(order + 1)[:, None] / fact[:, None]  # (N + 1, M)
    out = np.empty((u_c.size, order + 1, weights.shape[1]), complex)
    block = max(1, 2**21 // (xt.size * (order + 1)))
    for lo in range(0, u_c.size, block):
        a = np.exp(1j * np.outer(u_c[lo:lo + block], xt))  # (block, M)
        out[lo:lo + block] = (a[:, None, :] * powers[None]) @ weights
    return out


def _product_weights(w2: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The two-way gain as one sum, ``h_i(u) = sum_k v_ki exp(j y_k u)``, for uniformly spaced elements; else None.

    ``h_i = r_i t_i = sum_{m, n} w_T,mi w_R,ni exp(j (x_m + x_n) u)``; with ``x_m = x_0 + m dx`` the sums
    ``y_k = 2 x_0 + k dx``, k < 2 M - 1, and ``v_ki = sum_{m + n = k} w_T,mi w_R,ni`` (a convolution per slot).
    Uniform: every ``x_m`` within 1e-12 (rad per unit u) of ``x_0 + m dx``, so each term's phase within 2e-12
    (the RHS' positions deviate by ~1e-14, their round-off).
    """
    m = x.size
    dx = (x[-1] - x[0]) / max(m - 1, 1)
    if m < 2 or np.abs(x - (x[0] + np.arange(m) * dx)).max() > 1e-12:
        return None
    n_i = w2.shape[1] // 2
    w_t, w_r = w2[:, :n_i], w2[:, n_i:]
    v = np.zeros((2 * m - 1, n_i), complex)
    for k in range(m):
        v[k:k + m] += w_t[k][None, :] * w_r
    return v, 2 * x[0] + np.arange(2 * m - 1) * dx


def taylor_tables(w2: np.ndarray, x: np.ndarray, candidates: np.ndarray, order: int = TAYLOR_ORDER,
                  product_order: int = PRODUCT_ORDER) -> tuple[np.ndarray, np.ndarray, float]:
    """Taylor coefficients of the centred gains in u = sin(theta) at every candidate.

    One-way gains, ``t_i(u) = sum_m w_T,im exp(j x_m u) = exp(j x_c u) t~_i(u)`` with ``x~_m = x_m - x_c``
    (x_c the middle of the aperture: the series converges over the half aperture only), and around
    ``u_c = sin(theta_c)``

        t~_i(u_c + delta) = sum_n T[c, n, i] delta^n,   T[c, n, i] = sum_m w_T,im (j x~_m)^n exp(j x~_m u_c) / n!,

    the same for r with w_R (the columns of ``w2 = [w_T | w_R]`` (M, 2 I)): the table ``[t~ | r~]``
    (I_c, N + 1, 2 I). For uniformly spaced elements whose two-way series (order ``product_order``) converges
    to :data:`PRODUCT_SERIES_BOUND` at the candidate spacing, the table of the two-way gain itself,
    ``h_i = exp(j 2 x_c u) h~_i(u)`` with ``h~_i = sum_k v_ki exp(j (y_k - 2 x_c) u)`` (:func:`_product_weights`):
    (I_c, N + 1, I), half the coefficients read per atom and no product rule. Returns the table (complex128),
    ``u_c`` (I_c,) and ``x_c``; :func:`_atom_at` tells the two apart by the table's width.
    """
    x_c = 0.5 * (float(x.min()) + float(x.max()))
    u_c = np.sin(candidates)
    product = _product_weights(w2, x)
    if product is not None:
        v, y = product
        du = float(np.max(np.abs(np.diff(u_c)))) / 2 if u_c.size > 1 else 1.0
        n = product_order + 1
        if (float(np.abs(y - 2 * x_c).max()) * du) ** n / float(np.prod(np.arange(1.0, n + 1))) <= PRODUCT_SERIES_BOUND:
            return _series(v, y - 2 * x_c, u_c, product_order), u_c, x_c
    return _series(w2, x - x_c, u_c, order), u_c, x_c


@njit
def _horner(table: np.ndarray, c: int, delta: float, order: int, work: np.ndarray) -> None:
    """``work[o] = d^o/ddelta^o sum_n table[c, n] delta^n`` for o <= min(order, 2), on the float64 view (re, im alike).

    One pass per term for the value and its first two derivatives; the three running values of an entry are
    read before any is written, so the loops vectorise.
    """
    n_n, n_f = table.shape[1], table.shape[2]
    for i in range(n_f):
        work[0, i] = table[c, n_n - 1, i]
        work[1, i] = 0.0
        work[2, i] = 0.0
    for n in range(n_n - 2, -1, -1):
        if order >= 2:
            for i in range(n_f):
                a0, a1, a2 = work[0, i], work[1, i], work[2, i]
                work[2, i] = a2 * delta + 2.0 * a1
                work[1, i] = a1 * delta + a0
                work[0, i] = a0 * delta + table[c, n, i]
        elif order == 1:
            for i in range(n_f):
                a0, a1 = work[0, i], work[1, i]
                work[1, i] = a1 * delta + a0
                work[0, i] = a0 * delta + table[c, n, i]
        else:
            for i in range(n_f):
                work[0, i] = work[0, i] * delta + table[c, n, i]


@njit
def _product_atom(work: np.ndarray, y_c: float, u: float, cos_t: float, order: int, h: np.ndarray) -> None:
    """h and its theta derivatives from the two-way series' Horner sums ``work`` (h~, dh~/du, d2h~/du2).

    ``h = p h~`` with ``p = exp(j y_c u)``: ``dh/du = p (j y_c h~ + h~')``, ``d2h/du2 = p (-y_c^2 h~ + 2 j y_c h~'
    + h~'')``; in theta ``h' = cos(theta) dh/du``, ``h'' = cos(theta)^2 d2h/du2 - sin(theta) dh/du``.
    """
    ph = np.exp(1j * y_c * u)
    jy = 1j * y_c
    for i in range(h.shape[1]):
        g0 = complex(work[0, 2 * i], work[0, 2 * i + 1])
        h[0, i] = ph * g0
        if order >= 1:
            g1 = complex(work[1, 2 * i], work[1, 2 * i + 1])
            d1 = ph * (jy * g0 + g1)
            h[1, i] = cos_t * d1
            if order >= 2:
                g2 = complex(work[2, 2 * i], work[2, 2 * i + 1])
                h[2, i] = cos_t * cos_t * (ph * (-y_c * y_c * g0 + 2.0 * jy * g1 + g2)) - u * d1


@njit
def _atom_at(table: np.ndarray, u_c: np.ndarray, x_c: float, lo: float, step: float, w2: np.ndarray, x: np.ndarray,
             th: float, order: int, f0: np.ndarray, f1: np.ndarray, f2: np.ndarray, h: np.ndarray,
             work: np.ndarray) -> None:
    """h (order + 1, I) at one angle th: :func:`taylor_atoms` for one angle (f0, f1, f2: (2 I,) complex and
    ``work`` (3, table width) float work arrays).

    ``table``: the coefficients of :func:`taylor_tables` viewed as float64, re, im interleaved: (I_c, N + 1, 2 I)
    for the two-way gain's own series (:func:`_product_atom`), (I_c, N + 1, 4 I) for ``[t~ | r~]``; delta is
    real, so the Horner steps act on the real and imaginary parts alike (the same values as in complex
    arithmetic, in vectorisable loops).
    """
    n_c, n_f = table.shape[0], table.shape[2]
    n_i2 = w2.shape[1]
    n_i = n_i2 // 2
    u = np.sin(th)
    cos_t = np.cos(th)
    c = int(np.floor((th - lo) / step + 0.5))
    inside = -1 <= c <= n_c
    if inside:
        c = min(max(c, 0), n_c - 1)
        _horner(table, c, u - u_c[c], order, work)
        if n_f == n_i2:  # the two-way gain's series
            _product_atom(work, 2.0 * x_c, u, cos_t, order, h)
            return
        p0 = work[0]
        p1 = work[1]
        p2 = work[2]
        for i in range(n_i2):
            f0[i] = complex(p0[2 * i], p0[2 * i + 1])
            f1[i] = complex(p1[2 * i], p1[2 * i + 1])
            f2[i] = complex(p2[2 * i], p2[2 * i + 1])
        ph = np.exp(1j * x_c * u)
        jx = 1j * x_c
        for i in range(n_i2):
            g0 = f0[i]
            g1 = jx * g0 + f1[i]
            g2 = -x_c * x_c * g0 + 2.0 * jx * f1[i] + f2[i]
            f0[i], f1[i], f2[i] = ph * g0, ph * g1, ph * g2
    else:
        for i in range(n_i2):
            f0[i] = 0
            f1[i] = 0
            f2[i] = 0
        for m in range(x.size):
            a = np.exp(1j * x[m] * u)
            jx = 1j * x[m]
            for i in range(n_i2):
                wa = w2[m, i] * a
                f0[i] += wa
                f1[i] += jx * wa
                f2[i] += jx * jx * wa
    for i in range(n_i):  # u -> theta, then h = r t and its derivatives
        t0, r0 = f0[i], f0[n_i + i]
        h[0, i] = r0 * t0
        if order >= 1:
            t1, r1 = cos_t * f1[i], cos_t * f1[n_i + i]
            h[1, i] = r1 * t0 + r0 * t1
            if order >= 2:
                t2 = cos_t * cos_t * f2[i] - u * f1[i]
                r2 = cos_t * cos_t * f2[n_i + i] - u * f1[n_i + i]
                h[2, i] = r2 * t0 + 2.0 * r1 * t1 + r0 * t2


@njit
def taylor_atoms(table: np.ndarray, u_c: np.ndarray, x_c: float, lo: float, step: float, w2: np.ndarray,
                 x: np.ndarray, theta: np.ndarray, order: int) -> np.ndarray:
    """``[h, dh/dtheta, d2h/dtheta2][:order + 1]`` (order + 1, T, I) of :meth:`rhs_env.point_cloud.AngleDictionary.atoms`.

    ``h_i = r_i t_i``; t, r and their u-derivatives from the series of :func:`taylor_tables` at the
    nearest candidate ``c`` (``delta = sin(theta) - u_c``): ``t~ = sum_n T_n delta^n``,
    ``t~' = sum_n n T_n delta^(n-1)``, ``t~'' = sum_n n (n-1) T_n delta^(n-2)``; with the centring
    phase ``p = exp(j x_c u)``: ``t = p t~``, ``dt/du = p (j x_c t~ + t~')``,
    ``d2t/du2 = p (-x_c^2 t~ + 2 j x_c t~' + t~'')``; in theta ``t' = cos(theta) dt/du``,
    ``t'' = cos(theta)^2 d2t/du2 - sin(theta) dt/du``; then ``h' = r' t + r t'``,
    ``h'' = r'' t + 2 r' t' + r t''``; a table of the two-way gain's own series gives h and its derivatives
    directly, the same way (:func:`_product_atom`). An angle more than one candidate outside the table is
    summed directly, ``t_i = sum_m w_T,im exp(j x_m u)`` (``w2 = [w_T | w_R]``, x in radians per unit u).
    ``table``: the coefficients of :func:`taylor_tables` viewed as float64 (re, im interleaved).
    """
    n_i2 = w2.shape[1]
    out = np.empty((order + 1, theta.size, n_i2 // 2), np.complex128)
    f0 = np.empty(n_i2, np.complex128)
    f1 = np.empty(n_i2, np.complex128)
    f2 = np.empty(n_i2, np.complex128)
    h = np.empty((order + 1, n_i2 // 2), np.complex128)
    work = np.empty((3, table.shape[2]))
    for q in range(theta.size):
        _atom_at(table, u_c, x_c, lo, step, w2, x, theta[q], order, f0, f1, f2, h, work)
        for o in range(order + 1):
            for i in range(n_i2 // 2):
                out[o, q, i] = h[o, i]
    return out


@njit
def newton_refine(table: np.ndarray, u_c: np.ndarray, x_c: float, lo: float, step: float, w2: np.ndarray,
                  x: np.ndarray, theta: np.ndarray, resid: np.ndarray, steps: int) -> np.ndarray:
    """:func:`rhs_env.point_cloud._newton_refine` per row: Newton steps maximising ``f = |h^H r|^2 / ||h||^2``.

    With ``g = h^H r``, ``G = |g|^2``, ``n = ||h||^2`` and their theta derivatives from h', h''
    (:func:`taylor_atoms`): ``G' = 2 Re(g* g')``, ``G'' = 2 |g'|^2 + 2 Re(g* g'')``, ``n' = 2 Re(h'^H h)``,
    ``n'' = 2 Re(h''^H h) + 2 ||h'||^2``; ``f' = (G' n - G n') / n^2``,
    ``f'' = (G'' n^2 - G n n'' - 2 G' n n' + 2 G n'^2) / n^3``; the step ``-f' / f''`` where f'' < 0,
    clipped to half a candidate spacing. theta (D,), resid (D, I).
    """
    half = 0.5 * step
    n_i2 = w2.shape[1]
    n_i = n_i2 // 2
    f0 = np.empty(n_i2, np.complex128)
    f1 = np.empty(n_i2, np.complex128)
    f2 = np.empty(n_i2, np.complex128)
    h = np.empty((3, n_i), np.complex128)
    work = np.empty((3, table.shape[2]))
    out = theta.copy()
    for d in range(theta.size):
        th = theta[d]
        for _ in range(steps):
            _atom_at(table, u_c, x_c, lo, step, w2, x, th, np.int64(2), f0, f1, f2, h, work)
            g = 0j
            g1 = 0j
            g2 = 0j
            n = 0.0
            n1 = 0.0
            n2a = 0.0
            n2b = 0.0
            for i in range(n_i):
                r = resid[d, i]
                h0c, h1c, h2c = np.conj(h[0, i]), np.conj(h[1, i]), np.conj(h[2, i])
                g += h0c * r
                g1 += h1c * r
                g2 += h2c * r
                n += (h0c * h[0, i]).real
                n1 += (h1c * h[0, i]).real
                n2a += (h2c * h[0, i]).real
                n2b += (h1c * h[1, i]).real
            n1, n2 = 2 * n1, 2 * n2a + 2 * n2b
            G = g.real ** 2 + g.imag ** 2
            G1 = 2 * (np.conj(g) * g1).real
            G2 = 2 * (g1.real ** 2 + g1.imag ** 2) + 2 * (np.conj(g) * g2).real
            fd1 = (G1 * n - G * n1) / n ** 2
            fd2 = (G2 * n ** 2 - G * n * n2 - 2 * G1 * n * n1 + 2 * G * n1 ** 2) / n ** 3
            delta = -fd1 / fd2 if fd2 < 0 else 0.0
            th = th + min(max(delta, -half), half)
        out[d] = th
    return out


# --------------------------------------------------------------------------- signal synthesis
@njit
def noise_uniforms(words: np.ndarray, scale: np.float32, half: np.float32, two_pi: np.float32, neg_u1: np.ndarray,
                   phase: np.ndarray) -> None:
    """The polar method's inputs of :meth:`rhs_env.radar.RadarSystem._noise_spectrum` from raw 32-bit words, in one pass.

    ``u = float32(w >> 8) 2^-24 + 1/2`` (a 24-bit signed word: u uniform on [0, 1) in steps of 2^-24, every
    step exact in float32) of the words ``words`` (2 M,) int32: the first M give ``neg_u1 = -u1``
    (the argument of ``log1p``), the last M ``phase = 2 pi u2`` (float32), both (M,) in the order of the
    numpy reference (``scale = 2^-24``, ``half = 1/2``, ``two_pi = 2 pi`` as float32).
    """
    m = neg_u1.size
    for q in range(m):
        neg_u1[q] = -(np.float32(words[q] >> 8) * scale + half)
    for q in range(m):
        phase[q] = (np.float32(words[m + q] >> 8) * scale + half) * two_pi


@njit
def noise_samples(log1p_neg_u1: np.ndarray, cos_ph: np.ndarray, sin_ph: np.ndarray, radius_window: np.ndarray,
                  out: np.ndarray) -> None:
    """Windowed CN(0, sigma_n^2) samples, zero-padded, into ``out`` (rows, 2 L) float32 (complex64 re, im interleaved).

    ``x[m] = rho_m (cos(phi_m) + j sin(phi_m))`` with the radius ``rho_m = sqrt(-log1p(-u1)) sqrt(D) sigma_n w[D m]``
    (``radius_window`` (n,) float32: ``sqrt(D) sigma_n w[D m]``; ``log1p_neg_u1``, ``cos_ph``, ``sin_ph``
    (rows, n) float32 from numpy), then zeros up to the FFT length L: the numpy reference's passes
    (negate, sqrt, window, the two products, the padding) in one, the same float32 operations per sample.
    """
    rows, n = cos_ph.shape
    width = out.shape[1]
    for r in range(rows):
        for k in range(n):
            rad = np.sqrt(-log1p_neg_u1[r, k]) * radius_window[k]
            out[r, 2 * k] = cos_ph[r, k] * rad
            out[r, 2 * k + 1] = sin_ph[r, k] * rad
        for k in range(2 * n, width):
            out[r, k] = 0


@njit
def tone_spectra(mu: np.ndarray, coef: np.ndarray, n: int, zero_pad: int, n_bins: int, freq: np.ndarray) -> np.ndarray:
    """:func:`rhs_env.point_cloud.tone_spectra`: windowed, zero-padded spectra of unit tones (P, n_bins) complex128.

    ``S_p[k] = sum_m c_m D(k / (Z N) - f_p - mu_m)``, ``D(x) = exp(-j pi x (N - 1)) sin(pi N x) / sin(pi x)``
    (``N cos(pi N x) / cos(pi x)`` where ``sin(pi x) = 0``), with ``e(x) = exp(j pi x) = e(k / (Z N)) e(-f_p - mu_m)``:
    ``e1 = e(x)``, ``en = e(N x)``, ``D = conj(en) e1 sin(pi N x) / sin(pi x)``.
    """
    n_p, n_m = freq.size, mu.size
    out = np.empty((n_p, n_bins), np.complex128)
    ek1 = np.empty(n_bins, np.complex128)
    ekn = np.empty(n_bins, np.complex128)
    for k in range(n_bins):
        kf = k / (zero_pad * n)
        ek1[k] = np.exp(1j * np.pi * kf)
        ekn[k] = np.exp(1j * np.pi * n * kf)
    ef1 = np.empty(n_m, np.complex128)
    efn = np.empty(n_m, np.complex128)
    for p in range(n_p):
        for m in range(n_m):
            fm = freq[p] + mu[m]
            ef1[m] = np.exp(-1j * np.pi * fm)
            efn[m] = np.exp(-1j * np.pi * n * fm)
        for k in range(n_bins):
            acc = 0j
            for m in range(n_m):
                e1 = ek1[k] * ef1[m]
                en = ekn[k] * efn[m]
                s1 = e1.imag
                if abs(s1) < 1e-12:
                    ratio = n * en.real / e1.real
                else:
                    ratio = en.imag / s1
                acc += coef[m] * np.conj(en) * e1 * ratio
            out[p, k] = acc
    return out


@njit
def tone_operands(g_mat: np.ndarray, omega: np.ndarray, wk: np.ndarray, chirps: int) -> tuple[np.ndarray, np.ndarray]:
    """The operands of ``Y_s[r] = G_r @ E_r`` (:meth:`rhs_env.radar.RadarSystem._mix`), complex64, the tones in order.

    ``G[i, p]`` (I, P) and ``E[p, (c, k)] = exp(j omega_p c) W_p[k]`` (P, C K) (the product formed in
    complex128 and rounded once, as numpy does). With the tones sorted by radar, radar r's operands are
    the column block ``G[:, lo_r:hi_r]`` and the row block ``E[lo_r:hi_r]``: no padding to the largest count.
    """
    n_p = omega.size
    n_i, n_k = g_mat.shape[0], wk.shape[1]
    gp = np.empty((n_i, n_p), np.complex64)
    ep = np.empty((n_p, chirps * n_k), np.complex64)
    for i in range(n_i):
        for p in range(n_p):
            gp[i, p] = g_mat[i, p]
    for p in range(n_p):
        for c in range(chirps):
            ph = np.exp(1j * omega[p] * c)
            for k in range(n_k):
                ep[p, c * n_k + k] = ph * wk[p, k]
    return gp, ep


@njit
def add_tone_products(gp: np.ndarray, ep: np.ndarray, bounds: np.ndarray, spec: np.ndarray, cgemm: int) -> None:
    """``spec[r] += G_r @ E_r`` in place: ``spec[r, i, c, k] += sum_{p of radar r} G[i, p] E[p, c K + k]``.

    The operands of :func:`tone_operands` (radar r's tones ``bounds[r]:bounds[r + 1]``, sorted by radar) and
    spec (4, I, C, K) complex64, a view with unit stride along k (the searched bins of the FFT buffer). One
    BLAS product per radar and chirp adds straight into the view (:func:`rhs_common.native.matmul_add`,
    ``cgemm`` its address): no temporary, no second pass.
    """
    n_c, n_k = spec.shape[2], spec.shape[3]
    for r in range(spec.shape[0]):
        lo, hi = bounds[r], bounds[r + 1]
        if hi > lo:
            for c in range(n_c):
                matmul_add(gp[:, lo:hi], ep[lo:hi, c * n_k:(c + 1) * n_k], spec[r, :, c, :], cgemm)


# --------------------------------------------------------------------------- OMP phases
#: the block of :func:`_ramp`: cos + j sin exactly at every RAMP-th sample of a uniform time axis
RAMP = 8


@njit
def _uniform(t: np.ndarray) -> bool:
    """Whether the times t (n,) are uniform, ``t_i = t_0 + i (t_1 - t_0)`` exactly (integer chirp times are)."""
    for i in range(2, t.size):
        if t[i] - t[0] != i * (t[1] - t[0]):
            return False
    return True


@njit
def _ramp(x: float, t: np.ndarray, uniform: bool, em: np.ndarray, out: np.ndarray) -> None:
    """``out[i] = exp(j x t_i)`` for the times t (n,); ``em`` (:data:`RAMP`,) complex work.

    On a uniform axis (``t_i = t_0 + i dt``, :func:`_uniform`) ``cos + j sin`` of ``x t_b`` at every
    :data:`RAMP`-th sample b, between them ``exp(j x t_b) exp(j x m dt)`` (m < RAMP): one complex product,
    ~2e-16 relative, the size of the argument's own rounding; 8 + n / 8 cosines and sines instead of n
    (the scalar sine and cosine are the phasors' cost: numba has no vectorised ones). Else ``cos + j sin``
    at every sample.
    """
    n = t.size
    if not uniform or n < 2 * RAMP:
        for i in range(n):
            v = x * t[i]
            out[i] = complex(np.cos(v), np.sin(v))
        return
    dt = t[1] - t[0]
    for m in range(RAMP):
        v = x * (m * dt)
        em[m] = complex(np.cos(v), np.sin(v))
    for b in range(0, n, RAMP):
        v = x * t[b]
        base = complex(np.cos(v), np.sin(v))
        out[b] = base
        for m in range(1, min(RAMP, n - b)):
            out[b + m] = base * em[m]


@njit
def phasors(w: np.ndarray, tgrid: np.ndarray, sign: float) -> np.ndarray:
    """``exp(sign j w_p t_ic)`` (P, I, C) for w (P,) rad per chirp and chirp times tgrid (I, C), sign +-1.

    ``cos(x) + j sin(x)`` with ``x = (sign w) t``: the values numpy's complex exp gives for
    ``np.exp(sign * 1j * w[:, None, None] * tgrid[None])``, without its complex temporaries. Where the
    chirp times are separable, ``t_ic = t_i + t_c`` (slot start plus chirp offset, every sweep here),
    ``exp(j x t_ic) = exp(j x t_i) exp(j x t_c)``: I + C cosines and sines instead of I C (one rounding
    more, ~1e-16 relative), the slot phases ``exp(j x t_i)`` by :func:`_ramp` (~2e-16 relative).
    """
    n_p = w.size
    n_i, n_c = tgrid.shape
    out = np.empty((n_p, n_i, n_c), np.complex128)
    separable = True
    for i in range(n_i):
        for c in range(n_c):
            if tgrid[i, c] != tgrid[i, 0] + (tgrid[0, c] - tgrid[0, 0]):
                separable = False
    if separable:
        ec = np.empty(n_c, np.complex128)
        ei = np.empty(n_i, np.complex128)
        em = np.empty(RAMP, np.complex128)
        t_slot = np.empty(n_i)
        for i in range(n_i):
            t_slot[i] = tgrid[i, 0]
        uniform = _uniform(t_slot)
        for p in range(n_p):
            sw = sign * w[p]
            for c in range(n_c):
                x = sw * (tgrid[0, c] - tgrid[0, 0])
                ec[c] = complex(np.cos(x), np.sin(x))
            _ramp(sw, t_slot, uniform, em, ei)
            for i in range(n_i):
                for c in range(n_c):
                    out[p, i, c] = ei[i] * ec[c]
        return out
    for p in range(n_p):
        sw = sign * w[p]
        for i in range(n_i):
            for c in range(n_c):
                x = sw * tgrid[i, c]
                out[p, i, c] = complex(np.cos(x), np.sin(x))
    return out


@njit
def joint_rho(r: np.ndarray, om: np.ndarray, t_chirp: np.ndarray, t_slot: np.ndarray) -> np.ndarray:
    """Doppler-compensated slot vectors of :func:`rhs_env.point_cloud._joint_grid_search`, complex64 (D, H, I).

    ``rho[d, h, i] = exp(-j omega_dh t_i) sum_c r[d, i, c] exp(-j omega_dh t_c)`` for separable chirp times
    ``t_ic = t_i + t_c`` (``t_slot`` (I,) holds t_i including the first chirp's time, ``t_chirp`` (C,) t_c); the
    slot phases by :func:`_ramp`.
    """
    n_d, n_i, n_c = r.shape
    n_h = om.shape[1]
    rho = np.empty((n_d, n_h, n_i), np.complex64)
    ec = np.empty(n_c, np.complex128)
    ei = np.empty(n_i, np.complex128)
    em = np.empty(RAMP, np.complex128)
    uniform = _uniform(t_slot)
    for d in range(n_d):
        for h in range(n_h):
            w = -om[d, h]
            for c in range(n_c):
                ec[c] = complex(np.cos(w * t_chirp[c]), np.sin(w * t_chirp[c]))
            _ramp(w, t_slot, uniform, em, ei)
            for i in range(n_i):
                acc = 0j
                for c in range(n_c):
                    acc += r[d, i, c] * ec[c]
                rho[d, h, i] = acc * ei[i]
    return rho


@njit
def atom_norms(a: np.ndarray) -> np.ndarray:
    """``||a_dl|| = sqrt(sum_q |a[d, q, l]|^2)`` (D, L) of atoms a (D, Q, L): ``np.linalg.norm(a, axis=1)`` (its order of
    summation over q; the last bit may differ where the compiler fuses a multiply-add)."""
    n_d, n_q, n_l = a.shape
    out = np.zeros((n_d, n_l))
    for d in range(n_d):
        for q in range(n_q):
            for l in range(n_l):
                v = a[d, q, l]
                out[d, l] += v.real * v.real + v.imag * v.imag
    return np.sqrt(out)


@njit
def angle_information(h: np.ndarray, h1: np.ndarray) -> np.ndarray:
    """:func:`rhs_env.uncertainty.angle_information` per row of the atoms h and dh/dtheta (T, I): (T,) rad^-2.

    ``g = ||P_perp h'||^2 / ||h||^2 = (||h'||^2 - |h^H h'|^2 / ||h||^2) / ||h||^2`` (floored at 1e-300 / ||h||^2),
    the three sums in one pass over the slots (sequential: ~1e-16 relative to numpy's pairwise sums).
    """
    n_t, n_i = h.shape
    out = np.empty(n_t)
    for q in range(n_t):
        nh = 0.0
        n1 = 0.0
        c_re = 0.0
        c_im = 0.0
        for i in range(n_i):
            a = h[q, i]
            b = h1[q, i]
            nh += a.real * a.real + a.imag * a.imag
            n1 += b.real * b.real + b.imag * b.imag
            c_re += a.real * b.real + a.imag * b.imag  # conj(a) b
            c_im += a.real * b.imag - a.imag * b.real
        out[q] = max(n1 - (c_re * c_re + c_im * c_im) / nh, 1e-300) / nh
    return out


@njit
def _cholesky_solve(chol: np.ndarray, rhs: np.ndarray, out: np.ndarray) -> None:
    """``out = (C C^H)^-1 rhs``: ``C z = rhs`` then ``C^H out = z`` by substitution (rhs overwritten by z)."""
    n_l = rhs.size
    for l in range(n_l):
        v = rhs[l]
        for k in range(l):
            v -= chol[l, k] * rhs[k]
        rhs[l] = v / chol[l, l].real
    for l in range(n_l - 1, -1, -1):
        v = rhs[l]
        for k in range(l + 1, n_l):
            v -= np.conj(chol[k, l]) * out[k]
        out[l] = v / chol[l, l].real


@njit
def lstsq(a: np.ndarray, y: np.ndarray) -> np.ndarray:
    """:func:`rhs_env.point_cloud._lstsq` for one right-hand side: ``s_d = (A_d^H A_d + 1e-12 I)^-1 A_d^H y_d`` (D, L).

    a (D, Q, L), y (D, Q) complex128. The Gram matrix ``G = A^H A + 1e-12 I`` is factored ``G = C C^H``
    (Cholesky, :func:`_cholesky_factor`), then ``C z = A^H y`` and ``C^H s = z`` (:func:`_cholesky_solve`). The sums
    over q of ``A^H A`` and ``A^H y`` run on split real and imaginary parts (:func:`_conj_dot`, vectorised; ~1e-15
    relative from the sums in order).
    """
    n_d, n_q, n_l = a.shape
    out = np.empty((n_d, n_l), np.complex128)
    gram = np.empty((n_l, n_l), np.complex128)
    chol = np.zeros((n_l, n_l), np.complex128)
    rhs = np.empty(n_l, np.complex128)
    a_re = np.empty((n_l, n_q))
    a_im = np.empty((n_l, n_q))
    y_re = np.empty(n_q)
    y_im = np.empty(n_q)
    for d in range(n_d):
        for q in range(n_q):
            for l in range(n_l):
                a_re[l, q] = a[d, q, l].real
                a_im[l, q] = a[d, q, l].imag
            y_re[q] = y[d, q].real
            y_im[q] = y[d, q].imag
        for l in range(n_l):
            for m in range(l, n_l):
                gr, gi = _conj_dot(a_re[l], a_im[l], a_re[m], a_im[m])
                gram[l, m] = complex(gr, gi)
            sr, si = _conj_dot(a_re[l], a_im[l], y_re, y_im)
            rhs[l] = complex(sr, si)
        _cholesky_factor(gram, chol)
        _cholesky_solve(chol, rhs, out[d])
    return out


@njit
def gather_bins(spec: np.ndarray, rd: np.ndarray, kk: np.ndarray, centre: int) -> tuple[np.ndarray, np.ndarray]:
    """The neighbouring bins of every detection, read from the spectrum Y (R, I, C, K) in one pass.

    ``win[d, i, c, w] = Y[rd_d, i, c, kk_dw]`` (D, I, C, W) complex64 (the bins of
    :meth:`rhs_env.radar.RadarSystem._target_bins`) and the OMP's data ``y[d, i, c] = Y[rd_d, i, c, kk_d,centre]``
    (D, I, C) complex128 (``kk[:, centre]`` the detection's own bin): each (slot, chirp) row of Y is visited once
    per detection, its W adjacent bins together, and :func:`bin_amplitudes` then reads them contiguously.
    """
    n_d, n_w = kk.shape
    _, n_i, n_c, _ = spec.shape
    win = np.empty((n_d, n_i, n_c, n_w), np.complex64)
    y = np.empty((n_d, n_i, n_c), np.complex128)
    for d in range(n_d):
        r = rd[d]
        for i in range(n_i):
            for c in range(n_c):
                for w in range(n_w):
                    win[d, i, c, w] = spec[r, i, c, kk[d, w]]
                y[d, i, c] = complex(win[d, i, c, centre])
    return win, y


@njit(fastmath={"reassoc", "contract"})
def _conj_dot(a_re: np.ndarray, a_im: np.ndarray, y_re: np.ndarray, y_im: np.ndarray) -> tuple[float, float]:
    """``sum_q conj(a_q) y_q`` as (re, im) from split real and imaginary parts (contiguous: a vectorised sum, its
    order free: ~1e-16 relative from the sum in order)."""
    sr = 0.0
    si = 0.0
    for q in range(a_re.size):
        sr += a_re[q] * y_re[q] + a_im[q] * y_im[q]
        si += a_re[q] * y_im[q] - a_im[q] * y_re[q]
    return sr, si


@njit
def _cholesky_factor(gram: np.ndarray, chol: np.ndarray) -> None:
    """``G + 1e-12 I = C C^H`` for the Gram matrix ``G = A^H A`` (upper triangle used; the ridge, added in place,
    keeps an unused all-zero column at amplitude 0), C (lower triangular) written into ``chol``."""
    n_l = gram.shape[0]
    for l in range(n_l):
        gram[l, l] += 1e-12
    for l in range(n_l):  # C[m, l] = (G[l, m]^* - sum_k C[m, k] C[l, k]^*) / C[l, l]
        acc = gram[l, l].real
        for k in range(l):
            acc -= chol[l, k].real ** 2 + chol[l, k].imag ** 2
        cll = np.sqrt(acc)
        chol[l, l] = cll
        for m in range(l + 1, n_l):
            v = np.conj(gram[l, m])
            for k in range(l):
                v -= chol[m, k] * np.conj(chol[l, k])
            chol[m, l] = v / cll


@njit
def bin_amplitudes(a: np.ndarray, spec: np.ndarray, rd: np.ndarray, kk: np.ndarray) -> np.ndarray:
    """Least-squares amplitudes of fixed atoms at neighbouring range bins (D, L, W), for
    :meth:`rhs_env.radar.RadarSystem._target_bins`.

    ``s_d[:, w] = (A_d^H A_d + 1e-12 I)^-1 A_d^H y_dw`` with ``y_dw[(i, c)] = Y[rd_d, i, c, kk_dw]`` read from the
    spectrum Y (R, I, C, K) complex64 (no gathered copy), one Cholesky factor per row for its W bins. The sums over
    q = (i, c) of ``A^H A`` and ``A^H y`` run on split real and imaginary parts (:func:`_conj_dot`, vectorised;
    ~1e-12 relative from the sums in order). An all-zero atom (a row's unused target slot) has ``A^H y = 0``
    without the sums: the same values (its Gram row and column are exact zeros).
    """
    n_d, n_q, n_l = a.shape
    n_w = kk.shape[1]
    n_c = spec.shape[2]
    n_i = n_q // n_c
    out = np.empty((n_d, n_l, n_w), np.complex128)
    gram = np.empty((n_l, n_l), np.complex128)
    chol = np.zeros((n_l, n_l), np.complex128)
    rhs = np.empty(n_l, np.complex128)
    sol = np.empty(n_l, np.complex128)
    a_re = np.empty((n_l, n_q))
    a_im = np.empty((n_l, n_q))
    y_re = np.empty((n_w, n_q))
    y_im = np.empty((n_w, n_q))
    acc = np.empty((n_l, n_w), np.complex128)
    zero = np.empty(n_l, np.bool_)
    for d in range(n_d):
        r = rd[d]
        for q in range(n_q):
            for l in range(n_l):
                a_re[l, q] = a[d, q, l].real
                a_im[l, q] = a[d, q, l].imag
        for l in range(n_l):  # G = A^H A (upper triangle)
            for m in range(l, n_l):
                gr, gi = _conj_dot(a_re[l], a_im[l], a_re[m], a_im[m])
                gram[l, m] = complex(gr, gi)
        for l in range(n_l):
            zero[l] = gram[l, l].real == 0.0
        _cholesky_factor(gram, chol)
        for i in range(n_i):  # the W neighbouring bins of a cell (i, c) read together: one pass over Y's rows
            for c in range(n_c):
                q = i * n_c + c
                for w in range(n_w):
                    v = spec[r, i, c, kk[d, w]]
                    y_re[w, q] = np.float64(v.real)
                    y_im[w, q] = np.float64(v.imag)
        for l in range(n_l):  # A^H y of every atom l and bin w (an all-zero atom, a padded target: exactly 0)
            if zero[l]:
                for w in range(n_w):
                    acc[l, w] = 0j
                continue
            for w in range(n_w):
                sr, si = _conj_dot(a_re[l], a_im[l], y_re[w], y_im[w])
                acc[l, w] = complex(sr, si)
        for w in range(n_w):
            for l in range(n_l):
                rhs[l] = acc[l, w]
            _cholesky_solve(chol, rhs, sol)
            for l in range(n_l):
                out[d, l, w] = sol[l]
    return out


@njit
def slot_projection(x: np.ndarray, y: np.ndarray, rho: np.ndarray) -> None:
    """``rho[p, i] = sum_c x[p, i, c] y[p, i, c]`` (P, I) of x, y (P, I, C): the per-slot projection of the Newton
    steps, e.g. ``rho_i = sum_c part_ic base_ic`` (:func:`joint_refine`) or ``rho_i = sum_c R_ic exp(-j omega t_ic)``
    (:func:`_new_atoms`), summed over c in order, as ``np.sum(x * y, axis=2)``."""
    n_p, n_i, n_c = x.shape
    for p in range(n_p):
        for i in range(n_i):
            acc = 0j
            for c in range(n_c):
                acc += x[p, i, c] * y[p, i, c]
            rho[p, i] = acc


@njit
def slot_sums(h: np.ndarray, r: np.ndarray, t: np.ndarray, q_re: np.ndarray, q_im: np.ndarray) -> None:
    """``q_t = sum_{t_ic = t} conj(h_i) r_ic`` into ``q_re + j q_im`` (n_t,), overwritten: one row's slot vector h (I,)
    against its residual r (I, C), summed into the chirp-time bins ``t[i C + c]`` (the Doppler searches' input)."""
    n_i, n_c = r.shape
    q_re[:] = 0.0
    q_im[:] = 0.0
    for i in range(n_i):
        hc = np.conj(h[i])
        for c in range(n_c):
            p = hc * r[i, c]
            tt = t[i * n_c + c]
            q_re[tt] += p.real
            q_im[tt] += p.imag


@njit(fastmath={"reassoc", "contract"})
def doppler_dtft_refine(h: np.ndarray, r: np.ndarray, t: np.ndarray, n_t: int, kern_re: np.ndarray,
                        kern_im: np.ndarray, w: np.ndarray, span: np.ndarray, nfft: int) -> np.ndarray:
    """The narrow search of :func:`rhs_env.point_cloud._doppler_grid_refine`: d_omega (D,) rad per chirp.

    ``q_t = sum_{t_ic = t} conj(h_i) r_ic`` (:func:`slot_sums`, rounded to complex64, as the reference), its DTFT
    ``V_j = |sum_t q_t exp(-j w_j t)|^2`` on the grid ``w_j = 2 pi j / nfft`` (``kern_re + j kern_im``
    (J, n_t): the reference's complex64 ``exp(-j w_j t)``, transposed), the first maximum ``j*`` within
    ``|w_j| <= span_d`` (clipped to 1..J-2), then the vertex of the parabola through
    ``log V`` at ``j* - 1, j*, j* + 1``: ``w_j* + off 2 pi / nfft``. Real and imaginary parts are
    separate float32 sums of the complex64 values (:func:`_dtft_row`: vectorised, the sums' order free, as the
    reference's float32 product: V within ~1e-6 relative of it).
    """
    n_d = r.shape[0]
    n_j = w.size
    out = np.empty(n_d)
    qr = np.empty(n_t)
    qi = np.empty(n_t)
    q32r = np.empty(n_t, np.float32)
    q32i = np.empty(n_t, np.float32)
    val = np.zeros(n_j)
    for d in range(n_d):
        slot_sums(h[d], r[d], t, qr, qi)
        for tt in range(n_t):
            q32r[tt] = np.float32(qr[tt])
            q32i[tt] = np.float32(qi[tt])
        j_lo = n_j
        j_hi = -1
        for j in range(n_j):
            if abs(w[j]) <= span[d]:
                j_lo = min(j_lo, j)
                j_hi = max(j_hi, j)
        a = max(min(j_lo, n_j - 2) - 1, 0)
        b = min(max(j_hi, 1) + 1, n_j - 1)
        for j in range(a, b + 1):
            val[j] = _dtft_row(q32r, q32i, kern_re[j], kern_im[j])
        best = -1.0
        jb = 0
        for j in range(n_j):
            v = val[j] if j_lo <= j <= j_hi else -1.0
            if v > best:
                best = v
                jb = j
        jb = min(max(jb, 1), n_j - 2)
        ym = np.log(max(val[jb - 1], 1e-300))
        y0 = np.log(max(val[jb], 1e-300))
        yp = np.log(max(val[jb + 1], 1e-300))
        den = ym - 2.0 * y0 + yp
        off = min(max(0.5 * (ym - yp) / den, -0.5), 0.5) if den < 0 else 0.0
        out[d] = w[jb] + off * 2 * np.pi / nfft
    return out


@njit
def _partial_residuals(flat: np.ndarray, a: np.ndarray, s: np.ndarray, base: np.ndarray, dd: np.ndarray,
                       kk: np.ndarray, sel: np.ndarray, n_i: int,
                       fit: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`joint_refine`'s per-pair operands for the pairs ``sel`` of (dd, kk): the partial residual
    ``part = data_d - sum_l a_l s_l + a_k s_k`` (M, I, C), ``comp = part base`` and ``h_i = a_k[i, 0] base[i, 0]``
    (M, I). ``fit`` (I C,) is work space for the row's ``A_d s_d`` (once per row: its pairs are adjacent)."""
    n_m = sel.size
    n_q, n_l = a.shape[1], a.shape[2]
    n_c = n_q // n_i
    part = np.empty((n_m, n_i, n_c), np.complex128)
    comp = np.empty((n_m, n_i, n_c), np.complex128)
    h = np.empty((n_m, n_i), np.complex128)
    for m in range(n_m):
        p = sel[m]
        d, k = dd[p], kk[p]
        if m == 0 or dd[sel[m - 1]] != d:
            for q in range(n_q):
                acc = 0j
                for l in range(n_l):
                    acc += a[d, q, l] * s[d, l]
                fit[q] = acc
        for i in range(n_i):
            for c in range(n_c):
                q = i * n_c + c
                v = flat[d, q] - fit[q] + a[d, q, k] * s[d, k]
                part[m, i, c] = v
                comp[m, i, c] = v * base[p, i, c]
            h[m, i] = a[d, i * n_c, k] * base[p, i, 0]
    return part, comp, h


@njit
def _refit_rows(flat: np.ndarray, a: np.ndarray, s: np.ndarray, rows: np.ndarray, r2: np.ndarray,
                moving: np.ndarray, tol: float, resid: np.ndarray) -> None:
    """Least squares for the amplitudes s of ``rows`` (in place, :func:`lstsq`); with ``tol > 0`` a row stays
    ``moving`` only if its residual ``r2 = ||data_d - A_d s_d||^2`` fell by at least the fraction ``tol``
    (:func:`_residual`, ``resid`` (I, C) its work space)."""
    s_r = lstsq(_take3(a, rows), _take2(flat, rows))
    for r in range(rows.size):
        d = rows[r]
        for l in range(s.shape[1]):
            s[d, l] = s_r[r, l]
        if tol > 0:
            r2_new = _residual(flat[d], a[d], s[d], resid)
            moving[d] = r2[d] - r2_new >= tol * r2[d]
            r2[d] = r2_new


@njit
def joint_refine(table: np.ndarray, u_c: np.ndarray, x_c: float, lo: float, step: float, w2: np.ndarray,
                 x: np.ndarray, flat: np.ndarray, tgrid: np.ndarray, t: np.ndarray, n_t: int, kern_re: np.ndarray,
                 kern_im: np.ndarray, w: np.ndarray, nfft: int, theta: np.ndarray, domega: np.ndarray,
                 valid: np.ndarray, span: np.ndarray, passes: int, newton_steps: int, a: np.ndarray,
                 s: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`rhs_env.point_cloud.joint_refine` in one call: up to ``passes`` Jacobi passes over every valid (row, target).

    Per pass, for every pair (d, k) of the rows not yet converged, against the pass' atoms a (D, I C, L) and
    amplitudes s (D, L): the partial residual ``part = data_d - sum_l a_l s_l + a_k s_k`` (I, C); with
    ``base = exp(-j omega_k t)`` (the previous pass' phases) and ``h_i = a_k[i, 0] base[i, 0]``, the Doppler step
    of :func:`doppler_dtft_refine` on ``part base``; then ``base = exp(-j omega'_k t)``, Newton steps on the angle
    (:func:`newton_refine`) with ``rho_i = sum_c part_ic base_ic``; then the new atoms
    ``a_k = h(theta'_k) conj(base)`` and least squares for the row's amplitudes (:func:`lstsq`). A row whose
    pass lowered its residual ``||data_d - A_d s_d||^2`` by less than the fraction ``tol`` has converged and takes no
    further pass (``tol <= 0``: every row takes every pass). Returns theta, d_omega, ``s * valid`` and a
    (updated copies). The narrow DTFT grid (w, kern) must cover ``span``.
    """
    n_d, n_q, n_l = a.shape
    n_i, n_c = tgrid.shape
    theta = theta.copy()
    domega = domega.copy()
    a = a.copy()
    s = s.copy()
    dd, kk = _valid_pairs(valid)  # the valid (row, target) pairs, row-major
    n_p = dd.size
    w_p = np.empty(n_p)
    for p in range(n_p):
        w_p[p] = domega[dd[p], kk[p]]
    base = phasors(w_p, tgrid, -1.0)  # (P, I, C), exp(-j omega t) of each pair's current omega
    fit = np.empty(n_q, np.complex128)
    moving = np.zeros(n_d, np.bool_)  # rows still refined
    for p in range(n_p):
        moving[dd[p]] = True
    r2 = np.empty(n_d)  # ||data_d - A_d s_d||^2 of each row's current fit
    resid = np.empty((n_i, n_c), np.complex128)
    if tol > 0:
        for d in range(n_d):
            r2[d] = _residual(flat[d], a[d], s[d], resid)
    for _ in range(passes):
        sel = _indices(moving[dd])  # the pairs of the moving rows, row-major
        n_m = sel.size
        if n_m == 0:
            break
        part, comp, h = _partial_residuals(flat, a, s, base, dd, kk, sel, n_i, fit)
        th = np.empty(n_m)
        span_m = np.empty(n_m)
        for m in range(n_m):
            th[m] = theta[dd[sel[m]], kk[sel[m]]]
            span_m[m] = span[dd[sel[m]]]
        dw = doppler_dtft_refine(h, comp, t, n_t, kern_re, kern_im, w, span_m, nfft)
        for m in range(n_m):
            p = sel[m]
            dw[m] += domega[dd[p], kk[p]]
        base_m = phasors(dw, tgrid, -1.0)
        if newton_steps:
            rho = np.empty((n_m, n_i), np.complex128)
            slot_projection(part, base_m, rho)
            th = newton_refine(table, u_c, x_c, lo, step, w2, x, th, rho, newton_steps)
        hs = taylor_atoms(table, u_c, x_c, lo, step, w2, x, th, np.int64(0))[0]  # (M, I)
        rows = np.empty(n_m, np.int64)  # the moving rows, in order
        n_r = 0
        for m in range(n_m):
            p = sel[m]
            d, k = dd[p], kk[p]
            theta[d, k] = th[m]
            domega[d, k] = dw[m]
            for i in range(n_i):
                for c in range(n_c):
                    base[p, i, c] = base_m[m, i, c]
                    a[d, i * n_c + c, k] = hs[m, i] * np.conj(base_m[m, i, c])
            if n_r == 0 or rows[n_r - 1] != d:
                rows[n_r] = d
                n_r += 1
        _refit_rows(flat, a, s, rows[:n_r], r2, moving, tol, resid)
    for d in range(n_d):
        for k in range(n_l):
            if not valid[d, k]:
                s[d, k] = 0
    return theta, domega, s, a


# --------------------------------------------------------------------------- the OMP in one call
@njit
def _fft_pow2(re: np.ndarray, im: np.ndarray, e_re: np.ndarray, e_im: np.ndarray) -> None:
    """In-place forward FFT ``X_k = sum_t x_t exp(-2 pi j k t / n)`` of ``re + j im`` (n a power of 2).

    Iterative radix 2 (bit-reversed order, then log2 n butterfly stages); ``e_re + j e_im`` the twiddles
    ``exp(-2 pi j m / n)``, m = 0..n-1.
    """
    n = re.size
    j = 0
    for i in range(1, n):
        bit = n >> 1
        while j & bit:
            j ^= bit
            bit >>= 1
        j |= bit
        if i < j:
            re[i], re[j] = re[j], re[i]
            im[i], im[j] = im[j], im[i]
    size = 2
    while size <= n:
        half = size // 2
        stride = n // size
        for start in range(0, n, size):
            for k in range(half):
                wr = e_re[k * stride]
                wi = e_im[k * stride]
                a = start + k
                b = a + half
                tr = re[b] * wr - im[b] * wi
                ti = re[b] * wi + im[b] * wr
                re[b] = re[a] - tr
                im[b] = im[a] - ti
                re[a] += tr
                im[a] += ti
        size *= 2


@njit
def _dtft_at(q_re: np.ndarray, q_im: np.ndarray, jj: int, nfft: int, e_re: np.ndarray, e_im: np.ndarray) -> float:
    """``|sum_t q_t exp(-2 pi j jj t / nfft)|^2`` (the twiddle table indexed by ``jj t mod nfft``)."""
    sr = 0.0
    si = 0.0
    inc = jj % nfft
    m = 0
    for tt in range(q_re.size):  # m = jj tt mod nfft, advanced without a division
        sr += q_re[tt] * e_re[m] - q_im[tt] * e_im[m]
        si += q_re[tt] * e_im[m] + q_im[tt] * e_re[m]
        m += inc
        if m >= nfft:
            m -= nfft
    return sr * sr + si * si


@njit(fastmath={"reassoc", "contract"})
def _dtft_row(q_re: np.ndarray, q_im: np.ndarray, k_re: np.ndarray, k_im: np.ndarray) -> float:
    """``|sum_t q_t k_t|^2`` for one row ``k = k_re + j k_im`` of a DTFT table, q and k float32 (complex64 values, as
    the reference's complex64 product): float32 sums, their order free (vectorised, 16 lanes), squared in float64."""
    sr = np.float32(0.0)
    si = np.float32(0.0)
    for tt in range(q_re.size):
        sr += q_re[tt] * k_re[tt] - q_im[tt] * k_im[tt]
        si += q_re[tt] * k_im[tt] + q_im[tt] * k_re[tt]
    return np.float64(sr) * np.float64(sr) + np.float64(si) * np.float64(si)


@njit
def _doppler_peak(q_re: np.ndarray, q_im: np.ndarray, span: float, nfft: int, e_re: np.ndarray, e_im: np.ndarray,
                  buf_re: np.ndarray, buf_im: np.ndarray, tab_re: np.ndarray, tab_im: np.ndarray) -> float:
    """d_omega of one row of :func:`rhs_env.point_cloud._doppler_grid_refine` from its ``q_t`` (n_t,).

    ``V(w) = |sum_t q_t exp(-j w t)|^2`` on ``w_k = 2 pi k / nfft``, the first maximum within ``|w| <= span``,
    plus the log-parabola vertex. A narrow search (``2 half + 1 < nfft / 8``, ``half`` the reference's
    power of two above ``span nfft / (2 pi)``) sums the few samples directly, q rounded to complex64 and the
    peak clipped to ``|k| <= half - 1`` as the reference's matrix product; a wide one takes the FFT
    (:func:`_fft_pow2`), neighbours wrapping around, frequencies in ``np.fft.fftfreq`` order.
    ``tab_re + j tab_im`` (2 H + 1, n_t): the reference's complex64 samples ``exp(-j w_k t)``, k = -H..H,
    read row by row where ``half <= H`` (else the twiddle table, indexed ``k t mod nfft``).
    """
    n_t = q_re.size
    two_pi = 2 * np.pi
    half = 1 << int(np.ceil(np.log2(np.ceil(span * nfft / two_pi) + 1)))
    if 2 * half + 1 < nfft // 8:
        q32r = np.empty(n_t, np.float32)
        q32i = np.empty(n_t, np.float32)
        for tt in range(n_t):
            q_re[tt] = q32r[tt] = np.float32(q_re[tt])
            q_im[tt] = q32i[tt] = np.float32(q_im[tt])
        tab_h = (tab_re.shape[0] - 1) // 2
        best = -1.0
        jb = -half
        for jj in range(-half, half + 1):
            if abs(two_pi * jj / nfft) <= span:
                if half <= tab_h:
                    v = _dtft_row(q32r, q32i, tab_re[jj + tab_h], tab_im[jj + tab_h])
                else:
                    v = _dtft_at(q_re, q_im, jj, nfft, e_re, e_im)
                if v > best:
                    best = v
                    jb = jj
        jb = min(max(jb, -half + 1), half - 1)
        if half <= tab_h:
            vm = _dtft_row(q32r, q32i, tab_re[jb - 1 + tab_h], tab_im[jb - 1 + tab_h])
            v0 = _dtft_row(q32r, q32i, tab_re[jb + tab_h], tab_im[jb + tab_h])
            vp = _dtft_row(q32r, q32i, tab_re[jb + 1 + tab_h], tab_im[jb + 1 + tab_h])
        else:
            vm = _dtft_at(q_re, q_im, jb - 1, nfft, e_re, e_im)
            v0 = _dtft_at(q_re, q_im, jb, nfft, e_re, e_im)
            vp = _dtft_at(q_re, q_im, jb + 1, nfft, e_re, e_im)
        w_b = two_pi * jb / nfft
    else:
        for k in range(buf_re.size):
            buf_re[k] = q_re[k] if k < n_t else 0.0
            buf_im[k] = q_im[k] if k < n_t else 0.0
        _fft_pow2(buf_re, buf_im, e_re, e_im)
        best = -1.0
        kb = 0
        inv = 1.0 / nfft
        for k in range(nfft):
            kf = k if k < (nfft - 1) // 2 + 1 else k - nfft
            if abs(two_pi * (kf * inv)) <= span:
                v = buf_re[k] ** 2 + buf_im[k] ** 2
                if v > best:
                    best = v
                    kb = k
        km, kp = (kb - 1) % nfft, (kb + 1) % nfft
        vm = buf_re[km] ** 2 + buf_im[km] ** 2
        v0 = buf_re[kb] ** 2 + buf_im[kb] ** 2
        vp = buf_re[kp] ** 2 + buf_im[kp] ** 2
        kf = kb if kb < (nfft - 1) // 2 + 1 else kb - nfft
        w_b = two_pi * (kf * inv)
    ym = np.log(max(vm, 1e-300))
    y0 = np.log(max(v0, 1e-300))
    yp = np.log(max(vp, 1e-300))
    den = ym - 2.0 * y0 + yp
    off = min(max(0.5 * (ym - yp) / den, -0.5), 0.5) if den < 0 else 0.0
    return w_b + off * two_pi / nfft


@njit
def _angle_peak(corr: np.ndarray, candidates: np.ndarray, step: float) -> tuple[int, float]:
    """Best candidate of one correlation line (I_c,) and the angle ``theta_j + off step`` (log-parabola; 0 at the ends)."""
    n_c = corr.size
    j = 0
    for jj in range(1, n_c):
        if corr[jj] > corr[j]:
            j = jj
    jm, jp = max(j - 1, 0), min(j + 1, n_c - 1)
    ym = np.log(max(corr[jm], 1e-30))
    y0 = np.log(max(corr[j], 1e-30))
    yp = np.log(max(corr[jp], 1e-30))
    den = ym - 2.0 * y0 + yp
    off = min(max(0.5 * (ym - yp) / den, -0.5), 0.5) if den < 0 else 0.0
    if j == 0 or j == n_c - 1:
        off = 0.0
    return j, candidates[j] + off * step


@njit
def _power(z: np.ndarray) -> np.ndarray:
    """``|z|^2`` (float32) of complex64 correlations z (rows, columns), as ``np.abs(z) ** 2``: ``|z|`` correctly
    rounded to float32 (``sqrt(re^2 + im^2)`` in float64, where the products are exact: hypot's value, in
    vectorised loops), then squared in float32."""
    n_a, n_b = z.shape
    out = np.empty((n_a, n_b), np.float32)
    for a in range(n_a):
        for b in range(n_b):
            re = np.float64(z[a, b].real)
            im = np.float64(z[a, b].imag)
            m = np.float32(np.sqrt(re * re + im * im))
            out[a, b] = m * m
    return out


@njit
def _search_widths(res: np.ndarray, noise_var: float, t_span: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row of res (D, I, C): the Doppler search half-width ``span``, the dwell and whether the row is wide.

    ``snr = max(||R||^2 / sigma^2 - I C, 1)``, ``span = clip(5 / sqrt(snr), min(pi, 8 pi / T), pi)``, the dwell
    ``clip(C (sum_i e_i)^2 / sum_i e_i^2, C, T)`` of the slot energies ``e_i = max(sum_c |R_ic|^2 - C sigma^2, 0)``,
    wide: ``5 dwell / sqrt(snr) > pi / 2`` (the joint angle x Doppler search).
    """
    n_d, n_i, n_c = res.shape
    span = np.empty(n_d)
    dwell = np.empty(n_d)
    wide = np.zeros(n_d, np.bool_)
    floor_span = min(np.pi, 8 * np.pi / t_span)
    for d in range(n_d):
        tot = 0.0
        e_sum = 0.0
        e_sq = 0.0
        for i in range(n_i):
            e = 0.0
            for c in range(n_c):
                v = res[d, i, c]
                e += v.real ** 2 + v.imag ** 2
            tot += e
            e = max(e - n_c * noise_var, 0.0)
            e_sum += e
            e_sq += e * e
        snr = max(tot / noise_var - n_i * n_c, 1.0)
        span[d] = min(max(5.0 / np.sqrt(snr), floor_span), np.pi)
        dw = e_sum ** 2 / max(e_sq, 1e-300) * n_c
        dwell[d] = min(max(dw, n_c), t_span)
        wide[d] = 5.0 / np.sqrt(snr) * dwell[d] > 0.5 * np.pi
    return span, dwell, wide


@njit
def _joint_search(res: np.ndarray, sub: np.ndarray, w0: np.ndarray, th: np.ndarray, span: np.ndarray,
                  dwell: np.ndarray, hn_conj: np.ndarray, candidates: np.ndarray, step: float, tgrid: np.ndarray,
                  rc: np.ndarray) -> None:
    """The joint angle x Doppler search of :func:`rhs_env.point_cloud._joint_grid_search` for the rows ``sub``.

    ``n_h = min(33, 2 ceil(max(span dwell) / 0.5) + 1)`` hypotheses ``w0 + span u`` (u on [-1, 1]) over the
    rows, ``rho`` of :func:`joint_rho`, the best (hypothesis, candidate) of ``|H_n^H rho|^2`` (one complex64
    product) and the log-parabola in angle; w0, th, span (``min(span, pi / dwell)``) and the compensated
    residuals rc of those rows updated in place.
    """
    n_i = res.shape[1]
    top = 0.0
    for s_ in range(sub.size):
        top = max(top, span[sub[s_]] * dwell[sub[s_]])
    n_h = int(min(33, 2 * np.ceil(top / 0.5) + 1))
    u = np.linspace(-1.0, 1.0, n_h)
    om = np.empty((sub.size, n_h))
    for s_ in range(sub.size):
        for hh in range(n_h):
            om[s_, hh] = w0[sub[s_]] + span[sub[s_]] * u[hh]
    n_c = res.shape[2]
    t_chirp = np.empty(n_c)
    for c in range(n_c):
        t_chirp[c] = tgrid[0, c] - tgrid[0, 0]
    t_slot = np.empty(n_i)
    for i in range(n_i):
        t_slot[i] = tgrid[i, 0]
    res_s = np.empty((sub.size, n_i, n_c), np.complex128)
    for s_ in range(sub.size):
        for i in range(n_i):
            for c in range(n_c):
                res_s[s_, i, c] = res[sub[s_], i, c]
    rho_j = joint_rho(res_s, om, t_chirp, t_slot)  # (S, H, I) complex64
    cj = _power(np.dot(rho_j.reshape(sub.size * n_h, n_i), hn_conj))  # (S H, I_c), row s H + h
    n_cand = cj.shape[1]
    for s_ in range(sub.size):
        d = sub[s_]
        hb, jb = 0, 0
        best = cj[s_ * n_h, 0]
        for hh in range(n_h):
            for jj in range(n_cand):
                if cj[s_ * n_h + hh, jj] > best:
                    best = cj[s_ * n_h + hh, jj]
                    hb, jb = hh, jj
        row = s_ * n_h + hb
        jm, jp = max(jb - 1, 0), min(jb + 1, n_cand - 1)
        ym = np.log(max(cj[row, jm], 1e-30))
        y0 = np.log(max(cj[row, jb], 1e-30))
        yp = np.log(max(cj[row, jp], 1e-30))
        den = ym - 2.0 * y0 + yp
        off = min(max(0.5 * (ym - yp) / den, -0.5), 0.5) if den < 0 else 0.0
        w0[d] = om[s_, hb]
        th[d] = candidates[jb] + off * step
        span[d] = min(span[d], np.pi / dwell[d])
    w_s = np.empty(sub.size)
    for s_ in range(sub.size):
        w_s[s_] = w0[sub[s_]]
    ph = phasors(w_s, tgrid, -1.0)
    for s_ in range(sub.size):
        for i in range(n_i):
            for c in range(n_c):
                rc[sub[s_], i, c] = res_s[s_, i, c] * ph[s_, i, c]


@njit
def _new_atoms(table: np.ndarray, u_c: np.ndarray, x_c: float, lo: float, step: float, w2: np.ndarray,
               x: np.ndarray, hn_conj: np.ndarray, candidates: np.ndarray, res: np.ndarray, tgrid: np.ndarray,
               t: np.ndarray, n_t: int, nfft: int, e_re: np.ndarray, e_im: np.ndarray, tab_re: np.ndarray,
               tab_im: np.ndarray, noise_var: float, newton_steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`rhs_env.point_cloud._new_atom` of the residuals res (D, I, C): theta, omega (D,) and ``exp(j omega t)``.

    Coarse Doppler ``w0 = arg sum R[i, c+1] R*[i, c]``; the best candidate of ``|H_n^H rho|^2`` with
    ``rho_i = sum_c R_ic exp(-j w0 t_ic)`` (one complex64 product); ``snr = max(||R||^2 / sigma^2 - I C, 1)``,
    ``span = clip(5 / sqrt(snr), min(pi, 8 pi / T), pi)``; the dwell ``C (sum_i e_i)^2 / sum_i e_i^2`` of the
    slot energies ``e_i = max(sum_c |R_ic|^2 - C sigma^2, 0)``; the rows with ``5 dwell / sqrt(snr) > pi / 2``
    take the joint angle x Doppler search (``n_h`` hypotheses over the batch, :func:`joint_rho`); the fine
    Doppler (:func:`_doppler_peak`) on ``q_t = sum conj(h_i) rc_it`` (:func:`slot_sums`), Newton steps on the angle.
    """
    n_d, n_i, n_c = res.shape
    w0, rc, th = _coarse_atoms(res, tgrid, hn_conj, candidates, step)
    span, dwell, wide = _search_widths(res, noise_var, float(n_t))
    sub = _indices(wide)
    if sub.size:
        _joint_search(res, sub, w0, th, span, dwell, hn_conj, candidates, step, tgrid, rc)
    h = taylor_atoms(table, u_c, x_c, lo, step, w2, x, th, np.int64(0))[0]
    w = _fine_doppler(h, rc, t, w0, span, n_t, nfft, e_re, e_im, tab_re, tab_im)
    comp = phasors(w, tgrid, -1.0)
    if newton_steps:
        rho_n = np.empty((n_d, n_i), np.complex128)
        slot_projection(res, comp, rho_n)
        th = newton_refine(table, u_c, x_c, lo, step, w2, x, th, rho_n, newton_steps)
    _conjugate(comp)  # exp(j omega t)
    return th, w, comp


@njit
def _coarse_atoms(res: np.ndarray, tgrid: np.ndarray, hn_conj: np.ndarray, candidates: np.ndarray,
                  step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The coarse Doppler ``w0 = arg sum R[i, c+1] R*[i, c]`` (D,), ``rc = R exp(-j w0 t)`` (D, I, C) and the angle of
    the best candidate of ``|H_n^H rho|^2``, ``rho_i = sum_c rc_ic`` (one complex64 product), of residuals R (D, I, C)."""
    n_d, n_i, n_c = res.shape
    th = np.empty(n_d)
    w0 = np.empty(n_d)
    for d in range(n_d):
        acc = 0j
        for i in range(n_i):
            for c in range(n_c - 1):
                acc += res[d, i, c + 1] * np.conj(res[d, i, c])
        w0[d] = np.arctan2(acc.imag, acc.real)
    rc = phasors(w0, tgrid, -1.0)  # then rc = res exp(-j w0 t), in place
    rho = np.empty((n_d, n_i), np.complex64)
    for d in range(n_d):
        for i in range(n_i):
            acc = 0j
            for c in range(n_c):
                v = res[d, i, c] * rc[d, i, c]
                rc[d, i, c] = v
                acc += v
            rho[d, i] = acc
    corr = _power(np.dot(rho, hn_conj))
    for d in range(n_d):
        th[d] = _angle_peak(corr[d], candidates, step)[1]
    return w0, rc, th


@njit
def _fine_doppler(h: np.ndarray, rc: np.ndarray, t: np.ndarray, w0: np.ndarray, span: np.ndarray, n_t: int, nfft: int,
                  e_re: np.ndarray, e_im: np.ndarray, tab_re: np.ndarray, tab_im: np.ndarray) -> np.ndarray:
    """``w0 +`` the Doppler peak (:func:`_doppler_peak`, within ``span``) of ``q_t = sum conj(h_i) rc_it``
    (:func:`slot_sums`) of each row (D,)."""
    n_d = w0.size
    q_re = np.empty(n_t)
    q_im = np.empty(n_t)
    buf_re = np.empty(nfft)
    buf_im = np.empty(nfft)
    w = np.empty(n_d)
    for d in range(n_d):
        slot_sums(h[d], rc[d], t, q_re, q_im)
        w[d] = w0[d] + _doppler_peak(q_re, q_im, span[d], nfft, e_re, e_im, buf_re, buf_im, tab_re, tab_im)
    return w


@njit
def _conjugate(z: np.ndarray) -> None:
    """``z = conj(z)`` of a 3-D complex array, in place."""
    n_a, n_b, n_c = z.shape
    for a in range(n_a):
        for b in range(n_b):
            for c in range(n_c):
                z[a, b, c] = np.conj(z[a, b, c])


@njit
def _amplitudes_pass(s: np.ndarray, a: np.ndarray, valid: np.ndarray, min_amplitude: float) -> np.ndarray:
    """Per row: every valid atom k has ``|s_k| ||a_k|| >= min_amplitude`` (s (D, L), a (D, Q, L), valid (D, L))."""
    norms = atom_norms(a)
    ok = np.ones(s.shape[0], np.bool_)
    for rr in range(s.shape[0]):
        for k in range(s.shape[1]):
            if valid[rr, k] and not np.abs(s[rr, k]) * norms[rr, k] >= min_amplitude:
                ok[rr] = False
    return ok


@njit
def _residual(y: np.ndarray, a: np.ndarray, s: np.ndarray, out: np.ndarray) -> float:
    """``R = y - A s`` written into out (I, C) (y (I C,), a (I C, L), s (L,)); returns ``||R||^2``."""
    n_c = out.shape[1]
    acc = 0.0
    for q in range(y.size):
        fit = 0j
        for k in range(s.size):
            fit += a[q, k] * s[k]
        v = y[q] - fit
        out[q // n_c, q % n_c] = v
        acc += v.real ** 2 + v.imag ** 2
    return acc


@njit
def _set_column(a: np.ndarray, l: int, h: np.ndarray, phase: np.ndarray) -> None:
    """Atom column l of every row: ``a[d, (i, c), l] = h[d, i] phase[d, i, c]`` (a (D, I C, L))."""
    n_d, n_i, n_c = phase.shape
    for d in range(n_d):
        for i in range(n_i):
            for c in range(n_c):
                a[d, i * n_c + c, l] = h[d, i] * phase[d, i, c]


@njit
def _indices(mask: np.ndarray) -> np.ndarray:
    """``np.flatnonzero(mask)`` of a 1-D bool array (a loop, as :func:`_take2`)."""
    n = 0
    for d in range(mask.size):
        n += mask[d]
    out = np.empty(n, np.int64)
    n = 0
    for d in range(mask.size):
        if mask[d]:
            out[n] = d
            n += 1
    return out


@njit
def _valid_pairs(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.nonzero(valid)`` of a 2-D bool array: the valid (row, target) pairs, row-major."""
    n_d, n_l = valid.shape
    n_p = 0
    for d in range(n_d):
        for k in range(n_l):
            n_p += valid[d, k]
    dd = np.empty(n_p, np.int64)
    kk = np.empty(n_p, np.int64)
    p = 0
    for d in range(n_d):
        for k in range(n_l):
            if valid[d, k]:
                dd[p], kk[p] = d, k
                p += 1
    return dd, kk


@njit
def _start(flat: np.ndarray, residual_threshold: np.ndarray, relative_threshold: float,
           detected: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``||data_d||^2``, the stop level ``max(delta_r, rel ||data_d||^2)`` and the rows active at the start (D,)."""
    n_d, n_q = flat.shape
    r2 = np.empty(n_d)
    stop = np.empty(n_d)
    active = np.empty(n_d, np.bool_)
    for d in range(n_d):
        acc = 0.0
        for q in range(n_q):
            v = abs(flat[d, q])
            acc += v * v
        r2[d] = acc
        stop[d] = max(residual_threshold[d], relative_threshold * acc)
        active[d] = detected or acc >= stop[d]
    return r2, stop, active


@njit
def _keep_rows(rows: np.ndarray, ok: np.ndarray, th_r: np.ndarray, om_r: np.ndarray, val_r: np.ndarray,
               s: np.ndarray, a: np.ndarray, theta: np.ndarray, omega: np.ndarray, valid: np.ndarray,
               amp: np.ndarray, atoms: np.ndarray, flat: np.ndarray, resid: np.ndarray, r2: np.ndarray,
               stop: np.ndarray, active: np.ndarray) -> None:
    """Write the accepted rows (``ok``) back and update their residual; a failed row stops (``active`` False)."""
    n_q, n_l = a.shape[1], a.shape[2]
    for rr in range(rows.size):
        d = rows[rr]
        if not ok[rr]:
            active[d] = False
            continue
        for k in range(n_l):
            theta[d, k] = th_r[rr, k]
            omega[d, k] = om_r[rr, k]
            valid[d, k] = val_r[rr, k]
            amp[d, k] = s[rr, k]
        for q in range(n_q):
            for k in range(n_l):
                atoms[d, q, k] = a[rr, q, k]
        r2[d] = _residual(flat[d], a[rr], s[rr], resid[d])
        active[d] = r2[d] >= stop[d]


@njit
def _take2(src: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``src[rows]`` of a 2-D array (a loop: numba's fancy indexing costs seconds of compile per type)."""
    out = np.empty((rows.size, src.shape[1]), src.dtype)
    for r in range(rows.size):
        for k in range(src.shape[1]):
            out[r, k] = src[rows[r], k]
    return out


@njit
def _take3(src: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``src[rows]`` of a 3-D array (a loop, as :func:`_take2`)."""
    out = np.empty((rows.size, src.shape[1], src.shape[2]), src.dtype)
    for r in range(rows.size):
        for q in range(src.shape[1]):
            for k in range(src.shape[2]):
                out[r, q, k] = src[rows[r], q, k]
    return out


@njit
def omp_doppler(table: np.ndarray, u_c: np.ndarray, x_c: float, lo: float, step: float, w2: np.ndarray,
                x: np.ndarray, hn_conj: np.ndarray, candidates: np.ndarray, data: np.ndarray, tgrid: np.ndarray,
                t: np.ndarray, n_t: int, nfft: int, e_re: np.ndarray, e_im: np.ndarray, tab_re: np.ndarray,
                tab_im: np.ndarray, fine_re: np.ndarray, fine_im: np.ndarray, fine_w: np.ndarray, max_targets: int,
                residual_threshold: np.ndarray, noise_var: float, relative_threshold: float, min_amplitude: float,
                newton_steps: int, cycles: int, refine_tol: float,
                detected: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`rhs_env.point_cloud.omp_doppler` in one call: theta, omega, amp, valid (D, L), atoms (D, I C, L), ``||R||^2``.

    Per iteration l on the residuals R of the active rows: the next atom (:func:`_new_atoms`), its column
    ``a_l = h(theta_l) exp(j omega_l t)``, least squares on the support (:func:`lstsq`), the amplitude test
    ``|s_k| ||a_k|| >= min_amplitude`` on every atom (waived for the first atom of a detected row), then,
    from the second atom on, up to ``cycles`` passes of :func:`joint_refine` (a row stops once a pass lowers
    its ``||R||^2`` by less than the fraction ``refine_tol``; the fine DTFT grid ``fine_w``,
    ``fine_re + j fine_im`` (J, n_t)) and the test again; a row that fails stops, the others keep the atom
    and continue while ``||R||^2 >= max(delta_r, rel ||data||^2)``. ``e_re + j e_im`` the twiddles
    ``exp(-2 pi j m / nfft)`` of the Doppler searches, ``tab_re + j tab_im`` the narrow searches' samples
    (:func:`_doppler_peak`).
    """
    n_d, n_i, n_c = data.shape
    n_q = n_i * n_c
    n_l = max_targets
    theta = np.zeros((n_d, n_l))
    omega = np.zeros((n_d, n_l))
    amp = np.zeros((n_d, n_l), np.complex128)
    valid = np.zeros((n_d, n_l), np.bool_)
    atoms = np.zeros((n_d, n_q, n_l), np.complex128)
    flat = data.reshape(n_d, n_q)
    resid = data.copy()
    r2, stop, active = _start(flat, residual_threshold, relative_threshold, detected)
    fine_span = min(np.pi, 8 * np.pi / float(n_t))
    for l in range(n_l):
        rows = _indices(active)
        n_r = rows.size
        if n_r == 0:
            break
        th, w, phase = _new_atoms(table, u_c, x_c, lo, step, w2, x, hn_conj, candidates, _take3(resid, rows), tgrid,
                                  t, n_t, nfft, e_re, e_im, tab_re, tab_im, noise_var, newton_steps)
        th_r = _take2(theta, rows)
        om_r = _take2(omega, rows)
        val_r = _take2(valid, rows)
        a = _take3(atoms, rows)
        h = taylor_atoms(table, u_c, x_c, lo, step, w2, x, th, np.int64(0))[0]
        data_r = _take2(flat, rows)
        for rr in range(n_r):
            th_r[rr, l], om_r[rr, l], val_r[rr, l] = th[rr], w[rr], True
        _set_column(a, l, h, phase)
        s = lstsq(a, data_r)
        for rr in range(n_r):
            for k in range(n_l):
                if not val_r[rr, k]:
                    s[rr, k] = 0
        ok = _amplitudes_pass(s, a, val_r, min_amplitude)
        for rr in range(n_r):
            ok[rr] = ok[rr] or (detected and l == 0)
        kk = _indices(ok)
        if l > 0 and cycles and kk.size:
            span_k = np.empty(kk.size)
            for m in range(kk.size):
                span_k[m] = fine_span
            val_k = _take2(val_r, kk)
            th_k, om_k, s_k, a_k = joint_refine(table, u_c, x_c, lo, step, w2, x, _take2(data_r, kk), tgrid, t, n_t,
                                                fine_re, fine_im, fine_w, nfft, _take2(th_r, kk), _take2(om_r, kk),
                                                val_k, span_k, cycles, newton_steps, _take3(a, kk), _take2(s, kk),
                                                refine_tol)
            ok_k = _amplitudes_pass(s_k, a_k, val_k, min_amplitude)
            for m in range(kk.size):
                rr = kk[m]
                for k in range(n_l):
                    th_r[rr, k] = th_k[m, k]
                    om_r[rr, k] = om_k[m, k]
                    s[rr, k] = s_k[m, k]
                for q in range(n_q):
                    for k in range(n_l):
                        a[rr, q, k] = a_k[m, q, k]
                ok[rr] = ok_k[m]
        _keep_rows(rows, ok, th_r, om_r, val_r, s, a, theta, omega, valid, amp, atoms, flat, resid, r2, stop, active)
    return theta, omega, amp, valid, atoms, r2


#: :func:`omp_doppler` as the radar calls it (:func:`rhs_env.point_cloud.omp_doppler`): compiled, except while a
#: background process compiles it on a cold cache (:mod:`slam.gym.precompile`), when its body and
#: :func:`joint_refine`'s run in Python on their compiled stages (:class:`rhs_common.jit.Tiered`): the same bits,
#: and the env's first step skips the ~8 s numba spends linking and optimising the one-call kernel's tree again.
omp_doppler_tiered = Tiered(omp_doppler, "joint_refine", "_new_atoms")


def warm_refinement(table: np.ndarray, u_c: np.ndarray, x_c: float, lo: float, step: float, w2: np.ndarray,
                    x: np.ndarray, tgrid: np.ndarray, t: np.ndarray, n_t: int, fine_re: np.ndarray, fine_im: np.ndarray,
                    fine_w: np.ndarray, nfft: int, max_targets: int, passes: int, newton_steps: int, tol: float) -> None:
    """Compile (or load) :func:`joint_refine`'s stages and ``_keep_rows`` with the operand types :func:`omp_doppler`
    passes them, on two synthetic rows of two targets (the dictionary's operands as
    :func:`rhs_env.point_cloud.warm_refinement_kernels` gives them): what a background compile
    (:mod:`slam.gym.precompile`) runs while a first scan compiles the search, which then runs :func:`joint_refine`'s body
    on them (:data:`omp_doppler_tiered`)."""
    n_i, n_c = tgrid.shape
    n_q, n_l, n_d = n_i * n_c, max_targets, 2
    rng = np.random.default_rng(1)
    flat = rng.normal(size=(n_d, n_q)) + 1j * rng.normal(size=(n_d, n_q))
    theta = np.zeros((n_d, n_l))
    theta[:, :2] = [0.1, -0.2]
    omega = np.zeros((n_d, n_l))
    valid = np.zeros((n_d, n_l), np.bool_)
    valid[:, :2] = True
    atoms = np.zeros((n_d, n_q, n_l), np.complex128)
    atoms[:, :, :2] = 1.0
    amp = np.zeros((n_d, n_l), np.complex128)
    python_body(joint_refine)(table, u_c, x_c, lo, step, w2, x, flat.copy(), tgrid, t, n_t, fine_re, fine_im, fine_w,
                              nfft, theta.copy(), omega.copy(), valid.copy(), np.full(n_d, 0.05), passes, newton_steps,
                              atoms.copy(), amp.copy(), tol)
    r2, stop, active = _start(flat, np.ones(n_d), 0.1, True)
    _keep_rows(np.arange(n_d, dtype=np.int64), np.ones(n_d, np.bool_), theta.copy(), omega.copy(), valid.copy(),
               amp.copy(), atoms.copy(), theta, omega, valid, amp, atoms, flat, flat.reshape(n_d, n_i, n_c).copy(), r2,
               stop, active)


# --------------------------------------------------------------------------- scene
@njit
def face_scatterers(pos: np.ndarray, heading: np.ndarray, vel: np.ndarray, yaw_rate: np.ndarray, length: np.ndarray,
                    width: np.ndarray, ego: np.ndarray, points_per_face: int,
                    vehicle_rcs: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`rhs_env.scene._face_scatterers`' points and occluders of V boxes, vehicle frame, in one pass.

    World-frame boxes (``pos`` (V, 2), ``heading``, ``vel`` (V, 2), ``yaw_rate``, ``length``, ``width`` (V,)) seen
    from the ego ``ego = (x, y, heading, vx, vy, yaw rate)``: centre ``c = R^T (pos - p_ego)``, faces f with
    outward normals n_f and tangents t_f (the box's rotation by ``heading - heading_ego`` applied to
    ``(1, 0), (0, 1), (-1, 0), (0, -1)`` and ``(0, 1), (-1, 0), (0, -1), (1, 0)``), half-extents
    ``(L, W, L, W) / 2`` and lengths ``(W, L, W, L)``; ``mid = c + n_f half_f``; a face is visible when
    ``cos_inc = -n_f . mid / |mid| > 1e-9`` and shares ``vehicle_rcs`` in proportion to ``len_f cos_inc`` over its
    ``points_per_face`` points ``mid + t_f ((k + 1/2) / P - 1/2) len_f``, whose velocity is
    ``R^T (v - v_ego) + w x (q - c) - w_ego x q``. Returns the points of the visible faces in (box, face,
    point) order: xy, velocity (K, 2), rcs (K,), each point's box (K,) int64; and every face as an occluder
    segment (corner, end) (4 V, 2, 2). The numpy reference's operations element by element.
    """
    n_v = pos.shape[0]
    p = points_per_face
    ct, st = np.cos(-ego[2]), np.sin(-ego[2])  # R^T = rotation(-heading_ego)
    xy = np.empty((4 * n_v * p, 2))
    velocity = np.empty((4 * n_v * p, 2))
    rcs = np.empty(4 * n_v * p)
    box = np.empty(4 * n_v * p, np.int64)
    segments = np.empty((4 * n_v, 2, 2))
    face = np.empty((4, 6))  # per face: mid x, mid y, tangent x, tangent y, length, weight
    q = 0
    for v in range(n_v):
        d0, d1 = pos[v, 0] - ego[0], pos[v, 1] - ego[1]
        c0, c1 = d0 * ct + d1 * -st, d0 * st + d1 * ct
        e0, e1 = vel[v, 0] - ego[3], vel[v, 1] - ego[4]
        w0, w1 = e0 * ct + e1 * -st, e0 * st + e1 * ct
        cr, sr = np.cos(heading[v] - ego[2]), np.sin(heading[v] - ego[2])
        total = 0.0
        for f in range(4):  # normal (cr, sr) turned by f quarter turns, the tangent a quarter turn further
            sign = 1.0 if f < 2 else -1.0
            even = f % 2 == 0
            n0 = sign * cr if even else sign * -sr
            n1 = sign * sr if even else sign * cr
            half = (length[v] if even else width[v]) / 2
            flen = width[v] if even else length[v]
            m0 = c0 + n0 * half
            m1 = c1 + n1 * half
            cos_inc = -(n0 * m0 + n1 * m1) / max(np.sqrt(m0 * m0 + m1 * m1), 1e-9)
            wgt = flen * cos_inc if cos_inc > 1e-9 else 0.0
            total += wgt
            face[f, 0], face[f, 1], face[f, 2], face[f, 3], face[f, 4], face[f, 5] = m0, m1, -n1, n0, flen, wgt
            h0, h1 = -n1 * (flen / 2), n0 * (flen / 2)
            segments[4 * v + f, 0, 0], segments[4 * v + f, 0, 1] = m0 - h0, m1 - h1
            segments[4 * v + f, 1, 0], segments[4 * v + f, 1, 1] = m0 + h0, m1 + h1
        for f in range(4):
            if face[f, 5] <= 0:
                continue
            share = face[f, 5] / total if total > 0 else 0.0
            for k in range(p):
                frac = (k + 0.5) / p - 0.5
                x0 = face[f, 0] + face[f, 2] * (frac * face[f, 4])
                x1 = face[f, 1] + face[f, 3] * (frac * face[f, 4])
                xy[q, 0], xy[q, 1] = x0, x1
                velocity[q, 0] = (w0 + yaw_rate[v] * -(x1 - c1)) - ego[5] * -x1
                velocity[q, 1] = (w1 + yaw_rate[v] * (x0 - c0)) - ego[5] * x0
                rcs[q] = vehicle_rcs * share / p
                box[q] = v
                q += 1
    return xy[:q], velocity[:q], rcs[:q], box[:q], segments


# --------------------------------------------------------------------------- line of sight
@njit
def line_of_sight(origins: np.ndarray, points: np.ndarray, segments: np.ndarray, point_object: np.ndarray,
                  segment_object: np.ndarray, candidates: np.ndarray, eps: float) -> np.ndarray:
    """``candidates & visible_mask(origins, ...)`` (R, K) of :func:`rhs_env.scatterers.visible_mask`, per pair.

    The segment ``o -> p`` of radar r and point k is hidden when it crosses an occluder segment ``a -> a + e``
    of another object: with ``d = p - o``, ``f = a - o`` and ``x(u, v) = u_x v_y - u_y v_x``,
    ``den = x(d, e)``, ``u = x(f, e) / den``, ``w = x(f, d) / den``, a crossing is ``|den| > 1e-12``,
    ``eps < u < 1 - eps``, ``0 <= w <= 1``: the reference's operations per (r, k, s), evaluated only for the
    candidate pairs (in the field of view) and up to the first crossing.
    """
    n_r, n_k = candidates.shape
    n_s = segments.shape[0]
    out = np.zeros((n_r, n_k), np.bool_)
    e0 = np.empty(n_s)
    e1 = np.empty(n_s)
    for s in range(n_s):
        e0[s] = segments[s, 1, 0] - segments[s, 0, 0]
        e1[s] = segments[s, 1, 1] - segments[s, 0, 1]
    u_hi = 1.0 - eps
    for r in range(n_r):
        for k in range(n_k):
            if not candidates[r, k]:
                continue
            d0 = points[k, 0] - origins[r, 0]
            d1 = points[k, 1] - origins[r, 1]
            seen = True
            for s in range(n_s):
                if point_object[k] == segment_object[s]:
                    continue
                f0 = segments[s, 0, 0] - origins[r, 0]
                f1 = segments[s, 0, 1] - origins[r, 1]
                den = d0 * e1[s] - d1 * e0[s]
                if not abs(den) > 1e-12:
                    continue
                u = (f0 * e1[s] - f1 * e0[s]) / den
                w = (f0 * d1 - f1 * d0) / den
                if u > eps and u < u_hi and w >= 0.0 and w <= 1.0:
                    seen = False
                    break
            out[r, k] = seen
    return out


# --------------------------------------------------------------------------- points
@njit
def range_offsets(pw: np.ndarray, half: int) -> np.ndarray:
    """Per-target range offset from the detection's bin (D, L), padded bins: :meth:`rhs_env.radar.RadarSystem._target_bins`.

    ``pw[d, l, w] = log |s_dl(k_d + w - half)|^2`` over the W neighbouring bins; ``j`` the first interior maximum
    (``1 + argmax pw[d, l, 1:W-1]``), then the vertex of the parabola through ``(ym, y0, yp) = pw[d, l, j-1..j+1]``
    (:func:`rhs_env.point_cloud.parabolic_offset`): ``den = ym - 2 y0 + yp``, ``delta = 0.5 (ym - yp) / den`` where
    ``den < 0`` (else 0), clipped to [-0.5, 0.5]; the offset is ``j - half + delta``.
    """
    n_d, n_l, n_w = pw.shape
    out = np.empty((n_d, n_l))
    for d in range(n_d):
        for l in range(n_l):
            j = 1
            best = pw[d, l, 1]
            for w in range(2, n_w - 1):
                if pw[d, l, w] > best:
                    best, j = pw[d, l, w], w
            ym, y0, yp = pw[d, l, j - 1], pw[d, l, j], pw[d, l, j + 1]
            den = ym - 2.0 * y0 + yp
            delta = 0.5 * (ym - yp) / den if den < 0 else 0.0
            out[d, l] = (j - half) + min(max(delta, -0.5), 0.5)
    return out


@njit
def assemble_points(rd: np.ndarray, kd: np.ndarray, theta: np.ndarray, omega: np.ndarray, amp_abs: np.ndarray,
                    valid: np.ndarray, anorm: np.ndarray, tfrac: np.ndarray, positions: np.ndarray,
                    boresights: np.ndarray, wavelength: float, four_pi_chirp_s: float, sample_rate_hz: float,
                    zero_pad: float, samples: float, c0: float, slope: float, sigma_y: float, min_range_m: float,
                    max_range_m: float, leak: np.ndarray, same_angle: float,
                    margin: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The points of the valid targets (:meth:`rhs_env.radar.RadarSystem._assemble_points`), in ``np.nonzero(valid)`` order.

    Per valid target (d, l) of radar ``r = rd_d``: radial velocity ``v = wrap(omega) lambda / (4 pi T_c)``
    (``wrap(a) = (a + pi) mod 2 pi - pi``), beat frequency ``f = (kd_d + tfrac) f_s / (Z N) - 2 v / lambda``,
    range ``R = c0 f / (2 S)``, position ``p_r + R (cos, sin)(boresight_r + theta)``, amplitude
    ``a = |s| ||atom|| / sigma_Y`` (``amp_abs = |s|`` from numpy: its complex absolute value is its own SIMD
    algorithm, not ``hypot``). Kept: ``min_range_m <= R <= max_range_m`` and not a range sidelobe
    (:meth:`rhs_env.radar.RadarSystem._sidelobe_points`): with ``b = R 2 S / c0 Z N / f_s`` (padded bins),
    ``a^2 < margin max a'^2 leak(|rint(b - b')|)`` over the stronger targets of the same radar within
    ``same_angle`` is a sidelobe. Returns rows (x, y, v, a) (N, 4), radar (N,), R (N,) and theta (N,).
    """
    n_d, n_l = valid.shape
    n = 0
    for d in range(n_d):
        for l in range(n_l):
            n += valid[d, l]
    vel = np.empty(n)
    rng_m = np.empty(n)
    th = np.empty(n)
    a = np.empty(n)
    radar = np.empty(n, np.int64)
    q = 0
    two_pi = 2 * np.pi
    for d in range(n_d):
        for l in range(n_l):
            if not valid[d, l]:
                continue
            v = ((omega[d, l] + np.pi) % two_pi - np.pi) * wavelength / four_pi_chirp_s
            f_beat = (kd[d] + tfrac[d, l]) * sample_rate_hz / (zero_pad * samples) - 2 * v / wavelength
            vel[q] = v
            rng_m[q] = c0 * f_beat / (2 * slope)
            th[q] = theta[d, l]
            radar[q] = rd[d]
            a[q] = amp_abs[d, l] * anorm[d, l] / sigma_y
            q += 1
    keep = np.empty(n, np.bool_)
    n_keep = 0
    for p in range(n):
        side = False
        if n >= 2:
            bins_p = rng_m[p] * 2 * slope / c0 * zero_pad * samples / sample_rate_hz
            a2 = a[p] ** 2
            worst = 0.0
            for o in range(n):
                if radar[o] == radar[p] and abs(th[p] - th[o]) < same_angle and a[o] ** 2 > a2:
                    bins_o = rng_m[o] * 2 * slope / c0 * zero_pad * samples / sample_rate_hz
                    dk = min(int(abs(np.rint(bins_p - bins_o))), leak.size - 1)
                    worst = max(worst, a[o] ** 2 * leak[dk])
            side = a2 < margin * worst
        keep[p] = (rng_m[p] >= min_range_m) and (rng_m[p] <= max_range_m) and not side
        n_keep += keep[p]
    pts = np.empty((n_keep, 4))
    radar_k = np.empty(n_keep, np.int64)
    rng_k = np.empty(n_keep)
    th_k = np.empty(n_keep)
    q = 0
    for p in range(n):
        if keep[p]:
            ang = boresights[radar[p]] + th[p]
            pts[q, 0] = positions[radar[p], 0] + rng_m[p] * np.cos(ang)
            pts[q, 1] = positions[radar[p], 1] + rng_m[p] * np.sin(ang)
            pts[q, 2] = vel[p]
            pts[q, 3] = a[p]
            radar_k[q], rng_k[q], th_k[q] = radar[p], rng_m[p], th[p]
            q += 1
    return pts, radar_k, rng_k, th_k
