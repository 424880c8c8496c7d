"""The echoes of one sweep of the four radars: the visible scatterers as tones, mixed into IQ samples or a spectrum.

A stage of :class:`rhs_env.radar.RadarSystem` (its ``synthesizer``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rhs_common.jit import KernelTable
from rhs_env.array_models import SPEED_OF_LIGHT
from rhs_env.point_cloud import tone_spectra
from rhs_env.radar.antennas import BeamPatterns
from rhs_env.radar.buffers import WorkBuffers
from rhs_env.radar.mounting import RadarMounts
from rhs_env.radar.noise import ReceiverNoise
from rhs_env.radar_config import RadarConfig
from rhs_env.scatterers import Occluders, Scatterers

__all__ = ["EchoSynthesizer", "EchoTones", "mix_tones"]


class EchoTones(NamedTuple):
    """The visible (radar, scatterer) pairs of one sweep as tones, P of them, sorted by radar."""

    radar: np.ndarray  #: (P,) int, the radar of each pair
    gains: np.ndarray  #: (I, P) complex, ``G[i, p] = sqrt(P_t) beta_p h_i(theta_p) exp(j omega_p i C)``
    omega: np.ndarray  #: (P,) chirp-to-chirp Doppler phase, rad
    f_tot: np.ndarray  #: (P,) beat + Doppler frequency, Hz


def mix_tones(rr: np.ndarray, g_mat: np.ndarray, e_mat: np.ndarray | tuple[np.ndarray, np.ndarray],
              out: np.ndarray) -> None:
    """``out[r] = G_r @ E_r`` (4, I, X): the tones of radar r only (rr sorted), one batched product.

    ``e_mat``: E (P, X), or the factors ``(e_slow (P, C), e_fast (P, N))`` of ``E[p, (c, n)] =
    e_slow[p, c] e_fast[p, n]``, multiplied straight into the complex64 operand (the same values).
    """
    counts = np.bincount(rr, minlength=4)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(rr.size) - start[rr]
    width = e_mat.shape[1] if isinstance(e_mat, np.ndarray) else e_mat[0].shape[1] * e_mat[1].shape[1]
    gp = np.zeros((4, g_mat.shape[0], counts.max()), np.complex64)
    ep = np.empty((4, counts.max(), width), np.complex64)
    gp[rr, :, slot] = g_mat.T
    if isinstance(e_mat, np.ndarray):
        ep[...] = 0
        ep[rr, slot] = e_mat
    else:
        e_slow, e_fast = e_mat
        for r in range(4):
            lo, hi = int(start[r]), int(start[r] + counts[r])
            np.multiply(e_slow[lo:hi, :, None], e_fast[lo:hi, None, :],
                        out=ep[r, : hi - lo].reshape(hi - lo, e_slow.shape[1], e_fast.shape[1]))
            ep[r, hi - lo:] = 0
    np.matmul(gp, ep, out=out)


class EchoSynthesizer:
    """Echo synthesis: the dechirped samples, or their range spectrum, of one sweep of the four radars.

    Waveform: a linear chirp over ``B`` = 250 MHz in ``T_c`` = 20 us, slope ``S = B / T_c``, complex baseband
    sampling at ``f_s`` = 20 MHz (``N = f_s T_c`` = 400 samples, range bin ``c0 / (2 B)`` = 0.6 m, unambiguous
    range ``c0 f_s / (2 S)`` = 240 m). Each radar sweeps I beam slots, ``C`` chirps per slot, back to back, so
    chirp c of slot i starts at ``t_ic = (i C + c) T_c``.

    Dechirped echo of slot i, chirp c, sample n (paper eq. 2, as a sum of tones):

        y[i, c, n] = sum_k sqrt(P_t) beta_k h_i(theta_k)
                     exp(j 2 pi (f_b,k + f_D,k) n / f_s) exp(j omega_k (i C + c)) + eps[i, c, n]

    * beat frequency ``f_b,k = 2 S R_k / c0``, Doppler ``f_D,k = 2 v_k / lambda`` and
      chirp-to-chirp phase ``omega_k = 4 pi v_k T_c / lambda`` (v_k radial velocity, m/s,
      > 0 receding). The geometry is frozen at the scan instant (the range and
      bearing change over the ~7 ms sweep is neglected; the Doppler phase, which
      is lambda-sensitive, is kept across chirps and slots; ``waveform.slot_doppler=False``
      restarts it every slot).
    * ``|beta_k|^2 = sigma_k lambda^2 / ((4 pi)^3 R_k^4)`` (radar equation with the
      antenna gains in h, :meth:`rhs_env.radar_config.RadarConfig.echo_power_w`), phase uniform in [0, 2 pi)
      from the rng.
    * ``h_i`` the slot gains (:meth:`rhs_env.radar.antennas.BeamPatterns.gains`); ``eps`` the receiver noise
      (:class:`rhs_env.radar.noise.ReceiverNoise`).

    As a matrix product per radar: ``y = G @ E`` with ``G[i, k] = sqrt(P_t) beta_k
    h_i(theta_k) exp(j omega_k i C)`` (I x K) and ``E[k, (c, n)] = exp(j 2 pi (f_b,k
    + f_D,k) n / f_s + j omega_k c)`` (K x C N), batched over the four radars (:func:`mix_tones`).

    Args:
        config: :class:`rhs_env.radar_config.RadarConfig` (``waveform``, ``link``, ``scan``, ``kernels``).
        mounts: the radars' geometry and field of view.
        beams: the antennas' slot gains.
        noise: the receiver noise.
    """

    def __init__(self, config: RadarConfig, mounts: RadarMounts, beams: BeamPatterns, noise: ReceiverNoise) -> None:
        self.config = config
        self.mounts, self.beams, self.noise = mounts, beams, noise
        self.bin_hi = noise.bin_hi
        self._n = np.arange(config.waveform.samples)
        self._buffers = WorkBuffers()
        self._impl = _STAGES.choose(config.kernels)  # the compiled or the numpy tone spectra

    def tones(self, scatterers: Scatterers, occluders: Occluders | None,
              rng: np.random.Generator) -> EchoTones | None:
        """The visible (radar, scatterer) pairs as tones (their phases drawn from ``rng``), or None when there are none."""
        cfg = self.config
        if not len(scatterers):
            return None
        frame = self.mounts.frame(scatterers.xy)
        rr, kk = np.nonzero(self.mounts.visible(scatterers, occluders, frame))
        if rr.size == 0:
            return None
        lam, i_slots = cfg.wavelength, cfg.scan.slots
        rng_m, ang, unit = frame
        r_k, th_k = rng_m[rr, kk], ang[rr, kk]
        v_k = np.einsum("pd,pd->p", unit[rr, kk], scatterers.velocity[kk])  # radial, m/s
        phase0 = rng.uniform(0.0, 2 * np.pi, rr.size)
        amp = np.sqrt(cfg.echo_power_w(r_k, scatterers.rcs[kk])) * np.exp(1j * phase0)  # sqrt(Pt) beta
        h = self.beams.gains(rr, th_k)
        omega = 4 * np.pi * v_k * cfg.waveform.chirp_s / lam  # rad per chirp
        f_tot = 2 * cfg.waveform.slope * r_k / SPEED_OF_LIGHT + 2 * v_k / lam  # Hz
        slot_t = np.arange(i_slots)[:, None] * (cfg.waveform.chirps_per_slot if cfg.waveform.slot_doppler else 0)
        return EchoTones(rr, h * amp[None, :] * np.exp(1j * omega[None, :] * slot_t), omega, f_tot)

    def samples(self, scatterers: Scatterers, occluders: Occluders | None, rng: np.random.Generator,
                out: np.ndarray | None = None) -> np.ndarray:
        """Dechirped samples y (4, I, C, N) complex64 of one sweep of the four radars (``fidelity="iq"``).

        ``y = G @ E`` per radar with ``E[p, (c, n)] = exp(j 2 pi f_tot,p n / f_s + j omega_p c)``, plus
        CN(0, sigma_n^2) noise per sample. ``out``: optional complex64 array of 4 I C N elements to write into.
        """
        cfg = self.config
        i_slots, c, n = cfg.scan.slots, cfg.waveform.chirps_per_slot, cfg.waveform.samples
        y = np.empty((4, i_slots, c * n), np.complex64) if out is None else out.reshape(4, i_slots, c * n)
        tones = self.tones(scatterers, occluders, rng)
        if tones is None:
            y[...] = 0
        else:  # the product G @ E writes every sample of y
            rr, g_mat, omega, f_tot = tones
            e_fast = np.exp(2j * np.pi * f_tot[:, None] * self._n[None, :] / cfg.waveform.sample_rate_hz)  # (P, N)
            e_slow = np.exp(1j * omega[:, None] * np.arange(c)[None, :])  # (P, C)
            mix_tones(rr, g_mat, (e_slow, e_fast), y)
        if cfg.link.add_noise:
            self.noise.add_to_samples(y, rng)
        return y.reshape(4, i_slots, c, n)

    def spectrum(self, scatterers: Scatterers, occluders: Occluders | None, rng: np.random.Generator) -> np.ndarray:
        """Range spectrum Y (4, I, C, K_b) complex64 of one sweep, written directly (``fidelity="range"``).

        The bins ``k < K_b`` searched (up to ``max_range_m`` plus the CFAR margin) of
        what :meth:`rhs_env.radar.range_fft.RangeFFT.spectrum` makes of :meth:`samples`:

        * signal, in closed form: ``Y_s[r, i, c, k] = sum_p G[i, p] exp(j omega_p c)
          W(k / (Z N) - f_tot,p / f_s)`` with W the window's DTFT
          (:func:`rhs_env.point_cloud.tone_spectra`);
        * noise: the windowed, zero-padded FFT of CN(0, sigma_n^2) white noise
          (:meth:`rhs_env.radar.noise.ReceiverNoise.spectrum`), whose covariance over the bins is exactly the
          IQ path's, ``sigma_n^2 sum_n w[n]^2 exp(-j 2 pi (k - l) n / (Z N))``.

        With ``kernels="numba"`` the tone spectra and the operands of the product are built compiled
        (:func:`rhs_env.kernels.tone_spectra`, :func:`rhs_env.kernels.tone_operands`) and multiplied per radar
        (its own tones only, no padding to the largest count), each product added by BLAS straight into the
        spectrum (:func:`rhs_env.kernels.add_tone_products`); the noise's elementwise passes are fused.
        """
        cfg = self.config
        spec = self.noise.spectrum((4, cfg.scan.slots, cfg.waveform.chirps_per_slot), rng)
        tones = self.tones(scatterers, occluders, rng)
        if tones is not None:
            self._impl.add_tones(self, spec, tones)
        return spec

    def _add_tones_numpy(self, spec: np.ndarray, tones: EchoTones) -> None:
        """Add the tones (:meth:`tones`) into the spectrum ``spec`` (4, I, C, K_b), numpy (the reference)."""
        cfg = self.config
        i_slots, c, n, z, kb = cfg.scan.slots, cfg.waveform.chirps_per_slot, cfg.waveform.samples, cfg.waveform.zero_pad, self.bin_hi
        rr, g_mat, omega, f_tot = tones
        wk = tone_spectra(cfg.waveform.window, n, z, kb, f_tot / cfg.waveform.sample_rate_hz)  # (P, K_b)
        e_mat = (np.exp(1j * omega[:, None] * np.arange(c))[:, :, None] * wk[:, None, :]).reshape(rr.size, c * kb)
        sig = self._buffers.get("sig", (4, i_slots, c * kb), np.complex64)
        mix_tones(rr, g_mat, e_mat, sig)
        spec += sig.reshape(spec.shape)


#: the tone spectra's two implementations, chosen once by ``RadarConfig.kernels``
_STAGES = KernelTable("rhs_env.radar.synthesis")
_STAGES.stage("add_tones", "numpy")(EchoSynthesizer._add_tones_numpy)


@_STAGES.stage("add_tones", "numba")
def _add_tones_compiled(synth: EchoSynthesizer, spec: np.ndarray, tones: EchoTones) -> None:
    """:meth:`EchoSynthesizer._add_tones_numpy` compiled: the tone spectra and the product's operands
    (:func:`rhs_env.kernels.tone_spectra`, :func:`rhs_env.kernels.tone_operands`), each radar's own tones only (no
    padding to the largest count), each product added by BLAS straight into the spectrum view
    (:func:`rhs_env.kernels.add_tone_products`)."""
    from rhs_common.native import cgemm_address
    from rhs_env import kernels
    from rhs_env.point_cloud import window_exponentials

    cfg = synth.config
    c, n, z, kb = cfg.waveform.chirps_per_slot, cfg.waveform.samples, cfg.waveform.zero_pad, synth.bin_hi
    rr, g_mat, omega, f_tot = tones
    mu, coef = window_exponentials(cfg.waveform.window, n)
    wk = kernels.tone_spectra(mu, coef, n, z, kb, np.ascontiguousarray(f_tot / cfg.waveform.sample_rate_hz))
    gp, ep = kernels.tone_operands(g_mat, omega, wk, c)
    bounds = np.searchsorted(rr, np.arange(5))  # rr sorted: radar r's tones are lo_r:hi_r
    kernels.add_tone_products(gp, ep, bounds, spec, cgemm_address())
