"""Scene side: landmark placement, frames, scatterers, occluders (no radar involved)."""

from __future__ import annotations

import numpy as np
import pytest
from highway_env.vehicle.kinematics import Vehicle

from rhs_env.envs import PAPER_OBSTACLES, RHSHighwayEnv, RHSPaperEnv
from rhs_env.scene import (
    VEHICLE_ID_OFFSET,
    LandmarkConfig,
    Landmarks,
    ScatterConfig,
    draw_disks,
    scene_scatterers,
    vehicle_to_he_xy,
    world_pose,
)


@pytest.fixture
def empty_env():
    """A highway without traffic or landmarks; tests place what they need."""
    env = RHSHighwayEnv(vehicles_count=0, landmarks={"enabled": False})
    env.reset(seed=0)
    yield env
    env.close()


def _place_ego(env, x=100.0, y=4.0, heading=0.0, speed=20.0, steering=0.0):
    ego = env.vehicle
    ego.position = np.array([x, y], dtype=float)
    ego.heading = heading
    ego.speed = speed
    ego.action = {"steering": steering, "acceleration": 0.0}
    return ego


def _add_vehicle(env, x, y, heading=0.0, speed=0.0, steering=0.0):
    v = Vehicle(env.road, [x, y], heading, speed)
    v.action = {"steering": steering, "acceleration": 0.0}
    env.road.vehicles.append(v)
    return v


# ------------------------------------------------------------------ configs
@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"spacing_m": 0.5}, "spacing_m"),
        ({"lateral_offset_m": -1.0}, "lateral_offset_m"),
        ({"rcs_m2": 0.0}, "rcs_m2"),
        ({"spacing_m": 10.0, "jitter_m": 5.0}, "jitter_m"),
        ({"lateral_jitter_m": -0.1}, "lateral_jitter_m"),
        ({"sides": "top"}, "sides"),
    ],
)
def test_landmark_config_rejects_bad_values(kwargs, field):
    with pytest.raises(ValueError, match=field):
        LandmarkConfig(**kwargs)


@pytest.mark.parametrize("kwargs, field", [({"enabled": "yes"}, "enabled"), ({"spacing_m": "20"}, "spacing_m")])
def test_landmark_config_rejects_wrong_types(kwargs, field):
    with pytest.raises(TypeError, match=field):
        LandmarkConfig(**kwargs)


def test_config_dicts_reject_unknown_fields():
    with pytest.raises(ValueError, match="spacing"):
        LandmarkConfig.make({"spacing": 10})
    with pytest.raises(ValueError, match="max_range_m"):
        ScatterConfig.make({"max_range_m": 0})
    with pytest.raises(ValueError, match="points_per_face"):
        ScatterConfig(points_per_face=0)


# ------------------------------------------------------------------ landmarks
def test_landmarks_line_both_road_edges_and_are_reproducible():
    env = RHSHighwayEnv(vehicles_count=0, landmarks={"spacing_m": 25.0, "lateral_offset_m": 3.0})
    env.reset(seed=3)
    lm = env.landmarks
    lanes = env.config["lanes_count"]
    width = 4.0  # highway-env StraightLane.DEFAULT_WIDTH
    y = lm.xy_he[:, 1]
    left, right = y < 0, y > (lanes - 1) * width
    assert np.all(left | right)  # never on the road
    assert np.all(y[left] <= -width / 2 - 3.0 + 1e-9)
    assert np.all(y[right] >= (lanes - 1) * width + width / 2 + 3.0 - 1e-9)
    assert abs(left.sum() - 10000 / 25) <= 1 and abs(right.sum() - 10000 / 25) <= 1
    np.testing.assert_allclose(lm.rcs, 5.0)
    first = lm.xy_he.copy()
    env.reset(seed=3)
    np.testing.assert_array_equal(env.landmarks.xy_he, first)
    env.reset(seed=4)
    assert not np.array_equal(env.landmarks.xy_he, first)
    env.close()


def test_landmarks_are_not_vehicles_for_highway_env():
    env = RHSHighwayEnv(vehicles_count=0, landmarks={"spacing_m": 5.0, "lateral_offset_m": 0.0, "jitter_m": 0.0})
    obs, _ = env.reset(seed=0)
    assert len(env.road.objects) == 0 and len(env.road.vehicles) == 1
    assert obs[1:, 0].sum() == 0  # Kinematics: only the ego row is present
    for _ in range(3):
        obs, _, terminated, _, _ = env.step(0)  # LANE_LEFT toward the landmarks
        assert not terminated
    env.close()


