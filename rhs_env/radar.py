"""Four swept-beam FMCW radars on the ego vehicle: echo synthesis and point clouds.

Waveform: a linear chirp over ``B`` = 250 MHz in ``T_c`` = 20 us,
slope ``S = B / T_c``, complex baseband sampling at ``f_s`` = 20 MHz (``N = f_s T_c``
= 400 samples, range bin ``c0 / (2 B)`` = 0.6 m, unambiguous range
``c0 f_s / (2 S)`` = 240 m). Each radar sweeps I beam slots (one grid per slot),
``C`` chirps per slot, back to back, so chirp c of slot i starts at
``t_ic = (i C + c) T_c``.

Dechirped echo of slot i, chirp c, sample n (paper eq. 2, as a sum of tones):

    y[i, c, n] = sum_k sqrt(P_t) beta_k h_i(theta_k)
                 exp(j 2 pi (f_b,k + f_D,k) n / f_s) exp(j omega_k (i C + c)) + eps[i, c, n]

* beat frequency ``f_b,k = 2 S R_k / c0``, Doppler ``f_D,k = 2 v_k / lambda`` and
  chirp-to-chirp phase ``omega_k = 4 pi v_k T_c / lambda`` (v_k radial velocity,
  > 0 receding). The geometry is frozen at the scan instant (the range and
  bearing change over the ~7 ms sweep is neglected; the Doppler phase, which
  is lambda-sensitive, is kept across chirps and slots; ``waveform.slot_doppler=False``
  restarts it every slot).
* ``|beta_k|^2 = sigma_k lambda^2 / ((4 pi)^3 R_k^4)`` (radar equation with the
  antenna gains in h), phase uniform in [0, 2 pi) from the rng.
* ``h_i = r_i t_i`` with the power-normalised gains of :class:`ArrayAntenna`
  (``|t|^2`` is the array gain at fixed radiated power ``P_t``, ``|r|^2`` the Rx
  SNR gain), so the noise of the normalised Rx output is that of one element:
  complex Gaussian, variance ``sigma_n^2 = k T0 F f_s`` per sample.

As a matrix product per radar: ``y = G @ E`` with ``G[i, k] = sqrt(P_t) beta_k
h_i(theta_k) exp(j omega_k i C)`` (I x K) and ``E[k, (c, n)] = exp(j 2 pi (f_b,k
+ f_D,k) n / f_s + j omega_k c)`` (K x C N), batched over the four radars.

Mounting: radars at the middle of the front, left, rear and right sides of a
``mounting.vehicle_length_m`` x ``mounting.vehicle_width_m`` box, boresights 0, +90, 180, -90 deg.
Field of view: the scan sector (+-45 deg) up to ``max_range_m``; hidden
scatterers (:func:`rhs_env.scatterers.visible_mask`) return nothing.
Far-field model: the array apertures (<= 0.3 m) are treated as points.

Settings: :class:`RadarConfig` (:mod:`rhs_env.radar_config`, re-exported here) and its
groups ``waveform`` (B, T_c, f_s, C, window, zero padding), ``link`` (P_t, F, T0),
``detection``, ``estimation`` (OMP), ``uncertainty`` and ``mounting``.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.fft as sfft

from rhs_common.jit import KernelTable
from rhs_common.linalg import batched_lstsq
from rhs_env.antenna_factory import make_antenna
from rhs_env.array_models import SPEED_OF_LIGHT, ArrayAntenna
from rhs_env.detection import FootprintDetector
from rhs_env.point_cloud import (
    AngleDictionary,
    PointCloud,
    angle_crb,
    atom_norms,
    ca_cfar_threshold,
    cfar_alpha,
    local_maxima,
    noise_decimation,
    omp_doppler,
    os_cfar_alpha,
    os_cfar_threshold,
    parabolic_offset,
    pointcloud_metrics,
    residual_threshold,
    tone_spectra,
    window_leak_envelope,
)
from rhs_env.radar_config import (
    BOLTZMANN,
    AngleEstimationConfig,
    DetectionConfig,
    LinkBudgetConfig,
    MountingConfig,
    RadarConfig,
    UncertaintyConfig,
    WaveformConfig,
)
from rhs_env.scatterers import LOS_EPS, Occluders, Scatterers, visible_mask
from rhs_env.uncertainty import attach_uncertainty
from rhs_env.windows import make_window

__all__ = [
    "BOLTZMANN",
    "RADAR_NAMES",
    "AngleEstimationConfig",
    "DetectionConfig",
    "LinkBudgetConfig",
    "MountingConfig",
    "PointCloud",
    "RadarConfig",
    "RadarSystem",
    "UncertaintyConfig",
    "WaveformConfig",
]

RADAR_NAMES = ("front", "left", "rear", "right")


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


@dataclass
class _Targets:
    """Per detection (D) and target slot (L): the OMP estimates and the range offsets (padded bins) from kd."""

    theta: np.ndarray  # (D, L) rad from boresight
    amp: np.ndarray  # (D, L) complex LS amplitude per unit atom
    valid: np.ndarray  # (D, L) bool
    anorm: np.ndarray  # (D, L) ||a|| of the atom over slots and chirps
    omega: np.ndarray  # (D, L) chirp-to-chirp Doppler phase, rad
    tfrac: np.ndarray  # (D, L) bin offset of the target from its detection cell

    @classmethod
    def empty(cls, d: int, n_l: int) -> _Targets:
        z = np.zeros((d, n_l))
        return cls(z.copy(), np.zeros((d, n_l), complex), np.zeros((d, n_l), bool), z.copy(), z.copy(), z.copy())


class RadarSystem:
    """The four radars of the ego vehicle with their antennas and OMP dictionaries.

    Args:
        config: :class:`RadarConfig`.
        rng: numpy Generator: the ``random`` antenna's patterns (one per radar,
            drawn here) and, at every scan, echo phases and noise.
        patterns: optional ``(tx_psi, rx_psi)`` (I, M) for the ``rhs`` antenna
            instead of the pattern library.
        antennas: optional explicit antenna per radar (list of 4 or one shared),
            overriding ``config.antenna``.
    """

    def __init__(self, config: RadarConfig | None = None, rng: np.random.Generator | None = None,
                 patterns: tuple[np.ndarray, np.ndarray] | None = None,
                 antennas: ArrayAntenna | list[ArrayAntenna] | None = None) -> None:
        self.config = config = config or RadarConfig()
        self._impl = _STAGES.choose(config.kernels)  # the compiled or the numpy stages (one choice, here)
        self.rng = rng if rng is not None else np.random.default_rng()
        self.positions, self.boresights = config.mounting.mounts()
        if antennas is not None:
            ants = [antennas] * 4 if isinstance(antennas, ArrayAntenna) else list(antennas)
            if len(ants) != 4:
                raise ValueError(f"antennas must be one ArrayAntenna or a list of 4, got {len(ants)}")
        elif config.antenna == "random":
            ants = [make_antenna("random", config.rhs, config.scan, rng=self.rng) for _ in range(4)]
        else:
            shared = make_antenna(config.antenna, config.rhs, config.scan, patterns=patterns)
            ants = [shared] * 4
        for a in ants:
            if a.slots != config.scan.slots:
                raise ValueError(f"antenna has {a.slots} slots, scan config needs {config.scan.slots}")
        self.antennas = ants
        # one dictionary per distinct antenna object
        self._groups: list[tuple[AngleDictionary, list[int]]] = []
        seen: dict[int, int] = {}
        radar_group = np.zeros(4, int)
        for r, a in enumerate(ants):
            if id(a) not in seen:
                seen[id(a)] = len(self._groups)
                dic = AngleDictionary(a, config.scan.grid_deg, config.scan.sector_deg,
                                      config.estimation.oversampling).use_kernels(config.kernels)
                self._groups.append((dic, []))
            radar_group[r] = seen[id(a)]
        self.dictionaries = [self._groups[radar_group[r]][0] for r in range(4)]
        self._radar_group = radar_group
        # processing constants
        wf, det = config.waveform, config.detection
        n, z = wf.samples, wf.zero_pad
        self._window = make_window(wf.window, n)
        self._buffers: dict[str, np.ndarray] = {}
        self._n = np.arange(n)
        self._win_energy = float(np.sum(self._window.astype(float) ** 2))
        bins_per_m = 2 * wf.slope / SPEED_OF_LIGHT * z * n / wf.sample_rate_hz
        margin = (det.guard + det.train + 2) * z
        self._bin_hi = int(min(z * n, math.ceil(config.max_range_m * bins_per_m) + margin))
        self._bin_range = np.arange(self._bin_hi) / bins_per_m  # range of bin k (zero Doppler), m
        self._leak = window_leak_envelope(self._window, z, z * n // 2)
        self._noise_rate = noise_decimation(self._window, z, self._bin_hi)
        # the range path's noise radius factor: sqrt(D) w[D m] sigma_n (:meth:`_noise_spectrum`)
        self._noise_window = self._window[:: self._noise_rate] * np.float32(math.sqrt(self._noise_rate * config.noise_power_w))
        self._same_angle = 0.25 * np.deg2rad(config.scan.grid_deg)
        looks = config.scan.slots * wf.chirps_per_slot
        self._p_noise = looks * config.noise_power_w * self._win_energy  # mean of P per cell, pure noise
        self._rank = max(1, round(det.rank * 2 * det.train))
        cells = config.scan.slots * wf.chirps_per_slot
        y_var = config.noise_power_w * self._win_energy
        self._detectors = ([FootprintDetector(dic, config, y_var, self._leak, self._window) for dic, _ in self._groups]
                           if det.statistic == "footprint" else [])
        self._min_amp = 10 ** (config.estimation.min_snr_db / 20) * math.sqrt(y_var)
        self._delta_r = float(residual_threshold(y_var, cells, config.estimation.residual_pfa))
        i, c = config.scan.slots, wf.chirps_per_slot
        self._chirp_index = (np.arange(i)[:, None] * c * (1 if wf.slot_doppler else 0)
                             + np.arange(c)[None, :]).astype(float)  # (I, C): chirp time / T_c

    # ------------------------------------------------------------------ geometry
    def radar_frame(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Range (4, K), angle from boresight (4, K) rad and unit vectors (4, K, 2) of points xy (K, 2)."""
        d = np.asarray(xy, float)[None, :, :] - self.positions[:, None, :]
        rng_m = np.hypot(d[..., 0], d[..., 1])
        ang = _wrap(np.arctan2(d[..., 1], d[..., 0]) - self.boresights[:, None])
        unit = d / np.maximum(rng_m, 1e-12)[..., None]
        return rng_m, ang, unit

    def visible(self, scatterers: Scatterers, occluders: Occluders | None = None,
                frame: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """(4, K) bool: inside radar r's sector and range interval and in line of sight (``frame``: :meth:`radar_frame`'s).

        With ``kernels="numba"`` the line of sight is tested compiled, only for the pairs in the field of view
        (:func:`rhs_env.kernels.line_of_sight`, the same mask as :func:`rhs_env.scatterers.visible_mask`).
        """
        rng_m, ang, _ = self.radar_frame(scatterers.xy) if frame is None else frame
        half = np.deg2rad(self.config.scan.sector_deg) / 2
        fov = (np.abs(ang) <= half) & (rng_m <= self.config.max_range_m) & (rng_m >= self.config.min_range_m)
        return np.asarray(self._impl.line_of_sight(self, fov, scatterers, occluders), dtype=bool)

    def _line_of_sight_numpy(self, fov: np.ndarray, scatterers: Scatterers, occluders: Occluders | None) -> np.ndarray:
        """``fov & visible_mask(...)`` (4, K) in numpy (the reference of :meth:`visible`)."""
        return np.asarray(fov & visible_mask(self.positions, scatterers, occluders), dtype=bool)

    def in_view(self, scatterers: Scatterers, occluders: Occluders | None = None) -> np.ndarray:
        """(K,) bool: seen by at least one radar."""
        return np.asarray(self.visible(scatterers, occluders).any(axis=0), dtype=bool)

    # ------------------------------------------------------------------ synthesis
    def _buffer(self, name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
        """Persistent work array (large temporaries re-used across scans: no page faults per scan)."""
        buf = self._buffers.get(name)
        if buf is None or buf.shape != shape or buf.dtype != dtype:
            buf = self._buffers[name] = np.empty(shape, dtype)
        return buf

    def _echoes(self, scatterers: Scatterers,
                occluders: Occluders | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The visible (radar, scatterer) pairs as tones, or None when there are none.

        Returns the radar of each pair ``rr`` (P,), the slot gains ``G[i, p] =
        sqrt(P_t) beta_p h_i(theta_p) exp(j omega_p i C)`` (I, P), the chirp-to-chirp
        Doppler phase ``omega`` (P,) rad and the beat + Doppler frequency ``f_tot`` (P,) Hz.
        """
        cfg = self.config
        if not len(scatterers):
            return None
        frame = self.radar_frame(scatterers.xy)
        rr, kk = np.nonzero(self.visible(scatterers, occluders, frame))
        if rr.size == 0:
            return None
        lam, i_slots = cfg.wavelength, cfg.scan.slots
        rng_m, ang, unit = frame
        r_k, th_k = rng_m[rr, kk], ang[rr, kk]
        v_k = np.einsum("pd,pd->p", unit[rr, kk], scatterers.velocity[kk])  # radial, m/s
        phase0 = self.rng.uniform(0.0, 2 * np.pi, rr.size)
        amp = np.sqrt(cfg.echo_power_w(r_k, scatterers.rcs[kk])) * np.exp(1j * phase0)  # sqrt(Pt) beta
        h = np.empty((i_slots, rr.size), complex)
        for g, (dic, _) in enumerate(self._groups):
            sel = self._radar_group[rr] == g
            if np.any(sel):  # compiled: the dictionary's series (the same gains to ~1e-15), else the direct product
                h[:, sel] = self._impl.gains(dic, th_k[sel])
        omega = 4 * np.pi * v_k * cfg.waveform.chirp_s / lam  # rad per chirp
        f_tot = 2 * cfg.waveform.slope * r_k / SPEED_OF_LIGHT + 2 * v_k / lam  # Hz
        slot_t = np.arange(i_slots)[:, None] * (cfg.waveform.chirps_per_slot if cfg.waveform.slot_doppler else 0)
        return rr, h * amp[None, :] * np.exp(1j * omega[None, :] * slot_t), omega, f_tot

    @staticmethod
    def _mix(rr: np.ndarray, g_mat: np.ndarray, e_mat: np.ndarray | tuple[np.ndarray, np.ndarray],
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

    def synthesize(self, scatterers: Scatterers, occluders: Occluders | None = None,
                   out: np.ndarray | None = None) -> np.ndarray:
        """Dechirped samples y (4, I, C, N) complex64 of one sweep of the four radars (``fidelity="iq"``).

        ``y = G @ E`` per radar with ``E[p, (c, n)] = exp(j 2 pi f_tot,p n / f_s + j omega_p c)``, plus
        CN(0, sigma_n^2) noise per sample. ``out``: optional complex64 array of 4 I C N elements to write into.
        """
        cfg = self.config
        i_slots, c, n = cfg.scan.slots, cfg.waveform.chirps_per_slot, cfg.waveform.samples
        y = np.empty((4, i_slots, c * n), np.complex64) if out is None else out.reshape(4, i_slots, c * n)
        tones = self._echoes(scatterers, occluders)
        if tones is None:
            y[...] = 0
        else:  # the product G @ E writes every sample of y
            rr, g_mat, omega, f_tot = tones
            e_fast = np.exp(2j * np.pi * f_tot[:, None] * self._n[None, :] / cfg.waveform.sample_rate_hz)  # (P, N)
            e_slow = np.exp(1j * omega[:, None] * np.arange(c)[None, :])  # (P, C)
            self._mix(rr, g_mat, (e_slow, e_fast), y)
        if cfg.link.add_noise:
            # circular complex Gaussian CN(0, sigma_n^2) by the polar method: |eps|^2 ~ Exp(sigma_n^2)
            # from -ln(1 - u1), phase 2 pi u2 (float32 uniforms: the radius tail is cut at P = 2^-24)
            u = self._uniform32(self._buffer("u", (2,) + y.shape, np.float32))
            rad = self._buffer("rad", y.shape, np.float32)
            tmp = self._buffer("tmp", y.shape, np.float32)
            np.negative(u[0], out=rad)
            np.log1p(rad, out=rad)
            np.negative(rad, out=rad)
            np.sqrt(rad, out=rad)
            rad *= np.float32(math.sqrt(cfg.noise_power_w))
            ph = u[1]
            ph *= np.float32(2 * np.pi)
            np.cos(ph, out=tmp)
            tmp *= rad
            y.real += tmp
            np.sin(ph, out=tmp)
            tmp *= rad
            y.imag += tmp
        return y.reshape(4, i_slots, c, n)

    def _uniform32(self, out: np.ndarray) -> np.ndarray:
        """``self.rng.random(dtype=np.float32, out=out)``: the same numbers, drawn faster for PCG64.

        ``Generator.random`` in float32 takes 32-bit words ``w`` of the bit generator
        (PCG64: the low then the high half of each 64-bit output) and returns
        ``(w >> 8) 2^-24``; for an even count and no buffered half word that is
        exactly the vectorised form below on ``random_raw``, and the generator ends
        in the same state. Any other generator (or a buffered half word) takes the
        ``Generator.random`` call itself.
        """
        bg = self.rng.bit_generator
        if (out.size % 2 or not out.flags.c_contiguous or not np.little_endian or type(bg) is not np.random.PCG64
                or bg.state.get("has_uint32", 1) != 0):
            return self.rng.random(dtype=np.float32, out=out)
        words = bg.random_raw(out.size // 2).view(np.uint32)  # little-endian: low half first
        np.right_shift(words, 8, out=words)
        np.copyto(out.reshape(-1), words, casting="unsafe")  # < 2^24: exact in float32
        out *= np.float32(2.0 ** -24)
        return out

    def synthesize_spectrum(self, scatterers: Scatterers, occluders: Occluders | None = None) -> np.ndarray:
        """Range spectrum Y (4, I, C, K_b) complex64 of one sweep, written directly (``fidelity="range"``).

        The bins ``k < K_b`` searched (up to ``max_range_m`` plus the CFAR margin) of
        what :meth:`range_spectrum` makes of :meth:`synthesize`'s samples:

        * signal, in closed form: ``Y_s[r, i, c, k] = sum_p G[i, p] exp(j omega_p c)
          W(k / (Z N) - f_tot,p / f_s)`` with W the window's DTFT
          (:func:`rhs_env.point_cloud.tone_spectra`);
        * noise: the windowed, zero-padded FFT of CN(0, sigma_n^2) white noise
          (:meth:`_noise_spectrum`), whose covariance over the bins is exactly the
          IQ path's, ``sigma_n^2 sum_n w[n]^2 exp(-j 2 pi (k - l) n / (Z N))``.

        With ``kernels="numba"`` the tone spectra and the operands of the product are built compiled
        (:func:`rhs_env.kernels.tone_spectra`, :func:`rhs_env.kernels.tone_operands`) and multiplied per radar
        (its own tones only, no padding to the largest count), each product added by BLAS straight into the
        spectrum (:func:`rhs_env.kernels.add_tone_products`); the noise stays numpy.
        """
        cfg = self.config
        spec = self._noise_spectrum((4, cfg.scan.slots, cfg.waveform.chirps_per_slot))
        tones = self._echoes(scatterers, occluders)
        if tones is not None:
            self._impl.add_tones(self, spec, tones)
        return spec

    def _add_tones_numpy(self, spec: np.ndarray, tones: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]) -> None:
        """Add the tones (:meth:`_echoes`) into the spectrum ``spec`` (4, I, C, K_b), numpy (the reference)."""
        cfg = self.config
        i_slots, c, n, z, kb = cfg.scan.slots, cfg.waveform.chirps_per_slot, cfg.waveform.samples, cfg.waveform.zero_pad, self._bin_hi
        rr, g_mat, omega, f_tot = tones
        wk = tone_spectra(cfg.waveform.window, n, z, kb, f_tot / cfg.waveform.sample_rate_hz)  # (P, K_b)
        e_mat = (np.exp(1j * omega[:, None] * np.arange(c))[:, :, None] * wk[:, None, :]).reshape(rr.size, c * kb)
        sig = self._buffer("sig", (4, i_slots, c * kb), np.complex64)
        self._mix(rr, g_mat, e_mat, sig)
        spec += sig.reshape(spec.shape)

    def _noise_spectrum(self, shape: tuple[int, ...]) -> np.ndarray:
        """``FFT_{Z N}(w * eps)[..., :K_b]``, eps ~ CN(0, sigma_n^2) i.i.d. (zeros without noise): shape + (K_b,), a view.

        Drawn at the rate ``1 / D`` (:func:`noise_decimation`, D = 2 for the default Hann
        window and range): ``x[m] = sqrt(D) w[D m] eps[m]``, m < N / D, and its FFT of
        ``Z N / D`` bins. For D = 2 its bins have the covariance
        ``R(k - l) + R(k - l + Z N / 2)``, ``R(d) = sigma_n^2 sum_n w[n]^2
        exp(-j 2 pi d n / (Z N))`` (the identity ``2 sum_{n even} g[n] = sum_n g[n] (1 + (-1)^n)``):
        the full-rate covariance R plus an alias term that :func:`noise_decimation` has checked
        to be negligible on the searched bins. Half the normals and half the FFT.

        eps by the polar method as in :meth:`synthesize` (``|eps| = sigma_n
        sqrt(-ln(1 - u1))``, phase ``2 pi u2``), the uniforms as 24-bit fractions
        of the generator's raw 64-bit draws (one draw gives u1 and u2 for two
        samples; cheaper than ``Generator.random`` in float32), the window
        folded into the radius, then one zero-padded FFT per chirp. With ``kernels="numba"`` the
        elementwise passes around numpy's ``log1p``, ``cos`` and ``sin`` (uniforms, radius, window, products)
        run fused (:func:`rhs_env.kernels.noise_uniforms`, :func:`rhs_env.kernels.noise_samples`) and the FFT
        pads each row itself (``n = Z N / D``: no zeros written to memory, 0.1-0.3 ms less per scan): the same
        float32 operations, the same spectrum bit for bit.
        """
        cfg = self.config
        d, z, kb = self._noise_rate, cfg.waveform.zero_pad, self._bin_hi
        n = cfg.waveform.samples // d
        m = math.prod(shape)
        if not cfg.link.add_noise:
            buf = self._buffer("nfft", (m, z * n), np.complex64)
            buf[:, :kb] = 0
            return buf[:, :kb].reshape(shape + (kb,))
        bits = self.rng.bit_generator.random_raw(m * n).view(np.int32)  # 2 m n independent 32-bit words
        return np.asarray(self._impl.noise(self, bits, m, n)[:, :kb].reshape(shape + (kb,)))

    def _noise_numpy(self, bits: np.ndarray, m: int, n: int) -> np.ndarray:
        """The noise spectra (m, Z n) of :meth:`_noise_spectrum` from the raw words ``bits``, numpy (the reference)."""
        z = self.config.waveform.zero_pad
        buf = self._buffer("nfft", (m, z * n), np.complex64)
        np.right_shift(bits, 8, out=bits)  # 24-bit signed: [-2^23, 2^23)
        u = self._buffer("nu", (2, m, n), np.float32)
        np.copyto(u, bits.reshape(2, m, n), casting="unsafe")
        u *= np.float32(2.0 ** -24)
        u += np.float32(0.5)  # uniform on [0, 1) in steps of 2^-24
        rad, ph = u
        np.negative(rad, out=rad)
        np.log1p(rad, out=rad)
        np.negative(rad, out=rad)
        np.sqrt(rad, out=rad)
        rad *= self._noise_window
        ph *= np.float32(2 * np.pi)
        tmp = self._buffer("ntmp", (m, n), np.float32)
        np.cos(ph, out=tmp)
        np.multiply(tmp, rad, out=buf.real[:, :n])
        np.sin(ph, out=tmp)
        np.multiply(tmp, rad, out=buf.imag[:, :n])
        buf[:, n:] = 0
        return np.asarray(sfft.fft(buf, axis=-1, workers=1, overwrite_x=True))  # in place: the result is buf

    # ------------------------------------------------------------------ processing
    def range_spectrum(self, y: np.ndarray) -> np.ndarray:
        """Windowed, zero-padded range FFT of y (4, I, C, N) -> bins ``k < K_b`` (4, I, C, K_b) complex64 (a view)."""
        z, n = self.config.waveform.zero_pad, self.config.waveform.samples
        buf = self._buffer("fft", y.shape[:-1] + (z * n,), np.complex64)
        np.multiply(y, self._window, out=buf[..., :n])
        buf[..., n:] = 0
        # in place (overwrite_x): the padded buffer becomes the spectrum, no fresh 9 MB array per scan
        return sfft.fft(buf, axis=-1, workers=1, overwrite_x=True)[..., : self._bin_hi]

    def process(self, y: np.ndarray) -> tuple[PointCloud, dict[str, float]]:
        """Range FFT, detection and OMP on IQ samples y (4, I, C, N) -> point cloud (and stage times)."""
        t0 = time.perf_counter()
        spec = self.range_spectrum(y)
        t_fft = time.perf_counter() - t0
        cloud, times = self.process_spectrum(spec)
        times["range_cfar"] += t_fft
        return cloud, times

    def process_spectrum(self, spec: np.ndarray) -> tuple[PointCloud, dict[str, float]]:
        """Detection, angle / Doppler estimation and points from the range spectrum (4, I, C, K_b).

        Stages: :meth:`_detect` (slot-combined profile, CFAR, peaks) -> range bins
        (rd, kd); :meth:`_estimate_angles` (OMP per detection, per-target range);
        :meth:`_assemble_points` (coordinates, target-level sidelobe check).
        """
        t0 = time.perf_counter()
        rd, kd = self._detect(spec)
        t1 = time.perf_counter()
        est = self._estimate_angles(spec, rd, kd)
        cloud = self._assemble_points(rd, kd, est)
        t2 = time.perf_counter()
        return cloud, {"range_cfar": t1 - t0, "omp": t2 - t1}

    def _profile(self, spec: np.ndarray) -> np.ndarray:
        """Slot-combined power profile ``P[r, k] = sum_{i,c} |Y[r, i, c, k]|^2`` (4, K_b), float64."""
        f = spec.view(np.float32)  # (..., 2 K_b): re, im interleaved
        p = np.einsum("ricb,ricb->rb", f, f)
        return p.reshape(p.shape[0], -1, 2).sum(axis=-1, dtype=np.float64)

    @functools.cached_property
    def _alpha(self) -> float:
        """The slot-summed statistic's threshold multiplier (:meth:`_threshold`): OS-CFAR's (:func:`os_cfar_alpha`,
        ~0.5 s of quadrature, so computed on first use: the default footprint detector has its own), CA-CFAR's, or the
        fixed threshold."""
        det = self.config.detection
        looks = self.config.scan.slots * self.config.waveform.chirps_per_slot
        if det.mode == "cfar" and det.method == "os":
            return os_cfar_alpha(det.pfa, looks, 2 * det.train, self._rank)
        if det.mode == "cfar":
            return cfar_alpha(det.pfa, looks, 2 * det.train)
        return float(10 ** (det.fixed_threshold_db / 10))

    def _threshold(self, prof: np.ndarray) -> np.ndarray:
        """Detection threshold per cell of the profile: OS / CA CFAR (noise estimate clipped to [floor, cap]) or fixed."""
        cfg = self.config
        cap = self._p_noise * 10 ** (cfg.detection.cap_db / 10)
        if cfg.detection.mode == "cfar" and cfg.detection.method == "os":
            return os_cfar_threshold(prof, cfg.detection.guard, cfg.detection.train, cfg.waveform.zero_pad, self._alpha, self._rank,
                                     floor=self._p_noise, cap=cap)
        if cfg.detection.mode == "cfar":
            return ca_cfar_threshold(prof, cfg.detection.guard, cfg.detection.train, cfg.waveform.zero_pad, self._alpha,
                                     floor=self._p_noise, cap=cap)
        return np.full(prof.shape, self._alpha * self._p_noise)

    def _detect(self, spec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Detected range cells (radar rd, bin kd): CFAR peaks beyond ``min_range_m``, window sidelobes dropped.

        ``config.detection.statistic`` chooses the statistic: "footprint", :class:`rhs_env.detection.FootprintDetector`
        per antenna (CFAR per beam footprint of slots); "summed", CFAR on the slot-summed profile (the paper's).
        """
        cfg = self.config
        if cfg.detection.statistic == "footprint":
            return self._detect_footprint(spec)
        prof = self._profile(spec)
        det = local_maxima(prof, self._threshold(prof))
        det &= (self._bin_range >= cfg.min_range_m - cfg.waveform.range_resolution_m / 2)[None, :]
        rd, kd = np.nonzero(det)
        if rd.size > 1:  # drop peaks explained by the window sidelobes of a stronger peak (same radar)
            pk = prof[rd, kd]
            dk = np.minimum(np.abs(kd[:, None] - kd[None, :]), self._leak.size - 1)
            leak = np.where((rd[:, None] == rd[None, :]) & (pk[None, :] > pk[:, None]),
                            pk[None, :] * self._leak[dk], 0.0).max(axis=1)
            keep = pk >= 10 ** (cfg.detection.sidelobe_margin_db / 10) * leak
            rd, kd = rd[keep], kd[keep]
        return rd, kd

    def _detect_footprint(self, spec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rd, kd) of the footprint detectors, one per distinct antenna, sorted by radar then bin."""
        cfg = self.config
        in_range = self._bin_range >= cfg.min_range_m - cfg.waveform.range_resolution_m / 2
        rds, kds = [], []
        for g, det in enumerate(self._detectors):
            radars = np.flatnonzero(self._radar_group == g)
            r, k, _ = det.detect(spec if radars.size == 4 else spec[radars], in_range)
            rds.append(radars[r])
            kds.append(k)
        rd, kd = np.concatenate(rds), np.concatenate(kds)
        o = np.lexsort((kd, rd))
        return rd[o], kd[o]

    def _estimate_angles(self, spec: np.ndarray, rd: np.ndarray, kd: np.ndarray) -> _Targets:
        """OMP (angle, Doppler, amplitude; up to ``estimation.max_targets`` per cell) and per-target range offsets.

        One :func:`omp_doppler` call per distinct antenna (all four radars share
        one unless the patterns differ), batched over every detection of the scan.
        """
        cfg = self.config
        kk = self._neighbour_bins(kd, spec.shape[-1])
        win, yd = self._impl.gather(spec, rd, kd, kk)  # compiled: the bins of _target_bins too, in one pass over Y
        est = _Targets.empty(rd.size, cfg.estimation.max_targets)
        y_var = cfg.noise_power_w * self._win_energy  # noise variance per cell of Y
        rel = 10 ** (cfg.estimation.residual_rel_db / 10)
        for g, (dic, _) in enumerate(self._groups):
            sel = np.flatnonzero(self._radar_group[rd] == g)
            if sel.size == 0:
                continue
            res = omp_doppler(dic, yd[sel], self._chirp_index, cfg.estimation.max_targets, np.full(sel.size, self._delta_r),
                              y_var, rel, self._min_amp, cfg.estimation.newton_steps,
                              cycles=cfg.estimation.refine_passes,
                              detected=bool(self._detectors),
                              refine_tol=cfg.estimation.refine_tol)
            est.theta[sel], est.amp[sel], est.valid[sel], est.omega[sel] = res.theta, res.amp, res.valid, res.omega
            est.anorm[sel] = atom_norms(res.atoms, cfg.kernels)
            win_sel = win if win is None or sel.size == rd.size else win[sel]  # sel: every row, in order, or some
            est.tfrac[sel] = self._target_bins(spec, rd[sel], kk[sel], res.atoms, win_sel)
        return est

    def _neighbour_bins(self, kd: np.ndarray, n_bins: int) -> np.ndarray:
        """The bins ``kd + m``, ``|m| <= 2 Z + 1``, clipped to the spectrum (D, W) int64: :meth:`_target_bins`' window."""
        half = 2 * self.config.waveform.zero_pad + 1
        return np.clip(kd[:, None] + np.arange(-half, half + 1)[None, :], 0, n_bins - 1).astype(np.int64)

    def _target_bins(self, spec: np.ndarray, rd: np.ndarray, kk: np.ndarray, atoms: np.ndarray,
                     win: np.ndarray | None = None) -> np.ndarray:
        """Per-target range offset from the detection's bin (D, L), padded bins.

        LS amplitudes of the fixed atoms at the neighbouring bins kk (:meth:`_neighbour_bins`), parabola on
        log|s|^2 (a target merged into the peak of another lies within the window
        main lobe, +-2 bins). Compiled with ``kernels="numba"`` (:func:`rhs_env.kernels.bin_amplitudes`), on the
        bins already gathered (``win`` (D, I, C, W), :func:`rhs_env.kernels.gather_bins`) or read from the spectrum.
        """
        return np.asarray(self._impl.target_bins(self, spec, rd, kk, atoms, win))

    def _target_bins_numpy(self, spec: np.ndarray, rd: np.ndarray, kk: np.ndarray, atoms: np.ndarray,
                           win: np.ndarray | None = None) -> np.ndarray:
        """:meth:`_target_bins` in numpy (the reference; ``win`` unused)."""
        half = kk.shape[1] // 2
        nb = spec[rd[:, None], :, :, kk].reshape(rd.size, 2 * half + 1, -1)  # (D, W, I C)
        s_nb = batched_lstsq(atoms, np.swapaxes(nb, 1, 2).astype(complex))  # (D, L, W)
        return self._peak_offsets(np.log(np.abs(s_nb) ** 2 + 1e-300), half)

    @staticmethod
    def _peak_offsets(pw: np.ndarray, half: int) -> np.ndarray:
        """Offset (D, L) of each target's peak from the window's centre ``half``, padded bins: the first interior
        maximum j of ``pw[d, l]`` (log-power over the W bins) and the parabola through its neighbours."""
        j = 1 + np.argmax(pw[:, :, 1:-1], axis=2)  # interior peak
        lm = np.take_along_axis(pw, (j - 1)[..., None], 2)[..., 0]
        l0 = np.take_along_axis(pw, j[..., None], 2)[..., 0]
        lp = np.take_along_axis(pw, (j + 1)[..., None], 2)[..., 0]
        return (j - half) + parabolic_offset(lm, l0, lp)

    def _assemble_points(self, rd: np.ndarray, kd: np.ndarray, est: _Targets) -> PointCloud:
        """Points of the valid targets: range (Doppler shift of the beat removed), position, velocity, amplitude.

        ``R = c0 (f - 2 v / lambda) / (2 S)`` with ``f = (kd + offset) f_s / (Z N)``,
        ``v = omega lambda / (4 pi T_c)``; amplitude ``|s| ||a|| / sigma_Y``. Points
        outside [min_range_m, max_range_m] and range sidelobes of stronger points
        at the same angle (:meth:`_sidelobe_points`) are dropped.
        """
        cloud: PointCloud = self._impl.points(self, rd, kd, est)
        return cloud

    def _assemble_points_numpy(self, rd: np.ndarray, kd: np.ndarray, est: _Targets) -> PointCloud:
        """:meth:`_assemble_points` in numpy (the reference)."""
        cfg = self.config
        lam, z, n = cfg.wavelength, cfg.waveform.zero_pad, cfg.waveform.samples
        di, li = np.nonzero(est.valid)
        vel = _wrap(est.omega[di, li]) * lam / (4 * np.pi * cfg.waveform.chirp_s)
        f_beat = (kd[di] + est.tfrac[di, li]) * cfg.waveform.sample_rate_hz / (z * n) - 2 * vel / lam
        rng_m = SPEED_OF_LIGHT * f_beat / (2 * cfg.waveform.slope)
        th = est.theta[di, li]
        radar = rd[di]
        ang_v = self.boresights[radar] + th
        xy = self.positions[radar] + rng_m[:, None] * np.stack([np.cos(ang_v), np.sin(ang_v)], -1)
        a = np.abs(est.amp[di, li]) * est.anorm[di, li] / math.sqrt(cfg.noise_power_w * self._win_energy)
        keep = (rng_m >= cfg.min_range_m) & (rng_m <= cfg.max_range_m) & ~self._sidelobe_points(radar, rng_m, th, a)
        pts = np.column_stack([xy, vel, a])[keep]
        cloud = PointCloud(points=pts, radar=radar[keep], range_m=rng_m[keep], angle_rad=th[keep])
        attach_uncertainty(self, cloud)  # per-point range / angle std (rhs_env.uncertainty)
        return cloud

    def _assemble_points_compiled(self, rd: np.ndarray, kd: np.ndarray, est: _Targets) -> PointCloud:
        """:meth:`_assemble_points` with the points compiled (:func:`rhs_env.kernels.assemble_points`): the same
        operations in the same order, the same values bit for bit; the uncertainty stays numpy's (its SIMD complex
        products and absolute values)."""
        from rhs_env import kernels

        cfg = self.config
        wf = cfg.waveform
        pts, radar, rng_m, th = kernels.assemble_points(
            rd.astype(np.int64), kd.astype(np.int64), est.theta, est.omega, np.abs(est.amp), est.valid, est.anorm, est.tfrac,
            self.positions, self.boresights, cfg.wavelength, 4 * np.pi * wf.chirp_s, wf.sample_rate_hz,
            float(wf.zero_pad), float(wf.samples), SPEED_OF_LIGHT, wf.slope, math.sqrt(cfg.noise_power_w * self._win_energy),
            cfg.min_range_m, cfg.max_range_m, self._leak, self._same_angle, 10 ** (cfg.detection.sidelobe_margin_db / 10))
        cloud = PointCloud(points=pts, radar=radar, range_m=rng_m, angle_rad=th)
        attach_uncertainty(self, cloud)  # per-point range / angle std (rhs_env.uncertainty)
        return cloud

    def _sidelobe_points(self, radar: np.ndarray, rng_m: np.ndarray, th: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Target-level range-sidelobe check (bool per point).

        A weaker point at the same angle, as strong as the window's sidelobe of a
        stronger point at that range offset (+ margin), is that sidelobe.
        """
        cfg = self.config
        if radar.size < 2:
            return np.zeros(radar.size, bool)
        bins = rng_m * 2 * cfg.waveform.slope / SPEED_OF_LIGHT * cfg.waveform.zero_pad * cfg.waveform.samples / cfg.waveform.sample_rate_hz
        dk = np.minimum(np.abs(np.rint(bins[:, None] - bins[None, :])).astype(int), self._leak.size - 1)
        same = (radar[:, None] == radar[None, :]) & (np.abs(th[:, None] - th[None, :]) < self._same_angle)
        a2 = a ** 2
        leak = np.where(same & (a2[None, :] > a2[:, None]), a2[None, :] * self._leak[dk], 0.0).max(axis=1)
        return a2 < 10 ** (cfg.detection.sidelobe_margin_db / 10) * leak

    def warm_refinement(self) -> None:
        """Compile (or load) the OMP's joint refinement's stages and row bookkeeping with the scan's own operand types
        (:func:`rhs_env.point_cloud.warm_refinement_kernels`): the first part of a background compile's radar work
        (:mod:`slam.gym.precompile`), while an env's first scan compiles the synthesis, the detector and the OMP's
        search. Each ``warm_*`` method does nothing with ``kernels="numpy"``."""
        self._impl.warm_refinement(self)

    def _warm_refinement_compiled(self) -> None:
        """:meth:`warm_refinement` (the compiled stages)."""
        cfg = self.config
        from rhs_env.point_cloud import warm_refinement_kernels

        for dic, _ in self._groups:
            warm_refinement_kernels(dic, self._chirp_index, cfg.estimation.max_targets, cfg.estimation.refine_passes,
                                    cfg.estimation.newton_steps, cfg.estimation.refine_tol)

    def warm_points(self) -> None:
        """Compile (or load) the points' kernels (:meth:`_target_bins`, :meth:`_assemble_points`) on one synthetic
        target in each of the four cells of :meth:`_warm_cells`."""
        self._impl.warm_points(self)

    def _warm_points_compiled(self) -> None:
        """:meth:`warm_points` (the compiled stages)."""
        cfg = self.config
        from rhs_env.kernels import gather_bins

        n_q, n_l = cfg.scan.slots * cfg.waveform.chirps_per_slot, cfg.estimation.max_targets
        rd, kd, spec = self._warm_cells()
        kk = self._neighbour_bins(kd, spec.shape[-1])
        win, _ = gather_bins(spec, rd, kk, kk.shape[1] // 2)
        est = _Targets.empty(4, n_l)
        est.valid[:, 0], est.amp[:, 0], est.anorm[:, 0] = True, 1.0, 1.0
        est.tfrac[:] = self._target_bins(spec, rd, kk, np.ones((4, n_q, n_l), complex), win)
        self._assemble_points(rd, kd, est)

    def warm_one_call_omp(self) -> None:
        """Compile (or load) the one-call OMP (:func:`rhs_env.kernels.omp_doppler`) with the scan's own operand types,
        on the noise of :meth:`_warm_cells`: the last thing a background compile does, after which an env's scans
        switch from its Python body to it (:data:`rhs_env.kernels.omp_doppler_tiered`)."""
        self._impl.warm_one_call_omp(self)

    def _warm_one_call_omp_compiled(self) -> None:
        """:meth:`warm_one_call_omp` (the compiled stages)."""
        from rhs_env.kernels import omp_doppler_tiered

        rd, kd, spec = self._warm_cells()
        mode, omp_doppler_tiered.mode = omp_doppler_tiered.mode, "compiled"
        try:
            self._estimate_angles(spec, rd, kd)
        finally:
            omp_doppler_tiered.mode = mode

    def _warm_cells(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cells (radar ``rd``, bin ``kd``), bin 40 of each radar, and a noise spectrum to warm kernels on."""
        cfg = self.config
        spec = self._noise_spectrum((4, cfg.scan.slots, cfg.waveform.chirps_per_slot))
        return np.arange(4, dtype=np.int64), np.full(4, 40, np.int64), spec

    def scan(self, scatterers: Scatterers, occluders: Occluders | None = None) -> PointCloud:
        """One sensing cycle of the four radars -> :class:`PointCloud` with ``stage_times``.

        ``fidelity="iq"``: samples (:meth:`synthesize`), range FFT, processing;
        ``"range"``: the spectrum directly (:meth:`synthesize_spectrum`), processing.
        """
        t0 = time.perf_counter()
        cfg = self.config
        if cfg.fidelity == "iq":
            y = self.synthesize(scatterers, occluders, out=self._buffer(
                "y", (4, cfg.scan.slots, cfg.waveform.chirps_per_slot, cfg.waveform.samples), np.complex64))
            t1 = time.perf_counter()
            cloud, times = self.process(y)
        else:
            spec = self.synthesize_spectrum(scatterers, occluders)
            t1 = time.perf_counter()
            cloud, times = self.process_spectrum(spec)
        cloud.stage_times = {"synthesis": t1 - t0, **times}
        cloud.stage_times["total"] = sum(cloud.stage_times.values())
        return cloud

    # ------------------------------------------------------------------ references
    def angle_crb(self, theta_rad: np.ndarray, range_m: float, rcs_m2: float, radar: int = 0) -> np.ndarray:
        """Angle CRB (rad^2) of a single target at (theta, R, sigma) for radar ``radar``."""
        return angle_crb(self.antennas[radar], theta_rad, self.config.unit_gain_snr(range_m, rcs_m2))

    def point_errors(self, cloud: PointCloud, scatterers: Scatterers, occluders: Occluders | None = None,
                     gate_m: float = 1.0) -> dict[str, Any]:
        """Per-target errors of ``cloud`` against the scatterers in view.

        Each scatterer in view is matched to its nearest point; it is detected when
        that point lies within ``gate_m``. For the detected ones, the errors of the
        point's own measurement against the truth seen from the point's radar:
        ``xy`` (m, Euclidean), ``range`` (m), ``angle`` (rad, wrapped) and ``doppler``
        (radial velocity, m/s, ``u . v`` with u the unit vector radar -> scatterer).
        Returns ``n_true``, ``n_detected``, ``false_points`` and the error arrays.
        """
        view = self.in_view(scatterers, occluders)
        truth = scatterers.xy[view]
        out: dict[str, Any] = {"n_true": int(view.sum()), "n_points": len(cloud)}
        empty = np.zeros(0)
        if len(cloud) == 0 or truth.shape[0] == 0:
            return {**out, "n_detected": 0, "false_points": len(cloud),
                    "xy": empty, "range": empty, "angle": empty, "doppler": empty}
        d2 = np.sum((truth[:, None, :] - cloud.xy[None, :, :]) ** 2, axis=-1)  # (T, P)
        j = np.argmin(d2, axis=1)
        hit = d2[np.arange(truth.shape[0]), j] <= gate_m ** 2
        p, t = j[hit], np.flatnonzero(view)[hit]
        rng_m, ang, unit = self.radar_frame(scatterers.xy[t])
        r = cloud.radar[p]
        k = np.arange(p.size)
        v_true = np.einsum("kd,kd->k", unit[r, k], scatterers.velocity[t])
        return {**out, "n_detected": int(hit.sum()), "false_points": int(np.sum(d2.min(axis=0) > gate_m ** 2)),
                "xy": np.sqrt(d2[hit, p]), "range": cloud.range_m[p] - rng_m[r, k],
                "angle": _wrap(cloud.angle_rad[p] - ang[r, k]), "doppler": cloud.points[p, 2] - v_true}

    def metrics(self, cloud: PointCloud, scatterers: Scatterers, occluders: Occluders | None = None,
                gate_m: float = 1.0, per_object: bool = False) -> dict:
        """Point-cloud metrics of ``cloud`` against the scatterers in view."""
        view = self.in_view(scatterers, occluders)
        return pointcloud_metrics(cloud.xy, scatterers.xy[view], gate_m,
                                  scatterers.object_id[view] if per_object else None)


def _nothing(radar: RadarSystem) -> None:
    """A compiled path's warm-up with ``kernels="numpy"``: nothing to compile."""


#: the radar's stages that have a compiled twin (:mod:`rhs_env.kernels`), chosen once by ``RadarConfig.kernels``
#: (:attr:`RadarSystem._impl`); each numba function computes what its numpy one does (the equivalence tests)
_STAGES = KernelTable("rhs_env.radar")
_STAGES.stage("line_of_sight", "numpy")(RadarSystem._line_of_sight_numpy)
_STAGES.stage("add_tones", "numpy")(RadarSystem._add_tones_numpy)
_STAGES.stage("noise", "numpy")(RadarSystem._noise_numpy)
_STAGES.stage("target_bins", "numpy")(RadarSystem._target_bins_numpy)
_STAGES.stage("points", "numpy")(RadarSystem._assemble_points_numpy)
_STAGES.stage("points", "numba")(RadarSystem._assemble_points_compiled)
_STAGES.stage("warm_refinement", "numba")(RadarSystem._warm_refinement_compiled)
_STAGES.stage("warm_points", "numba")(RadarSystem._warm_points_compiled)
_STAGES.stage("warm_one_call_omp", "numba")(RadarSystem._warm_one_call_omp_compiled)
for _warm in ("warm_refinement", "warm_points", "warm_one_call_omp"):
    _STAGES.stage(_warm, "numpy")(_nothing)


@_STAGES.stage("line_of_sight", "numba")
def _line_of_sight_compiled(radar: RadarSystem, fov: np.ndarray, scatterers: Scatterers,
                            occluders: Occluders | None) -> np.ndarray:
    """:meth:`RadarSystem.visible`'s line of sight compiled (:func:`rhs_env.kernels.line_of_sight`): the same test per
    (radar, point) in the field of view, up to its first crossing; numpy without occluders or scatterers."""
    if occluders is None or not len(occluders) or not len(scatterers):
        return radar._line_of_sight_numpy(fov, scatterers, occluders)
    from rhs_env.kernels import line_of_sight

    return np.asarray(line_of_sight(radar.positions, np.ascontiguousarray(scatterers.xy, dtype=float),
                                    np.ascontiguousarray(occluders.segments, dtype=float),
                                    np.ascontiguousarray(scatterers.object_id), np.ascontiguousarray(occluders.object_id),
                                    np.ascontiguousarray(fov), LOS_EPS))


@_STAGES.stage("gains", "numpy")
def _gains_numpy(dic: AngleDictionary, theta: np.ndarray) -> np.ndarray:
    """The slot gains h (I, P) toward the angles ``theta`` (P,): the antenna's direct product (the reference)."""
    return np.asarray(dic.antenna.two_way_gain(theta))


@_STAGES.stage("gains", "numba")
def _gains_compiled(dic: AngleDictionary, theta: np.ndarray) -> np.ndarray:
    """:func:`_gains_numpy` from the dictionary's series (:meth:`AngleDictionary.atoms`: the same gains to ~1e-15)."""
    return np.asarray(dic.atoms(theta)[0])


@_STAGES.stage("add_tones", "numba")
def _add_tones_compiled(radar: RadarSystem, spec: np.ndarray,
                        tones: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]) -> None:
    """:meth:`RadarSystem._add_tones_numpy` compiled: the tone spectra and the product's operands
    (:func:`rhs_env.kernels.tone_spectra`, :func:`rhs_env.kernels.tone_operands`), each radar's own tones only (no
    padding to the largest count), each product added by BLAS straight into the spectrum view
    (:func:`rhs_env.kernels.add_tone_products`)."""
    from rhs_common.native import cgemm_address
    from rhs_env import kernels
    from rhs_env.point_cloud import window_exponentials

    cfg = radar.config
    c, n, z, kb = cfg.waveform.chirps_per_slot, cfg.waveform.samples, cfg.waveform.zero_pad, radar._bin_hi
    rr, g_mat, omega, f_tot = tones
    mu, coef = window_exponentials(cfg.waveform.window, n)
    wk = kernels.tone_spectra(mu, coef, n, z, kb, np.ascontiguousarray(f_tot / cfg.waveform.sample_rate_hz))
    gp, ep = kernels.tone_operands(g_mat, omega, wk, c)
    bounds = np.searchsorted(rr, np.arange(5))  # rr sorted: radar r's tones are lo_r:hi_r
    kernels.add_tone_products(gp, ep, bounds, spec, cgemm_address())


@_STAGES.stage("noise", "numba")
def _noise_compiled(radar: RadarSystem, bits: np.ndarray, m: int, n: int) -> np.ndarray:
    """:meth:`RadarSystem._noise_numpy` with the elementwise passes fused (:func:`rhs_env.kernels.noise_uniforms`,
    :func:`rhs_env.kernels.noise_samples`) around numpy's ``log1p``, ``cos`` and ``sin``, the FFT padding each row
    itself: the same float32 operations, the same spectrum bit for bit."""
    from rhs_env.kernels import noise_samples, noise_uniforms

    neg_u1 = radar._buffer("nu1", (m, n), np.float32)
    ph = radar._buffer("nph", (m, n), np.float32)
    noise_uniforms(bits, np.float32(2.0 ** -24), np.float32(0.5), np.float32(2 * np.pi), neg_u1.reshape(-1),
                   ph.reshape(-1))
    np.log1p(neg_u1, out=neg_u1)
    cos_ph = radar._buffer("ncos", (m, n), np.float32)
    np.cos(ph, out=cos_ph)
    np.sin(ph, out=ph)
    samples = radar._buffer("nsmp", (m, n), np.complex64)
    noise_samples(neg_u1, cos_ph, ph, radar._noise_window, samples.view(np.float32))
    # zero-padded inside pocketfft: the same spectrum
    return np.asarray(sfft.fft(samples, n=radar.config.waveform.zero_pad * n, axis=-1, workers=1))


@_STAGES.stage("gather", "numpy")
def _gather_numpy(spec: np.ndarray, rd: np.ndarray, kd: np.ndarray, kk: np.ndarray) -> tuple[None, np.ndarray]:
    """The OMP's data ``Y[rd, :, :, kd]`` (D, I, C) complex128, numpy (no window of bins: None)."""
    return None, spec[rd, :, :, kd].astype(np.complex128)


@_STAGES.stage("gather", "numba")
def _gather_compiled(spec: np.ndarray, rd: np.ndarray, kd: np.ndarray, kk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The neighbouring bins ``kk`` of :meth:`RadarSystem._target_bins` (D, I, C, W) and the OMP's data in one pass
    over Y (:func:`rhs_env.kernels.gather_bins`)."""
    from rhs_env.kernels import gather_bins

    win, yd = gather_bins(spec, rd.astype(np.int64), kk, kk.shape[1] // 2)
    return win, yd


@_STAGES.stage("target_bins", "numba")
def _target_bins_compiled(radar: RadarSystem, spec: np.ndarray, rd: np.ndarray, kk: np.ndarray, atoms: np.ndarray,
                          win: np.ndarray | None = None) -> np.ndarray:
    """:meth:`RadarSystem._target_bins` compiled: the same least squares (:func:`rhs_env.kernels.bin_amplitudes`) on
    the bins already gathered (``win``) or read from the spectrum, and the parabola
    (:func:`rhs_env.kernels.range_offsets`); the logarithm stays numpy's (its SIMD log)."""
    from rhs_env.kernels import bin_amplitudes, range_offsets

    a = np.ascontiguousarray(atoms, dtype=complex)
    if win is None:
        s_nb = bin_amplitudes(a, spec, rd.astype(np.int64), kk)
    else:  # Y := win, radar d, bins 0..W-1: the same values, read contiguously
        s_nb = bin_amplitudes(a, win, np.arange(rd.size, dtype=np.int64),
                              np.ascontiguousarray(np.broadcast_to(np.arange(kk.shape[1]), kk.shape)))
    return np.asarray(range_offsets(np.log(np.abs(s_nb) ** 2 + 1e-300), kk.shape[1] // 2))
