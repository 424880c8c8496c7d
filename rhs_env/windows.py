"""The range tapers of the FMCW matched filter, by name.

``WINDOWS`` are the names a :class:`rhs_env.radar_config.WaveformConfig` accepts;
:func:`make_window` builds one (scipy's symmetric forms). Both the config (its
processing gain, :meth:`rhs_env.radar_config.RadarConfig.unit_gain_snr`) and the
point-cloud code (the range FFT) use them, so they sit below both.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.signal import get_window

__all__ = ["WINDOWS", "make_window"]

WINDOWS = ("hann", "hamming", "blackman", "boxcar", "taylor")


def make_window(name: str, n: int) -> np.ndarray:
    """Real taper of length n, float32 (``taylor``: 4 nearly equal sidelobes at -35 dB).

    A new array each call (the caller may write to it), copied from the one scipy built on the first call with
    these arguments (scipy's ``get_window`` costs ~0.2 ms, and every scan's point uncertainty asks for it).
    """
    return _window(name, int(n)).copy()


@functools.lru_cache(maxsize=64)
def _window(name: str, n: int) -> np.ndarray:
    """:func:`make_window`'s taper, built once per ``(name, n)``."""
    if name == "taylor":
        w = get_window(("taylor", 4, 35), n, fftbins=False)
    else:
        w = get_window(name, n, fftbins=False)
    return np.asarray(w, dtype=np.float32)
