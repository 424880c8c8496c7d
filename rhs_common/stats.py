"""Confidence intervals of the studies: one definition of each, tested against scipy.

* :func:`mean_interval`: the mean of i.i.d. samples and its Student-t interval,
  ``mean +- t_{(1+level)/2, n-1} s / sqrt(n)`` with the sample standard deviation
  ``s`` (ddof = 1), over the finite values (NaN and None are dropped and counted);
* :func:`paired_difference`: the same interval on the differences ``a_i - b_i`` of
  paired samples (the same seeds run twice), which cancels what the pairs share;
* :func:`rmse_interval`: the root of the mean square ``sqrt(m)``, ``m = mean(e^2)``,
  with the delta method ``se(sqrt(m)) = se(m) / (2 sqrt(m))`` and the t quantile;
* :func:`wilson_interval`: a rate ``k / n`` and its Wilson score interval
  ``(p + z^2/2n +- z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n)``, which stays inside
  [0, 1] and is not empty at ``k = 0`` or ``k = n``;
* :func:`ratio_bootstrap`: ``mean(a) / mean(b)`` of two independent samples and its
  percentile bootstrap interval (each sample resampled with replacement on its own).

All take ``level`` (default 0.95). scipy is imported inside the functions, so
importing this module costs no more than numpy.

Examples:
    >>> iv = mean_interval([1.0, 2.0, 3.0, 4.0])
    >>> round(iv.mean, 3), round(iv.half_width, 3), iv.n
    (2.5, 2.054, 4)
    >>> [round(x, 4) for x in wilson_interval(0, 30)]
    [0.0, 0.1135]
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "MeanInterval", "format_record", "mean_half_record", "mean_interval", "normal_quantile", "paired_difference",
    "ratio_bootstrap", "rmse_interval", "t_quantile", "wilson_interval",
]


def _check_level(level: float) -> float:
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    return float(level)


def t_quantile(n: int, level: float = 0.95) -> float:
    """The two-sided Student-t quantile ``t_{(1+level)/2, n-1}`` of a mean over n samples; NaN for n < 2."""
    from scipy.stats import t

    if n < 2:
        return float("nan")
    return float(t.ppf(0.5 + _check_level(level) / 2, n - 1))


def normal_quantile(level: float = 0.95) -> float:
    """The two-sided standard normal quantile ``z_{(1+level)/2}`` (1.959964 at 95 %)."""
    from scipy.stats import norm

    return float(norm.ppf(0.5 + _check_level(level) / 2))


def _finite(values: Iterable[float | None]) -> tuple[np.ndarray, int]:
    """The finite values as floats and how many were dropped (NaN, inf or None)."""
    v = np.array([np.nan if x is None else x for x in values], dtype=float).ravel()
    ok = v[np.isfinite(v)]
    return ok, int(v.size - ok.size)


@dataclass(frozen=True)
class MeanInterval:
    """A sample mean and its two-sided Student-t interval ``mean +- half_width``.

    ``n`` counts the finite values used, ``n_dropped`` the NaN / None ones left out;
    ``std`` is the sample standard deviation (ddof = 1). With n < 2 the spread and
    the half-width are NaN (and everything is NaN with n = 0).
    """

    mean: float
    half_width: float
    std: float
    n: int
    n_dropped: int = 0
    level: float = 0.95

    @property
    def low(self) -> float:
        return self.mean - self.half_width

    @property
    def high(self) -> float:
        return self.mean + self.half_width

    def mean_and_half(self) -> tuple[float, float]:
        """``(mean, half_width)``."""
        return self.mean, self.half_width

    def mean_low_high(self) -> tuple[float, float, float]:
        """``(mean, low, high)``: the form the results files store."""
        return self.mean, self.low, self.high

    def to_dict(self) -> dict[str, Any]:
        """The JSON record of the SLAM studies: mean, std, ci95 ``[low, high]``, ci95_half_width, n, n_failed;
        None where undefined (no finite value, or one)."""
        some, spread = self.n > 0, self.n > 1
        return {
            "mean": self.mean if some else None,
            "std": self.std if spread else None,
            "ci95": [self.low, self.high] if spread else None,
            "ci95_half_width": self.half_width if spread else None,
            "n": self.n,
            "n_failed": self.n_dropped,
        }

    def to_mean_half(self) -> dict[str, Any]:
        """The short JSON record: ``{"mean", "ci95": half-width, "n"}``, None where undefined."""
        return {"mean": self.mean if self.n else None, "ci95": self.half_width if self.n > 1 else None, "n": self.n}


def mean_interval(values: Iterable[float | None], level: float = 0.95) -> MeanInterval:
    """Mean of the finite values and its Student-t interval (see the module docstring)."""
    v, dropped = _finite(values)
    n = int(v.size)
    mean = float(v.mean()) if n else float("nan")
    std = float(v.std(ddof=1)) if n > 1 else float("nan")
    half = t_quantile(n, level) * std / math.sqrt(n) if n > 1 else float("nan")
    return MeanInterval(mean, float(half), std, n, dropped, _check_level(level))


def mean_half_record(values: Iterable[float | None], level: float = 0.95) -> dict[str, Any]:
    """:meth:`MeanInterval.to_mean_half` of :func:`mean_interval`: ``{"mean", "ci95": half-width, "n"}``."""
    return mean_interval(values, level).to_mean_half()


def format_record(record: dict[str, Any], digits: int = 3) -> str:
    """A :meth:`MeanInterval.to_dict` record as ``mean [low, high]`` (the mean alone from one value), ``n/a``
    without one, and how many values were left out."""
    if record["mean"] is None:
        return "n/a"
    txt = f"{record['mean']:.{digits}f}"
    if record["ci95"] is not None:
        txt += f" [{record['ci95'][0]:.{digits}f}, {record['ci95'][1]:.{digits}f}]"
    return txt + (f" ({record['n_failed']} unmatched)" if record["n_failed"] else "")


def paired_difference(a: Iterable[float], b: Iterable[float], level: float = 0.95) -> MeanInterval:
    """:func:`mean_interval` of ``a_i - b_i`` over pairs (the same seed under two settings)."""
    x = np.asarray(list(a), dtype=float)
    y = np.asarray(list(b), dtype=float)
    if x.shape != y.shape:
        raise ValueError(f"paired samples must have the same length, got {x.size} and {y.size}")
    return mean_interval(x - y, level)


def rmse_interval(errors: Iterable[float], level: float = 0.95) -> tuple[float, float, int]:
    """RMSE of the finite errors, its half-width (delta method, t quantile) and n; NaNs for n < 2."""
    e, _ = _finite(errors)
    n = int(e.size)
    if n < 2:
        return float("nan"), float("nan"), n
    sq = e**2
    m = float(sq.mean())
    half = t_quantile(n, level) * float(sq.std(ddof=1)) / math.sqrt(n) / (2 * math.sqrt(m)) if m > 0 else 0.0
    return math.sqrt(m), float(half), n


def wilson_interval(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Wilson score interval (low, high) of the rate k / n; NaNs for n = 0."""
    if n == 0:
        return float("nan"), float("nan")
    if not 0 <= k <= n:
        raise ValueError(f"k must be in [0, n] = [0, {n}], got {k}")
    z = normal_quantile(level)
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return max(0.0, centre - half), min(1.0, centre + half)


def ratio_bootstrap(
    a: Iterable[float], b: Iterable[float], rng: np.random.Generator, n_boot: int = 2000, level: float = 0.95
) -> tuple[float, float, float]:
    """``mean(a) / mean(b)`` over the finite values and its percentile bootstrap interval (low, high).

    Each sample is resampled on its own (independent samples, ``n_boot`` draws);
    resamples whose mean of b is not positive are left out. NaNs when either sample
    has fewer than two finite values or ``mean(b) <= 0``.
    """
    x, _ = _finite(a)
    y, _ = _finite(b)
    if x.size < 2 or y.size < 2 or y.mean() <= 0:
        return float("nan"), float("nan"), float("nan")
    tail = round(50.0 * (1.0 - _check_level(level)), 12)  # 2.5 for 95 %, exactly
    rx = x[rng.integers(0, x.size, (n_boot, x.size))].mean(axis=1)
    ry = y[rng.integers(0, y.size, (n_boot, y.size))].mean(axis=1)
    r = rx / np.where(ry > 0, ry, np.nan)
    lo, hi = np.nanpercentile(r, [tail, 100.0 - tail])
    return float(x.mean() / y.mean()), float(lo), float(hi)
