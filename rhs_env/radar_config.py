"""Configuration of the four radars: :class:`RadarConfig` and its groups.

A :class:`RadarConfig` is a frozen dataclass of frozen groups, each validated
on its own (``__post_init__``; errors name the field, and :func:`rhs_common.validation.build`
prefixes the path: ``radar.detection.pfa must be in (0.0, 0.5], got 2.0``):

===============  ================================  ==================================================
field            group                             what
===============  ================================  ==================================================
``waveform``     :class:`WaveformConfig`           chirp, sampling, chirps per slot, range FFT
``link``         :class:`LinkBudgetConfig`         Tx power, noise figure, temperature, noise on/off
``detection``    :class:`DetectionConfig`          CFAR / fixed threshold, statistic, sidelobe check
``estimation``   :class:`AngleEstimationConfig`    OMP angle / Doppler estimation per detection
``uncertainty``  :class:`UncertaintyConfig`        floors of the per-point range / angle std
``mounting``     :class:`MountingConfig`           the vehicle box the radars sit on
===============  ================================  ==================================================

plus, at the top level, the antenna (``antenna`` kind, ``rhs`` geometry, ``scan``
grid), the field of view (``min_range_m`` .. ``max_range_m``), the synthesis
``fidelity`` and the checks that span groups (``max_range_m`` below the waveform's
unambiguous range). Quantities that need several groups (``noise_power_w``,
``wavelength``, ``unit_gain_snr``) are properties of :class:`RadarConfig`.

The flat field names of before the grouping (``cfar_pfa``, ``tx_power_dbm``,
``detection="cfar"``, ...) are :attr:`RadarConfig.MOVED_FIELDS`: given in a mapping to
:func:`~rhs_common.validation.build` (``gym.make(..., radar={"cfar_pfa": 1e-5})``) they
still work, with a ``DeprecationWarning`` naming the new path.

Examples:
    >>> cfg = RadarConfig(detection=DetectionConfig(pfa=1e-5), link=LinkBudgetConfig(tx_power_dbm=20.0))
    >>> cfg.detection.pfa, cfg.link.tx_power_dbm, cfg.waveform.samples
    (1e-05, 20.0, 400)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from rhs_common.jit import KERNELS
from rhs_common.validation import (
    check_bool,
    check_choice,
    check_int,
    check_memory,
    check_range,
    check_types,
    flat_dict,
)
from rhs_env.array_models import ANTENNA_KINDS, SPEED_OF_LIGHT, RHSConfig, ScanConfig
from rhs_env.windows import WINDOWS, make_window

__all__ = [
    "BOLTZMANN",
    "CFAR_METHODS",
    "DETECTION_MODES",
    "FIDELITIES",
    "AngleEstimationConfig",
    "DetectionConfig",
    "LinkBudgetConfig",
    "MountingConfig",
    "RadarConfig",
    "UncertaintyConfig",
    "WaveformConfig",
]

BOLTZMANN = 1.380649e-23  # J/K
DETECTION_MODES = ("cfar", "fixed")
FIDELITIES = ("range", "iq")
CFAR_METHODS = ("os", "ca")


@dataclass(frozen=True)
class WaveformConfig:
    """FMCW chirp, sampling and range FFT of each radar.

    A linear chirp over B in T_c, slope ``S = B / T_c``; complex baseband
    sampling at f_s, ``N = f_s T_c`` samples per chirp (a whole number >= 16);
    range bin ``c0 / (2 B)``, unambiguous range ``c0 f_s / (2 S)`` (beat
    frequencies in [0, f_s)). Each beam slot holds C chirps back to back:
    chirp c of slot i starts at ``(i C + c) T_c``.

    Attributes:
        bandwidth_hz: B, swept bandwidth, Hz (1 MHz .. 5 GHz; default 250 MHz).
        chirp_s: T_c, chirp duration, s (0.1 us .. 10 ms; default 20 us).
        sample_rate_hz: f_s, complex sample rate, Hz (default 20 MHz).
        chirps_per_slot: C, chirps per beam slot, combined coherently (2 .. 1024).
        zero_pad: Z, the range FFT is ``Z N`` points long (1 .. 16).
        window: range taper w[n] (hann, hamming, blackman, boxcar, taylor).
        slot_doppler: the Doppler phase runs on across the slots of the sweep
            (True, physical: ``exp(j omega (i C + c))``) or restarts every slot (False).
    """

    bandwidth_hz: float = 250e6
    chirp_s: float = 20e-6
    sample_rate_hz: float = 20e6
    chirps_per_slot: int = 4
    zero_pad: int = 2
    window: str = "hann"
    slot_doppler: bool = True

    def __post_init__(self) -> None:
        check_types(self)
        check_range("bandwidth_hz", self.bandwidth_hz, 1e6, 5e9)
        check_range("chirp_s", self.chirp_s, 1e-7, 1e-2)
        check_range("sample_rate_hz", self.sample_rate_hz, 1e5, 1e10)
        check_int("chirps_per_slot", self.chirps_per_slot, 2, 1024)
        check_int("zero_pad", self.zero_pad, 1, 16)
        check_choice("window", self.window, WINDOWS)
        check_bool("slot_doppler", self.slot_doppler)
        n = self.sample_rate_hz * self.chirp_s
        if abs(n - round(n)) > 1e-6 or round(n) < 16:
            raise ValueError(
                f"sample_rate_hz * chirp_s must be a whole number of samples >= 16, got {n:.6g}"
            )

    @property
    def samples(self) -> int:
        """N = f_s T_c samples per chirp."""
        return round(self.sample_rate_hz * self.chirp_s)

    @property
    def slope(self) -> float:
        """Chirp slope S = B / T_c, Hz/s."""
        return self.bandwidth_hz / self.chirp_s

    @property
    def range_resolution_m(self) -> float:
        """c0 / (2 B), m."""
        return SPEED_OF_LIGHT / (2 * self.bandwidth_hz)

    @property
    def unambiguous_range_m(self) -> float:
        """c0 f_s / (2 S), m: complex sampling, beat frequencies in [0, f_s)."""
        return SPEED_OF_LIGHT * self.sample_rate_hz / (2 * self.bandwidth_hz / self.chirp_s)


@dataclass(frozen=True)
class LinkBudgetConfig:
    """Transmit power and receiver noise (radar equation).

    Echo power at unit two-way gain ``P_t sigma lambda^2 / ((4 pi)^3 R^4)``;
    receiver noise ``sigma_n^2 = k T0 F f_s`` per complex sample
    (:attr:`RadarConfig.noise_power_w`).

    Attributes:
        tx_power_dbm: P_t, radiated power, dBm (-100 .. 80; default 30 dBm = 1 W).
        noise_figure_db: F, receiver noise figure, dB (0 .. 60).
        temperature_k: T0, noise temperature, K (0 .. 5000, exclusive of 0).
        add_noise: False gives noiseless echoes (the thresholds still use the
            thermal noise level).
    """

    tx_power_dbm: float = 30.0
    noise_figure_db: float = 10.0
    temperature_k: float = 290.0
    add_noise: bool = True

    def __post_init__(self) -> None:
        check_types(self)
        check_range("tx_power_dbm", self.tx_power_dbm, -100.0, 80.0)
        check_range("noise_figure_db", self.noise_figure_db, 0.0, 60.0)
        check_range("temperature_k", self.temperature_k, 0.0, 5000.0, low_open=True)
        check_bool("add_noise", self.add_noise)

    @property
    def tx_power_w(self) -> float:
        """P_t = 10^((P_dBm - 30) / 10), W."""
        return 10 ** ((self.tx_power_dbm - 30) / 10)


#: the detector statistics (:class:`DetectionConfig` ``statistic``; :mod:`rhs_env.detection` implements them)
DETECTORS = ("footprint", "summed")


@dataclass(frozen=True)
class DetectionConfig:
    """Range detection: which cells of the range spectrum go on to angle estimation.

    ``statistic`` chooses what the threshold runs on: "footprint" (default; per
    angle hypothesis, the echo energy over that beam's footprint of slots,
    :mod:`rhs_env.detection`; its first OMP atom per detected bin is taken
    without the residual and amplitude tests, which the detection replaces) or
    "summed" (the power profile summed over all slots and chirps, the paper's).
    ``mode`` chooses the threshold: "cfar" (``method`` "os", ordered statistic of
    rank ``rank`` x 2 ``train`` training cells, or "ca", cell averaging; the
    noise estimate is clipped to [floor, floor + ``cap_db``] around the
    calibrated noise floor: the slot-combined profile mixes every direction, so
    without the cap a near vehicle in the training cells masks landmarks a few
    metres behind it) or "fixed" (``fixed_threshold_db`` above the noise mean,
    the paper's delta_d). A peak weaker than ``sidelobe_margin_db`` above the
    window's sidelobe envelope under a stronger peak is dropped.

    Attributes:
        mode: "cfar" or "fixed".
        statistic: "footprint" or "summed".
        guard: guard cells per side, unpadded bins (0 .. 64).
        train: training cells per side, unpadded bins (1 .. 256).
        pfa: design false-alarm probability per cell, (0, 0.5].
        method: CFAR noise estimate, "os" (ordered statistic) or "ca" (cell average).
        rank: OS-CFAR rank as a fraction of the 2 ``train`` cells, (0, 1].
        cap_db: the CFAR noise estimate is at most this far above the noise floor, dB (0 .. 200).
        fixed_threshold_db: ``mode="fixed"``: threshold above the noise mean, dB (0 .. 200).
        sidelobe_margin_db: a peak must exceed the window sidelobe of a stronger
            one by this much, dB (0 .. 60).
    """

    mode: str = "cfar"
    statistic: str = "footprint"
    guard: int = 2
    train: int = 8
    pfa: float = 1e-6
    method: str = "os"
    rank: float = 0.75
    cap_db: float = 10.0
    fixed_threshold_db: float = 15.0
    sidelobe_margin_db: float = 6.0

    def __post_init__(self) -> None:
        check_types(self)
        check_choice("mode", self.mode, DETECTION_MODES)
        check_choice("statistic", self.statistic, DETECTORS)
        check_int("guard", self.guard, 0, 64)
        check_int("train", self.train, 1, 256)
        check_range("pfa", self.pfa, 0.0, 0.5, low_open=True)
        check_choice("method", self.method, CFAR_METHODS)
        check_range("rank", self.rank, 0.0, 1.0, low_open=True)
        check_range("cap_db", self.cap_db, 0.0, 200.0)
        check_range("fixed_threshold_db", self.fixed_threshold_db, 0.0, 200.0)
        check_range("sidelobe_margin_db", self.sidelobe_margin_db, 0.0, 60.0)


@dataclass(frozen=True)
class AngleEstimationConfig:
    """OMP angle / Doppler estimation of the targets in each detected range cell (paper eq. 5-6).

    The search over the dictionary H stops at ``l <= L_max`` atoms and when the
    residual ``||r||^2`` falls below delta_r or below ``residual_rel_db`` of
    ``||iota||^2`` (:func:`rhs_env.point_cloud.omp_doppler`).

    Attributes:
        oversampling: candidate angles per beam-grid step in H (1 .. 64).
        max_targets: L_max, most targets per range cell (1 .. 32).
        residual_pfa: delta_r is the level the residual noise alone exceeds with
            this probability, (0, 0.5].
        residual_rel_db: stop below this fraction of ``||iota||^2`` (the dynamic
            range of the angle model), dB (-200 .. 0).
        newton_steps: Newton refinements of each atom's angle (0 .. 10).
        refine_passes: the most cyclic re-refinement passes of every atom in angle and Doppler against
            its own partial residual, after each new atom (0 .. 10; :func:`rhs_env.point_cloud.joint_refine`).
        refine_tol: a range cell's refinement stops once a pass lowers its residual ``||R||^2`` by less
            than this fraction of it ([0, 1]; 0: always ``refine_passes`` passes). The passes are a
            Jacobi iteration, each atom re-fitted with the others held: two targets a beamwidth apart
            need tens of passes, well separated ones two or three. Until 2026-11 the radar ran two
            fixed passes (``refine_passes=2, refine_tol=0``, the ``fixed2`` profile of
            ``results/radar_profiles.md``); the converged default cuts the Fig. 5b scenes' angle RMSE
            by a third and their false points by two thirds, at some speed (``results/benchmark.json``),
            and lowers the SLAM's error on paired tuning drives (docs/design/physics.md).
        min_snr_db: an atom whose amplitude SNR over the sweep, ``20 log10(|s| ||a|| / sigma_Y)``,
            is lower is rejected and ends the search, dB (-50 .. 100).
    """

    oversampling: int = 4
    max_targets: int = 4
    residual_pfa: float = 1e-3
    residual_rel_db: float = -25.0
    newton_steps: int = 2
    refine_passes: int = 8
    refine_tol: float = 0.01
    min_snr_db: float = 15.0

    def __post_init__(self) -> None:
        check_types(self)
        check_int("oversampling", self.oversampling, 1, 64)
        check_int("max_targets", self.max_targets, 1, 32)
        check_range("residual_pfa", self.residual_pfa, 0.0, 0.5, low_open=True)
        check_range("residual_rel_db", self.residual_rel_db, -200.0, 0.0)
        check_int("newton_steps", self.newton_steps, 0, 10)
        check_int("refine_passes", self.refine_passes, 0, 10)
        check_range("refine_tol", self.refine_tol, 0.0, 1.0)
        check_range("min_snr_db", self.min_snr_db, -50.0, 100.0)


@dataclass(frozen=True)
class UncertaintyConfig:
    """Floors of the per-point uncertainty (:mod:`rhs_env.uncertainty`).

    Every point's range / angle std is its Cramer-Rao bound at its SNR plus
    these floors (model error: ``std^2 = CRB + floor^2``).

    Attributes:
        range_std_floor_m: range std floor, m (0 .. 10; default 3 mm).
        angle_std_floor_deg: angle std floor, deg (0 .. 10; default 0.003 deg).
    """

    range_std_floor_m: float = 0.003
    angle_std_floor_deg: float = 0.003

    def __post_init__(self) -> None:
        check_types(self)
        check_range("range_std_floor_m", self.range_std_floor_m, 0.0, 10.0)
        check_range("angle_std_floor_deg", self.angle_std_floor_deg, 0.0, 10.0)


@dataclass(frozen=True)
class MountingConfig:
    """Where the four radars sit: the middle of the front, left, rear and right sides of the vehicle box.

    Attributes:
        vehicle_length_m: box length along the vehicle's x axis, m (0 .. 50).
        vehicle_width_m: box width along y, m (0 .. 20).
    """

    vehicle_length_m: float = 5.0
    vehicle_width_m: float = 2.0

    def __post_init__(self) -> None:
        check_types(self)
        check_range("vehicle_length_m", self.vehicle_length_m, 0.0, 50.0)
        check_range("vehicle_width_m", self.vehicle_width_m, 0.0, 20.0)

    def mounts(self) -> tuple[np.ndarray, np.ndarray]:
        """Radar positions (4, 2) m and boresights (4,) rad in the vehicle frame: front, left, rear, right.

        Positions ``(L/2, 0), (0, W/2), (-L/2, 0), (0, -W/2)``; boresights 0, +90, 180, -90 deg.
        """
        hl, hw = self.vehicle_length_m / 2, self.vehicle_width_m / 2
        pos = np.array([[hl, 0.0], [0.0, hw], [-hl, 0.0], [0.0, -hw]])
        return pos, np.deg2rad([0.0, 90.0, 180.0, -90.0])


#: the flat field names of before the grouping -> their path in :class:`RadarConfig`
_MOVED = {
    **{f: f"waveform.{f}" for f in ("bandwidth_hz", "chirp_s", "sample_rate_hz", "chirps_per_slot",
                                     "zero_pad", "window", "slot_doppler")},
    **{f: f"link.{f}" for f in ("tx_power_dbm", "noise_figure_db", "temperature_k", "add_noise")},
    "detection": "detection.mode",
    "detector": "detection.statistic",
    **{f"cfar_{f}": f"detection.{f}" for f in ("guard", "train", "pfa", "method", "rank", "cap_db")},
    "fixed_threshold_db": "detection.fixed_threshold_db",
    "sidelobe_margin_db": "detection.sidelobe_margin_db",
    **{f"omp_{f}": f"estimation.{f}" for f in ("oversampling", "max_targets", "residual_pfa", "residual_rel_db",
                                               "newton_steps", "min_snr_db")},
    **{f: f"uncertainty.{f}" for f in ("range_std_floor_m", "angle_std_floor_deg")},
    **{f: f"mounting.{f}" for f in ("vehicle_length_m", "vehicle_width_m")},
}


@dataclass(frozen=True)
class RadarConfig:
    """The four radars: antenna, field of view, synthesis fidelity and the groups of settings.

    Attributes:
        antenna: antenna kind, rhs | phased | random | hologram (:func:`rhs_env.antenna_factory.make_antenna`).
        rhs: :class:`rhs_env.array_models.RHSConfig`, the RHS geometry (and carrier, lambda).
        scan: :class:`rhs_env.array_models.ScanConfig`, the beam grid of the sweep.
        min_range_m: nearest reported range, m, [0, ``max_range_m``).
        max_range_m: farthest range, m, [1, 0.95 x the waveform's unambiguous range]
            (field of view: the scan sector up to this range).
        fidelity: synthesis path, "range" (the default) or "iq" (the reference: the
            dechirped samples and their windowed FFT). "range": the range spectrum written directly:
            each tone's windowed, zero-padded spectrum in closed form, the noise as
            the windowed FFT of white noise drawn at half rate where the alias term
            is negligible (:func:`rhs_env.point_cloud.noise_decimation`), only the bins
            searched; the same distribution at a fraction of the cost,
            :meth:`rhs_env.radar.RadarSystem.synthesize_spectrum` (tests/test_radar_fidelity.py,
            scripts/radar_profiles.py).
        waveform: :class:`WaveformConfig` (chirp, sampling, range FFT).
        link: :class:`LinkBudgetConfig` (Tx power, receiver noise).
        detection: :class:`DetectionConfig` (CFAR / fixed threshold).
        estimation: :class:`AngleEstimationConfig` (OMP per detection).
        uncertainty: :class:`UncertaintyConfig` (per-point std floors).
        mounting: :class:`MountingConfig` (vehicle box of the mounts).
        kernels: implementation of the inner loops (detector, OMP, signal mixing, points, the scene's
            vehicle faces): "numba" (the default: compiled, :mod:`rhs_env.kernels`) or "numpy" (the reference); the same
            results to round-off. Left out of :meth:`flat_dict` at its default.
    """

    #: flat names of before the grouping, mapped by :func:`rhs_common.validation.build` with a DeprecationWarning
    MOVED_FIELDS: ClassVar[MappingProxyType[str, str]] = MappingProxyType(_MOVED)
    #: fields added since the grouping -> the value that does what the code did before them (left out of
    #: :meth:`flat_dict` at that value: cache keys and seeds derived from it stay as they were)
    ADDED_FIELDS: ClassVar[MappingProxyType[str, Any]] = MappingProxyType({"estimation.refine_passes": 2,
                                                                                     "estimation.refine_tol": 0.0,
                                                                                     "kernels": "numba"})

    antenna: str = "rhs"
    rhs: RHSConfig = field(default_factory=RHSConfig)
    scan: ScanConfig = field(default_factory=ScanConfig)
    min_range_m: float = 1.0
    max_range_m: float = 100.0
    fidelity: str = "range"
    waveform: WaveformConfig = field(default_factory=WaveformConfig)
    link: LinkBudgetConfig = field(default_factory=LinkBudgetConfig)
    detection: DetectionConfig = field(default_factory=DetectionConfig)
    estimation: AngleEstimationConfig = field(default_factory=AngleEstimationConfig)
    uncertainty: UncertaintyConfig = field(default_factory=UncertaintyConfig)
    mounting: MountingConfig = field(default_factory=MountingConfig)
    kernels: str = "numba"

    def __post_init__(self) -> None:
        check_types(self)  # every group an instance of its class (each validated itself)
        check_choice("antenna", self.antenna, ANTENNA_KINDS)
        check_choice("fidelity", self.fidelity, FIDELITIES)
        check_choice("kernels", self.kernels, KERNELS)
        check_range("max_range_m", self.max_range_m, 1.0, 0.95 * self.waveform.unambiguous_range_m)
        check_range("min_range_m", self.min_range_m, 0.0, self.max_range_m, high_open=True)
        wf, slots = self.waveform, self.scan.slots
        # one sweep holds, per radar, slot and chirp, the N samples and their Z N-point range FFT (complex64)
        check_memory(f"waveform.sample_rate_hz x waveform.chirp_s = {wf.samples} samples per chirp x "
                     f"{wf.chirps_per_slot} chirps x {slots} slots (scan.grid_deg) x (1 + waveform.zero_pad = "
                     f"{1 + wf.zero_pad}) x 4 radars", 4 * slots * wf.chirps_per_slot * wf.samples * (1 + wf.zero_pad) * 8)

    # -- derived quantities that span groups ------------------------------------
    @property
    def wavelength(self) -> float:
        """lambda = c0 / f_c of the RHS carrier, m."""
        return self.rhs.wavelength

    @property
    def max_velocity_mps(self) -> float:
        """Unambiguous radial speed lambda / (4 T_c), m/s."""
        return self.wavelength / (4 * self.waveform.chirp_s)

    @property
    def noise_power_w(self) -> float:
        """sigma_n^2 = k T0 F f_s per complex sample, W."""
        link = self.link
        return BOLTZMANN * link.temperature_k * 10 ** (link.noise_figure_db / 10) * self.waveform.sample_rate_hz

    def echo_power_w(self, range_m: np.ndarray | float, rcs_m2: np.ndarray | float) -> np.ndarray:
        """P_t |beta|^2 = P_t sigma lambda^2 / ((4 pi)^3 R^4) at unit two-way gain, W."""
        r = np.asarray(range_m, float)
        return self.link.tx_power_w * np.asarray(rcs_m2, float) * self.wavelength ** 2 / ((4 * np.pi) ** 3 * r ** 4)

    def unit_gain_snr(self, range_m: np.ndarray | float, rcs_m2: np.ndarray | float) -> np.ndarray:
        """|s|^2 / sigma_iota^2 of one slot's iota entry at unit two-way gain (the SNR of :func:`angle_crb`).

        ``s = sqrt(P_t) beta C sum(w)``, ``sigma_iota^2 = C sigma_n^2 sum(w^2)``
        (window w, C chirps combined coherently).
        """
        wf = self.waveform
        w = make_window(wf.window, wf.samples).astype(float)
        gain = wf.chirps_per_slot * w.sum() ** 2 / np.sum(w ** 2)
        return self.echo_power_w(range_m, rcs_m2) * gain / self.noise_power_w

    def to_dict(self) -> dict[str, Any]:
        """The fields as a nested dict (``build(RadarConfig, cfg.to_dict()) == cfg``)."""
        return asdict(self)

    def flat_dict(self) -> dict[str, Any]:
        """The fields under their names of before the grouping (``cfar_pfa``, ...), as ``to_dict`` used to be.

        A stable identity of the settings for keys and seeds derived from them
        (``scripts/claim_study.py`` caches and seeds its cells by it).
        """
        return flat_dict(self)
