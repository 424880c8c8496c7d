"""The radar safety shield (agents.policies.shield): its rules on hand-made scans, its config, and the evaluation path.

The scans are built in the vehicle frame (x forward, y left, m; radial velocity m/s, negative when the range
shrinks), two points per car (the shield's ``min_points``), with the SLAM pose that the rules read.
"""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from conftest import small_env_kwargs

import rhs_env  # noqa: F401  (registers the ids)
from agents.evaluate import evaluate, load_policy
from agents.policies.decision import FASTER, IDLE, LANE_LEFT, LANE_RIGHT, SLOWER
from agents.policies.shield import RadarShield, ShieldAction, ShieldConfig, ShieldedPolicy, objects
from rhs_slam.cli import main as cli_main


def scan(*cars: tuple[float, float, float], pose=(0.0, 0.0, 0.0), per_car: int = 2) -> dict[str, np.ndarray]:
    """An observation with ``per_car`` points on each car's near face at (x, y) m, radial velocity v_r m/s."""
    rows = [[x + 0.3 * k, y + 0.2 * k, v_r, 100.0, 0.0, 0.0, 0.0] for x, y, v_r in cars for k in range(per_car)]
    points = np.zeros((16, 7), np.float32)
    mask = np.zeros(16, np.int8)
    points[: len(rows)], mask[: len(rows)] = rows, 1
    return {"points": points, "points_mask": mask, "pose": np.asarray(pose, np.float32)}


def test_car_ahead_closing_inside_its_gap_brakes_and_one_receding_does_not():
    # 10 m ahead (gap 7.5 m): closing at 5 m/s needs 4 + 1.2 * 5 = 10 m, pulling away at 2 m/s needs 4 m,
    # and one FASTER more (closing at 3 m/s) 4 + 1.2 * 3 = 7.6 m
    assert RadarShield().filter(scan((10.0, 0.0, -5.0)), IDLE) == (SLOWER, "front")
    assert RadarShield().filter(scan((10.0, 0.0, 2.0)), IDLE) == (IDLE, None)
    assert RadarShield().filter(scan((10.0, 0.0, 2.0)), FASTER) == (IDLE, "faster")
    assert RadarShield().filter(scan((30.0, 0.0, -5.0)), FASTER) == (FASTER, None)


def test_lone_points_and_cars_one_lane_over_are_not_in_the_path():
    assert RadarShield().filter(scan((8.0, 0.0, -10.0), per_car=1), IDLE) == (IDLE, None)  # a ghost
    assert RadarShield().filter(scan((8.0, 3.0, -10.0)), IDLE) == (IDLE, None)  # the next lane's car


def test_lane_change_is_vetoed_by_a_car_closing_in_the_target_lane_behind():
    behind = scan((-12.0, 3.5, -8.0))  # 9.5 m behind on the left, closing at 8 m/s: needs 4 + 1.5 * 8 = 16 m
    assert RadarShield().filter(behind, LANE_LEFT) == (IDLE, "lane")
    assert RadarShield().filter(behind, LANE_RIGHT) == (LANE_RIGHT, None)
    assert RadarShield().filter(scan((-12.0, 3.5, 2.0)), LANE_LEFT) == (LANE_LEFT, None)  # falling back


def test_one_point_alongside_blocks_a_lane_change_and_one_farther_does_not():
    flank = scan((-0.5, 3.0, 1.0), per_car=1)  # a car beside the ego shows one point of its flank
    assert RadarShield().filter(flank, LANE_LEFT) == (IDLE, "lane")
    assert RadarShield().filter(flank, LANE_RIGHT) == (LANE_RIGHT, None)  # the other side is free
    assert RadarShield({"alongside_m": 0.0}).filter(flank, LANE_LEFT) == (LANE_LEFT, None)  # the rule off
    assert RadarShield().filter(flank, IDLE) == (IDLE, None)  # beside, not in the path: no braking
    far = scan((12.0, 3.0, 1.0), per_car=1)  # one point 12 m ahead in the left lane: a ghost, not an object
    assert RadarShield().filter(far, LANE_LEFT) == (LANE_LEFT, None)


def test_lane_body_counts_a_target_lane_car_from_its_points_far_end():
    ahead = scan((9.0, 3.5, -1.0))  # two points 9 m ahead on the left, pulling away: 6.5 m from the bumper, needs 4
    assert RadarShield().filter(ahead, LANE_LEFT) == (LANE_LEFT, None)
    # the points may lie on the car's flank up to its far end: 6.5 - 5 = 1.5 m of gap is too little
    assert RadarShield({"lane_body_m": 5.0}).filter(ahead, LANE_LEFT) == (IDLE, "lane")
    assert RadarShield({"lane_body_m": 5.0}).filter(scan((9.0, 0.0, 1.0)), IDLE) == (IDLE, None)  # not the path's


