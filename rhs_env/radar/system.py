"""The four swept-beam FMCW radars of the ego vehicle, composed of their stages (:class:`RadarSystem`)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from rhs_env.array_models import ArrayAntenna
from rhs_env.omp import AngleDictionary
from rhs_env.point_cloud import PointCloud, angle_crb
from rhs_env.radar.antennas import BeamPatterns
from rhs_env.radar.buffers import WorkBuffers
from rhs_env.radar.detection import RangeDetector
from rhs_env.radar.estimation import AngleEstimator
from rhs_env.radar.evaluation import cloud_metrics, point_errors
from rhs_env.radar.mounting import RadarMounts
from rhs_env.radar.noise import ReceiverNoise
from rhs_env.radar.points import PointAssembler
from rhs_env.radar.range_fft import RangeFFT
from rhs_env.radar.synthesis import EchoSynthesizer
from rhs_env.radar_config import RadarConfig
from rhs_env.scatterers import Occluders, Scatterers

__all__ = ["RadarSystem"]


class RadarSystem:
    """The four radars of the ego vehicle: one object per stage of a scan, each with its own concern.

    * ``mounts``: :class:`~rhs_env.radar.mounting.RadarMounts`, positions, boresights, field of view and line of
      sight;
    * ``beams``: :class:`~rhs_env.radar.antennas.BeamPatterns`, the antennas, their slot gains and one OMP
      dictionary per distinct antenna;
    * ``range_fft``: :class:`~rhs_env.radar.range_fft.RangeFFT`, window, searched bins, range FFT;
    * ``noise``: :class:`~rhs_env.radar.noise.ReceiverNoise`, CN(0, sigma_n^2) receiver noise;
    * ``synthesizer``: :class:`~rhs_env.radar.synthesis.EchoSynthesizer`, the echoes as tones, IQ samples or the
      range spectrum;
    * ``detector``: :class:`~rhs_env.radar.detection.RangeDetector`, CFAR detection of the range cells;
    * ``estimator``: :class:`~rhs_env.radar.estimation.AngleEstimator`, OMP angle / Doppler and per-target range;
    * ``assembler``: :class:`~rhs_env.radar.points.PointAssembler`, points, sidelobe check and their range / angle
      standard deviations.

    :meth:`scan` runs them in order: synthesis (``fidelity="iq"``: samples, then the range FFT; ``"range"``: the
    spectrum directly), detection, estimation, points. Each stage with compiled kernels chooses them once from
    ``config.kernels`` (its module's :class:`rhs_common.jit.KernelTable`).

    Args:
        config: :class:`RadarConfig`.
        rng: numpy Generator: the ``random`` antenna's patterns (one per radar,
            drawn here) and, at every scan, echo phases and noise (``rng`` may be replaced between scans).
        patterns: optional ``(tx_psi, rx_psi)`` (I, M) for the ``rhs`` antenna
            instead of the pattern library.
        antennas: optional explicit antenna per radar (list of 4 or one shared),
            overriding ``config.antenna``.
    """

    def __init__(self, config: RadarConfig | None = None, rng: np.random.Generator | None = None,
                 patterns: tuple[np.ndarray, np.ndarray] | None = None,
                 antennas: ArrayAntenna | list[ArrayAntenna] | None = None) -> None:
        self.config = config = config or RadarConfig()
        self.rng = rng if rng is not None else np.random.default_rng()
        self.mounts = RadarMounts(config)
        self.beams = BeamPatterns(config, self.rng, patterns=patterns, antennas=antennas)
        self.range_fft = RangeFFT(config)
        self.noise = ReceiverNoise(config, self.range_fft)
        self.synthesizer = EchoSynthesizer(config, self.mounts, self.beams, self.noise)
        self.detector = RangeDetector(config, self.range_fft, self.beams)
        self.estimator = AngleEstimator(config, self.beams, self.range_fft,
                                        detected=bool(self.detector.footprint_detectors))
        self.assembler = PointAssembler(config, self.mounts, self.range_fft, self.beams)
        self._buffers = WorkBuffers()

    # ------------------------------------------------------------------ the stages' state, as attributes
    @property
    def positions(self) -> np.ndarray:
        """(4, 2) radar positions in the vehicle frame, m (:attr:`RadarMounts.positions`)."""
        return self.mounts.positions

    @property
    def boresights(self) -> np.ndarray:
        """(4,) boresight angles, rad (:attr:`RadarMounts.boresights`)."""
        return self.mounts.boresights

    @property
    def antennas(self) -> list[ArrayAntenna]:
        """The antenna of each radar (:attr:`BeamPatterns.antennas`)."""
        return self.beams.antennas

    @property
    def dictionaries(self) -> list[AngleDictionary]:
        """The OMP dictionary of each radar (:attr:`BeamPatterns.dictionaries`)."""
        return self.beams.dictionaries

    # ------------------------------------------------------------------ geometry
    def radar_frame(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Range (4, K), angle from boresight (4, K) rad and unit vectors (4, K, 2) of points xy (K, 2)."""
        return self.mounts.frame(xy)

    def visible(self, scatterers: Scatterers, occluders: Occluders | None = None,
                frame: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """(4, K) bool: inside radar r's sector and range interval and in line of sight (:meth:`RadarMounts.visible`)."""
        return self.mounts.visible(scatterers, occluders, frame)

    def in_view(self, scatterers: Scatterers, occluders: Occluders | None = None) -> np.ndarray:
        """(K,) bool: seen by at least one radar."""
        return self.mounts.in_view(scatterers, occluders)

    # ------------------------------------------------------------------ synthesis
    def synthesize(self, scatterers: Scatterers, occluders: Occluders | None = None,
                   out: np.ndarray | None = None) -> np.ndarray:
        """Dechirped samples y (4, I, C, N) complex64 of one sweep (``fidelity="iq"``; :meth:`EchoSynthesizer.samples`)."""
        return self.synthesizer.samples(scatterers, occluders, self.rng, out)

    def synthesize_spectrum(self, scatterers: Scatterers, occluders: Occluders | None = None) -> np.ndarray:
        """Range spectrum Y (4, I, C, K_b) complex64 of one sweep, written directly (``fidelity="range"``;
        :meth:`EchoSynthesizer.spectrum`)."""
        return self.synthesizer.spectrum(scatterers, occluders, self.rng)

    # ------------------------------------------------------------------ processing
    def range_spectrum(self, y: np.ndarray) -> np.ndarray:
        """Windowed, zero-padded range FFT of y (4, I, C, N) -> bins ``k < K_b`` (4, I, C, K_b) complex64 (a view)."""
        return self.range_fft.spectrum(y)

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

        Stages: :meth:`RangeDetector.detect` -> range cells (rd, kd); :meth:`AngleEstimator.estimate` (OMP per
        detection, per-target range); :meth:`PointAssembler.assemble` (coordinates, target-level sidelobe check,
        uncertainty). Stage times: ``range_cfar`` (detection) and ``omp`` (estimation and points), s.
        """
        t0 = time.perf_counter()
        rd, kd = self.detector.detect(spec)
        t1 = time.perf_counter()
        est = self.estimator.estimate(spec, rd, kd)
        cloud = self.assembler.assemble(rd, kd, est)
        t2 = time.perf_counter()
        return cloud, {"range_cfar": t1 - t0, "omp": t2 - t1}

    def scan(self, scatterers: Scatterers, occluders: Occluders | None = None) -> PointCloud:
        """One sensing cycle of the four radars -> :class:`PointCloud` with ``stage_times``.

        ``fidelity="iq"``: samples (:meth:`synthesize`), range FFT, processing;
        ``"range"``: the spectrum directly (:meth:`synthesize_spectrum`), processing.
        """
        t0 = time.perf_counter()
        cfg = self.config
        if cfg.fidelity == "iq":
            y = self.synthesize(scatterers, occluders, out=self._buffers.get(
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

    # ------------------------------------------------------------------ compiled kernels, ahead of the first scan
    def warm_refinement(self) -> None:
        """Compile (or load) the OMP's joint refinement's stages and row bookkeeping with the scan's own operand types
        (:meth:`AngleEstimator.warm_refinement`): the first part of a background compile's radar work
        (:mod:`slam.gym.precompile`), while an env's first scan compiles the synthesis, the detector and the OMP's
        search. Each ``warm_*`` method does nothing with ``kernels="numpy"``."""
        self.estimator.warm_refinement()

    def warm_points(self) -> None:
        """Compile (or load) the points' kernels (:meth:`PointAssembler.warm`) on one synthetic target in each of
        the four cells of :meth:`_warm_cells`."""
        self.assembler.warm(self.estimator, self._warm_cells)

    def warm_one_call_omp(self) -> None:
        """Compile (or load) the one-call OMP (:func:`rhs_env.kernels.omp_doppler`) with the scan's own operand types,
        on the noise of :meth:`_warm_cells`: the last thing a background compile does, after which an env's scans
        switch from its Python body to it (:data:`rhs_env.kernels.omp_doppler_tiered`)."""
        self.estimator.warm_one_call_omp(self._warm_cells)

    def _warm_cells(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cells (radar ``rd``, bin ``kd``), bin 40 of each radar, and a noise spectrum to warm kernels on."""
        cfg = self.config
        spec = self.noise.spectrum((4, cfg.scan.slots, cfg.waveform.chirps_per_slot), self.rng)
        return np.arange(4, dtype=np.int64), np.full(4, 40, np.int64), spec

    # ------------------------------------------------------------------ references
    def angle_crb(self, theta_rad: np.ndarray, range_m: float, rcs_m2: float, radar: int = 0) -> np.ndarray:
        """Angle CRB (rad^2) of a single target at (theta, R, sigma) for radar ``radar``."""
        return angle_crb(self.antennas[radar], theta_rad, self.config.unit_gain_snr(range_m, rcs_m2))

    def point_errors(self, cloud: PointCloud, scatterers: Scatterers, occluders: Occluders | None = None,
                     gate_m: float = 1.0) -> dict[str, Any]:
        """Per-target errors of ``cloud`` against the scatterers in view (:func:`rhs_env.radar.evaluation.point_errors`:
        ``n_true``, ``n_detected``, ``false_points`` and the ``xy``, ``range``, ``angle``, ``doppler`` errors)."""
        return point_errors(self.mounts, cloud, scatterers, occluders, gate_m)

    def metrics(self, cloud: PointCloud, scatterers: Scatterers, occluders: Occluders | None = None,
                gate_m: float = 1.0, per_object: bool = False) -> dict:
        """Point-cloud metrics of ``cloud`` against the scatterers in view (:func:`rhs_env.radar.evaluation.cloud_metrics`)."""
        return cloud_metrics(self.mounts, cloud, scatterers, occluders, gate_m, per_object)
