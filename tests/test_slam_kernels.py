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
from slam.core.kernels import mahalanobis_association, prune_slots, radius_components


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


def test_prune_slots_equals_the_numpy_test():
    rng = np.random.default_rng(2)
    for _ in range(50):
        used = rng.random(30) < 0.7
        active = (rng.random((6, 30)) < 0.5) & used
        last_seen = rng.integers(0, 60, (6, 30))
        hits = rng.integers(0, 4, (6, 30))
        cycle = 60
        age = cycle - last_seen
        kill = active & ((age > 50) | ((hits < 2) & (age > 3)))
        after, gone, n = prune_slots(active, last_seen, hits, np.flatnonzero(used), cycle, 50, 2, 3)
        assert n == int(kill.sum())
        if n:
            assert np.array_equal(after, active & ~kill)
            assert np.array_equal(gone, np.flatnonzero(used & ~after.any(axis=0)))


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


def _filters(rng, P: int, L: int = 40):
    """A numpy-kernel and a numba-kernel RBPF holding the same random state: poses, landmarks (some slots free,
    some held by few particles), weights, hits, last-seen cycles."""
    from slam.core.rbpf import RBPFSlam, SlamConfig

    filters = [RBPFSlam(SlamConfig(n_particles=P, max_landmarks=L, kernels=k), np.random.default_rng(0))
               for k in ("numpy", "numba")]
    pose = np.column_stack([rng.normal(0, 2, (P, 2)), rng.uniform(-np.pi, np.pi, P)])
    mean = rng.normal(0, 20, (P, L, 2))
    a = rng.normal(0, 0.3, (P, L, 2, 2))
    cov = a @ a.transpose(0, 1, 3, 2) + 0.01 * np.eye(2)
    used = rng.random(L) < 0.7
    active = (rng.random((P, L)) < rng.uniform(0.05, 1.0, L)) & used
    logw = rng.normal(0, 1, P)
    logw -= np.log(np.sum(np.exp(logw)))
    hits, last_seen = rng.integers(1, 9, (P, L)), rng.integers(0, 60, (P, L))
    for f in filters:
        f.pose, f.mean, f.cov, f.active, f.logw = pose.copy(), mean.copy(), cov.copy(), active.copy(), logw.copy()
        f.slot_used, f.slot_id = used.copy(), np.arange(L)
        f.hits, f.last_seen = hits.copy(), last_seen.copy()
        f.cycle = 60
    return filters


def test_pairwise_sum_and_einsum_dot_are_numpys_sums():
    """numpy's pairwise summation (np.add.reduce) and einsum's contiguous reduction, emulated bit for bit."""
    import slam.core.kernels as kernels

    rng = np.random.default_rng(4)
    for n in [*range(0, 140), 255, 256, 257, 1000, 1031, 4096]:
        a = rng.random(n) * 10.0 ** rng.uniform(-4, 4, n)
        b = rng.normal(size=n)
        assert kernels._pairwise_sum(a) == np.add.reduce(a), n
        assert kernels._einsum_dot(a, b) == np.einsum("p,p->", a, b), n
    a, b = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    want = np.einsum("pa,pa->p", a, b)
    assert np.array_equal([kernels._einsum_dot3(*x, *y) for x, y in zip(a, b)], want)
    r, s = rng.normal(size=(50, 2)), rng.normal(size=(50, 2, 2))
    want = np.einsum("ki,kij,kj->k", r, s, r)
    assert np.array_equal([kernels._einsum_quad2(*x, *m.ravel()) for x, m in zip(r, s)], want)


@pytest.mark.parametrize("P", [1, 2, 7, 100, 300])
def test_slot_estimates_equal_the_numpy_reference(P):
    """The particle-weighted landmark statistics (RBPFSlam._slot_estimates) compiled: the same bits, one slot or many."""
    rng = np.random.default_rng(P)
    for _ in range(4):
        filters = _filters(rng, P)
        for slots in (np.flatnonzero(filters[0].slot_used), np.array([3]), np.array([0, 39]), np.arange(40)):
            want, got = (f._slot_estimates(slots) for f in filters)
            for x, y in zip(want, got):
                assert np.array_equal(x, y)


