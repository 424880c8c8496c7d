"""RBPF SLAM: exactness, accuracy vs dead reckoning, resampling, numerics, memory."""

import math

import numpy as np
import pytest

from slam.core.rbpf import Observations, RBPFSlam, SlamConfig, circular_mean
from slam.core.registration import ICPRegistration, OdometryRegistration
from slam.core.scenario import SyntheticCloud, run_scenario

NOISELESS = dict(trans_std_m=0.0, trans_frac=0.0, rot_std_rad=0.0, accel_std_mps2=0.0, yaw_accel_std_radps2=0.0)


def _road(T=100, v=15.0, dt=0.1, n_lm=30, spacing=10.0):
    lm = np.stack([np.arange(n_lm) * spacing, np.where(np.arange(n_lm) % 2, 8.0, -8.0)], axis=1)
    x = np.arange(T) * v * dt
    y = 2.0 * np.sin(x / 40.0)
    th = np.arctan2(np.gradient(y), np.gradient(x))
    return lm, np.stack([x, y, th], axis=1)


def test_config_validation_names_field():
    with pytest.raises(ValueError, match="n_particles"):
        SlamConfig(n_particles=0)
    with pytest.raises(ValueError, match="weighting"):
        SlamConfig(weighting="max")
    with pytest.raises(ValueError, match="range_std_m"):
        SlamConfig(range_std_m=0.0)
    with pytest.raises(ValueError, match="resample_threshold"):
        SlamConfig(resample_threshold=1.5)


def test_noiseless_reproduces_trajectory_and_map():
    lm, poses = _road()
    cfg = SlamConfig(n_particles=20, **NOISELESS)
    cloud = SyntheticCloud(lm, 1, max_range_m=40.0, dt=0.1)
    r = run_scenario(lm, poses, cloud, OdometryRegistration(), cfg, 0, dt=0.1)
    assert r["ate_rmse_m"] < 1e-6
    assert r["heading_rmse_rad"] < 1e-8
    assert r["map_rmse_m"] < 1e-6
    # every landmark that came within range was mapped, nothing spurious
    seen = np.sum(lm[:, 0] <= poses[-1, 0] + 40.0)
    assert r["map_matched"] == seen and r["map_spurious"] == 0
    assert r["finite"]


def test_noiseless_with_icp_registration():
    lm, poses = _road(T=60)
    cfg = SlamConfig(n_particles=10, **NOISELESS)
    r = run_scenario(lm, poses, SyntheticCloud(lm, 1, max_range_m=40.0, dt=0.1), ICPRegistration(), cfg, 0, dt=0.1)
    assert r["ate_rmse_m"] < 1e-3 and r["map_rmse_m"] < 1e-3


@pytest.mark.parametrize("seed", [0, 1])
def test_noisy_filter_beats_dead_reckoning(seed):
    lm, poses = _road()
    cfg = SlamConfig(
        n_particles=100, trans_std_m=0.05, rot_std_rad=0.01, trans_frac=0.0, accel_std_mps2=0.0, yaw_accel_std_radps2=0.0
    )
    cloud = SyntheticCloud(
        lm, 100 + seed, max_range_m=40.0, dt=0.1, range_std_m=0.2, bearing_std_rad=math.radians(1.0), p_miss=0.1, false_rate=1.0
    )
    odo = OdometryRegistration(200 + seed, trans_std_m=0.05, rot_std_rad=0.01)
    r = run_scenario(lm, poses, cloud, odo, cfg, seed, dt=0.1)
    assert r["finite"]
    assert r["ate_rmse_m"] < 0.5 * r["dead_reckoning_rmse_m"]
    assert r["map_rmse_m"] < 1.5 and r["map_matched"] >= 12


def test_resampling_copies_particle_state():
    slam = RBPFSlam(SlamConfig(n_particles=4, max_landmarks=8), 0)
    slam.update(np.array([[10.0, 0.0, 0.0, 1.0], [0.0, 10.0, 0.0, 1.0]]), None, 0.1)
    slam.logw = np.log(np.array([1.0, 1e-30, 1e-30, 1e-30]))
    slam._normalize()
    slam._resample()
    assert np.all(slam.weights == pytest.approx(0.25))
    for a in ("pose", "mean", "cov", "active", "hits", "last_seen"):
        arr = getattr(slam, a)
        assert arr.base is None or not np.shares_memory(arr[0], arr[1])
    before = slam.mean[1].copy()
    slam.mean[0, 0] += 100.0
    slam.cov[0, 0] *= 5.0
    np.testing.assert_array_equal(slam.mean[1], before)
    assert not np.allclose(slam.cov[0, 0], slam.cov[1, 0])


