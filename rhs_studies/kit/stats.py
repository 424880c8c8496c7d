"""Aggregate statistics over training runs, as the RL field reads them (Agarwal et al. 2021, "Deep RL at the edge
of the statistical precipice"; the ``rliable`` library's definitions, without its dependencies).

Scores are a matrix ``(runs, tasks)``: one row per training seed, one column per task (here: an env, or an
evaluation condition), each entry a run's score on that task (a normalised return, e.g. return / IDM + MOBIL's
return on the same seeds).

* **IQM**, the interquartile mean: the mean of the middle 50 % of all ``runs x tasks`` scores, i.e.
  ``scipy.stats.trim_mean(scores, 0.25, axis=None)`` (``rliable.metrics.aggregate_iqm``): with ``n`` scores,
  ``k = floor(0.25 n)`` are cut from each end of the sorted scores and the rest averaged
  (``n < 4``: nothing is cut, the IQM is the mean).
* **Optimality gap** at ``gamma``: ``mean(gamma - min(score, gamma))`` (``aggregate_optimality_gap``).
* **Stratified bootstrap**: each replicate draws, for every task independently, ``runs`` rows with
  replacement (``rliable.library.StratifiedBootstrap``, ``task_bootstrap=False``); the interval is the percentile
  interval of the aggregate over the replicates (rliable's default ``method="percentile"``).
* **Performance profile** (score distribution): ``P(tau) = mean(scores > tau)`` over every run and task
  (``rliable.library.create_performance_profile`` with ``use_score_distribution=True``), with its stratified
  bootstrap interval at each ``tau``.

``rliable`` itself was not taken: it requires ``arch`` (with statsmodels), ``absl-py`` and ``seaborn``
for these few lines (docs/installation.md).

>>> iqm([[1.0], [2.0], [3.0], [4.0], [100.0]])  # 5 scores: 1 cut each end
3.0
>>> round(iqm([[0.0], [1.0], [2.0], [3.0]]), 3)  # 4 scores: the middle two
1.5
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from rhs_common.validation import check_int

__all__ = ["aggregate", "iqm", "mean", "median", "optimality_gap", "performance_profile", "score_matrix",
           "stratified_bootstrap"]


def score_matrix(scores: Any) -> np.ndarray:
    """``scores`` as a finite float matrix ``(runs, tasks)`` (a 1-D sequence is one task); ``ValueError`` else."""
    m = np.asarray(scores, dtype=float)
    if m.ndim == 1:
        m = m[:, None]
    if m.ndim != 2 or m.shape[0] < 1 or m.shape[1] < 1:
        raise ValueError(f"scores must be a (runs, tasks) matrix with at least one run and task, got shape {m.shape}")
    if not np.isfinite(m).all():
        raise ValueError("scores must be finite (a run without a score has no place in the matrix)")
    return m


def iqm(scores: Any) -> float:
    """Interquartile mean of every score: ``k = floor(n / 4)`` cut from each end of the ``n`` sorted scores, the rest
    averaged (``scipy.stats.trim_mean(x, 0.25, axis=None)``)."""
    x = np.sort(score_matrix(scores), axis=None)
    k = int(0.25 * x.size)
    return float(x[k:x.size - k].mean())


def mean(scores: Any) -> float:
    """Mean over tasks of the mean over runs (rliable's ``aggregate_mean``; equal to the mean of every score)."""
    return float(score_matrix(scores).mean(axis=0).mean())


def median(scores: Any) -> float:
    """Median over tasks of the mean over runs (rliable's ``aggregate_median``)."""
    return float(np.median(score_matrix(scores).mean(axis=0)))


def optimality_gap(scores: Any, gamma: float = 1.0) -> float:
    """``mean(gamma - min(score, gamma))``: how far the scores stay below ``gamma`` on average."""
    return float(np.mean(gamma - np.minimum(score_matrix(scores), gamma)))


def stratified_bootstrap(scores: Any, func: Callable[[np.ndarray], Any], reps: int = 2000, size: float = 0.95,
                         seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``func`` of ``scores`` and its stratified bootstrap percentile interval.

    Args:
        scores: ``(runs, tasks)``.
        func: the aggregate, a scalar or 1-D array of a ``(runs, tasks)`` matrix.
        reps: bootstrap replicates (>= 10).
        size: the interval's coverage, in (0, 1).
        seed: the resampling generator's seed.

    Returns:
        The point estimate (array) and the interval, shape ``(2, ...)``: lower and upper percentiles
        ``100 (1 - size) / 2`` and ``100 (1 + size) / 2`` of the replicates.
    """
    m = score_matrix(scores)
    check_int("reps", reps, 10, 10**7)
    if not 0.0 < size < 1.0:
        raise ValueError(f"size must be in (0, 1), got {size}")
    rng = np.random.default_rng(seed)
    runs, tasks = m.shape
    cols = np.arange(tasks)[None, :]
    reps_out = np.asarray([np.asarray(func(m[rng.integers(0, runs, size=m.shape), cols]), dtype=float)
                           for _ in range(reps)])
    alpha = 100.0 * (1.0 - size) / 2.0
    interval = np.percentile(reps_out, [alpha, 100.0 - alpha], axis=0)
    return np.asarray(func(m), dtype=float), interval


def performance_profile(scores: Any, taus: Sequence[float], reps: int = 2000, size: float = 0.95,
                        seed: int = 0) -> dict[str, list[float]]:
    """The score distribution ``P(tau) = mean(scores > tau)`` at each ``tau``, with stratified bootstrap bands.

    Returns:
        ``{"tau", "profile", "low", "high"}``, lists over ``taus``.
    """
    t = np.asarray(list(taus), dtype=float)
    if t.ndim != 1 or t.size < 1 or not np.isfinite(t).all():
        raise ValueError("taus must be a non-empty 1-D sequence of finite thresholds")
    point, band = stratified_bootstrap(scores, lambda m: (m.reshape(-1)[:, None] > t[None, :]).mean(axis=0),
                                       reps=reps, size=size, seed=seed)
    return {"tau": t.tolist(), "profile": point.tolist(), "low": band[0].tolist(), "high": band[1].tolist()}


def aggregate(scores: Any, reps: int = 2000, size: float = 0.95, seed: int = 0,
              gamma: float = 1.0) -> dict[str, dict[str, float]]:
    """IQM, mean, median and optimality gap of ``scores``, each ``{"value", "low", "high"}`` (stratified bootstrap)."""
    funcs: dict[str, Callable[[np.ndarray], float]] = {
        "iqm": iqm, "mean": mean, "median": median, "optimality_gap": lambda m: optimality_gap(m, gamma)}
    out = {}
    for name, f in funcs.items():
        point, band = stratified_bootstrap(scores, f, reps=reps, size=size, seed=seed)
        out[name] = {"value": float(point), "low": float(band[0]), "high": float(band[1])}
    return out
