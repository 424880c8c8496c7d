"""Episodes as video: :class:`rhs_env.video.RecordEpisodeVideo` on any id, and ``rhs-slam demo --video``."""

from __future__ import annotations

import json
import sys

import gymnasium as gym
import numpy as np
import pytest
from PIL import Image

import rhs_env  # noqa: F401
from rhs_env import video
from rhs_env.video import RecordEpisodeVideo

SMALL = {"radar": {"scan": {"grid_deg": 5}}, "duration": 1}  # 5 steps at 5 Hz


def _drive(env, seed=0):
    env.reset(seed=seed)
    steps, done = 0, False
    while not done:
        *_, terminated, truncated, _ = env.step(1)
        steps += 1
        done = terminated or truncated
    return steps


@pytest.mark.parametrize("env_id", ["rhs-highway-v0", "rhs-highway-slam-v0"])
def test_the_wrapper_writes_a_gif_with_one_frame_per_step_and_the_strip(tmp_path, env_id):
    kwargs = {"duration": 1} if env_id == "rhs-highway-v0" else SMALL
    env = RecordEpisodeVideo(gym.make(env_id, render_mode="rgb_array", **kwargs), tmp_path / "ep.gif")
    frame_shape = None
    try:
        steps = _drive(env)
        frame_shape = env.env.render().shape
    finally:
        env.close()
    assert env.written == [tmp_path / "ep.gif"]
    with Image.open(tmp_path / "ep.gif") as im:
        assert im.n_frames == steps + 1 == 6  # the reset's frame and one per step
        assert im.width == frame_shape[1] and im.height > frame_shape[0]  # the strip sits below the road
        assert im.info["duration"] == 200  # 5 Hz: real time


def test_the_strip_shows_the_slam_health_and_error():
    info = {"speed": 25.0, "slam_health": 0.5, "position_error_m": 0.3, "slam_pose_std": [0.1, 0.0, 0.0],
            "slam_lost": True, "estimated_pose": [0, 0, 0], "radar_points_total": 3}
    line = video.status_line(info, 2.0, 10.0)
    assert "SLAM health 0.50" in line and "error 0.30 m (2-sigma 0.20 m)" in line and "LOST" in line
    assert [t for _, t in video.legend_for(info)] == [t for _, t in video.LEGEND]
    assert "SLAM trajectory + map" not in [t for _, t in video.legend_for({"speed": 1.0})]
    frame = np.zeros((40, 300, 3), np.uint8)
    with_bar = video.annotate(frame, info, 2.0, 10.0)
    without = video.annotate(frame, {"speed": 25.0}, 2.0, 10.0)
    assert with_bar.shape[0] > 40 and with_bar.shape[1] == 300
    assert not np.array_equal(with_bar[40:], without[40:])  # the health bar and text differ
    assert video.annotate(frame, info, 0.0, 0.0, scale=0.5).shape[1] == 150


def test_the_legend_colours_are_the_drawn_ones():
    from highway_env.vehicle.graphics import VehicleGraphics

    from rhs_env.envs import LANDMARK_COLOR
    from rhs_env.wrappers import POINT_COLOR
    from slam.gym.wrappers import EST_COLOR, TRUE_COLOR

    colours = {label: c for c, label in video.LEGEND}
    assert colours == {"radar points": POINT_COLOR, "landmarks": LANDMARK_COLOR, "true trajectory": TRUE_COLOR,
                       "SLAM trajectory + map": EST_COLOR, "ego car": VehicleGraphics.EGO_COLOR,
                       "other cars": VehicleGraphics.BLUE}


def test_every_and_further_episodes(tmp_path):
    env = RecordEpisodeVideo(gym.make("rhs-highway-v0", render_mode="rgb_array", duration=2), tmp_path / "e.gif",
                             every=2, scale=0.5)
    try:
        _drive(env, 0)
        _drive(env, 1)
    finally:
        env.close()
    assert env.written == [tmp_path / "e.gif", tmp_path / "e-1.gif"]
    for path in env.written:
        with Image.open(path) as im:
            assert im.n_frames == 1 + 5 and im.width == 300  # the reset's frame and steps 2, 4, ..., 10
            assert im.info["duration"] == 400


def test_bad_settings_are_clean_errors(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="render_mode='rgb_array'"):
        RecordEpisodeVideo(gym.make("rhs-highway-v0"), tmp_path / "x.gif")
    env = gym.make("rhs-highway-v0", render_mode="rgb_array")
    with pytest.raises(ValueError, match=r"must end in \.gif or \.mp4"):
        RecordEpisodeVideo(env, tmp_path / "x.avi")
    with pytest.raises(ValueError, match="every must be"):
        RecordEpisodeVideo(env, tmp_path / "x.gif", every=0)
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # not installed
    with pytest.raises(ValueError, match=r"imageio-ffmpeg.*\[video\]"):
        RecordEpisodeVideo(env, tmp_path / "x.mp4")
    env.close()


def test_mp4_has_the_frames(tmp_path):
    ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="MP4 needs the video extra (imageio-ffmpeg)")
    frames = [np.full((51, 77, 3), 20 * k, np.uint8) for k in range(7)]  # odd sides are padded to even
    video.write_video(tmp_path / "x.mp4", frames, fps=5)
    reader = ffmpeg.read_frames(str(tmp_path / "x.mp4"))
    meta = next(reader)
    assert meta["size"] == (78, 52) and len(list(reader)) == 7


def test_demo_writes_the_video(tmp_path, capsys):
    from rhs_slam.cli import main

    out = tmp_path / "demo"
    code = main(["demo", "--policy", "constant:1", "--env", "rhs-highway-slam-v0", "--env-kwargs", json.dumps(SMALL),
                 "--out", str(out), "--video", str(tmp_path / "v.gif")])
    assert code == 0
    summary = json.loads((out / "demo.json").read_text())
    assert summary["video"] == str(tmp_path / "v.gif")
    with Image.open(tmp_path / "v.gif") as im:
        assert im.n_frames == summary["steps"] + 1
    assert main(["demo", "--out", str(out), "--video", str(tmp_path / "v.webm")]) == 2
    assert "--video must end in .gif or .mp4" in capsys.readouterr().err


def test_the_front_page_video_script(tmp_path):
    from rhs_studies import make_video

    assert make_video.main(["--policy", "constant:1", "--env", "rhs-highway-slam-v0", "--seconds", "1",
                            "--out-dir", str(tmp_path)]) == 0
    record = json.loads((tmp_path / "episode_video.json").read_text())
    with Image.open(tmp_path / "episode.gif") as im:
        assert im.n_frames == record["frames"] == record["steps"] + 1 == 6
    assert record["bytes"] == (tmp_path / "episode.gif").stat().st_size < make_video.MAX_BYTES
    assert record["provenance"]["command"][1] == "scripts/make_video.py"
    assert make_video.main(["--seconds", "0.1", "--out-dir", str(tmp_path)]) == 2