def test_lanes_come_from_the_slam_lateral_offset_and_the_path_from_its_heading():
    car = (14.0, 2.6, -6.0)  # 11.5 m ahead, 2.6 m left of the ego, closing at 6 m/s: in a lane's 4 + 1.5 * 6 = 13 m
    # on its lane's centre the ego sees the car in the left lane; 1 m right of it (SLAM offset -1 m), in its own
    assert RadarShield().filter(scan(car), LANE_LEFT) == (IDLE, "lane")
    assert RadarShield().filter(scan(car, pose=(0.0, -1.0, 0.0)), LANE_LEFT) == (LANE_LEFT, None)
    assert RadarShield().filter(scan(car, pose=(0.0, 3.0, 0.0)), LANE_LEFT) == (LANE_LEFT, None)  # lanes repeat
    # a car one lane over (road offset (12, 4)) seen while the ego heads 0.2 rad towards it lies near the ego's
    # axis in the vehicle frame; the heading puts it back in its lane
    h = 0.2
    x, y = 12 * np.cos(h) + 4 * np.sin(h), -12 * np.sin(h) + 4 * np.cos(h)
    assert abs(y) < 1.8
    assert RadarShield().filter(scan((x, y, -8.0), pose=(0.0, 0.0, h)), IDLE) == (IDLE, None)
    assert RadarShield().filter(scan((x, y, -8.0)), IDLE) == (SLOWER, "front")


def test_a_braking_shield_re_arms_after_its_interval():
    shield = RadarShield({"rearm_steps": 3})
    # a leader closing at 6 m/s (1.2 m per step) from a 9.5 m gap: inside the 4 + 1.2 * 6 = 11.2 m it needs
    near = [scan((12.0 - 1.2 * k, 0.0, -6.0)) for k in range(5)]
    assert [shield.filter(obs, IDLE)[0] for obs in near] == [SLOWER, IDLE, IDLE, SLOWER, IDLE]
    assert shield.overrides == {"front": 2, "faster": 0, "lane": 0}
    shield.reset()
    assert shield.filter(near[0], IDLE)[0] == SLOWER and shield.overrides["front"] == 1


def test_the_leader_track_gives_the_closing_speed_when_its_doppler_is_wrong():
    # a leader closing at 5 m/s (1 m per 0.2 s step) whose points carry a Doppler of a car pulling away
    shield = RadarShield()
    leads = [shield.leader(np.array([x, x + 0.3]), np.array([-3.0, -3.0])) for x in (30.0, 29.0, 28.0, 27.0)]
    assert leads[0] == (27.5, -3.0) and leads[1][1] == -3.0  # Doppler until three gaps
    assert leads[2][1] == pytest.approx(5.0) and leads[3][1] == pytest.approx(5.0)
    assert shield.leader(np.array([60.0, 60.5]), np.array([0.0, 0.0])) == (57.5, 0.0)  # a jump: a new track
    assert len(shield.track) == 1


def test_objects_need_min_points_within_reach_and_take_their_median_closing():
    x, c = objects(np.array([5.0, 6.0, 7.5, 40.0]), np.array([1.0, 3.0, 8.0, 2.0]), 2, 2.0)
    assert x.tolist() == [5.0, 6.0, 7.5] and c.tolist() == [2.0, 3.0, 5.5]
    assert objects(np.array([5.0]), np.array([1.0]), 2, 2.0)[0].size == 0


@pytest.mark.parametrize(("field", "value"), [("front_time_s", -1.0), ("min_points", 0), ("track_steps", 2),
                                              ("lane_width_m", 0.0), ("dt_s", float("nan")),
                                              ("alongside_m", -1.0), ("lane_body_m", -0.5)])
def test_bad_config_names_the_field(field, value):
    with pytest.raises(ValueError, match=f"shield.{field}"):
        RadarShield({field: value})


def test_config_types_and_unknown_fields():
    with pytest.raises(TypeError, match="rearm_steps must be an integer"):
        ShieldConfig(rearm_steps=1.5)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="front_gap"):
        RadarShield({"front_gap": 4.0})


