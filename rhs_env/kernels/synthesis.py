"""Compiled signal synthesis (numba): the radar's noise and tone spectra (:meth:`rhs_env.radar.RadarSystem.synthesize_spectrum`).

:func:`noise_uniforms` and :func:`noise_samples` fuse the elementwise float32 passes of the receiver noise (the
transcendental functions stay numpy's, whose SIMD numba's wheels lack); :func:`tone_spectra` and
:func:`tone_operands` build the windowed unit-tone spectra and the gain x Doppler operands, and
:func:`add_tone_products` adds each radar's tone product into the spectrum with scipy's BLAS (float32 round-off from
the numpy reference's own product).
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import njit
from rhs_common.native import matmul_add

__all__ = ["add_tone_products", "noise_samples", "noise_uniforms", "tone_operands", "tone_spectra"]


@njit
def noise_uniforms(words: np.ndarray, scale: np.float32, half: np.float32, two_pi: np.float32, neg_u1: np.ndarray,
                   phase: np.ndarray) -> None:
    """The polar method's inputs of :meth:`rhs_env.radar.noise.ReceiverNoise.spectrum` from raw 32-bit words, in one pass.

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
    """The operands of ``Y_s[r] = G_r @ E_r`` (:func:`rhs_env.radar.synthesis.mix_tones`), complex64, the tones in order.

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
