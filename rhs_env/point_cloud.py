"""Point-cloud generation from swept-beam FMCW echoes (paper section VI).

Processing chain for one radar with I beam slots and C chirps per slot; the
dechirped samples ``y[i, c, n]`` (n = 0..N-1 at ``f_s``) are already the sum of
complex tones, one per scatterer (see :mod:`rhs_env.radar`):

1. **Range (matched filter).** For a linear chirp, correlating the echo with the
   transmitted chirp equals dechirping and taking the Fourier transform, so the
   range profile of slot i, chirp c is the windowed, zero-padded FFT

       Y[i, c, k] = sum_n w[n] y[i, c, n] exp(-j 2 pi k n / (Z N)),

   bin k <-> beat frequency ``f = k f_s / (Z N)`` <-> range ``R = c0 f / (2 S)``
   with the chirp slope ``S = B / T_c`` (bin width ``c0 / (2 B)`` = 0.6 m before
   the zero padding Z).
2. **Detection.** The slot-combined profile ``P[k] = sum_{i,c} |Y[i, c, k]|^2``
   (non-coherent integration over the sweep; pure noise makes each cell a
   Gamma(L = I C) variable) is compared with a cell-averaging CFAR threshold
   ``alpha * mean(training cells)``; with a Gamma(L) test cell and N_t
   independent Gamma(L) training cells, ``P / mean`` is F(2L, 2 N_t L)
   distributed, so ``alpha = F^{-1}(1 - P_fa; 2L, 2 N_t L)`` exactly (training
   cells are taken one per unpadded bin, which the window leaves weakly
   correlated); the ordered-statistic variant (default) uses the rank-th
   smallest training cell. The noise estimate is clipped between the
   receiver's calibrated noise floor and ``cap`` above it: the slot sum mixes
   every direction, so the training cells of a landmark hold the returns of
   vehicles at other angles, and an unclipped CFAR would mask it. Option
   ``fixed``: the paper's threshold ``delta_d`` in dB above the noise mean of
   P. Detections are local maxima above the threshold; peaks that the window's
   sidelobes under a stronger peak explain are dropped.
3. **Angle and velocity (OMP over H).** At a detected bin the data over slots
   and chirps obey ``Y[i, c] = sum_k s_k h_i(theta_k) exp(j omega_k t_ic) + noise``
   with ``H[i, j] = h_i(theta_j)`` (two-way gain of slot i toward candidate j;
   candidates finer than dtheta), ``t_ic = i C + c`` the chirp time over the
   sweep and ``omega = 4 pi v T_c / lambda`` the chirp-to-chirp Doppler phase
   (|v| < lambda / (4 T_c)). OMP (paper Algorithm 1, loop condition corrected
   to "l <= L_max AND ||r||^2 >= delta_r", :func:`omp_doppler`): on the
   residual, a coarse Doppler from the chirp pairs ``arg sum r[i, c+1] r*[i, c]``,
   the best candidate of ``|h_j^H rho| / ||h_j||`` for the Doppler-compensated
   slot vector ``rho_i = sum_c r_ic exp(-j omega t_ic)`` (a joint angle x Doppler
   grid when the Doppler uncertainty matters over the target's dwell), fine
   Doppler over the whole sweep, angle refinement below the candidate spacing
   (parabola through the log-correlation, then Newton steps on
   ``f(theta) = |h(theta)^H rho|^2 / ||h(theta)||^2`` with the analytic
   derivatives of h), least squares for all amplitudes, cyclic re-refinement
   of every atom against its own partial residual (as in Newtonized OMP).
   Stop when ``||r||^2 < delta_r = sigma_Y^2 Gamma^{-1}(1 - p; I C)`` (the
   residual noise alone leaves with probability p), below a fraction of the
   data power (the dynamic range of the angle model), when a new atom is
   weaker than ``min_amplitude``, or after L_max atoms.
   The dictionary and the OMP are in :mod:`rhs_env.omp` (their compiled twin in :mod:`rhs_env.kernels.omp`),
   re-exported here.
4. **Range per target.** The least-squares amplitude of each atom at the
   neighbouring range bins gives its own range profile; a parabola through its
   log-peak refines the range below a bin (two targets in one bin keep their
   own ranges). The within-chirp Doppler shift ``2 v / lambda`` of the beat
   frequency is removed: ``R = c0 (f - 2 v / lambda) / (2 S)``.
5. **Points.** ``(x, y) = radar position + R (cos, sin)(boresight + theta)``,
   radial velocity ``v = omega lambda / (4 pi T_c)``, amplitude
   ``|s| ||a|| / sigma_Y`` (the amplitude SNR of the target over the sweep,
   linear; ``a`` the atom over slots and chirps).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import scipy.fft as sfft
from scipy import stats

from rhs_env import omp as _omp
from rhs_env.array_models import ArrayAntenna
from rhs_env.omp import (
    AngleDictionary,
    DopplerOMPResult,
    OMPResult,
    atom_norms,
    joint_refine,
    omp_angles,
    omp_doppler,
    parabolic_offset,
    residual_threshold,
    warm_refinement_kernels,
)
from rhs_env.windows import make_window

__all__ = [
    "AngleDictionary", "DopplerOMPResult", "NOISE_ALIAS_TOL", "OMPResult", "PointCloud", "angle_crb", "atom_norms",
    "ca_cfar_threshold", "cfar_alpha", "joint_refine", "local_maxima", "noise_decimation", "omp_angles",
    "omp_doppler", "os_cfar_alpha", "os_cfar_threshold", "parabolic_offset", "pointcloud_metrics", "range_crb",
    "range_fft", "residual_threshold", "tone_spectra", "warm_refinement_kernels", "window_exponentials",
    "window_leak_envelope",
]


# --------------------------------------------------------------------------- output
@dataclass
class PointCloud:
    """Radar detections of one cycle (all four radars).

    Attributes:
        points: (N, 4) float: x, y (vehicle frame, m), radial velocity (m/s,
            > 0 receding), amplitude (linear amplitude SNR over the sweep).
        radar: (N,) int, index of the radar (0 front, 1 left, 2 rear, 3 right).
        range_m: (N,) range from the radar, m.
        angle_rad: (N,) angle from the radar's boresight, rad (CCW positive).
        range_std_m: (N,) range standard deviation, m (CRB at the point's SNR + floor,
            :mod:`rhs_env.uncertainty`).
        angle_std_rad: (N,) angle standard deviation, rad (idem).
        stage_times: wall time per stage, s: ``synthesis``, ``range_cfar``, ``omp``.
    """

    points: np.ndarray
    radar: np.ndarray
    range_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    angle_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    range_std_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    angle_std_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stage_times: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return self.points.shape[0]

    @property
    def xy(self) -> np.ndarray:
        return self.points[:, :2]


# --------------------------------------------------------------------------- range
def range_fft(y: np.ndarray, window: np.ndarray, zero_pad: int, bins: slice | None = None) -> np.ndarray:
    """Windowed, zero-padded FFT over the last axis (the FMCW matched filter).

    ``Y[..., k] = sum_n w[n] y[..., n] exp(-j 2 pi k n / (Z N))``; returns the
    bins in ``bins`` (default all Z N), complex64.
    """
    n = y.shape[-1]
    out = sfft.fft(y * window, n=zero_pad * n, axis=-1, workers=1)
    return out if bins is None else out[..., bins]


@functools.lru_cache(maxsize=32)
def window_exponentials(name: str, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The window as a short sum of complex exponentials, ``w[n] = sum_m c_m exp(j 2 pi mu_m n)``.

    Every window of :data:`rhs_env.windows.WINDOWS` is a cosine sum: hann, hamming and blackman
    (scipy's symmetric forms) with period N - 1, taylor with period N, boxcar a
    constant; the coefficients are fitted by least squares on the frequencies
    ``mu = m / (N - 1)`` (else ``m / N``), |m| <= 4, and the fit is checked exact
    (max error < 1e-6 of the peak: the float32 rounding of the window used by
    the IQ path). Returns (mu, c) for :func:`tone_spectra`.
    """
    w = make_window(name, n).astype(float)
    for period in (n - 1, n):
        mu = np.arange(-4, 5) / period
        basis = np.exp(2j * np.pi * np.arange(n)[:, None] * mu[None, :])
        coef = np.linalg.lstsq(basis, w.astype(complex), rcond=None)[0]
        keep = np.abs(coef) > 1e-6 * np.abs(coef).max()  # the window's own terms; the rest fits float32 rounding
        mu, coef = mu[keep], np.linalg.lstsq(basis[:, keep], w.astype(complex), rcond=None)[0]
        if np.abs(basis[:, keep] @ coef - w).max() <= 1e-6 * np.abs(w).max():
            return mu, coef
    raise ValueError(f"window {name!r} is not a short cosine sum of period N - 1 or N")


