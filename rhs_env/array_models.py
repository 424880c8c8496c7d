"""Linear antenna arrays of the radar: the RHS and its same-interface baselines.

Azimuth-plane model. Elements lie on a line along the vehicle
side at ``x_m = m d`` (m = 0..M-1, metres); ``theta`` is measured from the
radar's boresight (normal to the side), positive toward increasing m.

* steering vector      ``a_m(theta) = exp(j k0 x_m sin(theta))``, ``k0 = 2 pi / lambda``
* RHS feed phase       ``q_m = exp(-j n k0 |x_m - x_feed|)`` (surface wave, index n)
* RHS element weight   ``w_m = psi_m q_m`` with an amplitude-only ``psi_m in [0, 1]``
* one-way gains        ``t(theta) = a(theta)^T w_T``, ``r(theta) = w_R^T a(theta)``
* two-way gain         ``h(theta) = r(theta) t(theta)``            (paper eq. 3)

Every antenna here is an :class:`ArrayAntenna`: element positions plus one
complex weight vector per beam slot for Tx and Rx, so the radar and the point
cloud code swap antennas by name (:func:`make_antenna`). Gains are returned
power-normalised per slot, ``t / ||w_T||`` and ``r / ||w_R||``: ``|t|^2`` is the
Tx array gain for a fixed radiated power (the Tx power is fixed by the power
constraint) and ``|r|^2`` the Rx array SNR gain, since the Rx noise
``w_R^T eps`` has variance ``||w_R||^2 sigma^2``. Both are at most M.

**Twin beam.** For real psi and an end-fed line, ``|t(theta)| = |t(theta')|``
with ``sin(theta') = 2n - sin(theta) - k lambda/d`` (integer k): one-way it
cannot be removed. Feeding Tx at element 0 and Rx at element M-1 puts the two
twins in different directions, so the two-way pattern can suppress both.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from rhs_common.validation import check_int, check_range, check_types

__all__ = [
    "ANTENNA_KINDS", "ArrayAntenna", "CARRIER_RANGE_HZ", "MAX_SLOTS", "PHASED_ARRAY_COST_RATIO", "RHSConfig",
    "SPEC_BAND_HZ", "SPEED_OF_LIGHT", "ScanConfig", "check_amplitudes", "hologram_pattern", "phased_array",
    "rhs_antenna", "steering",
]

SPEED_OF_LIGHT = 299_792_458.0  # m/s
#: carriers accepted, Hz: the microwave and millimetre-wave radar bands (1 Hz would be a 300 000 km wavelength)
CARRIER_RANGE_HZ = (1e9, 3e11)
#: the band the radar is designed for (24 GHz ISM); a carrier outside it is accepted with a warning
SPEC_BAND_HZ = (24.0e9, 24.25e9)

ANTENNA_KINDS = ("rhs", "phased", "random", "hologram")
PHASED_ARRAY_COST_RATIO = 6  # one phased-array element costs six RHS elements (paper footnote)


@dataclass(frozen=True)
class RHSConfig:
    """Geometry and physics of one RHS (Tx and Rx share it).

    Attributes:
        elements: M, elements per RHS (>= 2).
        spacing_wl: element spacing d in wavelengths (default 1/4).
        refractive_index: n of the surface wave in the feed line (>= 1, slow wave).
        tx_feed: element index of the Tx feed (negative counts from the end).
        rx_feed: element index of the Rx feed (default -1: the last element,
            opposite to the Tx feed, so that the one-way twins do not coincide).
        carrier_hz: carrier frequency f_c (default 24.125 GHz, band centre); 1 .. 300 GHz, outside
            the 24.00-24.25 GHz band with a ``UserWarning``.
    """

    elements: int = 60
    spacing_wl: float = 0.25
    refractive_index: float = math.sqrt(3.0)
    tx_feed: int = 0
    rx_feed: int = -1
    carrier_hz: float = 24.125e9

    def __post_init__(self) -> None:
        check_types(self)
        check_int("elements", self.elements, 2, 4096)
        check_range("spacing_wl", self.spacing_wl, 0.0, 2.0, low_open=True)
        check_range("refractive_index", self.refractive_index, 1.0, 10.0)
        check_int("tx_feed", self.tx_feed, -self.elements, self.elements - 1)
        check_int("rx_feed", self.rx_feed, -self.elements, self.elements - 1)
        check_range("carrier_hz", self.carrier_hz, *CARRIER_RANGE_HZ)
        if not SPEC_BAND_HZ[0] <= self.carrier_hz <= SPEC_BAND_HZ[1]:
            warnings.warn(f"carrier_hz={self.carrier_hz:g} Hz is outside the 24.00-24.25 GHz ISM band the radar is "
                          "designed for (SPEC: f_c = 24.125 GHz); the patterns scale with the wavelength, the link "
                          "budget and the Doppler follow it", UserWarning, stacklevel=3)
        # Normalise negative feed indices so equal geometries hash equally.
        object.__setattr__(self, "elements", int(self.elements))
        object.__setattr__(self, "tx_feed", int(self.tx_feed) % self.elements)
        object.__setattr__(self, "rx_feed", int(self.rx_feed) % self.elements)
        if self.tx_feed == self.rx_feed:  # SPEC section 2: the twin beam of a shared feed cannot be suppressed
            raise ValueError(f"tx_feed and rx_feed must be different elements (the two-way pattern of one feed keeps "
                             f"its one-way twin beam at full gain), got both {self.tx_feed}; the default is "
                             f"tx_feed=0, rx_feed=-1 (the last element, {self.elements - 1})")

    @property
    def wavelength(self) -> float:
        """lambda = c / f_c in metres."""
        return SPEED_OF_LIGHT / self.carrier_hz

    @property
    def spacing_m(self) -> float:
        return self.spacing_wl * self.wavelength

    @property
    def positions_m(self) -> np.ndarray:
        """Element positions x_m = m d, shape (M,), metres."""
        return np.arange(self.elements) * self.spacing_m

    @property
    def mainlobe_halfwidth(self) -> float:
        """Main-lobe half-width in sin(theta): lambda / (M d), the first null of a uniform line."""
        return 1.0 / (self.elements * self.spacing_wl)

    def feed_phase(self, feed: int) -> np.ndarray:
        """q_m = exp(-j n k0 |x_m - x_feed|), shape (M,)."""
        x = np.arange(self.elements) * self.spacing_wl  # in wavelengths
        return np.exp(-2j * np.pi * self.refractive_index * np.abs(x - x[feed]))

    def twin_sin(self, sin_theta: np.ndarray | float, feed: int) -> np.ndarray:
        """sin of the one-way twin directions of a beam at ``sin_theta`` for a line fed at ``feed``.

        Returns every alias ``s' = +-2n - s - k / d_wl`` that is visible (|s'| <= 1),
        sign + for a feed at element 0 and - for a feed at element M-1; a NaN
        where there is none. Shape: ``np.shape(sin_theta) + (K,)`` for the aliases considered.
        """
        s = np.asarray(sin_theta, dtype=float)
        sign = 1.0 if feed == 0 else -1.0 if feed == self.elements - 1 else None
        if sign is None:
            raise ValueError("twin_sin is defined for a feed at either end of the line")
        ks = np.arange(-8, 9)
        cand = sign * 2.0 * self.refractive_index - s[..., None] - ks / self.spacing_wl
        return np.where(np.abs(cand) <= 1.0, cand, np.nan)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


#: most beam slots I per sweep (bounds ``ScanConfig.grid_deg`` below by ``sector_deg / MAX_SLOTS``)
MAX_SLOTS = 360


@dataclass(frozen=True)
class ScanConfig:
    """The beam sweep of one radar: I slots of width ``grid_deg`` covering ``sector_deg``.

    Grid centres: ``-sector/2 + grid/2 + k grid`` degrees, k = 0..I-1.
    """

    grid_deg: float = 1.0
    sector_deg: float = 90.0

    def __post_init__(self) -> None:
        check_types(self)
        check_range("sector_deg", self.sector_deg, 0.0, 180.0, low_open=True, high_open=True)
        # at most MAX_SLOTS beams per sweep (0.25 deg over 90 deg): the pattern library
        # build and every scan cost grow with I; 0.01 deg would be a 20-40 h build
        check_range("grid_deg", self.grid_deg, self.sector_deg / MAX_SLOTS, self.sector_deg)
        ratio = self.sector_deg / self.grid_deg
        if abs(ratio - round(ratio)) > 1e-9 * max(1.0, ratio):
            raise ValueError(
                f"grid_deg must divide sector_deg={self.sector_deg} into a whole number of "
                f"slots, got grid_deg={self.grid_deg} ({ratio:.4g} slots)"
            )

    @property
    def slots(self) -> int:
        """I = sector / grid."""
        return int(round(self.sector_deg / self.grid_deg))

    @property
    def angles_deg(self) -> np.ndarray:
        """Grid centres in degrees from boresight, shape (I,)."""
        return -self.sector_deg / 2 + self.grid_deg / 2 + self.grid_deg * np.arange(self.slots)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def steering(positions_wl: np.ndarray, theta_rad: np.ndarray) -> np.ndarray:
    """a_m(theta) = exp(j 2 pi x_m sin(theta)) for positions in wavelengths; shape theta.shape + (M,)."""
    phase = 2.0 * np.pi * np.sin(np.asarray(theta_rad, dtype=float))[..., None] * positions_wl
    return np.exp(1j * phase)


@dataclass
class ArrayAntenna:
    """A Tx and an Rx linear array with one complex weight vector per beam slot.

    Attributes:
        name: one of ``ANTENNA_KINDS`` (or a user label).
        positions_wl: element positions in wavelengths, shape (M,).
        tx_weights, rx_weights: per-slot element weights, shape (I, M), complex.
        angles_deg: the slot grid centres, shape (I,).
        wavelength: lambda in metres.
    """

    name: str
    positions_wl: np.ndarray
    tx_weights: np.ndarray
    rx_weights: np.ndarray
    angles_deg: np.ndarray
    wavelength: float
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.positions_wl = np.asarray(self.positions_wl, dtype=float)
        self.tx_weights = np.atleast_2d(np.asarray(self.tx_weights, dtype=complex))
        self.rx_weights = np.atleast_2d(np.asarray(self.rx_weights, dtype=complex))
        self.angles_deg = np.atleast_1d(np.asarray(self.angles_deg, dtype=float))
        m = self.positions_wl.size
        i = self.angles_deg.size
        for fname in ("tx_weights", "rx_weights"):
            w = getattr(self, fname)
            if w.shape != (i, m):
                raise ValueError(f"{fname} must have shape (slots, elements) = ({i}, {m}), got {w.shape}")
            if not np.all(np.isfinite(w)):
                raise ValueError(f"{fname} must be finite")
            if np.any(np.linalg.norm(w, axis=1) == 0):
                raise ValueError(f"{fname} has a slot whose weights are all zero")
        self._tx_norm = np.linalg.norm(self.tx_weights, axis=1)
        self._rx_norm = np.linalg.norm(self.rx_weights, axis=1)

    @property
    def elements(self) -> int:
        return self.positions_wl.size

    @property
    def slots(self) -> int:
        return self.angles_deg.size

    def tx_gain(self, theta_rad: np.ndarray, normalized: bool = True, a: np.ndarray | None = None) -> np.ndarray:
        """One-way Tx gain t_i(theta) = a(theta)^T w_T,i for every slot; shape (I,) + theta.shape.

        ``a``: the steering vectors ``steering(positions_wl, theta_rad)`` when the caller has them.
        """
        if a is None:
            a = steering(self.positions_wl, theta_rad)  # (..., M)
        t = np.tensordot(self.tx_weights, a, axes=([1], [a.ndim - 1]))
        if normalized:
            t = t / self._tx_norm.reshape((-1,) + (1,) * (t.ndim - 1))
        return t

    def rx_gain(self, theta_rad: np.ndarray, normalized: bool = True, a: np.ndarray | None = None) -> np.ndarray:
        """One-way Rx gain r_i(theta) = w_R,i^T a(theta) for every slot; shape (I,) + theta.shape (``a`` as in tx_gain)."""
        if a is None:
            a = steering(self.positions_wl, theta_rad)
        r = np.tensordot(self.rx_weights, a, axes=([1], [a.ndim - 1]))
        if normalized:
            r = r / self._rx_norm.reshape((-1,) + (1,) * (r.ndim - 1))
        return r

    def two_way_gain(self, theta_rad: np.ndarray, normalized: bool = True) -> np.ndarray:
        """h_i(theta) = r_i(theta) t_i(theta), shape (I,) + theta.shape (the dictionary H for a theta grid)."""
        a = steering(self.positions_wl, theta_rad)  # one steering vector for both gains
        return self.rx_gain(theta_rad, normalized, a) * self.tx_gain(theta_rad, normalized, a)


def check_amplitudes(name: str, psi: np.ndarray, slots: int, elements: int) -> np.ndarray:
    """Validate an amplitude-only pattern: shape (slots, elements), values in [0, 1]."""
    psi = np.asarray(psi, dtype=float)
    if psi.shape != (slots, elements):
        raise ValueError(f"{name} must have shape (slots, elements) = ({slots}, {elements}), got {psi.shape}")
    if not np.all(np.isfinite(psi)) or psi.min() < 0.0 or psi.max() > 1.0:
        raise ValueError(
            f"{name} amplitudes must lie in [0, 1], got range "
            f"[{np.nanmin(psi):.4g}, {np.nanmax(psi):.4g}]"
        )
    return psi


def rhs_antenna(
    config: RHSConfig, tx_psi: np.ndarray, rx_psi: np.ndarray, angles_deg: np.ndarray, name: str = "rhs"
) -> ArrayAntenna:
    """An RHS pair with amplitude patterns ``tx_psi``, ``rx_psi`` (I, M) in [0, 1]: w = psi * q."""
    angles_deg = np.atleast_1d(np.asarray(angles_deg, dtype=float))
    tx_psi = check_amplitudes("tx", tx_psi, angles_deg.size, config.elements)
    rx_psi = check_amplitudes("rx", rx_psi, angles_deg.size, config.elements)
    return ArrayAntenna(
        name=name,
        positions_wl=np.arange(config.elements) * config.spacing_wl,
        tx_weights=tx_psi * config.feed_phase(config.tx_feed),
        rx_weights=rx_psi * config.feed_phase(config.rx_feed),
        angles_deg=angles_deg,
        wavelength=config.wavelength,
        meta={"tx_psi": tx_psi, "rx_psi": rx_psi, "config": config.to_dict()},
    )


def hologram_pattern(config: RHSConfig, angles_deg: np.ndarray, feed: int) -> np.ndarray:
    """Closed-form cosine hologram psi_m = (1 + Re(a_m(theta0) q_m)) / 2, shape (I, M).

    For a feed at element 0 this is ``(1 + cos(k0 x_m (n - sin theta0))) / 2``.
    """
    a = steering(np.arange(config.elements) * config.spacing_wl, np.deg2rad(np.atleast_1d(angles_deg)))
    return 0.5 * (1.0 + np.real(a * config.feed_phase(feed)))


def phased_array(config: RHSConfig, angles_deg: np.ndarray, elements: int | None = None) -> ArrayAntenna:
    """Same-cost phased array: round(M / 6) elements at lambda/2, conjugate-phase steering per slot."""
    m_pa = max(2, round(config.elements / PHASED_ARRAY_COST_RATIO)) if elements is None else int(elements)
    check_int("phased elements", m_pa, 2, 4096)
    angles_deg = np.atleast_1d(np.asarray(angles_deg, dtype=float))
    pos = 0.5 * np.arange(m_pa)
    w = np.conj(steering(pos, np.deg2rad(angles_deg)))
    return ArrayAntenna("phased", pos, w, w.copy(), angles_deg, config.wavelength, meta={"elements": m_pa})
