"""Classical registration: ICP and the odometry oracle."""

import math

import numpy as np
import pytest

from slam.core.registration import (
    ICPRegistration,
    OdometryRegistration,
    apply_motion,
    relative_motion,
)


def _cloud(rng, n=40):
    xy = rng.uniform(-30, 30, (n, 2))
    return np.column_stack([xy, np.zeros(n), rng.uniform(1, 10, n)])


def test_icp_recovers_known_transform():
    rng = np.random.default_rng(1)
    prev = _cloud(rng)
    motion = np.array([1.2, -0.3, math.radians(3.0)])
    # current-frame coordinates: inverse of x_prev = R x_cur + t
    c, s = math.cos(motion[2]), math.sin(motion[2])
    d = prev[:, :2] - motion[:2]
    cur_xy = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)
    np.testing.assert_allclose(apply_motion(cur_xy, motion), prev[:, :2], atol=1e-12)
    cur = np.column_stack([cur_xy, prev[:, 2:]])
    est = ICPRegistration().estimate(prev, cur)
    np.testing.assert_allclose(est, motion, atol=1e-6)


def test_icp_noise_outliers_and_prior():
    rng = np.random.default_rng(2)
    prev = _cloud(rng, 60)
    motion = np.array([2.0, 0.2, math.radians(-2.0)])
    c, s = math.cos(motion[2]), math.sin(motion[2])
    d = prev[:, :2] - motion[:2]
    cur_xy = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)
    cur_xy += 0.05 * rng.standard_normal(cur_xy.shape)
    cur_xy[:6] = rng.uniform(-30, 30, (6, 2))  # 10 % outliers
    cur = np.column_stack([cur_xy, prev[:, 2:]])
    icp = ICPRegistration()
    est = icp.estimate(prev, cur, prior=np.array([1.8, 0.0, 0.0]))
    assert np.hypot(*(est[:2] - motion[:2])) < 0.05
    assert abs(est[2] - motion[2]) < math.radians(0.3)
    # too few points: the constant-velocity prior (last estimate) comes back
    np.testing.assert_allclose(icp.estimate(prev[:1], cur[:1]), est)
    with pytest.raises(ValueError, match="max_gate_m"):
        ICPRegistration(max_gate_m=0.0)


def test_relative_motion_wraps():
    a = np.array([1.0, 1.0, math.radians(179)])
    b = np.array([1.0, 2.0, math.radians(-179)])
    m = relative_motion(a, b)
    assert m[2] == pytest.approx(math.radians(2))


def test_odometry_registration_noise():
    odo = OdometryRegistration(np.random.default_rng(0), trans_std_m=0.1, rot_std_rad=0.01)
    truth = np.array([1.0, 0.0, 0.0])
    samples = []
    for _ in range(400):
        odo.set_true_motion(truth)
        samples.append(odo.estimate(None, None))
    samples = np.array(samples)
    np.testing.assert_allclose(samples.mean(0), truth, atol=0.02)
    np.testing.assert_allclose(samples.std(0), [0.1, 0.1, 0.01], rtol=0.15)
    exact = OdometryRegistration()
    exact.set_true_motion(truth)
    np.testing.assert_array_equal(exact.estimate(None, None), truth)


def test_icp_heading_search_recovers_a_lane_change_turn():
    """A 10 deg turn within one cycle with a yaw-free prior: plain ICP stalls, the search finds it."""
    from slam.core.registration import ICPRegistration, apply_motion

    rng = np.random.default_rng(4)
    prev = np.column_stack([rng.uniform(5, 80, 30) * rng.choice([-1, 1], 30), rng.uniform(-40, 40, 30)])
    truth = np.array([4.9, 0.8, np.deg2rad(10.0)])
    # current points: prev expressed in the moved frame (inverse of apply_motion)
    c, s = np.cos(truth[2]), np.sin(truth[2])
    q = prev - truth[:2]
    cur = np.column_stack([c * q[:, 0] + s * q[:, 1], -s * q[:, 0] + c * q[:, 1]])
    assert np.allclose(apply_motion(cur, truth), prev)
    prior = np.array([5.0, 0.0, 0.0])
    plain = ICPRegistration(yaw_search_rad=0.0).estimate(prev, cur, prior=prior)
    searched = ICPRegistration().estimate(prev, cur, prior=prior)
    assert abs(plain[2] - truth[2]) > np.deg2rad(3.0)
    assert np.allclose(searched, truth, atol=1e-3)