def tone_spectra(name: str, n: int, zero_pad: int, n_bins: int, freq: np.ndarray) -> np.ndarray:
    """Windowed, zero-padded spectra of unit tones ``exp(j 2 pi f_p n)``, bins ``k < n_bins``: (P, n_bins) complex128.

    ``S_p[k] = sum_n w[n] exp(j 2 pi (f_p - k / (Z N)) n) = sum_m c_m D(k / (Z N) - f_p - mu_m)``
    in closed form, with ``w[n] = sum_m c_m exp(j 2 pi mu_m n)`` (:func:`window_exponentials`)
    and the Dirichlet kernel ``D(x) = sum_{n<N} exp(-j 2 pi x n) = exp(-j pi x (N-1)) sin(pi N x) / sin(pi x)``
    (``N cos(pi N x) / cos(pi x)`` where ``sin(pi x) = 0``). ``freq`` in cycles per sample.
    With ``e(x) = exp(j pi x)`` separable in the bin and the tone,
    ``e(x) = e(k / (Z N)) e(-f_p - mu_m)``, no transcendental function is taken per (tone, bin).
    """
    mu, coef = window_exponentials(name, n)
    k = np.arange(n_bins)[None, :, None] / (zero_pad * n)
    fm = (np.asarray(freq, float)[:, None] + mu[None, :])[:, None, :]  # f + mu, (P, 1, J)
    e1 = np.exp(1j * np.pi * k) * np.exp(-1j * np.pi * fm)  # e(x)
    en = np.exp(1j * np.pi * n * k) * np.exp(-1j * np.pi * n * fm)  # e(N x)
    s1, sn = e1.imag, en.imag
    near = np.abs(s1) < 1e-12
    ratio = np.where(near, n * en.real / np.where(near, e1.real, 1.0), sn / np.where(near, 1.0, s1))
    return np.sum(coef * np.conj(en) * e1 * ratio, axis=-1)  # exp(-j pi x (N - 1)) = e(N x)^* e(x)


