"""The SLAM on a scene with nothing static to map says so: one warning at reset, and a health that drops.

highway-env's own roads (roundabout, intersection, exit, racetrack...) have no roadside landmarks: wrapped
in :class:`slam.gym.wrappers.SlamObservation` the filter can only dead-reckon, so it must not report a
confident pose (:mod:`slam.core.health`, the anchor score).
"""

from __future__ import annotations

import warnings

import gymnasium as gym
import highway_env  # noqa: F401  (registers roundabout-v0)
import pytest

import rhs_env  # noqa: F401
from rhs_env.wrappers import RadarObservation
from slam.core.health import HealthConfig, TrackHealth
from slam.gym.wrappers import SlamObservation, static_features

FAST_RADAR = {"scan": {"grid_deg": 5}}


def _healthy_cycle(h: TrackHealth, n_matched: float) -> float:
    """One cycle whose other scores are all 1: a good registration fit, a tight particle cloud, and two
    observations (too few for the matched fraction to count: it holds)."""
    return h.update(2, n_matched, 20, 1.0, True, False, 0.1, 0)


def test_cycles_without_a_match_lower_the_health():
    h = TrackHealth()
    k = h.config.unanchored_cycles_ok
    assert [_healthy_cycle(h, 2.0) for _ in range(10)] == [1.0] * 10
    scores = [_healthy_cycle(h, 0.0) for _ in range(2 * k)]
    assert scores[: k] == [1.0] * k  # the first cycles of a map match nothing: no penalty
    assert scores[k] < h.config.lost_below and scores[-1] == 0.0 and h.lost
    _healthy_cycle(h, 2.0)  # a match clears the count (the loss stays latched)
    assert h.unanchored == 0 and h.h_anchor == 1.0


def test_a_scene_without_static_features_never_anchors_and_a_new_map_keeps_it():
    h = TrackHealth()
    h.static_scene = False  # a match is then a car's
    scores = [_healthy_cycle(h, 2.0) for _ in range(8)]
    assert min(scores[4:]) < h.config.lost_below and h.lost
    h.new_map()
    assert not h.lost and h.health == 0.0  # a fresh map is no confident pose
    assert _healthy_cycle(h, 2.0) == 0.0 and h.lost
    h.relocalised()
    assert h.health == 1.0 and h.unanchored == 0


def test_unanchored_cycles_ok_is_validated():
    with pytest.raises(ValueError, match="unanchored_cycles_ok"):
        HealthConfig(unanchored_cycles_ok=0)


def _roundabout() -> gym.Env:
    return SlamObservation(RadarObservation(gym.make("roundabout-v0"), radar=FAST_RADAR), slam={"n_particles": 8})


def test_roundabout_warns_once_and_its_health_is_not_confident():
    env = _roundabout()
    assert static_features(env) == 0
    with pytest.warns(UserWarning, match="odometry-only") as record:
        env.reset(seed=0)
    assert sum("odometry-only" in str(w.message) for w in record) == 1
    health, lost = [], []
    for _ in range(12):  # 1 Hz: past new_map_after_cycles, so a map break is in it
        _, _, terminated, truncated, info = env.step(1)  # IDLE
        health.append(info["slam_health"])
        lost.append(info["slam_lost"])
        if terminated or truncated:
            break
    k = env.pipeline.health.config.unanchored_cycles_ok
    assert len(health) > k + 2
    assert max(health[k - 1:]) < env.pipeline.health.config.lost_below, health  # a map break included
    assert any(lost)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # a second episode does not warn again
        env.reset(seed=1)
    env.close()


def test_a_slam_env_with_landmarks_does_not_warn():
    env = gym.make("rhs-highway-slam-v0", radar=FAST_RADAR, vehicles_count=3, slam={"n_particles": 8})
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        env.reset(seed=0)
    assert static_features(env) > 0 and env.get_wrapper_attr("pipeline").health.static_scene
    env.close()


def test_a_lone_obstacle_counts_as_static_but_still_warns():
    """merge-v0's one obstacle at the end of the ramp can be matched (the anchor score counts it), but it is no map."""
    env = SlamObservation(RadarObservation(gym.make("merge-v0"), radar=FAST_RADAR), slam={"n_particles": 8})
    with pytest.warns(UserWarning, match=r"only 1 static landmark\(s\) or obstacle\(s\)"):
        env.reset(seed=0)
    assert static_features(env) == 1 and env.pipeline.health.static_scene
    env.close()
