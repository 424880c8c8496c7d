"""Angle, Doppler and per-target range of the detected cells of the four radars: the OMP over the angle dictionary.

A stage of :class:`rhs_env.radar.RadarSystem` (its ``estimator``); the dictionary and the OMP are in
:mod:`rhs_env.omp` (their compiled twin in :mod:`rhs_env.kernels.omp`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rhs_common.jit import KernelTable
from rhs_common.linalg import batched_lstsq
from rhs_env.point_cloud import atom_norms, omp_doppler, parabolic_offset, residual_threshold
from rhs_env.radar.antennas import BeamPatterns
from rhs_env.radar.range_fft import RangeFFT
from rhs_env.radar_config import RadarConfig

__all__ = ["AngleEstimator", "Targets", "WarmCells", "peak_offsets"]

#: a zero-argument function giving warm-up cells: radar ``rd`` (D,), bin ``kd`` (D,) and a spectrum (4, I, C, K_b)
WarmCells = Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]]


@dataclass
class Targets:
    """Per detection (D) and target slot (L): the OMP estimates and the range offsets (padded bins) from kd."""

    theta: np.ndarray  #: (D, L) rad from boresight
    amp: np.ndarray  #: (D, L) complex LS amplitude per unit atom
    valid: np.ndarray  #: (D, L) bool
    anorm: np.ndarray  #: (D, L) ||a|| of the atom over slots and chirps
    omega: np.ndarray  #: (D, L) chirp-to-chirp Doppler phase, rad
    tfrac: np.ndarray  #: (D, L) bin offset of the target from its detection cell

    @classmethod
    def empty(cls, d: int, n_l: int) -> Targets:
        """D x L targets, none valid."""
        z = np.zeros((d, n_l))
        return cls(z.copy(), np.zeros((d, n_l), complex), np.zeros((d, n_l), bool), z.copy(), z.copy(), z.copy())


def peak_offsets(pw: np.ndarray, half: int) -> np.ndarray:
    """Offset (D, L) of each target's peak from the window's centre ``half``, padded bins: the first interior
    maximum j of ``pw[d, l]`` (log-power over the W bins) and the parabola through its neighbours."""
    j = 1 + np.argmax(pw[:, :, 1:-1], axis=2)  # interior peak
    lm = np.take_along_axis(pw, (j - 1)[..., None], 2)[..., 0]
    l0 = np.take_along_axis(pw, j[..., None], 2)[..., 0]
    lp = np.take_along_axis(pw, (j + 1)[..., None], 2)[..., 0]
    return (j - half) + parabolic_offset(lm, l0, lp)


class AngleEstimator:
    """The OMP per detected cell (angle, Doppler, amplitude) and each target's own range offset.

    At a detected bin the data over slots and chirps obey ``Y[i, c] = sum_k s_k h_i(theta_k) exp(j omega_k t_ic)
    + noise`` with ``t_ic = i C + c`` the chirp time over the sweep (:attr:`chirp_index`, in units of ``T_c``;
    ``i C`` left out with ``waveform.slot_doppler=False``) and ``omega = 4 pi v T_c / lambda`` (rad per chirp,
    ``|v| < lambda / (4 T_c)``). :func:`rhs_env.point_cloud.omp_doppler` adds atoms up to ``estimation.max_targets``
    and stops when ``||r||^2 < delta_r = sigma_Y^2 Gamma^{-1}(1 - p; I C)`` (:attr:`delta_r`: the residual noise
    alone leaves with probability ``p = estimation.residual_pfa``), below ``residual_rel_db`` of the data power, or
    when a new atom is weaker than ``min_amp = 10^(min_snr_db / 20) sigma_Y`` (:attr:`min_amp`), with ``sigma_Y^2 =
    sigma_n^2 sum_n w[n]^2`` the noise variance per cell of Y (W). One call per distinct antenna (all four radars
    share one unless the patterns differ), batched over every detection of the scan.

    Range per target: the least-squares amplitudes of the fixed atoms at the neighbouring bins ``kd + m``,
    ``|m| <= 2 Z + 1`` (:meth:`neighbour_bins`), give each target its own range profile; the parabola through its
    log-peak (:func:`peak_offsets`) refines it below a bin (two targets in one bin keep their own ranges; a target
    merged into the peak of another lies within the window main lobe, +-2 bins).

    Args:
        config: :class:`rhs_env.radar_config.RadarConfig` (``estimation``, ``scan``, ``waveform``, ``kernels``).
        beams: the antennas' dictionaries.
        range_fft: the range transform (its window energy).
        detected: the cells come from the footprint detectors (:func:`rhs_env.point_cloud.omp_doppler`'s
            ``detected``).
    """

    def __init__(self, config: RadarConfig, beams: BeamPatterns, range_fft: RangeFFT, detected: bool) -> None:
        self.config = config
        self.beams = beams
        self.detected = detected
        self._win_energy = range_fft.win_energy
        wf = config.waveform
        cells = config.scan.slots * wf.chirps_per_slot
        y_var = config.noise_power_w * range_fft.win_energy
        self.min_amp = 10 ** (config.estimation.min_snr_db / 20) * math.sqrt(y_var)
        self.delta_r = float(residual_threshold(y_var, cells, config.estimation.residual_pfa))
        i, c = config.scan.slots, wf.chirps_per_slot
        self.chirp_index = (np.arange(i)[:, None] * c * (1 if wf.slot_doppler else 0)
                            + np.arange(c)[None, :]).astype(float)  # (I, C): chirp time / T_c
        self._impl = _STAGES.choose(config.kernels)  # the compiled or the numpy gather, bins and warm-up

    def estimate(self, spec: np.ndarray, rd: np.ndarray, kd: np.ndarray) -> Targets:
        """The targets (up to ``estimation.max_targets`` per cell) of the cells (``rd``, ``kd``) of ``spec``."""
        cfg = self.config
        kk = self.neighbour_bins(kd, spec.shape[-1])
        win, yd = self._impl.gather(spec, rd, kd, kk)  # compiled: the bins of target_bins too, in one pass over Y
        est = Targets.empty(rd.size, cfg.estimation.max_targets)
        y_var = cfg.noise_power_w * self._win_energy  # noise variance per cell of Y
        rel = 10 ** (cfg.estimation.residual_rel_db / 10)
        for g, dic in enumerate(self.beams.groups):
            sel = np.flatnonzero(self.beams.radar_group[rd] == g)
            if sel.size == 0:
                continue
            res = omp_doppler(dic, yd[sel], self.chirp_index, cfg.estimation.max_targets, np.full(sel.size, self.delta_r),
                              y_var, rel, self.min_amp, cfg.estimation.newton_steps,
                              cycles=cfg.estimation.refine_passes,
                              detected=self.detected,
                              refine_tol=cfg.estimation.refine_tol)
            est.theta[sel], est.amp[sel], est.valid[sel], est.omega[sel] = res.theta, res.amp, res.valid, res.omega
            est.anorm[sel] = atom_norms(res.atoms, cfg.kernels)
            win_sel = win if win is None or sel.size == rd.size else win[sel]  # sel: every row, in order, or some
            est.tfrac[sel] = self.target_bins(spec, rd[sel], kk[sel], res.atoms, win_sel)
        return est

    def neighbour_bins(self, kd: np.ndarray, n_bins: int) -> np.ndarray:
        """The bins ``kd + m``, ``|m| <= 2 Z + 1``, clipped to the spectrum (D, W) int64: :meth:`target_bins`' window."""
        half = 2 * self.config.waveform.zero_pad + 1
        return np.clip(kd[:, None] + np.arange(-half, half + 1)[None, :], 0, n_bins - 1).astype(np.int64)

    def target_bins(self, spec: np.ndarray, rd: np.ndarray, kk: np.ndarray, atoms: np.ndarray,
                    win: np.ndarray | None = None) -> np.ndarray:
        """Per-target range offset from the detection's bin (D, L), padded bins.

        LS amplitudes of the fixed atoms at the neighbouring bins kk (:meth:`neighbour_bins`), parabola on
        log|s|^2. Compiled with ``kernels="numba"`` (:func:`rhs_env.kernels.bin_amplitudes`), on the
        bins already gathered (``win`` (D, I, C, W), :func:`rhs_env.kernels.gather_bins`) or read from the spectrum.
        """
        return np.asarray(self._impl.target_bins(self, spec, rd, kk, atoms, win))

    def _target_bins_numpy(self, spec: np.ndarray, rd: np.ndarray, kk: np.ndarray, atoms: np.ndarray,
                           win: np.ndarray | None = None) -> np.ndarray:
        """:meth:`target_bins` in numpy (the reference; ``win`` unused)."""
        half = kk.shape[1] // 2
        nb = spec[rd[:, None], :, :, kk].reshape(rd.size, 2 * half + 1, -1)  # (D, W, I C)
        s_nb = batched_lstsq(atoms, np.swapaxes(nb, 1, 2).astype(complex))  # (D, L, W)
        return peak_offsets(np.log(np.abs(s_nb) ** 2 + 1e-300), half)

    def warm_refinement(self) -> None:
        """Compile (or load) the OMP's joint refinement's stages and row bookkeeping with the scan's own operand types
        (:func:`rhs_env.point_cloud.warm_refinement_kernels`); nothing with ``kernels="numpy"``."""
        self._impl.warm_refinement(self)

    def _warm_refinement_compiled(self) -> None:
        """:meth:`warm_refinement` (the compiled stages)."""
        cfg = self.config
        from rhs_env.point_cloud import warm_refinement_kernels

        for dic in self.beams.groups:
            warm_refinement_kernels(dic, self.chirp_index, cfg.estimation.max_targets, cfg.estimation.refine_passes,
                                    cfg.estimation.newton_steps, cfg.estimation.refine_tol)

    def warm_one_call_omp(self, cells: WarmCells) -> None:
        """Compile (or load) the one-call OMP (:func:`rhs_env.kernels.omp_doppler`) with the scan's own operand types,
        on the cells ``cells()`` gives (called only then: nothing is drawn with ``kernels="numpy"``)."""
        self._impl.warm_one_call_omp(self, cells)

    def _warm_one_call_omp_compiled(self, cells: WarmCells) -> None:
        """:meth:`warm_one_call_omp` (the compiled stages)."""
        from rhs_env.kernels import omp_doppler_tiered

        rd, kd, spec = cells()
        mode, omp_doppler_tiered.mode = omp_doppler_tiered.mode, "compiled"
        try:
            self.estimate(spec, rd, kd)
        finally:
            omp_doppler_tiered.mode = mode