def test_all_zero_likelihood_gives_no_nan():
    cfg = SlamConfig(n_particles=8, range_std_m=1e-6, bearing_std_rad=1e-9, delta_m=50.0)
    slam = RBPFSlam(cfg, 0)
    slam.update(np.array([[10.0, 0.0, 0.0, 1.0]]), None, 0.1)
    # the landmark now appears 30 m away: every particle's likelihood underflows to 0
    est = slam.update(np.array([[10.0, 30.0, 0.0, 1.0]]), np.zeros(3), 0.1)
    assert np.all(np.isfinite(slam.logw)) and np.isclose(slam.weights.sum(), 1.0)
    assert np.all(np.isfinite(est.pose)) and np.all(np.isfinite(est.landmarks))
    # weights that are all -inf / NaN fall back to uniform
    slam.logw = np.full(8, -np.inf)
    slam._normalize()
    np.testing.assert_allclose(slam.weights, 1.0 / 8)
    slam.logw = np.full(8, np.nan)
    slam._normalize()
    np.testing.assert_allclose(slam.weights, 1.0 / 8)


def test_heading_mean_on_circle():
    a = np.radians([179.0, -179.0])
    assert abs(abs(circular_mean(a)) - math.pi) < 1e-12
    slam = RBPFSlam(SlamConfig(n_particles=2, **NOISELESS), 0)
    slam.update(np.zeros((0, 4)), None, 0.1)
    slam.pose[:, 2] = a
    est = slam._estimate()
    assert abs(abs(est.pose[2]) - math.pi) < 1e-12
    assert est.pose_std[2] == pytest.approx(math.radians(1.0))


def test_amplitude_weighting_runs():
    lm, poses = _road(T=40)
    cfg = SlamConfig(n_particles=30, variant="fastslam1", weighting="amplitude", trans_std_m=0.05, rot_std_rad=0.01)
    cloud = SyntheticCloud(lm, 3, max_range_m=40.0, dt=0.1, range_std_m=0.2, bearing_std_rad=math.radians(1.0))
    r = run_scenario(lm, poses, cloud, OdometryRegistration(4, trans_std_m=0.05, rot_std_rad=0.01), cfg, 5, dt=0.1)
    assert r["finite"] and r["ate_rmse_m"] < r["dead_reckoning_rmse_m"]


def test_long_road_memory_bounded():
    # 2000 cycles at 15 m/s x 0.1 s = 3 km; landmarks every 10 m on both sides
    T, dt, v = 2000, 0.1, 15.0
    n_lm = int(T * v * dt / 10.0) + 10
    xs = np.arange(n_lm) * 10.0
    lm = np.concatenate([np.stack([xs, np.full(n_lm, 8.0)], 1), np.stack([xs + 5.0, np.full(n_lm, -8.0)], 1)])
    x = np.arange(T) * v * dt
    poses = np.stack([x, np.zeros(T), np.zeros(T)], axis=1)
    cfg = SlamConfig(n_particles=10, max_landmarks=64, prune_after_cycles=20, trans_std_m=0.03, rot_std_rad=0.002)
    cloud = SyntheticCloud(
        lm, 7, max_range_m=25.0, dt=dt, range_std_m=0.1, bearing_std_rad=math.radians(0.5), p_miss=0.1, false_rate=0.5
    )
    odo = OdometryRegistration(8, trans_std_m=0.03, rot_std_rad=0.002)
    slam = RBPFSlam(cfg, 9)
    in_view = 2 * (2 * 25.0 / 10.0)  # landmarks within 25 m ahead and behind, both sides
    max_slots = 0
    pose = poses[0]
    for t in range(T):
        pts = cloud(t, poses[t])
        if t:
            odo.set_true_motion(poses[t] - poses[t - 1])
        est = slam.update(pts, odo.estimate(None, None) if t else None, dt)
        assert np.all(np.isfinite(est.pose)) and np.all(np.isfinite(est.landmarks))
        max_slots = max(max_slots, slam.n_landmark_slots)
        pose = est.pose
    assert max_slots <= cfg.max_landmarks
    assert max_slots <= 3 * in_view  # in view + those waiting to be pruned
    assert len(est.landmarks) <= 1.5 * in_view
    assert abs(pose[0] - poses[-1, 0]) < 30.0  # still tracking after 3 km
    xy, ids = slam.full_map()
    assert len(ids) == len(np.unique(ids)) and len(xy) > 0.5 * len(lm)


def test_capacity_eviction_keeps_bound():
    cfg = SlamConfig(n_particles=5, max_landmarks=6, cluster_radius_m=0.0, **NOISELESS)
    slam = RBPFSlam(cfg, 0)
    rng = np.random.default_rng(0)
    for _t in range(20):
        pts = np.column_stack([rng.uniform(-40, 40, (10, 2)), np.zeros(10), np.ones(10)])
        est = slam.update(pts, np.zeros(3), 0.1)
        assert slam.n_landmark_slots <= 6 and len(est.landmarks) <= 6
        assert np.all(np.isfinite(est.landmarks))