def test_landmarks_near_query_matches_brute_force():
    rng = np.random.default_rng(0)
    lm = Landmarks(rng.uniform(-500, 500, (400, 2)), 5.0)
    c = np.array([12.0, -30.0])
    brute = np.flatnonzero(np.linalg.norm(lm.xy_he - c, axis=1) <= 150.0)
    np.testing.assert_array_equal(lm.near(c, 150.0), brute)


# ------------------------------------------------------------------ frames and scatterers
def test_landmark_appears_at_its_vehicle_frame_position(empty_env):
    # ego heading +x in highway-env, a landmark 10 m ahead and 5 m to the LEFT:
    # left is toward lane 0, i.e. smaller highway-env y (the screen's y points down).
    ego = _place_ego(empty_env, x=100.0, y=4.0)
    empty_env.landmarks = Landmarks(np.array([[110.0, -1.0]]), 5.0)
    sc, oc = scene_scatterers(empty_env)
    np.testing.assert_allclose(sc.xy, [[10.0, 5.0]], atol=1e-12)
    assert sc.is_static.tolist() == [True] and sc.object_id.tolist() == [0] and sc.rcs.tolist() == [5.0]
    assert len(oc) == 0
    # a rotated ego: place the landmark from its world pose and read it back
    ego.heading = 0.4  # highway-env heading (clockwise on screen)
    x, y, h = world_pose(ego)
    q = np.array([30.0, -7.0])
    p_world = np.array([x, y]) + np.array([[np.cos(h), -np.sin(h)], [np.sin(h), np.cos(h)]]) @ q
    empty_env.landmarks = Landmarks.from_world(p_world[None], 5.0)
    sc, _ = scene_scatterers(empty_env)
    np.testing.assert_allclose(sc.xy, [q], atol=1e-9)
    np.testing.assert_allclose(vehicle_to_he_xy(sc.xy, ego), empty_env.landmarks.xy_he, atol=1e-9)


def test_static_landmark_velocity_is_minus_ego_velocity(empty_env):
    _place_ego(empty_env, heading=0.3, speed=22.0)
    empty_env.landmarks = Landmarks(np.array([[130.0, 20.0], [60.0, -15.0]]), 5.0)
    sc, _ = scene_scatterers(empty_env)
    np.testing.assert_allclose(sc.velocity, [[-22.0, 0.0], [-22.0, 0.0]], atol=1e-9)


def test_relative_velocities_match_finite_differences_when_turning(empty_env):
    """velocity = d/dt of the vehicle-frame position, ego and target both turning."""
    dt = 1e-5
    _place_ego(empty_env, heading=0.1, speed=20.0, steering=0.05)
    _add_vehicle(empty_env, 140.0, 8.0, heading=-0.2, speed=12.0, steering=-0.1)
    empty_env.landmarks = Landmarks(np.array([[150.0, -10.0], [80.0, 25.0]]), 5.0)
    sc0, _ = scene_scatterers(empty_env)
    for v in empty_env.road.vehicles:
        v.step(dt)
    sc1, _ = scene_scatterers(empty_env)
    assert sc0.object_id.tolist() == sc1.object_id.tolist()
    fd = (sc1.xy - sc0.xy) / dt
    np.testing.assert_allclose(sc0.velocity, fd, atol=2e-3)
    assert np.any(sc0.object_id >= VEHICLE_ID_OFFSET)


def test_far_side_of_a_vehicle_is_not_a_scatterer(empty_env):
    _place_ego(empty_env, x=100.0, y=4.0, speed=25.0)
    _add_vehicle(empty_env, 120.0, 4.0, speed=20.0)  # straight ahead: only its rear face shows
    sc, oc = scene_scatterers(empty_env, config={"points_per_face": 3, "vehicle_rcs_m2": 10.0})
    veh = sc.object_id >= VEHICLE_ID_OFFSET
    assert veh.sum() == 3
    np.testing.assert_allclose(sc.xy[veh, 0], 20.0 - Vehicle.LENGTH / 2)  # rear face only
    assert np.all(np.abs(sc.xy[veh, 1]) <= Vehicle.WIDTH / 2)
    np.testing.assert_allclose(sc.rcs[veh].sum(), 10.0)
    np.testing.assert_allclose(sc.velocity[veh], [[-5.0, 0.0]] * 3, atol=1e-9)
    assert not sc.is_static[veh].any()
    # occluders: its four box edges, with its id
    assert oc.segments.shape == (4, 2, 2) and set(oc.object_id) == {VEHICLE_ID_OFFSET + 1}
    xs, ys = oc.segments[..., 0], oc.segments[..., 1]
    np.testing.assert_allclose([xs.min(), xs.max()], [17.5, 22.5])
    np.testing.assert_allclose([ys.min(), ys.max()], [-1.0, 1.0])