def test_pose_moments_and_prune_slots_equal_the_numpy_reference():
    """The estimate's pose statistics (pose_moments) and the pruning over the slots in use (prune_slots)."""
    rng = np.random.default_rng(6)
    for P in (1, 3, 9, 100, 129, 300):
        filters = _filters(rng, P)
        ests = [f._estimate() for f in filters]
        for name in ("pose", "pose_std", "landmarks", "landmark_std", "landmark_ids", "landmark_cov"):
            assert np.array_equal(getattr(ests[0], name), getattr(ests[1], name)), name
        for f in filters:
            f.slot_used[0], f.active[:, 0], f.hits[:, 0], f.last_seen[:, 0] = True, True, 5, 0  # confirmed, gone
            f._prune()
        for name in ("active", "slot_used"):
            assert np.array_equal(getattr(filters[0], name), getattr(filters[1], name)), name
        assert np.array_equal(filters[0].retired_xy, filters[1].retired_xy) and len(filters[0].retired_ids)
    active = np.zeros((3, 5), bool)
    after, gone, n = prune_slots(active, np.zeros((3, 5), np.int64), np.ones((3, 5), np.int64), np.arange(5), 9, 5,
                                 1, 3)
    assert after is active and gone.size == 0 and n == 0


def test_compiled_association_from_the_poses_equals_the_numpy_association():
    """mahalanobis_association_at (map frame, covariances, association, slot ids in one call) against
    RBPFSlam._associate's numpy path: the same slot, NEW or DROPPED per particle and observation."""
    from slam.core.rbpf import Observations

    rng = np.random.default_rng(7)
    for trial in range(20):
        filters = _filters(rng, int(rng.integers(1, 30)))
        M = int(rng.integers(1, 25))
        p0 = filters[0].pose[0]
        held = filters[0].mean[0, rng.choice(40, M)]  # near some landmarks: matches, DROPPED and NEW
        c, s = np.cos(p0[2]), np.sin(p0[2])
        d = held - p0[:2] + rng.normal(0, 0.5 + 2 * (trial % 3), (M, 2))
        z = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
        b = rng.normal(0, 0.3, (M, 2, 2))
        obs = Observations(z=z, Q=b @ b.transpose(0, 2, 1) + 0.05 * np.eye(2), amp=np.ones(M))
        for f in filters:
            f.pose_var = np.array([0.04, 0.04, 1e-4])
        want, got = (f._associate(obs) for f in filters)
        assert np.array_equal(want, got)


