"""``rhs-dense-v0``: the dense roadside preset, its registration, observation and env checkers."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from highway_env.road.road import RoadNetwork

import rhs_env  # noqa: F401  (registers the ids)
from agents.policies.decision import IDLE
from rhs_env.scene import DENSE_LANDMARKS, LandmarkConfig, get_landmarks, place_roadside_landmarks

DENSE = "rhs-dense-v0"
SCENE = {"vehicles_count": 4, "lanes_count": 3, "duration": 4}


def _place(config: LandmarkConfig, lanes: int = 3, seed: int = 0):
    net = RoadNetwork.straight_road_network(lanes, length=400.0)
    return place_roadside_landmarks(net, config, np.random.default_rng(seed))


def test_dense_preset_places_posts_pairs_and_gantries():
    lm = _place(DENSE_LANDMARKS)
    c = DENSE_LANDMARKS
    n_post = np.sum(lm.rcs == c.post_rcs_m2)
    n_gantry = np.sum(lm.rcs == c.gantry_rcs_m2)
    n_pole = np.sum(lm.rcs == c.rcs_m2)
    assert n_post == 2 * 160  # 400 m / 2.5 m on each side
    assert n_gantry == 2 * 3  # legs at 75, 225, 375 m, both sides
    assert n_pole == 2 * (20 + 19)  # 20 poles left (from 10 m), 19 right (from 20 m), each with its twin
    # guard-rail posts: 1 m off the road edge, spacing 2.5 m +- 10 %
    y_edge = 3 * 4.0 - 2.0  # the outer edge of the right lane (lanes 4 m wide, centred at 0, 4, 8)
    posts = lm.xy_he[lm.rcs == c.post_rcs_m2]
    right = np.sort(posts[posts[:, 1] > 0, 0])
    assert np.allclose(posts[posts[:, 1] > 0, 1], y_edge + c.post_offset_m)
    assert np.all(np.abs(np.diff(right) - c.post_spacing_m) <= 0.2 * c.post_spacing_m + 1e-9)
    # pairs: every pole has a twin pair_gap_m further along the road at the same offset
    poles = lm.xy_he[lm.rcs == c.rcs_m2]
    d = np.hypot(*(poles[:, None, :] - poles[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    assert np.allclose(np.sort(d.min(axis=1)), c.pair_gap_m, atol=1e-9)
    # gantry legs: both road edges at the same x
    legs = lm.xy_he[lm.rcs == c.gantry_rcs_m2]
    assert set(np.round(legs[:, 0], 6)) == {75.0, 225.0, 375.0} and np.sum(legs[:, 1] > 0) == 3


def test_defaults_unchanged_and_new_fields_validated():
    plain, dense_off = _place(LandmarkConfig()), _place(LandmarkConfig(post_offset_m=3.0, gantry_rcs_m2=1.0))
    np.testing.assert_array_equal(plain.xy_he, dense_off.xy_he)  # the extra structures are off by default
    for field, bad in (("pair_gap_m", 0.2), ("post_spacing_m", 0.5), ("gantry_spacing_m", 5.0),
                       ("post_rcs_m2", 0.0), ("post_offset_m", -1.0), ("gantry_rcs_m2", -2.0)):
        with pytest.raises(ValueError, match=field):
            LandmarkConfig(**{field: bad})


def test_dense_env_registered_with_the_slam_observation(small_env):
    env = small_env(DENSE, **SCENE)
    ref = small_env("rhs-highway-slam-v0", **SCENE)
    assert env.observation_space == ref.observation_space and env.action_space == ref.action_space
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    ref.reset(seed=0)
    assert len(get_landmarks(env)) > 5 * len(get_landmarks(ref))
    assert env.unwrapped.landmark_config == DENSE_LANDMARKS
    for _ in range(3):
        obs, _, _, _, info = env.step(IDLE)
    assert env.observation_space.contains(obs) and obs["points_mask"].sum() > 20  # a dense roadside, many points
    assert np.isfinite(info["position_error_m"])
    over = small_env(DENSE, **SCENE, landmarks={"post_spacing_m": 5.0})  # merged onto the preset
    over.reset(seed=0)
    assert over.unwrapped.landmark_config == LandmarkConfig(**{**DENSE_LANDMARKS.to_dict(), "post_spacing_m": 5.0})


def test_dense_env_passes_gymnasium_and_sb3_checkers(small_env):
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = small_env(DENSE, **SCENE)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "env is wrapped", "unconventional shape" notes
        gym_check_env(env)
        sb3_check_env(env, warn=False)