#: the largest |R(d)| / R(0) of the alias term that half-rate noise synthesis may add on the searched bins
NOISE_ALIAS_TOL = 1e-4


def noise_decimation(window: np.ndarray, zero_pad: int, n_bins: int, tol: float = NOISE_ALIAS_TOL) -> int:
    """Rate divisor D (2 or 1) at which the noise of the first ``n_bins`` bins of a windowed FFT may be drawn.

    The bins ``k < K`` of ``FFT_{Z N}(w * eps)``, eps white, have the covariance
    ``R(k - l) = sum_n w[n]^2 exp(-j 2 pi (k - l) n / (Z N))``. Drawn at half rate
    (``sqrt(2) w[2 m] eps[m]``, m < N / 2, FFT of ``Z N / 2`` bins) they have
    ``R(k - l) + R(k - l + Z N / 2)``: exact up to the alias term, whose lags are
    ``Z N / 2 - K < |d'| < Z N / 2 + K``. D = 2 when N is even and that term stays
    under ``tol`` R(0) there (a Hann window, N = 400, Z = 2, K = 334: 3e-8; a boxcar's
    slow sidelobes are not), else 1.
    """
    n = len(window)
    if n % 2 or n_bins >= zero_pad * n // 2:
        return 1
    r = np.abs(np.fft.fft(np.asarray(window, float) ** 2, zero_pad * n))
    lags = np.arange(zero_pad * n // 2 - n_bins + 1, zero_pad * n // 2 + n_bins) % (zero_pad * n)
    return 2 if r[lags].max() <= tol * r[0] else 1


def cfar_alpha(pfa: float, looks: int, train_cells: int) -> float:
    """CA-CFAR multiplier for Gamma(looks) cells: ``F^{-1}(1 - pfa; 2 looks, 2 train_cells looks)``."""
    return float(stats.f.isf(pfa, 2 * looks, 2 * train_cells * looks))


def ca_cfar_threshold(profile: np.ndarray, guard: int, train: int, stride: int, alpha: float,
                      floor: float = 0.0, cap: float = np.inf) -> np.ndarray:
    """Cell-averaging CFAR threshold along the last axis.

    For cell k the training cells are ``k +- (guard + 1 .. guard + train) * stride``
    (``stride`` = zero-padding factor, so one training cell per unpadded bin);
    cells beyond the ends are dropped and the mean is over the cells present.
    Returns ``alpha * clip(mean, floor, cap)``, same shape as ``profile``.
    """
    p = np.asarray(profile, dtype=np.float64)
    n = p.shape[-1]
    offsets = np.concatenate([-np.arange(guard + 1, guard + train + 1), np.arange(guard + 1, guard + train + 1)])
    idx = np.arange(n)[:, None] + stride * offsets[None, :]  # (n, 2 train)
    valid = (idx >= 0) & (idx < n)
    vals = np.take(p, np.clip(idx, 0, n - 1), axis=-1)  # (..., n, 2 train)
    mean = (vals * valid).sum(-1) / np.maximum(valid.sum(-1), 1)
    return alpha * np.clip(mean, floor, cap)


@functools.lru_cache(maxsize=64)  # a pure function of its scalars; ~5 s of quadrature per call
def os_cfar_alpha(pfa: float, looks: int, train_cells: int, rank: int) -> float:
    """OS-CFAR multiplier: threshold ``alpha * Y_(rank)`` (rank-th smallest of the training cells).

    Pure noise: test cell X and training cells Gamma(looks, 1) i.i.d.; the rank-th
    order statistic is ``F^{-1}(B)`` with ``B ~ Beta(rank, N - rank + 1)``, so

        P_fa(alpha) = int_0^1 S_X(alpha F^{-1}(b)) f_B(b) db,

    solved for alpha (quadrature + root finding; S_X, F the Gamma survival and cdf).
    """
    from scipy import integrate, optimize

    g = stats.gamma(looks)
    b = stats.beta(rank, train_cells - rank + 1)

    def pf(alpha: float) -> float:
        f = lambda p: g.sf(alpha * g.ppf(b.ppf(p)))
        val, _ = integrate.quad(f, 0.0, 1.0, limit=200, points=[1e-6, 1e-4, 1e-2])
        return val

    la = optimize.brentq(lambda x: math.log(max(pf(math.exp(x)), 1e-300)) - math.log(pfa), 0.0, 6.0, xtol=1e-7)
    return float(math.exp(la))


def os_cfar_threshold(profile: np.ndarray, guard: int, train: int, stride: int, alpha: float, rank: int,
                      floor: float = 0.0, cap: float = np.inf) -> np.ndarray:
    """Ordered-statistic CFAR threshold along the last axis: ``alpha * clip(Y_(rank), floor, cap)``.

    Training cells as in :func:`ca_cfar_threshold`; near the ends the missing
    cells are replaced by the floor (the calibrated noise mean), so the rank
    keeps its meaning. A few strong targets among the training cells do not
    raise the threshold (no masking of a weak target next to a strong one).
    """
    p = np.asarray(profile, dtype=np.float64)
    n = p.shape[-1]
    offsets = np.concatenate([-np.arange(guard + 1, guard + train + 1), np.arange(guard + 1, guard + train + 1)])
    idx = np.arange(n)[:, None] + stride * offsets[None, :]
    valid = (idx >= 0) & (idx < n)
    vals = np.where(valid, np.take(p, np.clip(idx, 0, n - 1), axis=-1), floor)
    kth = np.partition(vals, rank - 1, axis=-1)[..., rank - 1]
    return alpha * np.clip(kth, floor, cap)


def window_leak_envelope(window: np.ndarray, zero_pad: int, span: int) -> np.ndarray:
    """Monotone envelope of the window's power response, ``max_{|m| >= |k|} |W(m)|^2 / |W(0)|^2``, k = 0..span-1 (padded bins)."""
    n = window.size
    resp = np.abs(np.fft.fft(window.astype(float), zero_pad * n)) ** 2
    resp = resp / resp[0]
    half = resp[: zero_pad * n // 2]  # one side (the response of a real window is symmetric)
    env = np.maximum.accumulate(half[::-1])[::-1]
    return env[:span]


def local_maxima(profile: np.ndarray, threshold: np.ndarray) -> np.ndarray:
    """Mask of cells above threshold that are local maxima (> left, >= right), last axis."""
    p = profile
    m = np.zeros(p.shape, bool)
    m[..., 1:-1] = (p[..., 1:-1] > p[..., :-2]) & (p[..., 1:-1] >= p[..., 2:])
    return m & (p > threshold)




# --------------------------------------------------------------------------- bounds
def angle_crb(antenna: ArrayAntenna, theta_rad: np.ndarray, snr: np.ndarray | float) -> np.ndarray:
    """Cramer-Rao bound (rad^2) of the angle from the swept-beam vector iota over the I slots.

    Model ``iota = s h(theta) + n``, ``n ~ CN(0, sigma^2 I)``, unknown theta and
    complex s. The Fisher information of theta with s a nuisance parameter gives

        CRB(theta) = 1 / (2 SNR ||P_perp dh/dtheta||^2),
        P_perp = I - h h^H / ||h||^2,  SNR = |s|^2 / sigma^2,

    i.e. SNR is the per-slot SNR at unit two-way gain (``|h_i| = 1``); for the
    radar, :meth:`rhs_env.radar.RadarConfig.unit_gain_snr`. Velocity is taken
    as known (compensated). Broadcasts over theta and snr.
    """
    th = np.atleast_1d(np.asarray(theta_rad, dtype=float))
    dic = AngleDictionary.__new__(AngleDictionary)
    dic._set_weights(antenna)
    h, h1 = dic.atoms(th, order=1)  # (I, T)
    nh = np.sum(np.abs(h) ** 2, axis=0)
    proj = np.sum(np.abs(h1) ** 2, axis=0) - np.abs(np.sum(h.conj() * h1, axis=0)) ** 2 / nh
    out = 1.0 / (2.0 * np.asarray(snr, float) * proj)
    return out.reshape(np.broadcast_shapes(np.shape(theta_rad), np.shape(snr))) if np.ndim(out) else out


def range_crb(snr_per_sample: np.ndarray | float, samples: int, sample_rate_hz: float, slope_hz_per_s: float,
              looks: int = 1) -> np.ndarray:
    """CRB (m^2) of the range from ``looks`` independent N-sample tones (known-amplitude-free model).

    Frequency of a complex tone in white noise: ``var(f) >= 6 f_s^2 / ((2 pi)^2 SNR N (N^2 - 1))``
    (Rife & Boorstyn), ``R = c0 f / (2 S)``.
    """
    c0 = 299_792_458.0
    n = samples
    var_f = 6.0 * sample_rate_hz ** 2 / ((2 * np.pi) ** 2 * np.asarray(snr_per_sample) * looks * n * (n * n - 1))
    return var_f * (c0 / (2 * slope_hz_per_s)) ** 2


# --------------------------------------------------------------------------- metrics
def pointcloud_metrics(points_xy: np.ndarray, truth_xy: np.ndarray, gate_m: float = 1.0,
                       truth_object: np.ndarray | None = None) -> dict:
    """Point-cloud metrics of one cycle.

    Each true scatterer in view is matched to its nearest point; it is detected
    when that point lies within ``gate_m``. ``rmse_m`` is over detected
    scatterers; a point farther than the gate from every true scatterer is a
    false point. With ``truth_object`` (object id per scatterer), detection is
    counted per object (an extended vehicle is detected when any of its points is).

    Returns dict: ``n_true``, ``n_detected``, ``detection_rate``, ``rmse_m``,
    ``sq_errors`` (array), ``false_points``, ``n_points``.
    """
    p = np.asarray(points_xy, float).reshape(-1, 2)
    t = np.asarray(truth_xy, float).reshape(-1, 2)
    if t.shape[0] == 0:
        return {"n_true": 0, "n_detected": 0, "detection_rate": float("nan"), "rmse_m": float("nan"),
                    "sq_errors": np.zeros(0), "false_points": int(p.shape[0]), "n_points": int(p.shape[0])}
    if p.shape[0] == 0:
        n = t.shape[0] if truth_object is None else len(np.unique(truth_object))
        return {"n_true": n, "n_detected": 0, "detection_rate": 0.0, "rmse_m": float("nan"),
                    "sq_errors": np.zeros(0), "false_points": 0, "n_points": 0}
    d2 = np.sum((t[:, None, :] - p[None, :, :]) ** 2, axis=-1)  # (T, P)
    nearest = d2.min(axis=1)
    hit = nearest <= gate_m ** 2
    false_points = int(np.sum(d2.min(axis=0) > gate_m ** 2))
    if truth_object is None:
        n_true, n_det, sq = t.shape[0], int(hit.sum()), nearest[hit]
    else:
        obj = np.asarray(truth_object)
        uniq, inv = np.unique(obj, return_inverse=True)
        best = np.full(uniq.size, np.inf)
        np.minimum.at(best, inv, nearest)
        det = best <= gate_m ** 2
        n_true, n_det, sq = uniq.size, int(det.sum()), best[det]
    return {"n_true": int(n_true), "n_detected": n_det, "detection_rate": n_det / n_true,
                "rmse_m": float(np.sqrt(np.mean(sq))) if sq.size else float("nan"), "sq_errors": sq,
                "false_points": false_points, "n_points": int(p.shape[0])}


def __getattr__(name: str) -> object:
    """The OMP's private helpers, which lived here before the OMP moved to :mod:`rhs_env.omp` (the equivalence tests
    call some of them by their old module): looked up there."""
    if name in vars(_omp):
        return vars(_omp)[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
