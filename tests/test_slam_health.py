"""Track health, loss detection, relocalisation and the few-landmark start of the SLAM pipeline."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import rhs_env  # noqa: F401
from slam.core.health import HealthConfig, TrackHealth
from slam.core.pipeline import PipelineConfig, doppler_displacement, doppler_ego_motion, forward_speed_fit

CHEAP: dict[str, Any] = {"radar": {"scan": {"grid_deg": 5}}, "vehicles_count": 3}


def _drive(jump_m: float, cycles: int = 50, at: int = 25, **kw):
    """SLOWER on the highway; at cycle ``at`` the ego is teleported ``jump_m`` along the road."""
    env = gym.make("rhs-highway-slam-v0", duration=cycles / 5, **CHEAP, **kw)
    env.reset(seed=3)
    infos = []
    for t in range(cycles):
        if t == at:
            base: Any = env.unwrapped
            base.vehicle.position = base.vehicle.position + np.array([jump_m, 0.0])
        _, _, term, trunc, info = env.step(4)
        infos.append(info)
        if term or trunc:
            break
    env.close()
    return infos


def test_forward_speed_fit_two_points_and_a_mover():
    v = 20.0
    xy = np.array([[40.0, 5.0], [10.0, -8.0], [30.0, 3.0]])
    vr = -v * xy[:, 0] / np.hypot(xy[:, 0], xy[:, 1])
    vr[2] += 6.0  # a vehicle
    pts = np.column_stack([xy, vr, np.ones(3)])
    np.testing.assert_allclose(forward_speed_fit(pts, 0.5), [v, 0.0], atol=1e-9)
    assert forward_speed_fit(pts[[0, 2]], 0.5) is None  # two points that disagree: no consensus
    assert forward_speed_fit(pts[[0]], 0.5, min_inliers=1)[0] == pytest.approx(v)


RADAR_MOUNTS = np.array([[2.5, 0.0], [0.0, 1.0], [-2.5, 0.0], [0.0, -1.0]])  # front, left, rear, right (m)


def _static_cloud(rng: np.random.Generator, n: int = 40):
    """``n`` static points within 60 m of the car, each seen by one of :data:`RADAR_MOUNTS`:
    ``(sensor of each point, cloud)``, where ``cloud(v, w)`` gives the points ``(x, y, v_r, 1)`` whose radial
    speed is what the car moving at ``v`` (m/s) and turning at ``w`` (rad/s) measures along each radar's line
    of sight, ``v_r = -(v + w x p) . u``. Draws the points, then their radars, from ``rng``."""
    xy = rng.uniform(-60, 60, (n, 2))
    s = RADAR_MOUNTS[rng.integers(0, 4, n)]
    u = (xy - s) / np.hypot(*(xy - s).T)[:, None]

    def cloud(v, w: float) -> np.ndarray:
        vr = np.sum(-(np.asarray(v, dtype=float)[None, :] + w * np.stack([-xy[:, 1], xy[:, 0]], axis=1)) * u, axis=1)
        return np.column_stack([xy, vr, np.ones(n)])

    return s, cloud


def test_doppler_ego_motion_sees_the_turn_through_the_lever_arms():
    rng = np.random.default_rng(1)
    s, cloud = _static_cloud(rng)
    pts = cloud([12.0, 0.3], 2.0)  # a sharp lane change at 12 m/s
    pts[:5, 2] += 7.0  # five points on a vehicle
    fit = doppler_ego_motion(pts, s, 0.5, rng, n_hypotheses=128)
    np.testing.assert_allclose(fit, [12.0, 0.3, 2.0], atol=1e-6)
    # the velocity-only model is off by the lever arms' w |s| (2.5 m x 2 rad/s = 5 m/s across the front radar)
    assert doppler_ego_motion(pts, s, 0.5, rng, prior=np.array([0.0, 0.0]), max_change=5.0) is None


def test_doppler_displacement_is_the_chord_along_the_mean_heading():
    m = doppler_displacement(np.array([20.0, 0.0]), 0.2, 0.2)
    # a constant-rate turn: radius v / w, chord 2 r sin(dpsi / 2) at dpsi / 2
    r = 20.0 / (0.2 / 0.2)
    chord = 2 * r * math.sin(0.1)
    np.testing.assert_allclose(m, [chord * math.cos(0.1), chord * math.sin(0.1), 0.2], atol=1e-12)
    np.testing.assert_allclose(doppler_displacement(np.array([10.0, 1.0]), 0.0, 0.1), [1.0, 0.1, 0.0])


def test_health_latches_a_loss_until_relocalised():
    h = TrackHealth(HealthConfig())
    h.update(20, 15.0, 50, 0.9, True, False, 0.05, 100)
    assert h.health == 1.0 and not h.lost
    h.update(20, 0.0, 50, 0.9, True, False, 0.05, 120)  # nothing matches a map of 50 landmarks
    assert h.lost and h.losses == 1 and h.loss_landmark_id == 120
    h.update(20, 18.0, 50, 0.9, True, False, 0.05, 140)  # self-consistent again, around the wrong pose
    assert h.lost and h.lost_cycles == 2
    h.relocalised()
    assert not h.lost and h.losses == 1
    h.update(2, 0.0, 50, None, False, False, 0.05, 150)  # one cycle without a registration fit: fine
    assert not h.lost
    h.update(2, 0.0, 50, None, False, False, 0.05, 150)  # two: the heading is a guess
    assert h.h_blind == 0.0 and h.lost and h.losses == 2


@pytest.mark.parametrize(("field", "value"), [("match_ok", 0.05), ("spread_lost_m", 0.5), ("lost_below", 1.5)])
def test_health_config_rejects_bad_values(field, value):
    with pytest.raises(ValueError, match=field):
        HealthConfig(**{field: value})


def test_pipeline_config_rejects_bad_values():
    with pytest.raises(ValueError, match="doppler_gate_m"):
        PipelineConfig(doppler_gate_m=0.0)
    with pytest.raises(ValueError, match="doppler_gate_cross_m"):
        PipelineConfig(doppler_gate_cross_m=-1.0)
    with pytest.raises(ValueError, match="new_map_after_cycles"):
        PipelineConfig(new_map_after_cycles=0)


def test_teleport_back_is_flagged_then_relocalised():
    infos = _drive(-30.0)
    before, after = infos[:25], infos[25:]
    assert all(not i["slam_lost"] and i["slam_losses"] == 0 for i in before)
    assert max(i["position_error_m"] for i in before) < 0.5
    assert after[0]["slam_losses"] >= 1  # the jump is seen in its own cycle
    assert after[-1]["slam_relocalised"] >= 1 and after[-1]["slam_map_breaks"] == 0
    assert max(i["position_error_m"] for i in after[10:]) < 1.0  # back in the map within 10 cycles
    assert not any(i["slam_lost"] for i in after[10:])


def test_teleport_off_the_map_is_flagged_while_wrong_then_a_new_map():
    # no relocalisation: the pre-loss map is too far to be found, 10 lost cycles start a new map
    infos = _drive(400.0)
    wrong = [i for i in infos if i["position_error_m"] > 5.0]
    assert wrong, "the jump must put the estimate off"
    assert all(i["slam_lost"] for i in wrong)
    # while lost the reported std is at least the loss's spread and grows with the drive since the loss
    lost_std = [float(i["slam_pose_std"][0]) for i in infos if i["slam_lost"]]
    assert min(lost_std) >= 3.0 and np.all(np.diff(lost_std) > 0)
    assert infos[-1]["slam_map_breaks"] == 1 and not infos[-1]["slam_lost"]
    assert infos[-1]["position_error_m"] < 1.0  # measured in the new map
    assert infos[-1]["position_error_episode_m"] > 100.0  # against the episode start, the loss remains


def test_health_in_the_observation_is_opt_in():
    env = gym.make("rhs-highway-slam-v0", **CHEAP)
    obs, info = env.reset(seed=0)
    assert "slam_health" not in obs and info["slam_health"] == 1.0 and info["slam_lost"] is False
    env.close()
    env = gym.make("rhs-highway-slam-v0", health_in_obs=True, **CHEAP)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert obs["slam_health"].tolist() == [1.0] and obs["slam_lost"].tolist() == [0]
    env.close()
    with pytest.raises((TypeError, ValueError), match="health_in_obs"):
        gym.make("rhs-highway-slam-v0", health_in_obs="yes", **CHEAP)


@pytest.mark.parametrize("speed", [15.0, 25.0])
def test_few_landmarks_at_speed_keep_the_start(speed):
    """Three landmarks, straight at speed: the Doppler carries the first cycles (the first pose moves)."""
    from rhs_env.radar import RadarConfig, RadarSystem
    from slam.core.registration import make_registration
    from slam.core.scenario import run_scenario
    from slam.gym.radar_cloud import RadarCloud

    dt, cycles = 0.2, 30
    rng = np.random.default_rng(0)
    poses = np.stack([speed * dt * np.arange(cycles), np.zeros(cycles), np.zeros(cycles)], 1)
    lm = np.array([[10.0, 8.5], [poses[-1, 0] / 2 + 15.0, -8.9], [poses[-1, 0] + 20.0, 8.2]])
    res = run_scenario(lm, poses, RadarCloud(lm, poses, dt, RadarSystem(RadarConfig(), rng)),
                       make_registration("icp", rng), None, rng, dt=dt)
    assert res["ate_rmse_m"] < 0.3
    assert res["estimated_poses"][1, 0] == pytest.approx(speed * dt, abs=0.3)


def test_corrupted_odometry_is_flagged_at_once_and_relocalised():
    """One cycle's registration turns the car by 0.3 rad that it did not turn (a wrong fit in a lane change):
    the health signal fires in that cycle, the filter relocalises against its own map and reports it in
    ``info``, and no cycle with an error above 5 m goes unflagged."""
    env = gym.make("rhs-highway-slam-v0", duration=40 / 5, **CHEAP)
    env.reset(seed=3)
    reg = env.get_wrapper_attr("pipeline").registration
    fit = reg.estimate
    corrupt = {"on": False}

    def corrupted(prev, cur, prior=None):
        m = np.asarray(fit(prev, cur, prior=prior), dtype=float).copy()
        return m + np.array([0.0, 0.0, 0.3]) if corrupt["on"] else m

    reg.estimate = corrupted
    infos = []
    for t in range(40):
        corrupt["on"] = t == 20
        _, _, term, trunc, info = env.step(4)
        infos.append(info)
        if term or trunc:
            break
    env.close()
    assert len(infos) == 40
    assert all(i["slam_losses"] == 0 and i["position_error_m"] < 0.5 for i in infos[:20])
    assert infos[20]["slam_losses"] == 1 or infos[21]["slam_losses"] == 1  # within a cycle of the corruption
    assert infos[-1]["slam_relocalised"] + infos[-1]["slam_map_breaks"] >= 1
    assert all(i["slam_lost"] for i in infos if i["position_error_m"] > 5.0)
    assert max(i["position_error_m"] for i in infos[30:]) < 1.0 and not any(i["slam_lost"] for i in infos[30:])


def test_a_reversed_lane_change_is_found_with_the_speed_bound_alone():
    """A lane change reversed within a cycle at 10 m/s (yaw rate -1.9 -> +1.9 rad/s, the side slip of a
    kinematic bicycle from -2.5 to +4 m/s: the velocity vector moves by 6.5 m/s, past the acceleration
    bound of 3 m/s): the bounded turn fit finds nothing, the held turn leaves few points static, and the
    fit with the bound on the speed alone finds the new turn."""
    from slam.core.pipeline import SlamPipeline, static_mask
    from slam.core.registration import ICPRegistration

    s, cloud = _static_cloud(np.random.default_rng(5))
    pts = cloud([9.3, 4.0], 1.9)
    pipe = SlamPipeline(ICPRegistration(), rng=0, sensor_xy=RADAR_MOUNTS)
    pipe.velocity = np.array([10.1, -2.5, -1.9])  # the first half of the lane change, held
    thr = pipe.config.dynamic_threshold_mps
    assert static_mask(pts, pipe.velocity[:2], thr, yaw_rate=-1.9, sensor_xy=s).sum() < 20
    turn = pipe._doppler_turn(pts, s, 0.2, np.array([9.0, 0.5]))
    assert turn is not None
    np.testing.assert_allclose(turn, [9.3, 4.0, 1.9], atol=1e-6)
    # the same turn at 26 m/s is 49 m/s^2 of lateral acceleration, past what the vehicles can steer: refused
    pipe.velocity = np.array([26.0, -2.5, -1.9])
    assert pipe._doppler_turn(cloud([26.0, 4.0], 1.9), s, 0.2, np.array([25.0, 0.5])) is None


def test_a_stale_turn_is_ended_by_the_retried_fit(monkeypatch):
    """The lane change has ended (the points fit a straight drive) while the held state still turns at
    1.9 rad/s: its static mask keeps few points, the retried fit finds the motion without a turn and it
    replaces the held state (a result of None would keep the stale yaw rate, the loss of random drives 1232 and
    1264); with the retry kept to turns (``SLIP_TURN_END = False``) the stale turn stays."""
    import slam.core.pipeline as pipeline
    from slam.core.pipeline import SlamPipeline
    from slam.core.registration import ICPRegistration

    s, cloud = _static_cloud(np.random.default_rng(5))
    pts = cloud([9.3, 0.4], 0.0)

    def ended() -> np.ndarray | None:
        pipe = SlamPipeline(ICPRegistration(), rng=0, sensor_xy=RADAR_MOUNTS)
        pipe.velocity = np.array([9.3, 4.0, 1.9])  # the turn held from the last cycles
        return pipe._doppler_turn(pts, s, 0.2, np.array([9.3, 0.4]))

    found = ended()
    assert found is not None
    np.testing.assert_allclose(found, [9.3, 0.4, 0.0], atol=1e-6)
    monkeypatch.setattr(pipeline, "SLIP_TURN_END", False)
    assert ended() is None


def test_the_bounded_turn_fit_refuses_a_turn_past_the_vehicles_lateral_acceleration():
    """A Doppler field that fits a -2.39 rad/s turn at 26 m/s (63 m/s^2 of lateral acceleration, past the
    ~40 m/s^2 highway-env's vehicles can steer; random drive 1305 fitted it at a lane change's reversal) within the
    acceleration bound of the last velocity: no turn is taken, not from the bounded fit nor from the retry; the
    same turn at 12 m/s (29 m/s^2) is."""
    from slam.core.pipeline import LATERAL_ACCEL_MAX, SlamPipeline
    from slam.core.registration import ICPRegistration

    s, cloud = _static_cloud(np.random.default_rng(5))
    pipe = SlamPipeline(ICPRegistration(), rng=0, sensor_xy=RADAR_MOUNTS)
    pipe.velocity = np.array([27.0, 2.5, 0.98])  # within the 3 m/s acceleration bound of the fitted velocity
    assert math.hypot(26.16, 3.66) * 2.39 > LATERAL_ACCEL_MAX
    assert pipe._doppler_turn(cloud([26.16, 3.66], -2.39), s, 0.2, None) is None
    pipe.velocity = np.array([12.0, 1.61, 0.98])
    found = pipe._doppler_turn(cloud([11.5, 3.0], -2.39), s, 0.2, None)
    assert found is not None
    np.testing.assert_allclose(found, [11.5, 3.0, -2.39], atol=1e-6)


def test_the_doppler_gate_is_wider_across_the_displacement():
    """The gate is an ellipse about the Doppler displacement: 1 m along it, 1.5 m across (a turn's onset gets
    the Doppler velocity's direction wrong, not its length)."""
    from slam.core.pipeline import within_doppler_gate

    expected = np.array([2.0, 0.0])  # 10 m/s over 0.2 s, straight on
    assert within_doppler_gate(expected + [0.0, 1.2], expected, 1.0, 1.5)
    assert not within_doppler_gate(expected + [1.2, 0.0], expected, 1.0, 1.5)
    assert within_doppler_gate(expected + [0.6, 1.1], expected, 1.0, 1.5)  # (0.6)^2 + (1.1 / 1.5)^2 = 0.90
    assert not within_doppler_gate(expected + [0.7, 1.2], expected, 1.0, 1.5)  # 0.49 + 0.64 = 1.13
    rotated = np.array([0.0, 2.0])  # the same along a turned heading
    assert within_doppler_gate(rotated + [1.2, 0.0], rotated, 1.0, 1.5)
    assert not within_doppler_gate(rotated + [0.0, 1.2], rotated, 1.0, 1.5)
    assert within_doppler_gate([0.9, 0.0], [0.0, 0.0], 1.0, 1.5)  # at rest: the 1 m circle
    assert not within_doppler_gate([0.0, 1.2], [0.0, 0.0], 1.0, 1.5)


def test_a_retried_turn_counts_only_when_the_registration_confirms_it():
    """The speed-bound retry fits a 1.9 rad/s turn to the Doppler (as on traffic that a braking car's
    cloud holds): when the last cycle's static points, moved by that turn, land where the cloud is, the
    turn stands; when they land where the held state puts them (the car went on at its held turn), the
    registration from the retried turn fits nothing and the held state stands."""
    from rhs_common.geometry import apply_motion
    from slam.core.pipeline import SlamPipeline
    from slam.core.registration import ICPRegistration

    s, cloud = _static_cloud(np.random.default_rng(5))
    v, w, dt = np.array([9.3, 4.0]), 1.9, 0.2
    pts = cloud(v, w)
    xy = pts[:, :2]
    held_v, held_w = np.array([9.0, 0.5]), -1.9

    def turn_after(prev_motion: np.ndarray) -> np.ndarray | None:
        pipe = SlamPipeline(ICPRegistration(), rng=0, sensor_xy=RADAR_MOUNTS)
        pipe.velocity = np.array([10.1, -2.5, held_w])
        pipe.last_motion = doppler_displacement(held_v, held_w * dt, dt)
        # the last cycle's static points: the scene seen from the pose before ``prev_motion``
        prev = apply_motion(xy, prev_motion)
        pipe.prev_static = np.column_stack([prev, np.zeros(40), np.ones(40)])
        return pipe._doppler_turn(pts, s, dt, held_v)

    confirmed = turn_after(doppler_displacement(v, w * dt, dt))
    assert confirmed is not None
    np.testing.assert_allclose(confirmed, [9.3, 4.0, 1.9], atol=1e-6)
    assert turn_after(doppler_displacement(held_v, held_w * dt, dt)) is None


def _lost_beside_a_roadside(seed: int, driven_m: float):
    """A pipeline that mapped 30 roadside points (two rows 9 m either side, +-50 m along) from a car at rest
    (every point static), then lost the car ``driven_m`` metres ago: ``(pipeline, its estimate, the points)``."""
    from slam.core.pipeline import SlamPipeline
    from slam.core.registration import ICPRegistration

    rng = np.random.default_rng(seed)
    scene = np.column_stack([rng.uniform(-50, 50, 30), rng.choice([-9.0, 9.0], 30) + rng.normal(0, 1.0, 30)])
    pipe = SlamPipeline(ICPRegistration(), rng=0)
    for _ in range(3):
        pipe.step(np.column_stack([scene, np.zeros(30), np.ones(30)]), 0.2)
    pipe.health.lost, pipe.health.loss_landmark_id = True, pipe.slam.next_id
    pipe.distance_since_loss = driven_m
    return pipe, pipe.slam.last_estimate, scene


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_relocalisation_finds_a_heading_lost_by_0_68_rad(seed):
    """A loss at a lane change's onset can leave the estimate 0.7 rad off (dense random drive 1249: 0.68 rad);
    the relocalisation's coarse grid spans +-0.8 rad of heading and finds the correction (with +-0.4 rad it
    found none on these three scenes)."""
    from rhs_common.geometry import apply_motion, points_in_frame

    pipe, est, scene = _lost_beside_a_roadside(seed, driven_m=5.0)
    true = np.array([2.0, 0.5, 0.68])  # the correction: it moves the scan onto the map
    seen_xy = points_in_frame(scene, true)
    np.testing.assert_allclose(apply_motion(seen_xy, true), scene, atol=1e-9)
    correction = pipe._relocalise(est, np.column_stack([seen_xy, np.zeros(30), np.ones(30)]))
    assert correction is not None
    np.testing.assert_allclose(correction, true, atol=0.05)


@pytest.mark.parametrize(("shift_m", "driven_m", "accepted"), [(4.0, 0.0, True), (16.0, 0.0, False), (16.0, 5.0, True)])
def test_relocalisation_refuses_a_correction_past_the_reported_uncertainty(shift_m, driven_m, accepted):
    """A scan that fits the map built before the loss only ``shift_m`` along the road (a repeating roadside
    fits one period away) is taken while the shift lies within twice the position std the lost filter
    reports (``spread_lost_m`` = 6 m plus the distance driven since the loss)."""
    pipe, est, scene = _lost_beside_a_roadside(2, driven_m)
    # the scan the map predicts ``shift_m`` ahead: the estimate is that far behind the car
    seen = np.column_stack([scene[:, 0] - shift_m, scene[:, 1], np.zeros(30), np.ones(30)])
    correction = pipe._relocalise(est, seen)
    assert (correction is not None) == accepted
    if accepted:
        np.testing.assert_allclose(correction[:2], [shift_m, 0.0], atol=0.1)