def test_landmark_update_matches_dense_reference():
    cfg = SlamConfig(n_particles=1, measurement_floor_m=0.0, **NOISELESS)
    slam = RBPFSlam(cfg, 0)
    slam.update(np.array([[10.0, 5.0, 0.0, 1.0]]), None, 0.1)
    slam.pose[0] = [0.3, -0.2, 0.1]
    slam.cov[0, 0] = [[0.4, 0.1], [0.1, 0.2]]
    e0, L0, p = slam.mean[0, 0].copy(), slam.cov[0, 0].copy(), slam.pose[0].copy()
    z = np.array([9.5, 5.8])
    Q = np.array([[0.05, 0.01], [0.01, 0.02]])
    obs = Observations(z[None], Q[None], np.ones(1))
    ll = slam._landmark_update(np.array([0]), np.array([0]), np.array([0]), obs)
    c, s = math.cos(p[2]), math.sin(p[2])
    R = np.array([[c, -s], [s, c]])
    nu = p[:2] + R @ z - e0
    S = L0 + R @ Q @ R.T
    K = L0 @ np.linalg.inv(S)
    np.testing.assert_allclose(slam.mean[0, 0], e0 + K @ nu, rtol=1e-12)
    np.testing.assert_allclose(slam.cov[0, 0], (np.eye(2) - K) @ L0, rtol=1e-10, atol=1e-14)
    ref = -0.5 * nu @ np.linalg.solve(S, nu) - np.log(2 * np.pi) - 0.5 * np.log(np.linalg.det(S))
    assert ll[0] == pytest.approx(ref, rel=1e-12)


def test_fastslam2_proposal_matches_dense_gaussian_algebra():
    """Proposal mean/cov and weight against the joint Gaussian of two observations (one particle)."""
    cfg = SlamConfig(n_particles=1, measurement_floor_m=0.0, joint_compatibility=False)
    slam = RBPFSlam(cfg, 0)
    slam.cycle = 1
    slam.pose[0] = [1.0, 0.5, 0.2]
    slam.pose_var = np.array([0.04, 0.04, 0.001])
    slam.mean[0, :2] = [[12.0, 6.0], [4.0, -9.0]]
    slam.cov[0, :2] = [[[0.02, 0.0], [0.0, 0.03]], [[0.05, 0.01], [0.01, 0.02]]]
    slam.active[0, :2] = slam.slot_used[:2] = True
    z = np.array([[10.3, 3.8], [1.2, -10.1]])
    Q = np.array([np.diag([0.01, 0.02]), np.diag([0.03, 0.01])])
    obs = Observations(z, Q, np.ones(2))
    mu = slam.pose[0].copy()
    slam.rng = np.random.default_rng(5)
    loglik, _ = slam._sample_proposal(np.array([[0, 1]]), obs)
    # dense reference: linearise h at mu, stack both observations
    c, s = math.cos(mu[2]), math.sin(mu[2])
    Rt = np.array([[c, s], [-s, c]])
    Hs, nus, Ss = [], [], []
    for k in range(2):
        h = Rt @ (slam.mean[0, k] - mu[:2])
        Hs.append(np.column_stack([-Rt, [h[1], -h[0]]]))
        nus.append(z[k] - h)
        Ss.append(Rt @ slam.cov[0, k] @ Rt.T + Q[k])
    H, nu = np.vstack(Hs), np.concatenate(nus)
    S = np.zeros((4, 4))
    S[:2, :2], S[2:, 2:] = Ss
    Sp = np.diag(slam.pose_var)
    cov = np.linalg.inv(np.linalg.inv(Sp) + H.T @ np.linalg.solve(S, H))
    mean = mu + cov @ H.T @ np.linalg.solve(S, nu)
    C = S + H @ Sp @ H.T
    ref = -0.5 * nu @ np.linalg.solve(C, nu) - 2 * np.log(2 * np.pi) - 0.5 * np.linalg.slogdet(C)[1]
    assert loglik[0] == pytest.approx(ref, rel=1e-9)
    draw = np.random.default_rng(5).standard_normal(3)
    np.testing.assert_allclose(slam.pose[0], mean + np.linalg.cholesky(cov) @ draw, rtol=1e-9, atol=1e-12)


def test_log_sum_exp_is_scipys_value():
    """The RBPF's weight normaliser equals scipy.special.logsumexp bit for bit (entries at -inf, ties at the max)
    from scipy 1.15 on, whose operations it repeats; scipy 1.13-1.14 (allowed by the package's range) order them
    otherwise, measured within 1 ulp of the shift ``max(|a*|, 1)``: there, within 2."""
    import scipy
    from scipy.special import logsumexp

    from slam.core.rbpf import log_sum_exp

    same_operations = tuple(int(x) for x in scipy.__version__.split(".")[:2]) >= (1, 15)
    rng = np.random.default_rng(0)
    for trial in range(500):
        p = int(rng.integers(1, 300))
        a = rng.normal(size=p) * 10 ** rng.uniform(-3, 3) + rng.uniform(-1e4, 1e4)
        if trial % 3 == 0:
            a[rng.random(p) < 0.3] = -np.inf
            a[0] = 0.0
        if trial % 5 == 0:
            a[rng.integers(0, p, 3)] = a.max()
        if same_operations:
            assert log_sum_exp(a) == logsumexp(a)
        else:
            assert abs(log_sum_exp(a) - logsumexp(a)) <= 2 * np.spacing(max(abs(a.max()), 1.0))
    assert abs(log_sum_exp(np.log([1.0, 2.0, 3.0])) - np.log(6.0)) < 1e-15
