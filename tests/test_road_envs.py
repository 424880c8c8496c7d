"""highway-env's other roads (merge, roundabout, intersection, exit, racetrack): every id makes, resets, steps,
passes gymnasium's checker, renders its radar points, refuses unknown kwargs; the SLAM ids have landmarks to map
(no "nothing static" warning); landmarks follow curved lanes and stay off every lane; per-seed determinism."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from conftest import small_env_kwargs
from gymnasium.utils.env_checker import check_env as gym_check_env

import rhs_env  # noqa: F401  (registers the ids)
from rhs_env.registration import ENV_SPECS, ROAD_NAMES, SLAM_ENV_SPECS, with_cheap_base_observation
from rhs_env.road_envs import ROAD_ENVS, RHSRoundaboutEnv
from rhs_env.scene import off_lanes, place_roadside_landmarks
from rhs_env.wrappers import POINT_COLOR

KINDS = ("", "-radar", "-slam")
SLAM_KW = {"slam": {"n_particles": 8}}


def _kwargs(kind: str) -> dict:
    if kind == "":
        return {}
    return {**small_env_kwargs(slam=kind == "-slam"), **(SLAM_KW if kind == "-slam" else {})}


def test_every_road_has_three_registered_ids():
    ours = {env_id for env_id, _ in ENV_SPECS + SLAM_ENV_SPECS}
    for road in ROAD_NAMES:
        assert {f"rhs-{road}-v0", f"rhs-{road}-radar-v0", f"rhs-{road}-slam-v0"} <= ours
        assert f"rhs-{road}-slam-v0" in gym.registry


@pytest.mark.parametrize("road", ROAD_NAMES)
def test_ids_make_step_check_env_and_render(road):
    for kind in KINDS:
        env_id = f"rhs-{road}{kind}-v0"
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            env = gym.make(env_id, render_mode="rgb_array", **_kwargs(kind))
            env.reset(seed=3)
            for _ in range(3):
                _, _, term, trunc, info = env.step(env.action_space.sample())
                if term or trunc:
                    env.reset(seed=4)
            frame = env.render()
        assert not [w for w in caught if "static" in str(w.message)], f"{env_id}: {[str(w.message) for w in caught]}"
        assert "world_pose" in info
        assert isinstance(frame, np.ndarray) and frame.ndim == 3 and frame.dtype == np.uint8 and frame.std() > 0
        if kind:  # the radar points drawn over the road
            assert np.all(frame == np.array(POINT_COLOR, dtype=np.uint8), axis=-1).sum() > 0, env_id
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "env is wrapped" notes
            gym_check_env(env)
        env.close()


@pytest.mark.parametrize("road", ("roundabout", "racetrack"))
def test_unknown_kwarg_is_refused_by_name(road):
    with pytest.raises(ValueError, match="no_such_key"):
        gym.make(f"rhs-{road}-slam-v0", no_such_key=1, **small_env_kwargs())
    with pytest.raises(ValueError, match="spacing_m"):
        gym.make(f"rhs-{road}-v0", landmarks={"spacing_m": -1})


def test_default_actions_are_highway_envs():
    env = gym.make("rhs-racetrack-v0")
    assert isinstance(env.action_space, gym.spaces.Box) and env.action_space.shape == (1,)  # steering only
    assert isinstance(gym.make("rhs-intersection-v0").action_space, gym.spaces.Discrete)
    assert gym.make("rhs-exit-v0").unwrapped.config["simulation_frequency"] == 15
    assert all(cls(**with_cheap_base_observation({})).config["policy_frequency"] == 5 for cls in ROAD_ENVS.values())


def test_slam_vector_envs_sync_and_async():
    for mode in ("sync", "async"):
        env = gym.make_vec("rhs-roundabout-slam-v0", num_envs=2, vectorization_mode=mode, duration=0.4,
                           **{**small_env_kwargs(max_points=32), **SLAM_KW})
        obs, _ = env.reset(seed=0)
        for _ in range(3):  # past the 2-step episode: autoreset
            obs, _, _, _, _ = env.step(env.action_space.sample())
        assert obs["pose"].shape[0] == 2 and np.all(np.isfinite(obs["pose"]))
        env.close()


@pytest.mark.parametrize("vec", ["dummy", "subproc"])
def test_sb3_vec_envs_on_the_racetrack(vec):
    """stable-baselines3's vector envs on a road with a Box action (the racetrack's steering), whole episodes."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    cls, vkw = (DummyVecEnv, None) if vec == "dummy" else (SubprocVecEnv, {"start_method": "fork"})
    venv = make_vec_env("rhs-racetrack-slam-v0", n_envs=2, seed=0, vec_env_cls=cls, vec_env_kwargs=vkw,
                        env_kwargs={"duration": 0.4, **small_env_kwargs(max_points=32), **SLAM_KW})
    try:
        venv.reset()
        dones = 0
        for _ in range(2):
            obs, _, done, _ = venv.step(np.zeros((2, 1), dtype=np.float32))
            assert np.all(np.isfinite(obs["pose"]))
            dones += int(done.sum())
        assert dones == 2
    finally:
        venv.close()


