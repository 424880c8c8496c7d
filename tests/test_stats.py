"""rhs_common.stats: every interval against scipy's own implementation (or its definition, computed with scipy)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from rhs_common.stats import (
    mean_half_record,
    mean_interval,
    normal_quantile,
    paired_difference,
    ratio_bootstrap,
    rmse_interval,
    t_quantile,
    wilson_interval,
)


@pytest.mark.parametrize("level", [0.9, 0.95, 0.99])
@pytest.mark.parametrize("n", [2, 5, 30])
def test_mean_interval_is_scipys_student_t_interval(n, level):
    x = np.random.default_rng(n).normal(3.0, 2.0, n)
    iv = mean_interval(x, level)
    lo, hi = stats.t.interval(level, n - 1, loc=x.mean(), scale=stats.sem(x))
    assert iv.n == n and iv.mean == pytest.approx(x.mean())
    assert (iv.low, iv.high) == pytest.approx((lo, hi), rel=1e-12)
    assert iv.std == pytest.approx(x.std(ddof=1))


def test_mean_interval_drops_nan_and_none_and_is_nan_below_two():
    iv = mean_interval([1.0, None, float("nan"), 3.0])
    assert (iv.n, iv.n_dropped, iv.mean) == (2, 2, 2.0)
    assert iv.half_width == pytest.approx(stats.t.ppf(0.975, 1) * math.sqrt(2) / math.sqrt(2))
    one = mean_interval([4.0])
    assert one.mean == 4.0 and math.isnan(one.half_width) and math.isnan(one.std)
    assert math.isnan(mean_interval([]).mean)
    assert math.isnan(t_quantile(1))


def test_a_wider_interval_at_a_higher_level_and_the_t_wider_than_the_normal():
    x = np.arange(10.0)
    assert mean_interval(x, 0.99).half_width > mean_interval(x, 0.95).half_width > mean_interval(x, 0.9).half_width
    assert t_quantile(10) > normal_quantile() == pytest.approx(1.959963984540054)
    with pytest.raises(ValueError, match="level must be in"):
        mean_interval(x, 1.0)


def test_paired_difference_is_scipys_paired_t_interval():
    rng = np.random.default_rng(1)
    shared = rng.normal(0.0, 10.0, 12)  # a large per-seed effect the pairing cancels
    a, b = shared + rng.normal(1.0, 0.5, 12), shared + rng.normal(0.0, 0.5, 12)
    iv = paired_difference(a, b)
    ci = stats.ttest_rel(a, b).confidence_interval(0.95)
    assert (iv.low, iv.high) == pytest.approx((ci.low, ci.high), rel=1e-10)
    assert iv.high - iv.low < mean_interval(a).half_width  # pairing: far tighter than either sample's spread
    with pytest.raises(ValueError, match="same length"):
        paired_difference([1.0, 2.0], [1.0])


@pytest.mark.parametrize(("k", "n"), [(0, 30), (3, 30), (15, 30), (30, 30), (1, 7)])
def test_wilson_interval_is_scipys(k, n):
    ci = stats.binomtest(k, n).proportion_ci(0.95, method="wilson")
    assert wilson_interval(k, n) == pytest.approx((ci.low, ci.high), abs=1e-12)
    assert all(math.isnan(v) for v in wilson_interval(0, 0))
    with pytest.raises(ValueError, match="k must be in"):
        wilson_interval(4, 3)


def test_rmse_interval_delta_method_against_a_monte_carlo_of_the_rmse():
    e = np.random.default_rng(2).normal(0.0, 2.0, 400)
    rmse, half, n = rmse_interval(e)
    assert n == 400 and rmse == pytest.approx(np.sqrt(np.mean(e**2)))
    # the standard error of the RMSE of 400 N(0, 2^2) errors, by simulation: sigma / sqrt(2 n) = 0.0707
    sims = np.sqrt(np.mean(np.random.default_rng(3).normal(0.0, 2.0, (4000, 400)) ** 2, axis=1))
    assert half / stats.t.ppf(0.975, n - 1) == pytest.approx(sims.std(), rel=0.1)
    assert all(math.isnan(v) for v in rmse_interval([1.0])[:2])


def test_ratio_bootstrap_matches_scipys_percentile_bootstrap():
    rng = np.random.default_rng(4)
    a, b = rng.exponential(2.0, 40), rng.exponential(1.0, 50)
    r, lo, hi = ratio_bootstrap(a, b, np.random.default_rng(5), n_boot=20000)
    ref = stats.bootstrap((a, b), lambda x, y, axis=-1: x.mean(axis=axis) / y.mean(axis=axis), paired=False,
                          n_resamples=20000, method="percentile", vectorized=True, random_state=6).confidence_interval
    assert r == pytest.approx(a.mean() / b.mean())
    assert (lo, hi) == pytest.approx((ref.low, ref.high), rel=0.03)  # two Monte Carlo draws of the same quantiles
    assert lo < r < hi
    assert all(math.isnan(v) for v in ratio_bootstrap([1.0], b, rng))


def test_the_json_records_of_the_studies():
    st = mean_interval([1.0, 2.0, 4.0, None]).to_dict()
    assert st["n"] == 3 and st["n_failed"] == 1 and st["mean"] == pytest.approx(7 / 3)
    sd = float(np.std([1.0, 2.0, 4.0], ddof=1))
    half = stats.t.ppf(0.975, 2) * sd / math.sqrt(3)  # 4.30 s / sqrt(3): wider than the normal 1.96
    assert st["std"] == pytest.approx(sd) and st["ci95_half_width"] == pytest.approx(half)
    assert st["ci95"] == pytest.approx([7 / 3 - half, 7 / 3 + half])
    one = mean_interval([0.5]).to_dict()
    assert one["mean"] == 0.5 and one["std"] is None and one["ci95"] is None  # no interval from one seed
    assert mean_half_record([1.0, 3.0]) == {"mean": 2.0, "ci95": pytest.approx(stats.t.ppf(0.975, 1)), "n": 2}
    assert mean_half_record([]) == {"mean": None, "ci95": None, "n": 0}
