"""The Doppler OMP in one compiled call (numba): :func:`rhs_env.point_cloud.omp_doppler` for every detection of a scan.

:func:`omp_doppler` runs the new-atom search, the least squares, the stop rules and the refinement of
:mod:`rhs_env.kernels.omp_stages` in loops (numba's fancy indexing, ``np.where`` and array expressions cost seconds
of compile each). On a cold cache a background process compiles it (:mod:`slam.gym.precompile`) while the scans run
its body in Python on the compiled stages (:data:`omp_doppler_tiered`, the same bits); :func:`warm_refinement`
compiles the refinement's stages with the operand types the OMP passes them.
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import Tiered, njit, python_body
from rhs_env.kernels.atoms import newton_refine, taylor_atoms
from rhs_env.kernels.omp_stages import (
    atom_norms,
    dtft_row,
    joint_refine,
    joint_rho,
    lstsq,
    mask_indices,
    phasors,
    residual_into,
    slot_projection,
    slot_sums,
    take_rows2,
    take_rows3,
)

__all__ = ["omp_doppler", "omp_doppler_tiered", "warm_refinement"]


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
                    v = dtft_row(q32r, q32i, tab_re[jj + tab_h], tab_im[jj + tab_h])
                else:
                    v = _dtft_at(q_re, q_im, jj, nfft, e_re, e_im)
                if v > best:
                    best = v
                    jb = jj
        jb = min(max(jb, -half + 1), half - 1)
        if half <= tab_h:
            vm = dtft_row(q32r, q32i, tab_re[jb - 1 + tab_h], tab_im[jb - 1 + tab_h])
            v0 = dtft_row(q32r, q32i, tab_re[jb + tab_h], tab_im[jb + tab_h])
            vp = dtft_row(q32r, q32i, tab_re[jb + 1 + tab_h], tab_im[jb + 1 + tab_h])
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
    sub = mask_indices(wide)
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
def _set_column(a: np.ndarray, l: int, h: np.ndarray, phase: np.ndarray) -> None:
    """Atom column l of every row: ``a[d, (i, c), l] = h[d, i] phase[d, i, c]`` (a (D, I C, L))."""
    n_d, n_i, n_c = phase.shape
    for d in range(n_d):
        for i in range(n_i):
            for c in range(n_c):
                a[d, i * n_c + c, l] = h[d, i] * phase[d, i, c]


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
        r2[d] = residual_into(flat[d], a[rr], s[rr], resid[d])
        active[d] = r2[d] >= stop[d]


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
        rows = mask_indices(active)
        n_r = rows.size
        if n_r == 0:
            break
        th, w, phase = _new_atoms(table, u_c, x_c, lo, step, w2, x, hn_conj, candidates, take_rows3(resid, rows), tgrid,
                                  t, n_t, nfft, e_re, e_im, tab_re, tab_im, noise_var, newton_steps)
        th_r = take_rows2(theta, rows)
        om_r = take_rows2(omega, rows)
        val_r = take_rows2(valid, rows)
        a = take_rows3(atoms, rows)
        h = taylor_atoms(table, u_c, x_c, lo, step, w2, x, th, np.int64(0))[0]
        data_r = take_rows2(flat, rows)
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
        kk = mask_indices(ok)
        if l > 0 and cycles and kk.size:
            span_k = np.empty(kk.size)
            for m in range(kk.size):
                span_k[m] = fine_span
            val_k = take_rows2(val_r, kk)
            th_k, om_k, s_k, a_k = joint_refine(table, u_c, x_c, lo, step, w2, x, take_rows2(data_r, kk), tgrid, t, n_t,
                                                fine_re, fine_im, fine_w, nfft, take_rows2(th_r, kk), take_rows2(om_r, kk),
                                                val_k, span_k, cycles, newton_steps, take_rows3(a, kk), take_rows2(s, kk),
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
