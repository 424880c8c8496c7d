"""Compiled stages of the Doppler OMP (numba), each the numpy function of :mod:`rhs_env.point_cloud` it names.

The stages the step-by-step OMP calls one by one, and the one-call OMP (:mod:`rhs_env.kernels.omp`) strings
together: the chirp phasors (:func:`phasors`), the Doppler-compensated slot vectors (:func:`joint_rho`), the atoms'
norms and angle information, the least squares (:func:`lstsq`, :func:`bin_amplitudes`: vectorised ``A^H A`` and
``A^H y`` sums, ~1e-15 relative), the bins of the detections (:func:`gather_bins`), the narrow Doppler searches'
DTFT (:func:`doppler_dtft_refine`) and the cyclic refinement of every atom (:func:`joint_refine`); and the small
loops both OMPs share (:func:`dtft_row`, :func:`residual_into`, :func:`mask_indices`, :func:`take_rows2`,
:func:`take_rows3`: loops, not numba's fancy indexing, which costs seconds of compile).
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import njit
from rhs_env.kernels.atoms import newton_refine, taylor_atoms

__all__ = [
    "RAMP", "angle_information", "atom_norms", "bin_amplitudes", "doppler_dtft_refine", "dtft_row", "gather_bins",
    "joint_refine", "joint_rho", "lstsq", "mask_indices", "phasors", "residual_into", "slot_projection", "slot_sums",
    "take_rows2", "take_rows3",
]


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
    :meth:`rhs_env.radar.estimation.AngleEstimator.target_bins`) and the OMP's data ``y[d, i, c] = Y[rd_d, i, c, kk_d,centre]``
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
    :meth:`rhs_env.radar.estimation.AngleEstimator.target_bins`.

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
    separate float32 sums of the complex64 values (:func:`dtft_row`: vectorised, the sums' order free, as the
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
            val[j] = dtft_row(q32r, q32i, kern_re[j], kern_im[j])
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
    (:func:`residual_into`, ``resid`` (I, C) its work space)."""
    s_r = lstsq(take_rows3(a, rows), take_rows2(flat, rows))
    for r in range(rows.size):
        d = rows[r]
        for l in range(s.shape[1]):
            s[d, l] = s_r[r, l]
        if tol > 0:
            r2_new = residual_into(flat[d], a[d], s[d], resid)
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
            r2[d] = residual_into(flat[d], a[d], s[d], resid)
    for _ in range(passes):
        sel = mask_indices(moving[dd])  # the pairs of the moving rows, row-major
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


@njit(fastmath={"reassoc", "contract"})
def dtft_row(q_re: np.ndarray, q_im: np.ndarray, k_re: np.ndarray, k_im: np.ndarray) -> float:
    """``|sum_t q_t k_t|^2`` for one row ``k = k_re + j k_im`` of a DTFT table, q and k float32 (complex64 values, as
    the reference's complex64 product): float32 sums, their order free (vectorised, 16 lanes), squared in float64."""
    sr = np.float32(0.0)
    si = np.float32(0.0)
    for tt in range(q_re.size):
        sr += q_re[tt] * k_re[tt] - q_im[tt] * k_im[tt]
        si += q_re[tt] * k_im[tt] + q_im[tt] * k_re[tt]
    return np.float64(sr) * np.float64(sr) + np.float64(si) * np.float64(si)


@njit
def residual_into(y: np.ndarray, a: np.ndarray, s: np.ndarray, out: np.ndarray) -> float:
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
def mask_indices(mask: np.ndarray) -> np.ndarray:
    """``np.flatnonzero(mask)`` of a 1-D bool array (a loop, as :func:`take_rows2`)."""
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
def take_rows2(src: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``src[rows]`` of a 2-D array (a loop: numba's fancy indexing costs seconds of compile per type)."""
    out = np.empty((rows.size, src.shape[1]), src.dtype)
    for r in range(rows.size):
        for k in range(src.shape[1]):
            out[r, k] = src[rows[r], k]
    return out


@njit
def take_rows3(src: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``src[rows]`` of a 3-D array (a loop, as :func:`take_rows2`)."""
    out = np.empty((rows.size, src.shape[1], src.shape[2]), src.dtype)
    for r in range(rows.size):
        for q in range(src.shape[1]):
            for k in range(src.shape[2]):
                out[r, q, k] = src[rows[r], q, k]
    return out
