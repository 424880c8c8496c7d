"""SLAM metrics: RMSEs, Hungarian map matching, point-cloud metrics."""

import math

import numpy as np
import pytest

from slam.core.metrics import (
    MEASURED_GATE_M,
    MEASURED_MIN_SCANS,
    heading_rmse,
    landmark_hits,
    map_metrics,
    matched_fraction,
    position_rmse,
)


def test_position_and_heading_rmse():
    true = np.zeros((4, 3))
    est = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    assert position_rmse(est, true) == pytest.approx(math.sqrt(25 / 4))
    a = np.array([[0, 0, math.radians(179)], [0, 0, 0.1]])
    b = np.array([[0, 0, math.radians(-179)], [0, 0, 0.1]])
    assert heading_rmse(a, b) == pytest.approx(math.sqrt(math.radians(2) ** 2 / 2))
    with pytest.raises(ValueError):
        position_rmse(est, true[:2])


def test_hungarian_map_one_to_one():
    true = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    # two estimates near landmark 0 (greedy nearest would match both), one near 1,
    # one far away (spurious); landmark 2 missed
    est = np.array([[0.3, 0.0], [0.0, 1.0], [10.0, 0.4], [50.0, 50.0]])
    r = map_metrics(est, true, gate=2.0)
    assert r["matched"] == 2 and r["missed"] == 1 and r["spurious"] == 2
    assert r["rmse"] == pytest.approx(math.sqrt((0.3**2 + 0.4**2) / 2))


def test_hungarian_prefers_global_optimum():
    # greedy matching from the true side pairs true 0 with its nearest, est 0 (0.9), and
    # leaves est 1 unmatched (2.5 > gate);
    # the assignment pairs est 0 -> true 1 and est 1 -> true 0
    true = np.array([[0.0, 0.0], [1.5, 0.0]])
    est = np.array([[0.9, 0.0], [-1.0, 0.0]])
    r = map_metrics(est, true, gate=1.2)
    assert r["matched"] == 2 and r["missed"] == 0 and r["spurious"] == 0
    assert r["rmse"] == pytest.approx(math.sqrt((0.6**2 + 1.0**2) / 2))


def _full_hungarian(est, true, gate):
    """The reference: the Hungarian algorithm on the full (E, T) matrix, out-of-gate pairs priced above any sum."""
    from scipy.optimize import linear_sum_assignment

    d = np.linalg.norm(est[:, None, :] - true[None, :, :], axis=2)
    r, c = linear_sum_assignment(np.where(d <= gate, d, gate * 1e3 + d.max() * 10 + 1.0))
    ok = d[r, c] <= gate
    return np.stack([r[ok], c[ok]], axis=1), d[r[ok], c[ok]]


def test_map_metrics_is_the_full_hungarian():
    """Matching only the in-gate candidates (the lone pairs outright, the shared ones by the Hungarian) gives the
    full matrix's assignment: the same pairs, in the same order, and the same RMSE to the bit; crowded maps (many
    estimates sharing candidates) and maps large enough for the k-d tree's candidates included."""
    rng = np.random.default_rng(5)
    for k in range(400):
        ne, nt = rng.integers(0, 30, 2) if k % 20 else rng.integers(60, 300, 2)  # every 20th past DENSE_PAIRS
        side = rng.choice([5.0, 20.0, 100.0])
        est, true = rng.uniform(0, side, (ne, 2)), rng.uniform(0, side, (nt, 2))
        gate = float(rng.uniform(0.5, 4.0))
        r = map_metrics(est, true, gate)
        if ne == 0 or nt == 0:
            assert r["matched"] == 0
            continue
        pairs, dist = _full_hungarian(est, true, gate)
        assert np.array_equal(r["pairs"], pairs), k
        assert r["matched"] == len(pairs) and r["missed"] == nt - len(pairs) and r["spurious"] == ne - len(pairs)
        if len(pairs):
            assert r["rmse"] == float(np.sqrt(np.mean(dist**2)))
        else:
            assert math.isnan(r["rmse"])


def test_map_metrics_empty():
    r = map_metrics(np.zeros((0, 2)), np.ones((3, 2)), 1.0)
    assert r["matched"] == 0 and r["missed"] == 3 and r["spurious"] == 0 and math.isnan(r["rmse"])
    with pytest.raises(ValueError, match="gate"):
        map_metrics(np.zeros((1, 2)), np.ones((1, 2)), 0.0)


def test_landmark_hits_within_the_gate():
    lm = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    pts = np.array([[0.5, 0.5], [10.0, 1.01], [30.0, 0.0]])
    np.testing.assert_array_equal(landmark_hits(pts, lm, 1.0), [True, False, False])
    np.testing.assert_array_equal(landmark_hits(np.zeros((0, 2)), lm), [False, False, False])
    assert MEASURED_GATE_M == 1.0 and MEASURED_MIN_SCANS == 2
    with pytest.raises(ValueError, match="gate"):
        landmark_hits(pts, lm, 0.0)


def test_matched_fraction_over_the_measured_landmarks():
    true = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0]])
    est = np.array([[0.1, 0.0], [10.2, 0.0]])  # the map holds the two landmarks the radar measured
    scans = np.array([5, 3, 1, 0])  # scans with a point within the gate of each true landmark
    assert matched_fraction(est, true, None) == 0.5  # every landmark within range counts
    assert matched_fraction(est, true, scans >= MEASURED_MIN_SCANS) == 1.0
    assert matched_fraction(est, true, np.zeros(4, bool)) is None
    with pytest.raises(ValueError, match="one entry per true landmark"):
        matched_fraction(est, true, np.ones(3, bool))
