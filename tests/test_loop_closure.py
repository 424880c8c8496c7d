"""Loop closure and persistent maps (slam.core.loop_closure, SlamObservation's loop_closure and keep_map)."""

import math
import warnings

import numpy as np
import pytest


def test_rigid_match_recovers_a_transform_among_outliers():
    from slam.core.loop_closure import apply_transform, rigid_match

    rng = np.random.default_rng(3)
    dst = rng.uniform(-50, 50, (30, 2))
    phi, t = 0.4, np.array([3.0, -7.0])
    src = apply_transform(dst[:20], -phi, np.zeros(2)) - apply_transform(t[None], -phi, np.zeros(2))
    src = np.vstack([src + rng.normal(0, 0.05, src.shape), rng.uniform(-50, 50, (8, 2))])  # 8 outliers
    m = rigid_match(src, dst, gate=0.5, tol=0.3)
    assert m is not None and m.inliers >= 19
    assert m.phi == pytest.approx(phi, abs=5e-3)
    assert np.allclose(m.t, t, atol=0.1)
    assert m.rms_m < 0.15


def test_rigid_match_respects_the_allowed_hypotheses():
    from slam.core.loop_closure import apply_transform, rigid_match

    rng = np.random.default_rng(4)
    dst = rng.uniform(-30, 30, (15, 2))
    src = apply_transform(dst, 0.0, np.array([-20.0, 0.0]))
    near = rigid_match(src, dst, 0.5, 0.3, allowed=lambda p, t: np.hypot(*t.T) <= 5.0)
    assert near is None or near.inliers <= 3  # only chance pairs within 5 m
    m = rigid_match(src, dst, 0.5, 0.3, allowed=lambda p, t: np.hypot(*t.T) <= 25.0)
    assert m is not None and np.allclose(m.t, [20.0, 0.0], atol=0.05)


def test_duplicate_fraction_counts_second_estimates_of_one_landmark():
    from slam.core.loop_closure import duplicate_fraction

    true = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    est = np.array([[0.1, 0.0], [0.5, 0.2], [10.0, 0.1], [50.0, 0.0]])
    assert duplicate_fraction(est, true) == pytest.approx(1 / 4)
    assert duplicate_fraction(true, true) == 0.0
    assert duplicate_fraction(np.zeros((0, 2)), true) is None


def test_transform_filter_moves_poses_and_landmarks_rigidly():
    from slam.core.loop_closure import seed_landmarks, transform_filter
    from slam.core.rbpf import RBPFSlam, SlamConfig

    slam = RBPFSlam(SlamConfig(n_particles=4, max_landmarks=8), 0)
    slam.pose[:] = [1.0, 2.0, 0.1]
    assert seed_landmarks(slam, np.array([[5.0, 0.0], [0.0, 5.0]]), np.array([7, 8]), 0.2) == 2
    transform_filter(slam, math.pi / 2, np.array([1.0, 0.0]))
    assert np.allclose(slam.pose[0], [-1.0, 1.0, 0.1 + math.pi / 2])
    used = np.flatnonzero(slam.slot_used)
    assert np.allclose(slam.mean[0, used], [[1.0, 5.0], [-4.0, 0.0]])
    assert np.allclose(slam.cov[0, used[0]], 0.04 * np.eye(2))
    assert list(slam.slot_id[used]) == [7, 8]


def test_loop_closure_config_names_the_field():
    from slam.core.loop_closure import LoopClosureConfig

    with pytest.raises(ValueError, match="loop_closure.min_inliers"):
        LoopClosureConfig(min_inliers=1)


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_keep_map_relocalises_the_next_episode_in_the_old_map():
    import gymnasium as gym

    import rhs_env  # noqa: F401

    env = gym.make("rhs-racetrack-slam-v0", radar={"scan": {"grid_deg": 5}}, duration=10, loop_closure=True)
    env.reset(seed=0)
    for _ in range(25):
        _, _, _, _, info = env.step(np.zeros(1))
    assert "slam_map_kept" not in info and info["slam_loop_closures"] >= 0
    lm_before = env.unwrapped.landmarks.xy_world.copy()
    _, info = env.reset(seed=1, options={"keep_map": True})
    assert info["slam_map_kept"] is True
    assert np.array_equal(env.unwrapped.landmarks.xy_world, lm_before)  # the same world
    assert np.linalg.norm(info["true_pose"][:2]) > 1.0  # the new start, in the old map frame
    assert info["position_error_m"] < 0.3
    for _ in range(10):
        _, _, _, _, info = env.step(np.zeros(1))
    assert info["position_error_m"] < 0.3
    _, info = env.reset(seed=2)
    assert "slam_map_kept" not in info and np.allclose(info["true_pose"], 0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(TypeError, match="keep_map"):
            env.reset(seed=3, options={"keep_map": "yes"})
    env.close()


def test_a_landmark_mapped_again_merges_with_its_archived_twin():
    from slam.core.loop_closure import LoopCloser, LoopClosureConfig, seed_landmarks
    from slam.core.rbpf import RBPFSlam, SlamConfig

    slam = RBPFSlam(SlamConfig(n_particles=4, max_landmarks=8), 0)
    seed_landmarks(slam, np.array([[5.0, 0.0], [0.0, 5.0]]), np.array([10, 11]), 0.1)
    slam.retired_xy, slam.retired_ids = np.array([[5.2, 0.1], [100.0, 100.0]]), np.array([3, 4])
    closer = LoopCloser(LoopClosureConfig(every_cycles=1))
    assert closer.check(slam, slam._estimate(), 0)
    assert sorted(slam.slot_id[slam.slot_used]) == [3, 11]  # the re-mapped landmark is landmark 3 again
    assert list(slam.retired_ids) == [4] and closer.merged == 1
    assert not closer.check(slam, slam._estimate(), 0)  # nothing left to merge


def test_the_loop_closure_is_off_by_default():
    import gymnasium as gym

    import rhs_env  # noqa: F401

    for kw, on in (({}, False), ({"loop_closure": {"enabled": False}}, False), ({"loop_closure": {"every_cycles": 2}}, True)):
        env = gym.make("rhs-racetrack-slam-v0", radar={"scan": {"grid_deg": 5}}, **kw)
        closer = env.get_wrapper_attr("pipeline").loop_closer
        assert (closer is not None) is on
        if on:
            assert closer.config.every_cycles == 2
        env.close()
    with pytest.raises(ValueError, match="loop_closure.every_cycles"):
        gym.make("rhs-racetrack-slam-v0", loop_closure={"every_cycles": 0})
