"""Record a SLAM env's estimated and true trajectories per episode, as TUM / KITTI files for ``evo``.

:class:`TrajectoryRecorder` wraps an env whose ``info`` has ``true_pose`` and ``estimated_pose``
(:class:`slam.gym.metrics_info.SlamMetricsInfo`, which every ``rhs-*-slam`` id includes) and, at the end of
each episode (terminated, truncated, or a reset or close before the end), writes
``<prefix>_<episode>_est.tum`` and ``<prefix>_<episode>_gt.tum`` (and ``.kitti``), through
:func:`slam.core.trajectory_formats.write_trajectory_pair`.

The poses are those of the steps (the reset's is the origin of both), the cycles over which
``rhs-slam evaluate`` computes its ``position_rmse_m``: ``evo_ape`` on the pair without alignment gives
that RMSE. The time of a pose is the env's simulated time (highway-env's ``env.unwrapped.time``: one
policy period per step), not the wall clock. The true pose is in the current map's frame, re-anchored at a
map break after a loss as ``info["true_pose"]`` is (``info["slam_map_breaks"]`` counts them).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from rhs_common.validation import check_output_path
from slam.core.trajectory_formats import FORMATS, write_trajectory_pair

#: the ``info`` keys the recorder reads (added by :class:`slam.gym.metrics_info.SlamMetricsInfo`)
EST_KEY = "estimated_pose"
TRUE_KEY = "true_pose"


def sim_time(env: gym.Env, steps: int) -> float:
    """The env's simulated time (s) after ``steps`` steps: highway-env's ``time``, else ``steps`` policy periods."""
    base: Any = env.unwrapped
    t = getattr(base, "time", None)
    if isinstance(t, (int, float, np.floating)) and np.isfinite(t):
        return float(t)
    config = getattr(base, "config", None)
    freq = config.get("policy_frequency") if isinstance(config, dict) else None
    return steps / float(freq) if freq else float(steps)


class TrajectoryRecorder(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Writes each episode's estimated and true trajectory (see the module docstring).

    Args:
        env: an env whose ``info`` has ``true_pose`` and ``estimated_pose`` (3,) each step.
        directory: output folder (created).
        formats: some of ``("tum", "kitti")``.
        prefix: file name prefix; the files are ``<prefix>_<episode:04d>_{est,gt}.<format>`` (the copies of a
            vector env need a prefix or a directory each, or they write the same names).

    Attributes:
        paths: every file written so far.

    Example:
        >>> import gymnasium as gym, rhs_env, tempfile
        >>> from slam.gym.trajectory import TrajectoryRecorder
        >>> env = gym.make("rhs-highway-slam-v0", radar={"scan": {"grid_deg": 5}}, vehicles_count=3)
        >>> env = TrajectoryRecorder(env, tempfile.mkdtemp(), formats=("tum", "kitti"))
        >>> _ = env.reset(seed=0)
        >>> for _ in range(3):
        ...     _ = env.step(1)
        >>> env.close()
        >>> sorted(p.name for p in env.paths)
        ['episode_0000_est.kitti', 'episode_0000_est.tum', 'episode_0000_gt.kitti', 'episode_0000_gt.tum']
    """

    def __init__(self, env: gym.Env, directory: str | Path, formats: Sequence[str] = ("tum",), prefix: str = "episode") -> None:
        gym.utils.RecordConstructorArgs.__init__(self, directory=str(directory), formats=tuple(formats), prefix=prefix)
        gym.Wrapper.__init__(self, env)
        if isinstance(formats, str) or not formats or any(f not in FORMATS for f in formats):
            raise ValueError(f"formats must be a non-empty sequence of {', '.join(FORMATS)}, got {formats!r}")
        if not isinstance(prefix, str) or not prefix or any(c in prefix for c in "/\\"):
            raise ValueError(f"prefix must be a non-empty file name without a path separator, got {prefix!r}")
        check_output_path("directory", directory, directory=True)
        self.directory = Path(directory)
        self.formats = tuple(formats)
        self.prefix = prefix
        self.episode = -1
        self.paths: list[Path] = []
        self._clear()

    def _clear(self) -> None:
        self.times: list[float] = []
        self.estimated: list[np.ndarray] = []
        self.true: list[np.ndarray] = []

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        self.flush()
        obs, info = self.env.reset(seed=seed, options=options)
        self.episode += 1
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if EST_KEY not in info or TRUE_KEY not in info:
            raise KeyError(f"TrajectoryRecorder needs info[{EST_KEY!r}] and info[{TRUE_KEY!r}]: wrap the SLAM env in "
                           "slam.gym.metrics_info.SlamMetricsInfo (the rhs-*-slam ids include it)")
        self.times.append(sim_time(self.env, len(self.times) + 1))
        self.estimated.append(np.asarray(info[EST_KEY], dtype=float).reshape(3))
        self.true.append(np.asarray(info[TRUE_KEY], dtype=float).reshape(3))
        if terminated or truncated:
            self.flush()
        return obs, reward, terminated, truncated, info

    def flush(self) -> list[Path]:
        """Write the episode recorded so far (nothing when it has no step); returns the paths written."""
        if not self.times:
            return []
        paths = write_trajectory_pair(self.directory, f"{self.prefix}_{max(self.episode, 0):04d}",
                                      np.asarray(self.times), np.stack(self.estimated), np.stack(self.true), self.formats)
        self.paths.extend(paths)
        self._clear()
        return paths

    def close(self) -> None:
        self.flush()
        super().close()
