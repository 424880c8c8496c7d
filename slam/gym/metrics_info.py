"""Ground truth and SLAM errors in ``info``, apart from the observation.

:class:`SlamMetricsInfo` wraps a SLAM env (an env with a
:class:`slam.gym.wrappers.SlamObservation` inside), in the manner of gymnasium's
``RecordEpisodeStatistics``: it changes nothing but ``info``. Per step it adds
(all fixed-size, so vector envs can stack them):

* ``true_pose``, ``estimated_pose`` (3,): map frame (the start pose is the origin);
* ``position_error_m`` = ``||p_hat - p||``, ``heading_error_rad`` = ``|wrap(th_hat - th)|``;
* the map error against the true landmarks that have been within radar range
  so far (Hungarian matching within ``map_gate_m``): ``map_rmse_m`` (a float,
  and absent while nothing has matched: a value that is sometimes None and
  sometimes a float cannot be stacked by gymnasium's vector envs, and a NaN
  fails gymnasium's ``check_env`` determinism check, NaN != NaN; a vector env's
  ``info["_map_rmse_m"]`` mask says where it is defined), ``map_matched``, ``map_missed``, ``map_spurious``;
* ``registration_motion`` (3,): the registration's motion estimate of the cycle.

After a loss the filter may start a new map (``slam_map_breaks`` in ``info``): from then on
the truth is re-anchored so that it coincides with the estimate at the break, and
``position_error_m`` / ``heading_error_rad`` measure the error accumulated in the current map;
``position_error_episode_m`` keeps measuring against the episode's start (it counts the loss).

With ``landmarks_in_info=True`` (off by default: their number changes from
env to env, which vector envs cannot stack) ``info`` also gets
``true_landmarks`` and ``estimated_landmarks`` (map frame, variable length).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from rhs_common.geometry import compose, points_in_frame, relative_motion, wrap_angle
from rhs_common.validation import check_bool, check_range
from rhs_env.scene import get_landmarks, world_pose
from slam.core.metrics import map_metrics

__all__ = ["SlamMetricsInfo"]


class SlamMetricsInfo(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Adds the SLAM's ground truth and errors to ``info`` (see the module docstring).

    Args:
        env: an env wrapping a :class:`slam.gym.wrappers.SlamObservation`.
        map_gate_m: gate of the Hungarian map metric (m), > 0.
        landmarks_in_info: also add the variable-length true and estimated landmark arrays.

    Examples:
        >>> import gymnasium as gym, rhs_env
        >>> env = gym.make("rhs-highway-slam-v0", radar={"scan": {"grid_deg": 5}}, vehicles_count=3)
        >>> _, info = env.reset(seed=0)
        >>> info["position_error_m"], info["true_pose"].shape
        (0.0, (3,))
    """

    def __init__(self, env: gym.Env, map_gate_m: float = 2.0, landmarks_in_info: bool = False) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, map_gate_m=map_gate_m, landmarks_in_info=landmarks_in_info)
        gym.Wrapper.__init__(self, env)
        check_range("map_gate_m", map_gate_m, 0.0, 1e4, low_open=True)
        check_bool("landmarks_in_info", landmarks_in_info)
        self.map_gate_m = float(map_gate_m)
        self.landmarks_in_info = bool(landmarks_in_info)
        self.seen_ids: set[int] = set()
        self._seen_key: tuple | None = None  # (count, origin) of the cached map-frame positions of the seen landmarks
        self._seen_map = np.zeros((0, 2))
        self.anchor = np.zeros(3)  # the current map's truth: anchor (+) true pose (after a map break)
        self.breaks = 0

    @property
    def _base(self) -> Any:
        """The highway-env env underneath (its ``vehicle``, ``road``, ``config``: not in gymnasium's Env type)."""
        return self.env.unwrapped

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.seen_ids, self._seen_key = set(), None
        self.anchor, self.breaks = np.zeros(3), 0
        return obs, {**info, **self.metrics(int(info.get("slam_map_breaks", 0)))}

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, {**info, **self.metrics(int(info.get("slam_map_breaks", 0)))}

    def metrics(self, map_breaks: int = 0) -> dict[str, Any]:
        """Truth and errors of the current SLAM estimate (``map_breaks``: new maps the filter started so far)."""
        slam = self.env.get_wrapper_attr("pipeline")
        origin = self.env.get_wrapper_attr("origin")
        est = self.env.get_wrapper_attr("estimate")
        episode_pose = self.env.get_wrapper_attr("true_pose")()
        est_pose = np.asarray(est.pose, dtype=float)
        if map_breaks > self.breaks:  # a new map starts at the estimate: re-anchor the truth there
            self.anchor = compose(est_pose, relative_motion(episode_pose, np.zeros(3)))
            self.breaks = map_breaks
        true_pose = compose(self.anchor, episode_pose)
        true_lm = self._seen_landmarks(origin)
        est_lm, _ = slam.slam.full_map()
        mm = map_metrics(est_lm, true_lm, self.map_gate_m)
        err = est_pose - true_pose
        err_episode = est_pose - episode_pose
        rmse = mm["rmse"]
        out: dict[str, Any] = {
            "true_pose": true_pose,
            "estimated_pose": est_pose,
            "position_error_m": float(np.hypot(err[0], err[1])),
            "position_error_episode_m": float(np.hypot(err_episode[0], err_episode[1])),
            "heading_error_rad": float(abs(wrap_angle(err[2]))),
            "map_matched": int(mm["matched"]),
            "map_missed": int(mm["missed"]),
            "map_spurious": int(mm["spurious"]),
            "registration_motion": np.asarray(self.env.get_wrapper_attr("last_motion"), dtype=float),
        }
        if rmse is not None and np.isfinite(rmse):  # absent, not None or NaN, until a landmark matches
            out["map_rmse_m"] = float(rmse)
        if self.landmarks_in_info:
            out["true_landmarks"] = true_lm.copy()  # the cached array stays the wrapper's
            out["estimated_landmarks"] = est_lm
        return out

    def _seen_landmarks(self, origin: np.ndarray) -> np.ndarray:
        """True landmarks that have been within radar range so far, map frame (K, 2)."""
        base = self._base
        lms = get_landmarks(base)
        radar_cfg = self.env.get_wrapper_attr("radar_config")
        reach = float(getattr(radar_cfg, "max_range_m", 100.0))
        if len(lms):
            pose_w = world_pose(base.vehicle)
            self.seen_ids.update(lms.near(np.array([pose_w[0], -pose_w[1]]), reach).tolist())
        key = (len(self.seen_ids), *np.asarray(origin, dtype=float).tolist())
        if self._seen_key != key:  # the set only grows within an episode: recomputed when it did (or at a new origin)
            ids = np.array(sorted(self.seen_ids), dtype=int)
            self._seen_key, self._seen_map = key, points_in_frame(lms.xy_world[ids], origin)
        return self._seen_map
