"""Detection of the four radars: the range cells (radar, bin) that hold a target, from the range spectrum.

A stage of :class:`rhs_env.radar.RadarSystem` (its ``detector``); the per-footprint detector it runs by default is
:class:`rhs_env.detection.FootprintDetector`.
"""

from __future__ import annotations

import functools

import numpy as np

from rhs_env.detection import FootprintDetector
from rhs_env.point_cloud import (
    ca_cfar_threshold,
    cfar_alpha,
    local_maxima,
    os_cfar_alpha,
    os_cfar_threshold,
)
from rhs_env.radar.antennas import BeamPatterns
from rhs_env.radar.range_fft import RangeFFT
from rhs_env.radar_config import RadarConfig

__all__ = ["RangeDetector"]


class RangeDetector:
    """Detected range cells: CFAR peaks beyond ``min_range_m``, window sidelobes dropped.

    ``config.detection.statistic`` chooses the statistic:

    * ``"footprint"`` (default): :class:`rhs_env.detection.FootprintDetector` per distinct antenna, a CFAR per beam
      footprint of slots.
    * ``"summed"`` (the paper's): the slot-combined profile ``P[r, k] = sum_{i,c} |Y[r, i, c, k]|^2`` (W, per
      cell; non-coherent integration over the sweep: pure noise makes each cell a Gamma(L = I C) variable of mean
      ``L sigma_Y^2``, ``sigma_Y^2 = sigma_n^2 sum_n w[n]^2``) against a threshold per cell: the ordered-statistic
      CFAR (``method="os"``, default: ``alpha`` times the rank-th smallest of the ``2 train`` training cells) or
      the cell-averaging one (``"ca"``: ``alpha`` times their mean, ``alpha = F^{-1}(1 - P_fa; 2L, 2 N_t L)``),
      the noise estimate clipped to [``L sigma_Y^2``, ``cap_db`` above it]; or ``mode="fixed"``: the paper's
      ``delta_d`` (``fixed_threshold_db`` above the noise mean). Detections are the local maxima above the
      threshold; a peak that the window's sidelobes under a stronger peak of the same radar explain
      (``P < margin * P_strong * leak[dk]``, ``sidelobe_margin_db``) is dropped.

    Args:
        config: :class:`rhs_env.radar_config.RadarConfig` (``detection``, ``scan``, ``waveform``, ``link``).
        range_fft: the range transform (window, bins, leakage envelope).
        beams: the antennas (one footprint detector per distinct dictionary).

    Attributes:
        noise_mean: ``L sigma_Y^2``, the mean of P per cell on pure noise (W).
        rank: the ordered statistic's rank among the training cells.
        footprint_detectors: the footprint detector of each dictionary of ``beams`` (empty for ``"summed"``).
    """

    def __init__(self, config: RadarConfig, range_fft: RangeFFT, beams: BeamPatterns) -> None:
        self.config = config
        det = config.detection
        self._range_fft = range_fft
        self._radar_group = beams.radar_group
        looks = config.scan.slots * config.waveform.chirps_per_slot
        self.noise_mean = looks * config.noise_power_w * range_fft.win_energy  # mean of P per cell, pure noise
        self.rank = max(1, round(det.rank * 2 * det.train))
        y_var = config.noise_power_w * range_fft.win_energy
        self.footprint_detectors = ([FootprintDetector(dic, config, y_var, range_fft.leak, range_fft.window)
                                     for dic in beams.groups] if det.statistic == "footprint" else [])

    def profile(self, spec: np.ndarray) -> np.ndarray:
        """Slot-combined power profile ``P[r, k] = sum_{i,c} |Y[r, i, c, k]|^2`` (4, K_b), float64."""
        f = spec.view(np.float32)  # (..., 2 K_b): re, im interleaved
        p = np.einsum("ricb,ricb->rb", f, f)
        return p.reshape(p.shape[0], -1, 2).sum(axis=-1, dtype=np.float64)

    @functools.cached_property
    def alpha(self) -> float:
        """The slot-summed statistic's threshold multiplier (:meth:`threshold`): OS-CFAR's
        (:func:`rhs_env.point_cloud.os_cfar_alpha`, ~0.5 s of quadrature, so computed on first use: the default
        footprint detector has its own), CA-CFAR's, or the fixed threshold."""
        det = self.config.detection
        looks = self.config.scan.slots * self.config.waveform.chirps_per_slot
        if det.mode == "cfar" and det.method == "os":
            return os_cfar_alpha(det.pfa, looks, 2 * det.train, self.rank)
        if det.mode == "cfar":
            return cfar_alpha(det.pfa, looks, 2 * det.train)
        return float(10 ** (det.fixed_threshold_db / 10))

    def threshold(self, prof: np.ndarray) -> np.ndarray:
        """Detection threshold per cell of the profile: OS / CA CFAR (noise estimate clipped to [floor, cap]) or fixed."""
        cfg = self.config
        cap = self.noise_mean * 10 ** (cfg.detection.cap_db / 10)
        if cfg.detection.mode == "cfar" and cfg.detection.method == "os":
            return os_cfar_threshold(prof, cfg.detection.guard, cfg.detection.train, cfg.waveform.zero_pad, self.alpha, self.rank,
                                     floor=self.noise_mean, cap=cap)
        if cfg.detection.mode == "cfar":
            return ca_cfar_threshold(prof, cfg.detection.guard, cfg.detection.train, cfg.waveform.zero_pad, self.alpha,
                                     floor=self.noise_mean, cap=cap)
        return np.full(prof.shape, self.alpha * self.noise_mean)

    def detect(self, spec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The detected cells of the spectrum (4, I, C, K_b): radar ``rd`` and bin ``kd`` (D,) int, sorted by radar
        then bin."""
        cfg = self.config
        if cfg.detection.statistic == "footprint":
            return self._detect_footprint(spec)
        leak = self._range_fft.leak
        prof = self.profile(spec)
        det = local_maxima(prof, self.threshold(prof))
        det &= (self._range_fft.bin_range >= cfg.min_range_m - cfg.waveform.range_resolution_m / 2)[None, :]
        rd, kd = np.nonzero(det)
        if rd.size > 1:  # drop peaks explained by the window sidelobes of a stronger peak (same radar)
            pk = prof[rd, kd]
            dk = np.minimum(np.abs(kd[:, None] - kd[None, :]), leak.size - 1)
            leak_pk = np.where((rd[:, None] == rd[None, :]) & (pk[None, :] > pk[:, None]),
                               pk[None, :] * leak[dk], 0.0).max(axis=1)
            keep = pk >= 10 ** (cfg.detection.sidelobe_margin_db / 10) * leak_pk
            rd, kd = rd[keep], kd[keep]
        return rd, kd

    def _detect_footprint(self, spec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rd, kd) of the footprint detectors, one per distinct antenna, sorted by radar then bin."""
        cfg = self.config
        in_range = self._range_fft.bin_range >= cfg.min_range_m - cfg.waveform.range_resolution_m / 2
        rds, kds = [], []
        for g, det in enumerate(self.footprint_detectors):
            radars = np.flatnonzero(self._radar_group == g)
            r, k, _ = det.detect(spec if radars.size == 4 else spec[radars], in_range)
            rds.append(radars[r])
            kds.append(k)
        rd, kd = np.concatenate(rds), np.concatenate(kds)
        o = np.lexsort((kd, rd))
        return rd[o], kd[o]