def _nothing(stage: object, *args: object) -> None:
    """A compiled path's warm-up with ``kernels="numpy"``: nothing to compile."""


#: the estimator's stages that have a compiled twin (:mod:`rhs_env.kernels`), chosen once by ``RadarConfig.kernels``;
#: each numba function computes what its numpy one does (the equivalence tests)
_STAGES = KernelTable("rhs_env.radar.estimation")
_STAGES.stage("target_bins", "numpy")(AngleEstimator._target_bins_numpy)
_STAGES.stage("warm_refinement", "numba")(AngleEstimator._warm_refinement_compiled)
_STAGES.stage("warm_one_call_omp", "numba")(AngleEstimator._warm_one_call_omp_compiled)
for _warm in ("warm_refinement", "warm_one_call_omp"):
    _STAGES.stage(_warm, "numpy")(_nothing)


@_STAGES.stage("gather", "numpy")
def _gather_numpy(spec: np.ndarray, rd: np.ndarray, kd: np.ndarray, kk: np.ndarray) -> tuple[None, np.ndarray]:
    """The OMP's data ``Y[rd, :, :, kd]`` (D, I, C) complex128, numpy (no window of bins: None)."""
    return None, spec[rd, :, :, kd].astype(np.complex128)


@_STAGES.stage("gather", "numba")
def _gather_compiled(spec: np.ndarray, rd: np.ndarray, kd: np.ndarray, kk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The neighbouring bins ``kk`` of :meth:`AngleEstimator.target_bins` (D, I, C, W) and the OMP's data in one pass
    over Y (:func:`rhs_env.kernels.gather_bins`)."""
    from rhs_env.kernels import gather_bins

    win, yd = gather_bins(spec, rd.astype(np.int64), kk, kk.shape[1] // 2)
    return win, yd


@_STAGES.stage("target_bins", "numba")
def _target_bins_compiled(estimator: AngleEstimator, spec: np.ndarray, rd: np.ndarray, kk: np.ndarray,
                          atoms: np.ndarray, win: np.ndarray | None = None) -> np.ndarray:
    """:meth:`AngleEstimator.target_bins` compiled: the same least squares (:func:`rhs_env.kernels.bin_amplitudes`)
    on the bins already gathered (``win``) or read from the spectrum, and the parabola
    (:func:`rhs_env.kernels.range_offsets`); the logarithm stays numpy's (its SIMD log)."""
    from rhs_env.kernels import bin_amplitudes, range_offsets

    a = np.ascontiguousarray(atoms, dtype=complex)
    if win is None:
        s_nb = bin_amplitudes(a, spec, rd.astype(np.int64), kk)
    else:  # Y := win, radar d, bins 0..W-1: the same values, read contiguously
        s_nb = bin_amplitudes(a, win, np.arange(rd.size, dtype=np.int64),
                              np.ascontiguousarray(np.broadcast_to(np.arange(kk.shape[1]), kk.shape)))
    return np.asarray(range_offsets(np.log(np.abs(s_nb) ** 2 + 1e-300), kk.shape[1] // 2))
