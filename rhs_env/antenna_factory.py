"""The antenna kinds a radar can carry, built by name: ``rhs`` | ``phased`` | ``random`` | ``hologram``.

Sits above :mod:`rhs_env.array_models` (the array models) and :mod:`rhs_env.patterns`
(the optimised RHS patterns, which need the array models), so neither imports the other's user.
"""

from __future__ import annotations

import numpy as np

from rhs_common.validation import check_choice
from rhs_env.array_models import (
    ANTENNA_KINDS,
    ArrayAntenna,
    RHSConfig,
    ScanConfig,
    hologram_pattern,
    phased_array,
    rhs_antenna,
)
from rhs_env.patterns.library import get_library

__all__ = ["ANTENNA_KINDS", "make_antenna"]


def make_antenna(
    kind: str,
    config: RHSConfig | None = None,
    scan: ScanConfig | None = None,
    rng: np.random.Generator | None = None,
    patterns: tuple[np.ndarray, np.ndarray] | None = None,
) -> ArrayAntenna:
    """Build an antenna by name: ``rhs`` | ``phased`` | ``random`` | ``hologram``.

    ``rhs`` uses ``patterns=(tx_psi, rx_psi)`` when given, else the pattern
    library for (config, scan) from :func:`rhs_env.patterns.library.get_library`
    (shipped, or built once into the user cache). ``random`` draws psi uniformly
    in [0, 1] per slot from ``rng`` (required for reproducibility).
    """
    check_choice("antenna", kind, ANTENNA_KINDS)
    config = config or RHSConfig()
    scan = scan or ScanConfig()
    angles = scan.angles_deg
    if kind == "phased":
        return phased_array(config, angles)
    if kind == "hologram":
        return rhs_antenna(
            config,
            hologram_pattern(config, angles, config.tx_feed),
            hologram_pattern(config, angles, config.rx_feed),
            angles,
            name="hologram",
        )
    if kind == "random":
        if rng is None:
            raise ValueError("antenna 'random' needs rng (a numpy Generator) so episodes are reproducible")
        shape = (angles.size, config.elements)
        return rhs_antenna(config, rng.uniform(0, 1, shape), rng.uniform(0, 1, shape), angles, name="random")
    if patterns is None:
        lib = get_library(config, scan)
        patterns = (lib.tx, lib.rx)
    return rhs_antenna(config, patterns[0], patterns[1], angles, name="rhs")
