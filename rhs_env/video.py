"""Episodes as video: :class:`RecordEpisodeVideo` writes what an env renders, with a status strip, as GIF or MP4.

Works on every id of the project (and any env rendering ``rgb_array`` frames): the frames are the env's
own ``render()``, which on the radar ids already has the radar points drawn over the road
(:meth:`rhs_env.wrappers.RadarObservation.render`) and on the SLAM ids also the true and estimated
trajectory and the estimated map (:meth:`slam.gym.wrappers.SlamObservation.render`). Below each frame
the wrapper adds a white strip (never over the road) with a colour legend of those layers and one
status line read from the step's ``info``: time, return so far, speed and, where the info has them,
the SLAM track health (a bar from red, 0, to green, 1), the position error against the filter's own
2-sigma (``slam_pose_std``) and ``LOST`` while the filter says it has lost the car.

The file is written when the episode ends (``terminated`` / ``truncated``) or at ``close``; a second
episode goes to ``NAME-1.gif``, the next to ``NAME-2.gif`` and so on (``written`` lists them). The
suffix chooses the format: ``.gif`` needs only pillow (installed with matplotlib); ``.mp4`` needs
``imageio-ffmpeg`` (the ``video`` extra, which ships an ffmpeg binary), checked when the wrapper is made.

Examples:
    >>> import gymnasium as gym, rhs_env, tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "episode.gif"
    >>> env = RecordEpisodeVideo(gym.make("rhs-highway-v0", render_mode="rgb_array", duration=1), out)
    >>> _ = env.reset(seed=0)
    >>> done = False
    >>> while not done:
    ...     *_, terminated, truncated, _ = env.step(1)
    ...     done = terminated or truncated
    >>> env.close()
    >>> from PIL import Image
    >>> Image.open(out).n_frames  # the reset's frame and one per step
    6
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from rhs_common.validation import check_int, check_range

__all__ = ["FORMATS", "LEGEND", "RADAR_LABELS", "SLAM_LABELS", "VIDEO_HINT", "RecordEpisodeVideo", "annotate",
           "check_video_path", "legend_for", "status_line", "write_video"]

#: what the frames show, colour -> label (rhs_env.wrappers.POINT_COLOR, rhs_env.envs.LANDMARK_COLOR,
#: slam.gym.wrappers.TRUE_COLOR and EST_COLOR, highway-env's ego and IDM vehicles; tests/test_video.py checks them)
LEGEND: tuple[tuple[tuple[int, int, int], str], ...] = (
    ((255, 40, 40), "radar points"),
    ((60, 220, 60), "landmarks"),
    ((30, 30, 30), "true trajectory"),
    ((255, 140, 0), "SLAM trajectory + map"),
    ((50, 200, 0), "ego car"),
    ((100, 200, 255), "other cars"),
)
#: labels shown only where the env has a SLAM estimate (info["estimated_pose"]) / radar points (info["radar_points_total"])
SLAM_LABELS = ("true trajectory", "SLAM trajectory + map")
RADAR_LABELS = ("radar points",)
FORMATS = (".gif", ".mp4")
VIDEO_HINT = 'MP4 needs imageio-ffmpeg: pip install -c constraints/base.txt -e ".[video]" (or write a .gif)'


def check_video_path(field: str, path: str | Path) -> Path:
    """``path`` as a Path when its suffix is a known format (and MP4's writer is installed), else ``ValueError``.

    Args:
        field: the flag or argument named in the error (``--video``).
        path: the output file, ``.gif`` or ``.mp4``.

    Returns:
        The path.
    """
    p = Path(path)
    if p.suffix.lower() not in FORMATS:
        raise ValueError(f"{field} must end in .gif or .mp4, got {str(path)!r}")
    if p.exists() and p.is_dir():
        raise ValueError(f"{field} {str(path)!r} is a directory; give a file name ending in .gif or .mp4")
    if p.suffix.lower() == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ValueError(f"{field}: {VIDEO_HINT}") from None
    return p


def legend_for(info: dict[str, Any]) -> tuple[tuple[tuple[int, int, int], str], ...]:
    """The :data:`LEGEND` entries of the layers an env with this ``info`` draws (no SLAM or radar entries without them)."""
    hidden = (() if "estimated_pose" in info else SLAM_LABELS) + (() if "radar_points_total" in info else RADAR_LABELS)
    return tuple(e for e in LEGEND if e[1] not in hidden)


def status_line(info: dict[str, Any], t_s: float, total: float) -> str:
    """The strip's status text of one frame (time, return, speed and the SLAM health where ``info`` has it)."""
    parts = [f"t {t_s:5.1f} s", f"return {total:6.1f}"]
    if "speed" in info:
        parts.append(f"speed {float(info['speed']):4.1f} m/s")
    if "slam_health" in info:
        parts.append(f"SLAM health {float(info['slam_health']):.2f}")
    if "position_error_m" in info:
        err = f"error {float(info['position_error_m']):.2f} m"
        if "slam_pose_std" in info:
            err += f" (2-sigma {2.0 * float(np.hypot(*np.asarray(info['slam_pose_std'], float)[:2])):.2f} m)"
        parts.append(err)
    if bool(info.get("slam_lost", False)):
        parts.append("LOST")
    if bool(info.get("crashed", False)):
        parts.append("CRASHED")
    return "   ".join(parts)


def annotate(frame: np.ndarray, info: dict[str, Any], t_s: float, total: float,
             legend: Sequence[tuple[tuple[int, int, int], str]] = LEGEND, scale: float = 1.0) -> np.ndarray:
    """``frame`` (H, W, 3) with the legend and status strip below it, resized by ``scale``; uint8 (H', W', 3)."""
    from PIL import Image, ImageDraw

    image = Image.fromarray(np.asarray(frame, dtype=np.uint8))
    if scale != 1.0:
        image = image.resize((max(2, round(image.width * scale)), max(2, round(image.height * scale))), Image.Resampling.LANCZOS)
    w, h = image.size
    row_h, per_row = 14, max(1, w // 130)
    legend_rows = -(-len(legend) // per_row)
    out = Image.new("RGB", (w, h + (legend_rows + 1) * row_h + 8), "white")
    out.paste(image.convert("RGB"), (0, 0))
    draw = ImageDraw.Draw(out)
    for k, (color, text) in enumerate(legend):
        x, y = 6 + (k % per_row) * (w // per_row), h + 3 + (k // per_row) * row_h
        draw.ellipse([x, y + 2, x + 8, y + 10], fill=tuple(color))
        draw.text((x + 12, y), text, fill=(0, 0, 0))
    y = h + 5 + legend_rows * row_h
    x = 6
    if "slam_health" in info:  # a bar from red (0) to green (1)
        health = float(np.clip(float(info["slam_health"]), 0.0, 1.0))
        color = (round(255 * (1 - health)), round(190 * health), 40)
        draw.rectangle([x, y + 2, x + 40, y + 10], outline=(90, 90, 90))
        draw.rectangle([x, y + 2, x + round(40 * health), y + 10], fill=color)
        x += 48
    draw.text((x, y), status_line(info, t_s, total), fill=(0, 0, 0))
    return np.asarray(out)


def write_video(path: str | Path, frames: Sequence[np.ndarray], fps: float) -> Path:
    """Write ``frames`` (uint8 (H, W, 3), equal sizes) to ``path``: GIF (pillow, looping) or MP4 (imageio-ffmpeg).

    Args:
        path: ``.gif`` or ``.mp4`` file.
        frames: at least one frame.
        fps: frames per second.

    Returns:
        The path written.
    """
    from PIL import Image

    path = check_video_path("path", path)
    if not frames:
        raise ValueError("write_video needs at least one frame")
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        images = [Image.fromarray(np.asarray(f, dtype=np.uint8)).convert("RGB") for f in frames]
        # one palette for all frames (the first frame's colours plus the overlays'): smaller and no flicker
        palette = images[0].quantize(colors=128, method=Image.Quantize.MEDIANCUT)
        paletted = [im.quantize(palette=palette, dither=Image.Dither.NONE) for im in images]
        duration = max(20, round(1000.0 / fps))
        paletted[0].save(path, save_all=True, append_images=paletted[1:], duration=duration, loop=0, optimize=True)
        return path
    import imageio_ffmpeg

    h, w = np.asarray(frames[0]).shape[:2]
    H, W = h + h % 2, w + w % 2  # yuv420p needs even sides
    writer = imageio_ffmpeg.write_frames(str(path), (W, H), fps=fps, macro_block_size=1, ffmpeg_log_level="error")
    writer.send(None)
    for f in frames:
        padded = np.full((H, W, 3), 255, dtype=np.uint8)
        padded[:h, :w] = np.asarray(f, dtype=np.uint8)
        writer.send(np.ascontiguousarray(padded))
    writer.close()
    return path


class RecordEpisodeVideo(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Record each episode's rendered frames (with the legend and status strip) to a GIF or MP4.

    Args:
        env: an env made with ``render_mode="rgb_array"``.
        path: the output file, ``.gif`` or ``.mp4``; later episodes go to ``NAME-1``, ``NAME-2``, ...
        fps: frame rate (default: the env's ``policy_frequency``, else its ``render_fps``, else 5: real time).
        every: keep every k-th step's frame (the reset's frame is always kept), [1, 1000].
        max_frames: at most this many frames per episode (the first ones), [1, 100000].
        scale: resize factor of the env's frames, (0, 4] (0.5 halves width and height).
        overlay: add the legend and status strip (False: the env's frames as they are).
    """

    def __init__(self, env: gym.Env, path: str | Path, fps: float | None = None, every: int = 1,
                 max_frames: int = 10_000, scale: float = 1.0, overlay: bool = True) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, path=str(path), fps=fps, every=every, max_frames=max_frames,
                                                 scale=scale, overlay=overlay)
        super().__init__(env)
        if env.render_mode != "rgb_array":
            raise ValueError(f"RecordEpisodeVideo needs an env made with render_mode='rgb_array' "
                             f"(gym.make(id, render_mode='rgb_array')), got render_mode={env.render_mode!r}")
        self.path = check_video_path("path", path)
        check_int("every", every, 1, 1000)
        check_int("max_frames", max_frames, 1, 100_000)
        check_range("scale", scale, 0.0, 4.0, low_open=True)
        self.fps = float(fps) if fps is not None else self._env_fps()
        check_range("fps", self.fps, 0.1, 100.0)
        self.every, self.max_frames, self.scale, self.overlay = int(every), int(max_frames), float(scale), bool(overlay)
        self.frames: list[np.ndarray] = []
        self.written: list[Path] = []
        self._episode = 0
        self._steps = 0
        self._total = 0.0

    def _env_fps(self) -> float:
        cfg = getattr(self.env.unwrapped, "config", None) or {}
        return float(cfg.get("policy_frequency") or self.env.metadata.get("render_fps") or 5.0)

    def _capture(self, info: dict[str, Any]) -> None:
        if len(self.frames) >= self.max_frames:
            return
        frame = self.env.render()
        if not isinstance(frame, np.ndarray) or frame.ndim != 3:
            return
        if not self.overlay:
            self.frames.append(np.asarray(frame, dtype=np.uint8))
            return
        legend = legend_for(info)
        self.frames.append(annotate(frame, info, self._steps / self.fps, self._total, legend, self.scale))

    def _episode_path(self) -> Path:
        k = self._episode
        return self.path if k == 0 else self.path.with_name(f"{self.path.stem}-{k}{self.path.suffix}")

    def flush(self) -> Path | None:
        """Write the frames of the episode so far (if any) and start a new file; the path written, or None."""
        if not self.frames:
            return None
        path = write_video(self._episode_path(), self.frames, self.fps / self.every)
        self.written.append(path)
        self.frames = []
        self._episode += 1
        return path

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        self.flush()
        obs, info = self.env.reset(seed=seed, options=options)
        self._steps, self._total = 0, 0.0
        self._capture(info)
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._steps += 1
        self._total += float(reward)
        if self._steps % self.every == 0 or terminated or truncated:
            self._capture(info)
        if terminated or truncated:
            self.flush()
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        try:
            self.flush()
        finally:
            super().close()