def test_shielded_policy_and_env_wrapper_on_the_radar_env(small_env):
    env = small_env("rhs-highway-radar-v0", slam=False)
    policy = ShieldedPolicy(load_policy("constant:3", env))  # always FASTER
    obs, _ = env.reset(seed=3)
    actions = {int(policy.predict(obs)[0])}
    assert actions <= {FASTER, IDLE, SLOWER}
    wrapped = ShieldAction(env)
    wrapped.reset(seed=3)
    _, _, _, _, info = wrapped.step(FASTER)
    assert info["shield"] in (None, "faster", "front")
    with pytest.raises(ValueError, match="points"):
        ShieldAction(gym.make("rhs-highway-v0", vehicles_count=5))


def test_evaluate_records_the_shield_and_its_overrides(tmp_path):
    kw = small_env_kwargs(slam=False, vehicles_count=8, duration=6)
    plain = evaluate("constant:3", "rhs-highway-radar-v0", episodes=2, seed=4, env_kwargs=kw, progress=False)
    shielded = evaluate("constant:3", "rhs-highway-radar-v0", episodes=2, seed=4, env_kwargs=kw, progress=False,
                        shield={"front_time_s": 1.5})
    assert plain["shield"] is None and plain["shield_overrides"] is None
    assert shielded["shield"]["front_time_s"] == 1.5 and shielded["shield"]["min_points"] == 2
    counts = shielded["shield_overrides"]
    assert set(counts) == {"front", "faster", "lane"} and counts["lane"] == 0  # always FASTER never changes lane
    assert counts["faster"] + counts["front"] > 0  # always FASTER meets a leader within 6 s
    assert sum(r["shield_overrides"]["faster"] for r in shielded["runs"]) == counts["faster"]
    with pytest.raises(ValueError, match="points"):
        evaluate("constant:3", "rhs-highway-v0", episodes=1, env_kwargs={"duration": 2}, progress=False, shield={})


def test_evaluate_cli_shield_flag(tmp_path, capsys):
    out = tmp_path / "e.json"
    kw = json.dumps(small_env_kwargs(slam=False, vehicles_count=5, duration=2))
    rc = cli_main(["evaluate", "--policy", "constant:1", "--env", "rhs-highway-radar-v0", "--env-kwargs", kw,
                   "--episodes", "1", "--shield", "--out", str(out), "--no-progress"])
    assert rc == 0 and json.loads(out.read_text())["shield"]["front_gap_m"] == 4.0
    rc = cli_main(["evaluate", "--policy", "constant:1", "--env", "rhs-highway-radar-v0", "--episodes", "1",
                   "--shield", '{"front_gap_m": -2}', "--out", str(out), "--no-progress"])
    assert rc == 2 and "shield.front_gap_m" in capsys.readouterr().err


def test_both_training_backends_wrap_the_shield_inside_the_decision_interval():
    from agents.algos.finetune import training_wrapper
    from agents.algos.rllib import env_config, make_env
    from agents.algos.shaping import RewardShaping
    from agents.policies.decision import HoldAction

    kw = small_env_kwargs(slam=False, vehicles_count=5, duration=2)
    env = make_env("rhs-highway-radar-v0", env_config(kw, 5, "pulse", False, {"front_time_s": 1.5}, {"ttc_s": 2.0}))
    assert isinstance(env, HoldAction) and isinstance(env.env, RewardShaping)
    assert isinstance(env.env.env, ShieldAction) and env.env.env.shield.config.front_time_s == 1.5
    env.close()
    sb3 = training_wrapper(gym.make("rhs-highway-radar-v0", **kw), privileged=False, shaping=None, shield={})
    assert isinstance(sb3, ShieldAction)
    sb3.close()


def test_sensing_study_compares_the_radar_leader_with_the_truth():
    from rhs_studies.shield_sensing import markdown, measure

    r = measure([4050])
    assert r["steps"] > 0 and r["doppler"]["points_on_vehicles"] > 0
    assert abs(r["doppler"]["median_error_mps"]) < 0.5  # most points carry their car's Doppler
    assert 0.0 <= r["doppler"]["share_off_by_3_mps"] < 0.3 and 0.0 <= r["ghost_scan_share"] <= 1.0
    a = r["front_alarms"]
    # two-point objects alarm no more spuriously than single points (ghosts are single points)
    assert a["object"]["spurious"] <= a["point"]["spurious"]
    assert "tracked leader (the shield)" in markdown(r)
    f = r["flanks"]  # every env step counts once per side
    assert sum(f["beside_points"]) + f["empty_steps"] == 2 * r["steps"]
    # a car beside gives points alongside far more often than an empty flank does (ghosts)
    assert sum(f["beside_points"][1:]) / max(sum(f["beside_points"]), 1) > 5 * f["empty_with_point"] / f["empty_steps"]
