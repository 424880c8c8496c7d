"""The receiver noise of the four radars: thermal noise in the IQ samples, or drawn straight into the range spectrum.

A stage of :class:`rhs_env.radar.RadarSystem` (its ``noise``), used by the echo synthesis
(:class:`rhs_env.radar.synthesis.EchoSynthesizer`) and by the kernels' warm-up.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft

from rhs_common.jit import KernelTable
from rhs_env.point_cloud import noise_decimation
from rhs_env.radar.buffers import WorkBuffers
from rhs_env.radar.range_fft import RangeFFT
from rhs_env.radar_config import RadarConfig

__all__ = ["ReceiverNoise", "uniform32"]


def uniform32(rng: np.random.Generator, out: np.ndarray) -> np.ndarray:
    """``rng.random(dtype=np.float32, out=out)``: the same numbers, drawn faster for PCG64.

    ``Generator.random`` in float32 takes 32-bit words ``w`` of the bit generator
    (PCG64: the low then the high half of each 64-bit output) and returns
    ``(w >> 8) 2^-24``; for an even count and no buffered half word that is
    exactly the vectorised form below on ``random_raw``, and the generator ends
    in the same state. Any other generator (or a buffered half word) takes the
    ``Generator.random`` call itself.
    """
    bg = rng.bit_generator
    if (out.size % 2 or not out.flags.c_contiguous or not np.little_endian or type(bg) is not np.random.PCG64
            or bg.state.get("has_uint32", 1) != 0):
        return rng.random(dtype=np.float32, out=out)
    words = bg.random_raw(out.size // 2).view(np.uint32)  # little-endian: low half first
    np.right_shift(words, 8, out=words)
    np.copyto(out.reshape(-1), words, casting="unsafe")  # < 2^24: exact in float32
    out *= np.float32(2.0 ** -24)
    return out


class ReceiverNoise:
    """Circular complex Gaussian receiver noise, ``eps ~ CN(0, sigma_n^2)`` per sample.

    ``sigma_n^2 = k T0 F f_s`` (W: Boltzmann's constant, the reference temperature, the noise figure and the
    sample rate; ``RadarConfig.noise_power_w``), i.i.d. over samples, chirps, slots and radars (the noise of the
    normalised Rx output is that of one element). Drawn by the polar method: ``|eps|^2 ~ Exp(sigma_n^2)``, so
    ``|eps| = sigma_n sqrt(-ln(1 - u1))`` and phase ``2 pi u2`` with float32 uniforms (the radius tail is cut at
    ``P = 2^-24``). Without ``link.add_noise`` nothing is added.

    Args:
        config: :class:`rhs_env.radar_config.RadarConfig` (``link``, ``waveform``, ``kernels``).
        range_fft: the range transform (its window and searched bins ``K_b``).

    Attributes:
        rate: the decimation ``D`` of the spectrum path's noise (:func:`rhs_env.point_cloud.noise_decimation`).
        window: (N / D,) the radius factor ``sqrt(D) w[D m] sigma_n`` of the spectrum path, float32.
    """

    def __init__(self, config: RadarConfig, range_fft: RangeFFT) -> None:
        self.config = config
        self.bin_hi = range_fft.bin_hi
        self.rate = noise_decimation(range_fft.window, config.waveform.zero_pad, self.bin_hi)
        self.window = range_fft.window[:: self.rate] * np.float32(math.sqrt(self.rate * config.noise_power_w))
        self._buffers = WorkBuffers()
        self._impl = _STAGES.choose(config.kernels)  # the fused or the numpy passes

    def buffer(self, name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
        """This stage's work array ``name`` (:meth:`rhs_env.radar.buffers.WorkBuffers.get`)."""
        return self._buffers.get(name, shape, dtype)

    def add_to_samples(self, y: np.ndarray, rng: np.random.Generator) -> None:
        """Add CN(0, sigma_n^2) noise to every sample of ``y`` (complex64, C-contiguous), in place (the IQ path)."""
        u = uniform32(rng, self.buffer("u", (2,) + y.shape, np.float32))
        rad = self.buffer("rad", y.shape, np.float32)
        tmp = self.buffer("tmp", y.shape, np.float32)
        np.negative(u[0], out=rad)
        np.log1p(rad, out=rad)
        np.negative(rad, out=rad)
        np.sqrt(rad, out=rad)
        rad *= np.float32(math.sqrt(self.config.noise_power_w))
        ph = u[1]
        ph *= np.float32(2 * np.pi)
        np.cos(ph, out=tmp)
        tmp *= rad
        y.real += tmp
        np.sin(ph, out=tmp)
        tmp *= rad
        y.imag += tmp

    def spectrum(self, shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
        """``FFT_{Z N}(w * eps)[..., :K_b]``, eps ~ CN(0, sigma_n^2) i.i.d. (zeros without noise): shape + (K_b,), a view.

        Drawn at the rate ``1 / D`` (:func:`rhs_env.point_cloud.noise_decimation`, D = 2 for the default Hann
        window and range): ``x[m] = sqrt(D) w[D m] eps[m]``, m < N / D, and its FFT of
        ``Z N / D`` bins. For D = 2 its bins have the covariance
        ``R(k - l) + R(k - l + Z N / 2)``, ``R(d) = sigma_n^2 sum_n w[n]^2
        exp(-j 2 pi d n / (Z N))`` (the identity ``2 sum_{n even} g[n] = sum_n g[n] (1 + (-1)^n)``):
        the full-rate covariance R plus an alias term that :func:`rhs_env.point_cloud.noise_decimation` has
        checked to be negligible on the searched bins. Half the normals and half the FFT.

        eps by the polar method as in :meth:`add_to_samples`, the uniforms as 24-bit fractions
        of the generator's raw 64-bit draws (one draw gives u1 and u2 for two
        samples; cheaper than ``Generator.random`` in float32), the window
        folded into the radius, then one zero-padded FFT per chirp. With ``kernels="numba"`` the
        elementwise passes around numpy's ``log1p``, ``cos`` and ``sin`` (uniforms, radius, window, products)
        run fused (:func:`rhs_env.kernels.noise_uniforms`, :func:`rhs_env.kernels.noise_samples`) and the FFT
        pads each row itself (``n = Z N / D``: no zeros written to memory, 0.1-0.3 ms less per scan): the same
        float32 operations, the same spectrum bit for bit.
        """
        cfg = self.config
        d, z, kb = self.rate, cfg.waveform.zero_pad, self.bin_hi
        n = cfg.waveform.samples // d
        m = math.prod(shape)
        if not cfg.link.add_noise:
            buf = self.buffer("nfft", (m, z * n), np.complex64)
            buf[:, :kb] = 0
            return buf[:, :kb].reshape(shape + (kb,))
        bits = rng.bit_generator.random_raw(m * n).view(np.int32)  # 2 m n independent 32-bit words
        return np.asarray(self._impl.noise(self, bits, m, n)[:, :kb].reshape(shape + (kb,)))

    def _spectrum_numpy(self, bits: np.ndarray, m: int, n: int) -> np.ndarray:
        """The noise spectra (m, Z n) of :meth:`spectrum` from the raw words ``bits``, numpy (the reference)."""
        z = self.config.waveform.zero_pad
        buf = self.buffer("nfft", (m, z * n), np.complex64)
        np.right_shift(bits, 8, out=bits)  # 24-bit signed: [-2^23, 2^23)
        u = self.buffer("nu", (2, m, n), np.float32)
        np.copyto(u, bits.reshape(2, m, n), casting="unsafe")
        u *= np.float32(2.0 ** -24)
        u += np.float32(0.5)  # uniform on [0, 1) in steps of 2^-24
        rad, ph = u
        np.negative(rad, out=rad)
        np.log1p(rad, out=rad)
        np.negative(rad, out=rad)
        np.sqrt(rad, out=rad)
        rad *= self.window
        ph *= np.float32(2 * np.pi)
        tmp = self.buffer("ntmp", (m, n), np.float32)
        np.cos(ph, out=tmp)
        np.multiply(tmp, rad, out=buf.real[:, :n])
        np.sin(ph, out=tmp)
        np.multiply(tmp, rad, out=buf.imag[:, :n])
        buf[:, n:] = 0
        return np.asarray(sfft.fft(buf, axis=-1, workers=1, overwrite_x=True))  # in place: the result is buf


#: the noise spectrum's two implementations, chosen once by ``RadarConfig.kernels``
_STAGES = KernelTable("rhs_env.radar.noise")
_STAGES.stage("noise", "numpy")(ReceiverNoise._spectrum_numpy)


@_STAGES.stage("noise", "numba")
def _spectrum_compiled(noise: ReceiverNoise, bits: np.ndarray, m: int, n: int) -> np.ndarray:
    """:meth:`ReceiverNoise._spectrum_numpy` with the elementwise passes fused (:func:`rhs_env.kernels.noise_uniforms`,
    :func:`rhs_env.kernels.noise_samples`) around numpy's ``log1p``, ``cos`` and ``sin``, the FFT padding each row
    itself: the same float32 operations, the same spectrum bit for bit."""
    from rhs_env.kernels import noise_samples, noise_uniforms

    neg_u1 = noise.buffer("nu1", (m, n), np.float32)
    ph = noise.buffer("nph", (m, n), np.float32)
    noise_uniforms(bits, np.float32(2.0 ** -24), np.float32(0.5), np.float32(2 * np.pi), neg_u1.reshape(-1),
                   ph.reshape(-1))
    np.log1p(neg_u1, out=neg_u1)
    cos_ph = noise.buffer("ncos", (m, n), np.float32)
    np.cos(ph, out=cos_ph)
    np.sin(ph, out=ph)
    samples = noise.buffer("nsmp", (m, n), np.complex64)
    noise_samples(neg_u1, cos_ph, ph, noise.window, samples.view(np.float32))
    # zero-padded inside pocketfft: the same spectrum
    return np.asarray(sfft.fft(samples, n=noise.config.waveform.zero_pad * n, axis=-1, workers=1))