def _roundabout(seed: int) -> RHSRoundaboutEnv:
    env = RHSRoundaboutEnv(**with_cheap_base_observation({}))
    env.reset(seed=seed)
    return env


def test_roundabout_ring_is_lined_outside_and_on_the_island():
    """The ring's two lanes (radius 20 and 24 m, 4 m wide): landmarks ``lateral_offset_m`` + [0, lateral_jitter_m]
    beyond the outer lane's edge all around, and as far inside the inner lane's edge, on the island; one per
    ``spacing_m`` of the lane (10 seeds). Placed arc by arc, without the spacing carried on from arc to arc, the
    outer ring (arcs of 17-20 m, under the 20 m spacing) got 0.76 of its share and the island 1.27."""
    env = _roundabout(0)
    cfg = env.landmark_config
    ring = [lane for tos in env.road.network.graph.values() for lanes in tos.values() for lane in lanes
            if hasattr(lane, "center") and np.allclose(lane.center, 0.0) and lane.radius in (20, 24)]
    assert len(ring) == 16  # 8 arcs x 2 lanes
    tol = 1e-6
    outer_lo, inner_hi = 24 + 2 + cfg.lateral_offset_m, 20 - 2 - cfg.lateral_offset_m
    outer, island = [], []
    for seed in range(10):
        env.reset(seed=seed)
        xy = env.landmarks.xy_he
        r = np.hypot(*xy.T)
        on_outer = (r >= outer_lo - tol) & (r <= outer_lo + cfg.lateral_jitter_m + tol)
        on_island = r <= inner_hi + tol
        assert np.all(r[on_island] >= inner_hi - cfg.lateral_jitter_m - tol)  # nothing else on the island
        assert np.all(r[~on_island] > 26 + tol)  # nothing on the ring's carriageway
        angles = np.degrees(np.arctan2(xy[on_outer, 1], xy[on_outer, 0])) % 360
        assert len(set((angles // 90).astype(int))) >= 3  # all around the ring (the approaches take a few)
        outer.append(int(on_outer.sum()))
        island.append(int(on_island.sum()))
    assert 0.85 <= np.mean(outer) / (2 * np.pi * 24 / cfg.spacing_m) <= 1.2, outer
    assert 0.85 <= np.mean(island) / (2 * np.pi * 20 / cfg.spacing_m) <= 1.15, island


@pytest.mark.parametrize("road", ROAD_NAMES)
def test_landmarks_off_every_lane_and_deterministic_per_seed(road):
    cls = ROAD_ENVS[road]
    a, b, c = (cls(**with_cheap_base_observation({})) for _ in range(3))
    for env, seed in ((a, 7), (b, 7), (c, 8)):
        env.reset(seed=seed)
    lm = a.landmarks
    assert len(lm) >= 30
    assert np.all(off_lanes(a.road.network, lm.xy_he))
    assert np.array_equal(lm.xy_he, b.landmarks.xy_he) and np.array_equal(lm.rcs, b.landmarks.rcs)
    assert not (len(lm) == len(c.landmarks) and np.array_equal(lm.xy_he, c.landmarks.xy_he))
    # about one landmark per spacing_m per side of the lanes' length: the roads' spacing, as on the straight highway
    side_m = sum(float(lanes[0].length) + float(lanes[-1].length) for tos in a.road.network.graph.values()
                 for lanes in tos.values())
    assert 0.5 <= len(lm) / (side_m / a.landmark_config.spacing_m) <= 1.2


def test_the_filter_drops_landmarks_that_fell_on_lanes(monkeypatch):
    """Without :func:`off_lanes`, landmarks of the merge ramp, the intersection and the roundabout's approaches
    fall onto other lanes."""
    from rhs_env import scene

    monkeypatch.setattr(scene, "off_lanes", lambda network, xy: np.ones(len(xy), dtype=bool))
    for road in ("merge", "intersection", "roundabout"):
        env = ROAD_ENVS[road](**with_cheap_base_observation({}))
        env.reset(seed=0)
        raw = place_roadside_landmarks(env.road.network, env.landmark_config, np.random.default_rng(0))
        assert (~off_lanes(env.road.network, raw.xy_he)).sum() > 0, road


def test_traffic_is_highway_envs_for_the_seed():
    """The landmarks are drawn after highway-env's scene: the traffic of a seed is highway-env's own."""
    from highway_env.envs.roundabout_env import RoundaboutEnv

    ours = _roundabout(11)
    theirs = RoundaboutEnv(config={k: v for k, v in ours.config.items() if k != "landmarks"})
    theirs.reset(seed=11)
    assert len(ours.road.vehicles) == len(theirs.road.vehicles)
    for v, w in zip(ours.road.vehicles, theirs.road.vehicles, strict=True):
        assert np.allclose(v.position, w.position) and v.speed == pytest.approx(w.speed)


def test_segment_drift_is_kittis_relative_error():
    """1 % too long a path is 1 % drift at every length (to the overshoot of the segments' ends, under 2 %
    of it); a rigid motion of the whole estimate is none."""
    from rhs_studies.slam_accuracy import segment_drift

    x = np.linspace(0.0, 1200.0, 500)
    line = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    scaled = line.copy()
    scaled[:, 0] *= 1.01
    for length, (t_sum, r_sum, n) in segment_drift(scaled, line, (100.0, 800.0)).items():
        assert n > 0 and t_sum / n == pytest.approx(0.01, rel=2e-2) and r_sum == pytest.approx(0.0, abs=1e-9), length
    t = np.linspace(0.0, 2 * np.pi, 800)
    true = np.stack([300 * np.sin(t), 300 * (1 - np.cos(t)), t], 1)  # a 1.9 km circle, heading along it
    c, s = np.cos(0.3), np.sin(0.3)
    moved = np.stack([c * true[:, 0] - s * true[:, 1] + 5, s * true[:, 0] + c * true[:, 1] - 2, true[:, 2] + 0.3], 1)
    for t_sum, r_sum, n in segment_drift(moved, true, (100.0, 400.0)).values():
        assert n > 0 and t_sum / n < 1e-9 and r_sum / n < 1e-9


def test_slam_accuracy_roads_part(tmp_path):
    """``--parts roads``: the per-road page and JSON, the targets and KITTI's drift per road and driver."""
    import json

    from rhs_studies import slam_accuracy

    out = tmp_path / "roads"
    assert slam_accuracy.main(["--parts", "roads", "--quick", "--roads", "racetrack", "--out", str(out),
                               "--no-progress"]) == 0
    doc = json.loads(out.with_suffix(".json").read_text())
    combos = doc["parts"]["roads"]["combos"]
    assert set(combos) == {"racetrack/idm", "racetrack/random"}
    assert combos["racetrack/idm"]["policy"] == "idm:10"
    assert 10 <= combos["racetrack/idm"]["runs"][0]["cycles"] <= 11  # duration 2 s (highway-env's time >= duration)
    for combo in combos.values():
        assert {"worst_rmse_le_1m", "no_silent_loss", "nees_ge_90pct"} <= set(combo["targets"])
        assert np.isfinite(combo["summary"]["heading_rmse_deg"]["mean"])
    page = out.with_suffix(".md").read_text()
    assert page.startswith("# SLAM accuracy on highway-env's roads") and "| racetrack | idm |" in page
    assert "DRO 0.18 %" in page and "simulated" in page


def test_the_intersection_keeps_its_idm_constants_to_itself():
    """highway-env's intersection sets its IDM constants on the other vehicles' class: made in the same process, a
    highway afterwards drove with them (a SLAM drive's error changed). They now live on a private subclass."""
    from highway_env.vehicle.behavior import IDMVehicle

    before = {k: getattr(IDMVehicle, k) for k in ("DISTANCE_WANTED", "COMFORT_ACC_MAX", "COMFORT_ACC_MIN")}
    env = gym.make("rhs-intersection-v0")
    env.reset(seed=0)
    for _ in range(3):
        env.step(env.action_space.sample())
    others = [v for v in env.unwrapped.road.vehicles if v is not env.unwrapped.vehicle]
    env.close()
    assert others and all(isinstance(v, IDMVehicle) for v in others)
    assert all((v.DISTANCE_WANTED, v.COMFORT_ACC_MAX, v.COMFORT_ACC_MIN) == (7, 6, -3) for v in others)
    assert {k: getattr(IDMVehicle, k) for k in before} == before
