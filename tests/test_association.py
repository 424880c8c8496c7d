"""Data association: position compensation, clustering, nearest match, moving-point filter."""

import math

import numpy as np
import pytest

from slam.core.association import (
    DROPPED,
    NEW,
    associate,
    cluster_points,
    estimate_ego_velocity,
    static_mask,
    to_map_frame,
)


def test_to_map_frame_batched_matches_single():
    xy = np.array([[1.0, 0.0], [0.0, 2.0]])
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, math.pi / 2]])
    out = to_map_frame(xy, poses)
    assert out.shape == (2, 2, 2)
    np.testing.assert_allclose(out[0], xy)
    np.testing.assert_allclose(out[1], [[1.0, 3.0], [-1.0, 2.0]], atol=1e-12)
    np.testing.assert_allclose(to_map_frame(xy, poses[1]), out[1])


def test_cluster_amplitude_weighted_centroid():
    pts = np.array(
        [
            [10.0, 0.0, -1.0, 1.0],
            [10.5, 0.0, -3.0, 3.0],  # same object as the first
            [20.0, 5.0, 0.0, 2.0],  # alone
        ]
    )
    obs, labels = cluster_points(pts, radius=1.0)
    assert len(obs) == 2
    assert labels[0] == labels[1] != labels[2]
    o = obs[labels[0]]
    np.testing.assert_allclose(o[:2], [10.375, 0.0])
    np.testing.assert_allclose(o[2], -2.5)
    assert o[3] == 3.0
    np.testing.assert_allclose(obs[labels[2]], pts[2])
    obs0, _ = cluster_points(pts, radius=0.0)
    assert len(obs0) == 3
    assert cluster_points(np.zeros((0, 4)))[0].shape == (0, 4)


def test_associate_nearest_gate_and_conflicts():
    # 2 particles, 3 landmark slots (the last inactive in particle 0)
    lm = np.array([[[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]], [[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]]])
    active = np.array([[True, True, False], [True, True, True]])
    obs = np.array([[0.5, 0.0], [9.0, 0.0], [19.5, 0.0], [10.2, 0.0]])
    obs_map = np.broadcast_to(obs, (2, 4, 2)).copy()
    idx, dist = associate(obs_map, lm, active, delta_m=2.0)
    # obs 3 (0.2 m) is closer to landmark 1 than obs 1 (1.0 m): obs 1 is dropped
    np.testing.assert_array_equal(idx[0], [0, DROPPED, NEW, 1])
    np.testing.assert_array_equal(idx[1], [0, DROPPED, 2, 1])
    np.testing.assert_allclose(dist[1, [0, 2, 3]], [0.5, 0.5, 0.2])
    assert np.isinf(dist[0, 2])
    # no landmarks: everything new
    idx2, _ = associate(obs_map, lm[:, :0], active[:, :0], 2.0)
    assert np.all(idx2 == NEW)
    with pytest.raises(ValueError, match="delta_m"):
        associate(obs_map, lm, active, delta_m=0.0)


def test_static_mask_separates_moving_points():
    v = np.array([20.0, 0.0])  # ego forward at 20 m/s
    b = np.linspace(-3.0, 3.0, 13)
    r = 30.0
    xy = np.stack([r * np.cos(b), r * np.sin(b)], axis=1)
    vr_static = -(v[0] * np.cos(b) + v[1] * np.sin(b))
    static = np.column_stack([xy, vr_static, np.ones(13)])
    # a car ahead driving at 25 m/s: relative +5 m/s along x
    car = np.array([[40.0, 0.0, 5.0, 1.0], [40.0, 3.5, 5.0 * 40 / math.hypot(40, 3.5), 1.0]])
    # an oncoming car in the next lane at -25 m/s: relative -45 m/s
    oncoming = np.array([[30.0, -4.0, -45.0 * 30 / math.hypot(30, 4), 1.0]])
    pts = np.concatenate([static, car, oncoming])
    m = static_mask(pts, v, threshold=1.0)
    assert m[:13].all() and not m[13:].any()
    assert static_mask(pts, None).all()
    # the Doppler ego-velocity fit ignores the movers
    v_hat = estimate_ego_velocity(pts, 0.5, np.random.default_rng(0))
    np.testing.assert_allclose(v_hat, v, atol=1e-9)
    assert estimate_ego_velocity(pts[:1], 0.5) is None


def test_ego_velocity_prefers_the_surrounding_static_world_over_a_platoon():
    """A platoon ahead (many points, one common velocity, one narrow sector) must not win
    over fewer static points spread around the vehicle; the prior gate rejects it too."""
    from slam.core.association import estimate_ego_velocity

    rng = np.random.default_rng(3)
    v_ego = np.array([25.0, 0.0])
    b_static = rng.uniform(-np.pi, np.pi, 12)
    r_static = rng.uniform(10, 60, 12)
    static = np.column_stack([r_static * np.cos(b_static), r_static * np.sin(b_static),
                              -(v_ego[0] * np.cos(b_static) + v_ego[1] * np.sin(b_static)), np.ones(12)])
    # 30 points of vehicles 20-40 m ahead within +-8 deg, all driving at 21 m/s
    b_pl = np.deg2rad(rng.uniform(-8, 8, 30))
    r_pl = rng.uniform(20, 40, 30)
    rel = np.array([21.0, 0.0]) - v_ego
    platoon = np.column_stack([r_pl * np.cos(b_pl), r_pl * np.sin(b_pl),
                               rel[0] * np.cos(b_pl) + rel[1] * np.sin(b_pl), np.ones(30)])
    pts = np.concatenate([static, platoon])
    v = estimate_ego_velocity(pts, 0.3, np.random.default_rng(0), n_hypotheses=256)
    assert v is not None and np.allclose(v, v_ego, atol=0.3)
    # with only the platoon's sector covered, the prior gate refuses the platoon's 4 m/s
    v_gated = estimate_ego_velocity(platoon, 0.3, np.random.default_rng(0), prior=v_ego, max_change=3.0)
    assert v_gated is None
