"""The SLAM's compiled kernels against their numpy references (the same results, exactly), on scenes built to
hit their edge cases: far landmarks that the association skips, equal distances (first of equal minima), inactive
slots, points on the cluster radius."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from slam.core.association import cluster_points, mahalanobis_associate
from slam.core.kernels import mahalanobis_association, prune_mask, radius_components


def _dense_d2(obs, a00, a01, a11, mean, cov, active, used):
    """The squared Mahalanobis distances of the numpy reference (RBPFSlam._associate), (P, M, L)."""
    lam = cov[:, used]
    s00 = a00[:, :, None] + lam[:, None, :, 0, 0]
    s01 = a01[:, :, None] + lam[:, None, :, 0, 1]
    s11 = a11[:, :, None] + lam[:, None, :, 1, 1]
    det = np.maximum(s00 * s11 - s01 * s01, 1e-300)
    i00, i01, i11 = s11 / det, -s01 / det, s00 / det
    nx = obs[:, :, None, 0] - mean[:, None, used, 0]
    ny = obs[:, :, None, 1] - mean[:, None, used, 1]
    d2 = i00 * nx * nx + 2.0 * i01 * nx * ny + i11 * ny * ny
    d2[~np.broadcast_to(active[:, None, used], d2.shape)] = np.inf
    return d2


def _scene(rng, lattice: bool):
    P, L_all = 4, 24
    M, L = int(rng.integers(1, 14)), int(rng.integers(1, 18))
    obs = rng.normal(0, 3, (P, M, 2))
    mean = rng.normal(0, 3, (P, L_all, 2))
    mean[:, ::5] += 60.0  # far landmarks: beyond both gates, skipped by the kernel
    cov = np.zeros((P, L_all, 2, 2))
    v = rng.uniform(0.01, 1.0, (P, L_all))
    cov[..., 0, 0], cov[..., 1, 1] = v, v * rng.uniform(0.2, 3.0, (P, L_all))
    cov[..., 0, 1] = cov[..., 1, 0] = 0.3 * np.sqrt(cov[..., 0, 0] * cov[..., 1, 1]) * rng.uniform(-1, 1, (P, L_all))
    a00, a11 = rng.uniform(0.01, 0.5, (P, M)), rng.uniform(0.01, 0.5, (P, M))
    a01 = 0.2 * np.sqrt(a00 * a11) * rng.uniform(-1, 1, (P, M))
    if lattice:  # integer positions, equal covariances: many equal distances
        obs, mean = np.round(obs), np.round(mean)
        a00 = a11 = np.full((P, M), 0.25)
        a01 = np.zeros((P, M))
        cov[:] = 0.0
        cov[..., 0, 0] = cov[..., 1, 1] = 0.25
    active = rng.random((P, L_all)) < 0.8
    used = np.sort(rng.choice(L_all, L, replace=False)).astype(np.int64)
    return obs, a00, a01, a11, mean, cov, active, used


@pytest.mark.parametrize("lattice", [False, True])
def test_compiled_association_equals_the_dense_reference(lattice):
    rng = np.random.default_rng(1 + lattice)
    for _ in range(150):
        args = _scene(rng, lattice)
        want = mahalanobis_associate(_dense_d2(*args), 3.5**2, 6.0**2, 3)
        got = mahalanobis_association(*args, 3.5**2, 6.0**2, 3)
        assert np.array_equal(want, got)


def test_compiled_association_filter_equals_numpy_kernels():
    """The whole filter on the compiled association and the numpy reference: the same associations, cycle by cycle."""
    from slam.core.rbpf import RBPFSlam, SlamConfig

    rng = np.random.default_rng(5)
    lms = np.column_stack([np.arange(0.0, 200.0, 7.0), np.where(np.arange(29) % 2, 9.0, -9.0)])
    filters = [RBPFSlam(SlamConfig(n_particles=20, kernels=k), np.random.default_rng(0)) for k in ("numpy", "numba")]
    for k in range(25):
        x = 2.0 * k
        d = lms - [x, 0.0]
        near = d[np.hypot(d[:, 0], d[:, 1]) < 60]
        pts = np.column_stack([near + rng.normal(0, 0.1, near.shape), np.zeros(len(near)), np.ones(len(near))])
        ests = [f.update(pts, np.array([2.0, 0.0, 0.0]), 0.1) for f in filters]
        assert np.array_equal(ests[0].landmark_ids, ests[1].landmark_ids)
        assert np.allclose(ests[0].pose, ests[1].pose, rtol=0, atol=1e-9)
        assert np.array_equal(filters[0].active, filters[1].active)


def test_prune_mask_equals_the_numpy_test():
    rng = np.random.default_rng(2)
    for _ in range(50):
        active = rng.random((6, 30)) < 0.5
        last_seen = rng.integers(0, 60, (6, 30))
        hits = rng.integers(0, 4, (6, 30))
        cycle = 60
        age = cycle - last_seen
        kill = active & ((age > 50) | ((hits < 2) & (age > 3)))
        after, n = prune_mask(active, last_seen, hits, cycle, 50, 2, 3)
        assert np.array_equal(after, active & ~kill) and n == int(kill.sum())


def test_radius_components_equal_scipy():
    rng = np.random.default_rng(3)
    for trial in range(100):
        n = int(rng.integers(2, 40))
        xy = rng.uniform(0, 8, (n, 2))
        if trial % 4 == 0:  # points exactly on the radius
            xy = np.round(xy)
        pairs = cKDTree(xy).query_pairs(1.0, output_type="ndarray")
        n_c, labels = radius_components(xy, 1.0)
        if len(pairs) == 0:
            assert n_c == n and np.array_equal(labels, np.arange(n))
            continue
        want_n, want = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)),
                                             directed=False)
        assert n_c == want_n and np.array_equal(labels, want)
        pts = np.column_stack([xy, rng.normal(size=n), rng.uniform(0, 2, n)])
        for a, b in zip(cluster_points(pts, 1.0, kernels="numba"), cluster_points(pts, 1.0)):
            assert np.array_equal(a, b)


def test_a_nested_blas_limit_of_the_same_value_sets_the_pools_once(monkeypatch):
    """The SLAM wrapper's step limits the BLAS pools around the radar wrapper's, which limits them again: the
    inner block changes nothing, so it skips threadpoolctl; another value, or after the block, goes through."""
    import contextlib

    from rhs_common import threads

    calls = []

    class Controller:
        @contextlib.contextmanager
        def limit(self, limits):
            calls.append(limits)
            yield

    monkeypatch.setattr(threads, "_controller", lambda: Controller())
    with threads.blas_threads_limit(1):
        with threads.blas_threads_limit(1):
            pass
        with threads.blas_threads_limit(2):
            with threads.blas_threads_limit(1):
                pass
    with threads.blas_threads_limit(1):
        pass
    assert calls == [1, 2, 1, 1]
