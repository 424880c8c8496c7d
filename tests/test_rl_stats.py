"""rhs_studies.kit.stats (the RL aggregates) against rliable's published definitions (IQM = scipy's 25 % trimmed mean over every score,
the stratified bootstrap resampling runs within each task, percentile intervals, score-distribution profiles)."""

import numpy as np
import pytest
import scipy.stats

from rhs_studies.kit import stats


@pytest.mark.parametrize("shape", [(3, 1), (4, 1), (5, 2), (10, 7), (1, 9)])
def test_iqm_is_scipys_quarter_trimmed_mean(shape):
    x = np.random.default_rng(sum(shape)).normal(size=shape) ** 3
    assert stats.iqm(x) == pytest.approx(scipy.stats.trim_mean(x, proportiontocut=0.25, axis=None), rel=1e-12)


def test_iqm_ignores_the_outer_quarters():
    x = np.arange(8.0)[:, None]
    assert stats.iqm(x) == pytest.approx(np.mean([2, 3, 4, 5]))
    x[-1] = 1e9  # an outlier run moves the mean, not the IQM
    assert stats.iqm(x) == pytest.approx(3.5) and stats.mean(x) > 1e8


def test_mean_median_and_optimality_gap_follow_rliable():
    m = np.array([[0.5, 1.2, 2.0], [0.7, 0.8, 1.0]])
    assert stats.mean(m) == pytest.approx(np.mean(m))
    assert stats.median(m) == pytest.approx(np.median(m.mean(axis=0)))
    assert stats.optimality_gap(m) == pytest.approx(np.mean(1 - np.minimum(m, 1)))
    assert stats.optimality_gap(m, gamma=2.0) == pytest.approx(np.mean(2 - np.minimum(m, 2)))


def test_bootstrap_resamples_runs_within_each_task():
    rows = np.repeat(np.arange(5.0)[:, None], 4, axis=1)  # every task's score is the run's index
    mixed = []
    stats.stratified_bootstrap(rows, lambda m: mixed.append(bool((m != m[:, :1]).any())) or 0.0, reps=50)
    assert any(mixed)  # tasks draw their runs independently (rliable's task_bootstrap=False)
    const = np.tile(np.array([1.0, 2.0, 3.0]), (6, 1))  # no spread over runs: a zero-width interval
    point, band = stats.stratified_bootstrap(const, stats.mean, reps=200)
    assert float(point) == pytest.approx(2.0) and band[0] == pytest.approx(2.0) and band[1] == pytest.approx(2.0)


def test_bootstrap_interval_covers_like_the_normal_one():
    x = np.random.default_rng(1).normal(10.0, 2.0, size=(400, 1))
    point, (lo, hi) = stats.stratified_bootstrap(x, stats.mean, reps=2000, seed=3)
    half = 1.96 * x.std(ddof=1) / np.sqrt(x.size)
    assert lo < float(point) < hi
    assert (hi - lo) / 2 == pytest.approx(half, rel=0.15)
    assert stats.stratified_bootstrap(x, stats.mean, reps=100, seed=3)[1] == pytest.approx(
        stats.stratified_bootstrap(x, stats.mean, reps=100, seed=3)[1])  # seeded: reproducible


def test_performance_profile_is_the_score_distribution():
    m = np.array([[0.2, 0.9], [1.1, 1.5], [0.6, 0.8]])
    taus = [0.0, 0.7, 1.0, 2.0]
    p = stats.performance_profile(m, taus, reps=200)
    assert p["profile"] == pytest.approx([np.mean(m > t) for t in taus])
    assert all(a >= b for a, b in zip(p["profile"], p["profile"][1:]))
    assert all(lo <= v <= hi for lo, v, hi in zip(p["low"], p["profile"], p["high"]))


def test_aggregate_and_bad_input():
    agg = stats.aggregate(np.random.default_rng(0).uniform(size=(5, 3)), reps=100)
    assert set(agg) == {"iqm", "mean", "median", "optimality_gap"}
    assert all(v["low"] <= v["value"] <= v["high"] for v in agg.values())
    with pytest.raises(ValueError, match="finite"):
        stats.iqm([[1.0], [np.nan]])
    with pytest.raises(ValueError, match="matrix"):
        stats.iqm(np.zeros((2, 2, 2)))
    with pytest.raises(ValueError, match="size"):
        stats.stratified_bootstrap([[1.0]], stats.mean, size=1.5)
    with pytest.raises(ValueError, match="reps"):
        stats.stratified_bootstrap([[1.0]], stats.mean, reps=1)
