"""The antennas of the four radars and their slot patterns: one OMP dictionary per distinct antenna.

A stage of :class:`rhs_env.radar.RadarSystem` (its ``beams``): which antenna each radar carries (the
``rhs`` / ``phased`` / ``random`` / ``hologram`` patterns of :mod:`rhs_env.antenna_factory`), the angle
dictionary the OMP searches for it, and the two-way slot gains the echo synthesis applies.
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import KernelTable
from rhs_env.antenna_factory import make_antenna
from rhs_env.array_models import ArrayAntenna
from rhs_env.omp import AngleDictionary
from rhs_env.radar_config import RadarConfig

__all__ = ["BeamPatterns"]


class BeamPatterns:
    """The four radars' antennas, their beam slots and angle dictionaries.

    Each radar sweeps I beam slots (one grid per slot, ``config.scan``); slot i's two-way gain toward
    ``theta`` is ``h_i(theta) = r_i(theta) t_i(theta)`` with the power-normalised gains of
    :class:`rhs_env.array_models.ArrayAntenna` (``|t|^2`` the array gain at fixed radiated power ``P_t``,
    ``|r|^2`` the Rx SNR gain, dimensionless), so the noise of the normalised Rx output is that of one element.
    Radars that share an antenna object share one :class:`rhs_env.omp.AngleDictionary` (all four, unless the
    patterns differ: the ``random`` antenna draws one per radar).

    Args:
        config: :class:`rhs_env.radar_config.RadarConfig` (``antenna``, ``rhs``, ``scan``, ``estimation``, ``kernels``).
        rng: numpy Generator of the ``random`` antenna's patterns (one per radar, drawn here).
        patterns: optional ``(tx_psi, rx_psi)`` (I, M) for the ``rhs`` antenna instead of the pattern library.
        antennas: optional explicit antenna per radar (list of 4 or one shared), overriding ``config.antenna``.

    Attributes:
        antennas: the antenna of each radar (4,).
        groups: the distinct dictionaries, in order of first use.
        radar_group: (4,) int, the index in ``groups`` of each radar's dictionary.
        dictionaries: the dictionary of each radar (4,).
    """

    def __init__(self, config: RadarConfig, rng: np.random.Generator,
                 patterns: tuple[np.ndarray, np.ndarray] | None = None,
                 antennas: ArrayAntenna | list[ArrayAntenna] | None = None) -> None:
        if antennas is not None:
            ants = [antennas] * 4 if isinstance(antennas, ArrayAntenna) else list(antennas)
            if len(ants) != 4:
                raise ValueError(f"antennas must be one ArrayAntenna or a list of 4, got {len(ants)}")
        elif config.antenna == "random":
            ants = [make_antenna("random", config.rhs, config.scan, rng=rng) for _ in range(4)]
        else:
            shared = make_antenna(config.antenna, config.rhs, config.scan, patterns=patterns)
            ants = [shared] * 4
        for a in ants:
            if a.slots != config.scan.slots:
                raise ValueError(f"antenna has {a.slots} slots, scan config needs {config.scan.slots}")
        self.antennas = ants
        self.groups: list[AngleDictionary] = []  # one dictionary per distinct antenna object
        seen: dict[int, int] = {}
        self.radar_group = np.zeros(4, int)
        for r, a in enumerate(ants):
            if id(a) not in seen:
                seen[id(a)] = len(self.groups)
                self.groups.append(AngleDictionary(a, config.scan.grid_deg, config.scan.sector_deg,
                                                   config.estimation.oversampling).use_kernels(config.kernels))
            self.radar_group[r] = seen[id(a)]
        self.dictionaries = [self.groups[self.radar_group[r]] for r in range(4)]
        self.slots = config.scan.slots
        self._impl = _STAGES.choose(config.kernels)  # the dictionary's series or the direct product

    def gains(self, radar: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """The slot gains ``h[i, p] = h_i(theta_p)`` (I, P) complex of radar ``radar[p]`` toward ``theta[p]`` (rad).

        With ``kernels="numba"`` the dictionary's series (:meth:`rhs_env.omp.AngleDictionary.atoms`: the same
        gains to ~1e-15), else the antenna's direct product.
        """
        h = np.empty((self.slots, radar.size), complex)
        for g, dic in enumerate(self.groups):
            sel = self.radar_group[radar] == g
            if np.any(sel):
                h[:, sel] = self._impl.gains(dic, theta[sel])
        return h


#: the gains' two implementations, chosen once by ``RadarConfig.kernels``
_STAGES = KernelTable("rhs_env.radar.antennas")


@_STAGES.stage("gains", "numpy")
def _gains_numpy(dic: AngleDictionary, theta: np.ndarray) -> np.ndarray:
    """The slot gains h (I, P) toward the angles ``theta`` (P,): the antenna's direct product (the reference)."""
    return np.asarray(dic.antenna.two_way_gain(theta))


@_STAGES.stage("gains", "numba")
def _gains_compiled(dic: AngleDictionary, theta: np.ndarray) -> np.ndarray:
    """:func:`_gains_numpy` from the dictionary's series (:meth:`AngleDictionary.atoms`: the same gains to ~1e-15)."""
    return np.asarray(dic.atoms(theta)[0])