def test_vehicle_ahead_left_shows_rear_and_right_faces(empty_env):
    _place_ego(empty_env, x=100.0, y=8.0)
    _add_vehicle(empty_env, 115.0, 0.0)  # 15 m ahead, 8 m to the left
    sc, _ = scene_scatterers(empty_env)
    veh = sc.object_id >= VEHICLE_ID_OFFSET
    pts = sc.xy[veh]
    rear = np.isclose(pts[:, 0], 15.0 - 2.5)
    right = np.isclose(pts[:, 1], 8.0 - 1.0)
    assert rear.sum() == 3 and right.sum() == 3 and np.all(rear | right)
    assert not np.any(np.isclose(pts[:, 0], 17.5)) and not np.any(np.isclose(pts[:, 1], 9.0))
    np.testing.assert_allclose(sc.rcs[veh].sum(), 10.0)
    # the right face (5 m long, seen at a steeper angle) shares the RCS by its projected width
    assert sc.rcs[veh][right].sum() > 0 and sc.rcs[veh][rear].sum() > 0


def test_range_cut_bounds_the_work(empty_env):
    _place_ego(empty_env, x=1000.0, y=4.0)
    xs = np.arange(0.0, 2000.0, 10.0)
    empty_env.landmarks = Landmarks(np.column_stack([xs, np.full_like(xs, -8.0)]), 5.0)
    _add_vehicle(empty_env, 1300.0, 4.0)
    sc, oc = scene_scatterers(empty_env, config=ScatterConfig(max_range_m=150.0))
    assert np.all(np.linalg.norm(sc.xy, axis=1) <= 150.0)
    assert sc.is_static.sum() == np.sum(np.hypot(xs - 1000.0, 12.0) <= 150.0)
    assert len(oc) == 0 and not np.any(sc.object_id >= VEHICLE_ID_OFFSET)


def test_scatterers_on_a_plain_highway_env():
    import gymnasium as gym
    import highway_env  # noqa: F401

    env = gym.make("highway-fast-v0")
    env.reset(seed=0)
    sc, oc = scene_scatterers(env)  # no landmarks: vehicles only
    assert len(sc) > 0 and not sc.is_static.any() and len(oc) % 4 == 0
    env.close()


# ------------------------------------------------------------------ paper scene
def test_paper_scene_coordinates():
    env = RHSPaperEnv()
    _, info = env.reset(seed=0)
    np.testing.assert_allclose(info["world_pose"], [0.0, 37.5, 0.0])
    np.testing.assert_allclose(env.landmarks.xy_world, PAPER_OBSTACLES)
    sc, _ = scene_scatterers(env)
    # obstacle (10, 65) is 10 m ahead and 27.5 m to the left; (25, 10) 27.5 m to the right
    np.testing.assert_allclose(sc.xy[:2], [[10.0, 27.5], [25.0, -27.5]], atol=1e-9)
    steps, done = 0, False
    while not done:
        _, _, terminated, truncated, info = env.step(1)  # IDLE
        steps += 1
        done = terminated or truncated
    assert steps == 50 and not terminated
    assert 55.0 <= info["world_pose"][0] <= 65.0 and abs(info["world_pose"][1] - 37.5) < 0.5
    env.close()


def test_draw_disks_clips_to_the_frame():
    frame = np.zeros((20, 30, 3), np.uint8)
    draw_disks(frame, np.array([[5, 5], [29, 19], [-10, -10]]), (255, 0, 0), radius=2)
    assert frame[5, 5, 0] == 255 and frame[19, 29, 0] == 255 and frame[..., 1].max() == 0
    assert frame[0, 0, 0] == 0


def test_compiled_faces_match_numpy_on_a_busy_road():
    """The compiled vehicle faces (kernels="numba", the default) give the numpy reference's scatterers and occluders:
    the same points in the same order, ids and static flags, coordinates within 1e-12 m (m/s, m^2)."""
    import gymnasium as gym

    import rhs_env  # noqa: F401

    env = gym.make("rhs-highway-v0", vehicles_count=40)
    env.reset(seed=3)
    base = env.unwrapped
    for action in np.random.default_rng(3).integers(0, 5, 12):
        env.step(int(action))
        ref, got = (scene_scatterers(base, kernels=k) for k in ("numpy", "numba"))
        assert np.any(ref[0].object_id >= VEHICLE_ID_OFFSET)
        for name in ("object_id", "is_static"):
            np.testing.assert_array_equal(getattr(got[0], name), getattr(ref[0], name))
        for name in ("xy", "velocity", "rcs"):
            np.testing.assert_allclose(getattr(got[0], name), getattr(ref[0], name), rtol=0, atol=1e-12)
        np.testing.assert_array_equal(got[1].object_id, ref[1].object_id)
        np.testing.assert_allclose(got[1].segments, ref[1].segments, rtol=0, atol=1e-12)
