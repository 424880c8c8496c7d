"""Per-point uncertainty: the radar's stds are right (NEES ~ chi-square), and the filter uses them.

Radar level: isolated targets scanned with noise, the normalised errors
(err / std)^2 of range and angle average to 1 within the chi-square interval of
their count; without noise the errors sit inside the floors (model error).
Filter level: landmark NEES against the filter's own covariance is consistent
with chi-square(2); FastSLAM 2.0 converges and beats FastSLAM 1.0 when the
measurements are much more precise than the odometry.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from rhs_env.radar import LinkBudgetConfig, RadarConfig, RadarSystem
from rhs_env.scatterers import Scatterers
from rhs_env.uncertainty import point_rows
from slam.core.association import point_covariance
from slam.core.rbpf import SlamConfig
from slam.core.registration import OdometryRegistration
from slam.core.scenario import SyntheticCloud, run_scenario


def _isolated_errors(add_noise: bool, tx_power_dbm: float, n: int, antenna: str = "rhs", seed: int = 0):
    """Range / angle errors and predicted stds of the strongest front-radar point, one target per scan."""
    rs = RadarSystem(RadarConfig(link=LinkBudgetConfig(add_noise=add_noise, tx_power_dbm=tx_power_dbm), antenna=antenna),
                     np.random.default_rng(seed))
    rng = np.random.default_rng(seed + 1)
    out = []
    for _ in range(n):
        r, th = rng.uniform(8.0, 40.0), rng.uniform(-0.6, 0.6)
        xy = rs.positions[0] + r * np.array([math.cos(th), math.sin(th)])
        sc = Scatterers(xy[None], np.array([[-10.0, 0.0]]), np.array([5.0]), np.array([0]), np.array([True]))
        c = rs.scan(sc)
        sel = np.flatnonzero(c.radar == 0)
        if sel.size:
            j = sel[np.argmax(c.points[sel, 3])]
            out.append((c.range_m[j] - r, c.angle_rad[j] - th, c.range_std_m[j], c.angle_std_rad[j]))
    return np.array(out)


def _chi2_mean_interval(n: int, dof: int = 1, p: float = 1e-3) -> tuple[float, float]:
    return stats.chi2.ppf(p / 2, n * dof) / n, stats.chi2.ppf(1 - p / 2, n * dof) / n


@pytest.mark.parametrize("antenna", ["rhs", "phased"])
def test_point_nees_is_chi_square_at_low_snr(antenna):
    e = _isolated_errors(True, 0.0, 45, antenna)  # 0 dBm: SNR 20-35 dB, the CRB term dominates the floor
    assert len(e) >= 30
    lo, hi = _chi2_mean_interval(len(e))
    nees_r = np.mean((e[:, 0] / e[:, 2]) ** 2)
    nees_t = np.mean((e[:, 1] / e[:, 3]) ** 2)
    assert lo <= nees_r <= hi, nees_r
    assert lo <= nees_t <= hi, nees_t


def test_noiseless_errors_inside_the_floors():
    e = _isolated_errors(False, 30.0, 12)
    cfg = RadarConfig()
    assert np.sqrt(np.mean(e[:, 0] ** 2)) < cfg.uncertainty.range_std_floor_m
    assert np.degrees(np.sqrt(np.mean(e[:, 1] ** 2))) < cfg.uncertainty.angle_std_floor_deg


def test_rhs_angle_std_about_three_times_below_phased():
    rhs = _isolated_errors(True, 0.0, 10, "rhs")
    ph = _isolated_errors(True, 0.0, 10, "phased")
    ratio = np.median(ph[:, 3]) / np.median(rhs[:, 3])
    assert 2.0 < ratio < 5.0, ratio


def test_point_covariance_along_and_across_the_line_of_sight():
    # a point 20 m left of a sensor at (0, 1): range error along y, angle error along x
    rows = np.array([[0.0, 21.0, 0.0, 1.0, 0.1, 0.01, 1.0]])
    cov = point_covariance(rows, np.array([[5.0, 0.0], [0.0, 1.0]]))[0]
    np.testing.assert_allclose(cov, np.diag([(20.0 * 0.01) ** 2, 0.1**2]), atol=1e-12)
    cov_f = point_covariance(rows, np.array([[5.0, 0.0], [0.0, 1.0]]), floor_m=0.05)[0]
    np.testing.assert_allclose(cov_f - cov, 0.05**2 * np.eye(2), atol=1e-12)


def test_point_rows_without_uncertainty_are_infinite():
    from rhs_env.point_cloud import PointCloud

    rows = point_rows(PointCloud(points=np.ones((2, 4)), radar=np.array([0, 3])))
    assert rows.shape == (2, 7) and np.all(np.isinf(rows[:, 4:6])) and list(rows[:, 6]) == [0, 3]


def _road(T=80, v=12.0, dt=0.2, spacing=9.0):
    n = int(T * v * dt / spacing) + 8
    xs = np.arange(-2, n) * spacing
    lm = np.stack([xs, np.where(np.arange(xs.size) % 2, 9.0, -9.0)], axis=1)
    x = np.arange(T) * v * dt
    y = 3.0 * np.sin(x / 50.0)
    th = np.arctan2(np.gradient(y), np.gradient(x))
    return lm, np.stack([x, y, th], axis=1)


def _run(variant: str, seed: int, T: int = 80, particles: int = 30):
    lm, poses = _road(T)
    cloud = SyntheticCloud(lm, 100 + seed, max_range_m=30.0, dt=0.2, range_std_m=0.02,
                           bearing_std_rad=math.radians(0.1), report_std=True)
    odo = OdometryRegistration(200 + seed, trans_std_m=0.05, rot_std_rad=0.01)
    cfg = SlamConfig(n_particles=particles, variant=variant, trans_std_m=0.05, trans_frac=0.0, rot_std_rad=0.01,
                     accel_std_mps2=0.0, yaw_accel_std_radps2=0.0, measurement_floor_m=0.0)
    return run_scenario(lm, poses, cloud, odo, cfg, seed, dt=0.2, use_doppler=False)


def test_fastslam2_converges():
    for seed in range(3):
        r = _run("fastslam2", seed)
        assert r["finite"]
        assert r["ate_rmse_m"] < 0.1 * r["dead_reckoning_rmse_m"]
        assert r["ate_rmse_m"] < 0.1 and r["map_spurious"] == 0
    r = _run("fastslam2", 7)
    d = np.hypot(*(r["landmarks"][:, None] - r["true_landmarks"][None]).transpose(2, 0, 1))
    assert np.all(d.min(axis=1) < 0.3)  # every mapped landmark is a real one, placed to decimetres


def _landmark_nees(seed: int) -> np.ndarray:
    """Per-landmark NEES of the current map against its reported covariance, the pose known exactly.

    With the true motion and no motion noise every particle holds the same pose, so the
    landmark estimate is the Kalman fusion of its observations with their own covariances:
    its NEES is chi-square(2) exactly when those covariances are right.
    """
    from slam.core.pipeline import PipelineConfig, SlamPipeline
    from slam.core.registration import points_in_frame

    lm, poses = _road(40)
    cloud = SyntheticCloud(lm, 300 + seed, max_range_m=30.0, dt=0.2, range_std_m=0.02,
                           bearing_std_rad=math.radians(0.1), report_std=True)
    cfg = SlamConfig(n_particles=5, trans_std_m=0.0, trans_frac=0.0, rot_std_rad=0.0, accel_std_mps2=0.0,
                     yaw_accel_std_radps2=0.0, measurement_floor_m=0.0)
    odo = OdometryRegistration(400 + seed, trans_std_m=0.0, rot_std_rad=0.0)  # the pose is known
    pipe = SlamPipeline(odo, cfg, np.random.default_rng(seed), PipelineConfig(use_doppler=False))
    from slam.core.registration import relative_motion

    for t in range(len(poses)):
        if t:
            odo.set_true_motion(relative_motion(poses[t - 1], poses[t]))
        res = pipe.step(cloud(t, poses[t]), 0.2)
    est = res.estimate
    truth = points_in_frame(lm, poses[0])
    d = est.landmarks[:, None] - truth[None]
    j = np.argmin(np.hypot(d[..., 0], d[..., 1]), axis=1)
    e = est.landmarks - truth[j]
    return np.einsum("ni,nij,nj->n", e, np.linalg.inv(est.landmark_cov), e)


def test_landmark_nees_consistent_with_chi_square():
    nees = np.concatenate([_landmark_nees(s) for s in range(3)])
    assert len(nees) >= 20
    lo, hi = _chi2_mean_interval(len(nees), dof=2)
    assert lo <= np.mean(nees) <= hi, np.mean(nees)


def test_fastslam2_beats_fastslam1_with_precise_measurements():
    a2 = np.mean([_run("fastslam2", s, T=60, particles=20)["ate_rmse_m"] for s in range(2)])
    a1 = np.mean([_run("fastslam1", s, T=60, particles=20)["ate_rmse_m"] for s in range(2)])
    assert a2 < 0.5 * a1, (a2, a1)


@pytest.mark.parametrize("antenna", ["rhs", "phased"])
def test_compiled_angle_information_matches_numpy(antenna):
    """The compiled sums of the angle information (one pass over the slots) give numpy's values to 1e-12."""
    from rhs_env.uncertainty import angle_information

    dic = RadarSystem(RadarConfig(antenna=antenna, kernels="numpy"), np.random.default_rng(0)).dictionaries[0]
    th = np.random.default_rng(3).uniform(dic.candidates[0], dic.candidates[-1], (7, 9))
    ref = angle_information(dic, th)
    got = angle_information(dic.use_kernels("numba"), th)
    assert got.shape == th.shape and np.all(ref > 0)
    np.testing.assert_allclose(got, ref, rtol=1e-12)
