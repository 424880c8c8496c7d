"""The point cloud of the four radars: the estimated targets as points, with their range and angle uncertainty.

A stage of :class:`rhs_env.radar.RadarSystem` (its ``assembler``).
"""

from __future__ import annotations

import math

import numpy as np

from rhs_common.jit import KernelTable
from rhs_env.array_models import SPEED_OF_LIGHT
from rhs_env.point_cloud import PointCloud
from rhs_env.radar.antennas import BeamPatterns
from rhs_env.radar.estimation import AngleEstimator, Targets, WarmCells
from rhs_env.radar.mounting import RadarMounts, wrap_angle
from rhs_env.radar.range_fft import RangeFFT
from rhs_env.radar_config import RadarConfig
from rhs_env.uncertainty import attach_uncertainty

__all__ = ["PointAssembler"]


class PointAssembler:
    """Points of the valid targets: range (Doppler shift of the beat removed), position, velocity, amplitude, stds.

    ``R = c0 (f - 2 v / lambda) / (2 S)`` (m) with ``f = (kd + offset) f_s / (Z N)`` (Hz),
    ``v = wrap(omega) lambda / (4 pi T_c)`` (m/s, radial, > 0 receding), ``(x, y) = m_r + R (cos, sin)(b_r + theta)``
    (m, vehicle frame), amplitude ``|s| ||a|| / sigma_Y`` (the amplitude SNR of the target over the sweep, linear;
    ``a`` the atom over slots and chirps, ``sigma_Y^2 = sigma_n^2 sum_n w[n]^2``). Points outside
    [``min_range_m``, ``max_range_m``] are dropped, and so are range sidelobes: a weaker point at the same angle
    (within a quarter of the grid step) of the same radar, whose power ``a^2`` is below ``margin`` times the window's
    sidelobe ``a_strong^2 leak[dk]`` of a stronger point ``dk`` padded bins away (:meth:`sidelobe_points`).

    Each point then gets its range and angle standard deviations (``PointCloud.range_std_m``,
    ``angle_std_rad``: :func:`rhs_env.uncertainty.attach_uncertainty`, from the antenna's angle information and the
    waveform; the covariance the SLAM weighs it with).

    Args:
        config: :class:`rhs_env.radar_config.RadarConfig` (``waveform``, ``detection``, ``uncertainty``, range limits).
        mounts: the radars' positions and boresights.
        range_fft: the range transform (window energy, leakage envelope).
        beams: the antennas' dictionaries (the angle information of the uncertainty).

    Attributes:
        dictionaries: the dictionary of each radar (what :func:`rhs_env.uncertainty.attach_uncertainty` reads).
    """

    def __init__(self, config: RadarConfig, mounts: RadarMounts, range_fft: RangeFFT, beams: BeamPatterns) -> None:
        self.config = config
        self.mounts = mounts
        self.dictionaries = beams.dictionaries
        self._win_energy = range_fft.win_energy
        self._leak = range_fft.leak
        self._same_angle = 0.25 * np.deg2rad(config.scan.grid_deg)
        self._impl = _STAGES.choose(config.kernels)  # the compiled or the numpy points

    def assemble(self, rd: np.ndarray, kd: np.ndarray, est: Targets) -> PointCloud:
        """The point cloud of the targets ``est`` of the cells (radar ``rd``, bin ``kd``)."""
        cloud: PointCloud = self._impl.points(self, rd, kd, est)
        return cloud

    def _assemble_numpy(self, rd: np.ndarray, kd: np.ndarray, est: Targets) -> PointCloud:
        """:meth:`assemble` in numpy (the reference)."""
        cfg = self.config
        lam, z, n = cfg.wavelength, cfg.waveform.zero_pad, cfg.waveform.samples
        di, li = np.nonzero(est.valid)
        vel = wrap_angle(est.omega[di, li]) * lam / (4 * np.pi * cfg.waveform.chirp_s)
        f_beat = (kd[di] + est.tfrac[di, li]) * cfg.waveform.sample_rate_hz / (z * n) - 2 * vel / lam
        rng_m = SPEED_OF_LIGHT * f_beat / (2 * cfg.waveform.slope)
        th = est.theta[di, li]
        radar = rd[di]
        ang_v = self.mounts.boresights[radar] + th
        xy = self.mounts.positions[radar] + rng_m[:, None] * np.stack([np.cos(ang_v), np.sin(ang_v)], -1)
        a = np.abs(est.amp[di, li]) * est.anorm[di, li] / math.sqrt(cfg.noise_power_w * self._win_energy)
        keep = (rng_m >= cfg.min_range_m) & (rng_m <= cfg.max_range_m) & ~self.sidelobe_points(radar, rng_m, th, a)
        pts = np.column_stack([xy, vel, a])[keep]
        cloud = PointCloud(points=pts, radar=radar[keep], range_m=rng_m[keep], angle_rad=th[keep])
        attach_uncertainty(self, cloud)  # per-point range / angle std (rhs_env.uncertainty)
        return cloud

    def _assemble_compiled(self, rd: np.ndarray, kd: np.ndarray, est: Targets) -> PointCloud:
        """:meth:`assemble` with the points compiled (:func:`rhs_env.kernels.assemble_points`): the same
        operations in the same order, the same values bit for bit; the uncertainty stays numpy's (its SIMD complex
        products and absolute values)."""
        from rhs_env import kernels

        cfg = self.config
        wf = cfg.waveform
        pts, radar, rng_m, th = kernels.assemble_points(
            rd.astype(np.int64), kd.astype(np.int64), est.theta, est.omega, np.abs(est.amp), est.valid, est.anorm, est.tfrac,
            self.mounts.positions, self.mounts.boresights, cfg.wavelength, 4 * np.pi * wf.chirp_s, wf.sample_rate_hz,
            float(wf.zero_pad), float(wf.samples), SPEED_OF_LIGHT, wf.slope, math.sqrt(cfg.noise_power_w * self._win_energy),
            cfg.min_range_m, cfg.max_range_m, self._leak, self._same_angle, 10 ** (cfg.detection.sidelobe_margin_db / 10))
        cloud = PointCloud(points=pts, radar=radar, range_m=rng_m, angle_rad=th)
        attach_uncertainty(self, cloud)  # per-point range / angle std (rhs_env.uncertainty)
        return cloud

    def sidelobe_points(self, radar: np.ndarray, rng_m: np.ndarray, th: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Target-level range-sidelobe check (bool per point: True for a sidelobe of a stronger point).

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

    def warm(self, estimator: AngleEstimator, cells: WarmCells) -> None:
        """Compile (or load) the points' kernels (:meth:`AngleEstimator.target_bins`, :meth:`assemble`) on one
        synthetic target in each of the cells ``cells()`` gives (called only then: nothing with ``kernels="numpy"``)."""
        self._impl.warm_points(self, estimator, cells)

    def _warm_compiled(self, estimator: AngleEstimator, cells: WarmCells) -> None:
        """:meth:`warm` (the compiled stages)."""
        cfg = self.config
        from rhs_env.kernels import gather_bins

        n_q, n_l = cfg.scan.slots * cfg.waveform.chirps_per_slot, cfg.estimation.max_targets
        rd, kd, spec = cells()
        kk = estimator.neighbour_bins(kd, spec.shape[-1])
        win, _ = gather_bins(spec, rd, kk, kk.shape[1] // 2)
        est = Targets.empty(rd.size, n_l)
        est.valid[:, 0], est.amp[:, 0], est.anorm[:, 0] = True, 1.0, 1.0
        est.tfrac[:] = estimator.target_bins(spec, rd, kk, np.ones((rd.size, n_q, n_l), complex), win)
        self.assemble(rd, kd, est)


def _nothing(assembler: PointAssembler, estimator: AngleEstimator, cells: WarmCells) -> None:
    """The points' warm-up with ``kernels="numpy"``: nothing to compile."""


#: the points' two implementations and their warm-up, chosen once by ``RadarConfig.kernels``
_STAGES = KernelTable("rhs_env.radar.points")
_STAGES.stage("points", "numpy")(PointAssembler._assemble_numpy)
_STAGES.stage("points", "numba")(PointAssembler._assemble_compiled)
_STAGES.stage("warm_points", "numpy")(_nothing)
_STAGES.stage("warm_points", "numba")(PointAssembler._warm_compiled)
