"""Four swept-beam FMCW radars on the ego vehicle: echo synthesis and point clouds.

:class:`RadarSystem` composes one object per stage of a scan, each in its own module with its equations and units:

* :mod:`rhs_env.radar.mounting`, :class:`RadarMounts`: radars at the middle of the four sides, boresights
  0, +90, 180, -90 deg; field of view (+-45 deg sector, range limits) and line of sight;
* :mod:`rhs_env.radar.antennas`, :class:`BeamPatterns`: the antenna of each radar, its I beam slots' two-way gains
  ``h_i(theta)`` and one OMP dictionary per distinct antenna;
* :mod:`rhs_env.radar.range_fft`, :class:`RangeFFT`: window, searched bins ``k < K_b``, windowed zero-padded range
  FFT (the matched filter);
* :mod:`rhs_env.radar.noise`, :class:`ReceiverNoise`: CN(0, k T0 F f_s) per sample, in the IQ samples or drawn
  straight into the spectrum;
* :mod:`rhs_env.radar.synthesis`, :class:`EchoSynthesizer`: the visible scatterers as tones (paper eq. 2), mixed
  into IQ samples (``fidelity="iq"``) or the range spectrum (``"range"``);
* :mod:`rhs_env.radar.detection`, :class:`RangeDetector`: footprint or slot-summed CFAR detection of the range
  cells;
* :mod:`rhs_env.radar.estimation`, :class:`AngleEstimator`: OMP angle, Doppler and amplitude per cell, each
  target's own range offset;
* :mod:`rhs_env.radar.points`, :class:`PointAssembler`: points (range, position, radial velocity, amplitude),
  range-sidelobe check, range / angle standard deviations.

One scan: ``spectrum = synthesizer.spectrum(...)`` (or ``range_fft.spectrum(synthesizer.samples(...))``),
``rd, kd = detector.detect(spectrum)``, ``targets = estimator.estimate(spectrum, rd, kd)``,
``cloud = assembler.assemble(rd, kd, targets)`` (:meth:`RadarSystem.scan`, with the stage times).
:mod:`rhs_env.radar.evaluation` compares a cloud with the truth.

Settings: :class:`RadarConfig` (:mod:`rhs_env.radar_config`, re-exported here) and its
groups ``waveform`` (B, T_c, f_s, C, window, zero padding), ``link`` (P_t, F, T0),
``detection``, ``estimation`` (OMP), ``uncertainty`` and ``mounting``.
"""

from __future__ import annotations

from rhs_env.point_cloud import PointCloud
from rhs_env.radar.antennas import BeamPatterns
from rhs_env.radar.detection import RangeDetector
from rhs_env.radar.estimation import AngleEstimator, Targets
from rhs_env.radar.mounting import RADAR_NAMES, RadarMounts
from rhs_env.radar.noise import ReceiverNoise
from rhs_env.radar.points import PointAssembler
from rhs_env.radar.range_fft import RangeFFT
from rhs_env.radar.synthesis import EchoSynthesizer, EchoTones
from rhs_env.radar.system import RadarSystem
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

__all__ = [
    "BOLTZMANN",
    "RADAR_NAMES",
    "AngleEstimationConfig",
    "AngleEstimator",
    "BeamPatterns",
    "DetectionConfig",
    "EchoSynthesizer",
    "EchoTones",
    "LinkBudgetConfig",
    "MountingConfig",
    "PointAssembler",
    "PointCloud",
    "RadarConfig",
    "RadarMounts",
    "RadarSystem",
    "RangeDetector",
    "RangeFFT",
    "ReceiverNoise",
    "Targets",
    "UncertaintyConfig",
    "WaveformConfig",
]
