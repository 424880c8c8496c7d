"""The range transform of the four radars: the window, the searched bins and the range FFT (the matched filter).

A stage of :class:`rhs_env.radar.RadarSystem` (its ``range_fft``). Its constants (window, bins, leakage
envelope) are read by the noise, the detection, the angle estimation and the points.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft

from rhs_env.array_models import SPEED_OF_LIGHT
from rhs_env.point_cloud import window_leak_envelope
from rhs_env.radar.buffers import WorkBuffers
from rhs_env.radar_config import RadarConfig
from rhs_env.windows import make_window

__all__ = ["RangeFFT"]


class RangeFFT:
    """The windowed, zero-padded range FFT and its bins.

    For a linear chirp of slope ``S = B / T_c`` (Hz/s), correlating the echo with the transmitted chirp equals
    dechirping and taking the Fourier transform, so the range profile of slot i, chirp c is

        Y[i, c, k] = sum_n w[n] y[i, c, n] exp(-j 2 pi k n / (Z N)),

    bin k <-> beat frequency ``f = k f_s / (Z N)`` (Hz) <-> range ``R = c0 f / (2 S)`` (m): ``bins_per_m =
    2 S Z N / (c0 f_s)`` (bin width ``c0 / (2 B)`` = 0.6 m before the zero padding Z). Only the bins ``k < K_b``
    are kept: up to ``max_range_m`` plus the CFAR's margin ``(guard + train + 2) Z``.

    Args:
        config: :class:`rhs_env.radar_config.RadarConfig` (``waveform``, ``detection``, ``max_range_m``).

    Attributes:
        window: (N,) the range window ``w``.
        win_energy: ``sum_n w[n]^2`` (the noise variance per cell of Y is ``sigma_n^2`` times it).
        bins_per_m: padded bins per metre of range (zero Doppler).
        bin_hi: ``K_b``, the number of bins searched.
        bin_range: (K_b,) range of bin k at zero Doppler, m.
        leak: the window's sidelobe envelope per bin offset (power, relative to the peak:
            :func:`rhs_env.point_cloud.window_leak_envelope`).
    """

    def __init__(self, config: RadarConfig) -> None:
        self.config = config
        wf, det = config.waveform, config.detection
        n, z = wf.samples, wf.zero_pad
        self.window = make_window(wf.window, n)
        self.win_energy = float(np.sum(self.window.astype(float) ** 2))
        self.bins_per_m = bins_per_m = 2 * wf.slope / SPEED_OF_LIGHT * z * n / wf.sample_rate_hz
        margin = (det.guard + det.train + 2) * z
        self.bin_hi = int(min(z * n, math.ceil(config.max_range_m * bins_per_m) + margin))
        self.bin_range = np.arange(self.bin_hi) / bins_per_m
        self.leak = window_leak_envelope(self.window, z, z * n // 2)
        self._buffers = WorkBuffers()

    def spectrum(self, y: np.ndarray) -> np.ndarray:
        """Windowed, zero-padded range FFT of y (4, I, C, N) -> bins ``k < K_b`` (4, I, C, K_b) complex64 (a view)."""
        z, n = self.config.waveform.zero_pad, self.config.waveform.samples
        buf = self._buffers.get("fft", y.shape[:-1] + (z * n,), np.complex64)
        np.multiply(y, self.window, out=buf[..., :n])
        buf[..., n:] = 0
        # in place (overwrite_x): the padded buffer becomes the spectrum, no fresh 9 MB array per scan
        return sfft.fft(buf, axis=-1, workers=1, overwrite_x=True)[..., : self.bin_hi]