def test_proposal_kernels_equal_the_numpy_steps():
    """proposal_prior_information, proposal_shift (with the joint-compatibility test) and proposal_sample against
    the numpy expressions of RBPFSlam._sample_proposal, on the same information sums: the same bits."""
    from slam.core.kernels import proposal_information, proposal_prior_information, proposal_sample, proposal_shift

    rng = np.random.default_rng(9)
    log2pi = np.log(2 * np.pi)
    for _ in range(20):
        P, K = int(rng.integers(1, 40)), int(rng.integers(0, 200))
        pp = np.sort(rng.integers(0, P, K))
        H, nu = rng.normal(size=(K, 2, 3)), rng.normal(size=(K, 2))
        a = rng.normal(size=(K, 2, 2))
        S = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(2)
        Si, logdet = np.linalg.inv(S), np.log(np.linalg.det(S))
        ok, prior_var = rng.random(K) < 0.8, rng.uniform(1e-4, 0.1, 3)
        info, g = proposal_prior_information(pp, H, Si, nu, ok, prior_var, P)
        info0, g0 = proposal_information(pp, H, Si, nu, ok, P)
        info0 += np.diag(1.0 / prior_var)
        assert np.array_equal(info, info0) and np.array_equal(g, g0)
        cov = np.linalg.inv(info)
        delta0 = np.einsum("pab,pb->pa", cov, g)
        quad_r = np.einsum("ki,kij,kj->k", *(lambda r: (r, Si, r))(nu - np.einsum("kia,ka->ki", H, delta0[pp])))
        gate2 = float(np.quantile(quad_r, 0.8)) if K else 1.0
        delta, sym, bad, n_bad = proposal_shift(cov, g, pp, H, Si, nu, gate2, True)
        assert np.array_equal(delta, delta0) and np.array_equal(sym, 0.5 * (cov + cov.transpose(0, 2, 1)))
        assert np.array_equal(bad, quad_r > gate2) and n_bad == int(np.sum(quad_r > gate2))
        assert not proposal_shift(cov, g, pp, H, Si, nu, gate2, False)[2].any()
        post = np.sum(np.log(prior_var)) + np.linalg.slogdet(info)[1]
        chol, noise, pose = np.linalg.cholesky(sym), rng.normal(size=(P, 3)), rng.normal(size=(P, 3))
        quad = np.bincount(pp, weights=ok * np.einsum("ki,kij,kj->k", nu, Si, nu), minlength=P).astype(float)
        quad = quad - np.einsum("pa,pa->p", g, delta)
        n = np.bincount(pp, weights=ok.astype(float), minlength=P)
        sum_logdet = np.bincount(pp, weights=ok * logdet, minlength=P)
        want = -0.5 * quad - n * log2pi - 0.5 * (sum_logdet + post)
        moved = pose + (delta + np.einsum("pab,pb->pa", chol, noise))
        got = proposal_sample(pp, ok, nu, Si, logdet, g, delta, post, chol, noise, pose, log2pi)
        assert np.array_equal(got, want) and np.array_equal(pose, moved)


def test_cluster_fusion_equals_the_numpy_reference():
    """The information fusion of the clusters (cluster_covariance) compiled: the same positions and covariances."""
    from slam.core.association import cluster_covariance

    rng = np.random.default_rng(11)
    for _ in range(30):
        n = int(rng.integers(1, 60))
        pts = np.column_stack([rng.uniform(-50, 50, (n, 2)), rng.normal(size=n), rng.uniform(0, 3, n)])
        a = rng.normal(0, 0.3, (n, 2, 2))
        cov = a @ a.transpose(0, 2, 1) + 1e-3 * np.eye(2)
        labels = rng.integers(0, max(1, n // 3), n)
        labels = np.unique(labels, return_inverse=True)[1].astype(np.int64)
        n_c = int(labels.max()) + 1
        for x, y in zip(cluster_covariance(pts, labels, cov, n_c), cluster_covariance(pts, labels, cov, n_c, "numba")):
            assert np.array_equal(x, y)


def test_the_filter_on_the_compiled_kernels_is_the_numpy_filter_to_round_off():
    """The whole RBPF, every kernel compiled against the numpy reference, over a drive past roadside landmarks: the same
    landmarks, poses to round-off (the proposal's information sums differ from numpy's add.at in the last bits)."""
    from slam.core.rbpf import RBPFSlam, SlamConfig

    rng = np.random.default_rng(12)
    lms = np.column_stack([np.arange(0.0, 200.0, 6.0), np.where(np.arange(34) % 2, 8.0, -8.0)])
    filters = [RBPFSlam(SlamConfig(n_particles=30, kernels=k), np.random.default_rng(1)) for k in ("numpy", "numba")]
    for k in range(30):
        d = lms - [2.0 * k, 0.0]
        near = d[np.hypot(d[:, 0], d[:, 1]) < 50]
        pts = np.column_stack([near + rng.normal(0, 0.1, near.shape), np.zeros(len(near)), np.ones(len(near))])
        motion = np.array([2.0, 0.0, 0.0]) + rng.normal(0, 0.02, 3) * (k == 10)  # a jolt: the recovery path
        ests = [f.update(pts, motion, 0.1) for f in filters]
        assert np.array_equal(ests[0].landmark_ids, ests[1].landmark_ids)
        assert np.allclose(ests[0].pose, ests[1].pose, rtol=0, atol=1e-9)
        assert np.allclose(ests[0].landmark_cov, ests[1].landmark_cov, rtol=1e-9, atol=1e-12)
