"""A radar safety shield: vetoes the meta-actions that the radar points show to be unsafe.

A learned driver on radar points crashes mostly one decision late (``results/crash_analysis.md``):
it sees the car it hits (a few radar points on it) but changes lane into it, or brakes a second
too late, because it decides once a second. The shield runs at every env step (5 Hz), on the
observation alone (the actor's own input, no simulator state), and replaces an unsafe action:

* **Lane change** (LANE_LEFT / LANE_RIGHT) -> IDLE when a point in the target lane lies in the
  gap the change needs, ahead or behind, or when any point of it lies alongside the ego (see below);
* **Keeping on** (IDLE / FASTER) -> SLOWER when a point in the ego's path lies in the gap it
  needs at the present closing speed; FASTER -> IDLE when the gap would not hold after one
  target-speed step more (``speed_step_mps``). A SLOWER re-arms after ``rearm_steps`` env steps
  (any SLOWER the env received counts), so a braking shield steps the target speed down once
  per re-arm, as the driver's own SLOWER pulses do.

The gap an object needs is time-headway shaped, with every quantity from the radar:

    g = X - L_half  <  d + T * max(0, c)                                            (unsafe)

with ``X`` the object's along-road offset (m; ``|X|`` behind), ``L_half = ego_half_length_m`` (points lie
on the near face of the other car), ``c`` its closing speed (m/s, positive when the gap shrinks),
``d`` a standstill gap (m) and ``T`` a time gap (s): ``front_gap_m`` / ``front_time_s`` in the ego's
path, ``lane_gap_m`` / ``lane_time_s`` in a target lane.

Single radar points are not objects: the scans carry ghosts (points where no vehicle is, e.g. a roadside
post's echo placed at a wrong angle: 13 % of the scans have one in the ego's path within 40 m) and per-point
Doppler has heavy tails (8 % of the points on vehicles are off by more than 3 m/s; where a car ahead and a
post share a range, the joint angle-Doppler OMP can give the car the post's Doppler). So:

* an **object** is a point with at least ``min_points`` points (itself included) of the same region
  within ``cluster_m`` along the road; its closing speed is the median of ``-v_r`` over them;
* except **alongside** the ego (``|X| <= alongside_m`` in a target lane), where one point is enough: a car beside
  the ego shows the radars its flank, often as a single point, while a ghost there is rare (below: of 663 side-steps
  with a car beside the ego one lane over, 100 had exactly one point alongside and 399 two or more; of 3337 with
  none, 14 had a point there). A lane change into such a car was the commonest crash of the fastest PPO fine-tune
  behind the shield (``agents/data/rl/shield_explore.zip``: 3 of its 4 crashes on analysis seeds 5000-5059,
  inspected step by step, each with one point on the car it hit; with this rule 1 of 60); ``alongside_m = 0`` turns
  it off;
* a car in a target lane shows the radars its flank, so its points need not lie on its near end: with
  ``lane_body_m = b`` the gap of a target-lane object is ``|X| - L_half - b`` (``b`` up to a car's length, 5 m;
  0, the default, takes the points as the near end, as in the ego's path);
* the **leader** (the nearest object in the ego's path) is tracked: its gaps over the last
  ``track_steps`` env steps (``dt_s`` apart; a jump of more than ``track_jump_m`` starts a new track)
  give its closing speed as minus the least-squares slope, once three are there.

``python scripts/shield_sensing.py`` (:mod:`rhs_studies.shield_sensing`) measures these on 2000 env steps of
validation seeds against the simulator: the front rule alarmed where the truth did not in 170 steps from single
points, 76 from two-point objects and 79 from the tracked leader, and missed 20, 23 and 16 of the truth's alarms;
the tracked closing speed is within -1.5 / +1.9 m/s of the true one in 90 % of the steps with a leader within 40 m;
and the flank counts above.

Points go from the vehicle frame (x forward, y left) to road-aligned offsets with the SLAM
heading ``h`` (the map frame starts along the road): ``X = x cos h - y sin h``,
``Y = x sin h + y cos h``. The ego's path is ``|Y| < path_half_width_m``. Lanes come from the
SLAM lateral offset ``p_y`` (the episode starts on a lane centre, lanes ``w = lane_width_m`` apart):
the ego sits ``o = p_y - w round(p_y / w)`` left of its lane's centre, so a point lies ``Y + o``
left of that centre and in the left (right) lane when ``w/2 < Y + o < w/2 + band``
(``-w/2 - band < Y + o < -w/2``), ``band = lane_band_m``; the roadside posts stand beyond it.

Examples:
    >>> import numpy as np
    >>> shield = RadarShield()
    >>> car = np.array([[12.0, 0.3, -8.0, 1.0], [12.5, -0.4, -8.0, 1.0]])  # two points, closing at 8 m/s
    >>> obs = {"points": car, "points_mask": np.ones(2), "pose": np.zeros(3)}
    >>> shield.filter(obs, IDLE)    # 9.5 m gap: needs 4 + 1.2 * 8 = 13.6 m
    (4, 'front')
    >>> shield.filter(obs, LANE_LEFT)  # the left lane is empty: the change goes ahead
    (0, None)
    >>> shield.filter({**obs, "points_mask": np.array([1, 0])}, IDLE)  # one point is no object
    (1, None)
    >>> flank = np.array([[-0.5, 3.0, 1.0, 1.0]])  # one point on a car beside the ego, in the left lane
    >>> shield.filter({"points": flank, "points_mask": np.ones(1), "pose": np.zeros(3)}, LANE_LEFT)
    (1, 'lane')
"""

from __future__ import annotations

from collections import deque
from dataclasses import asdict, dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from agents.policies.decision import FASTER, IDLE, LANE_LEFT, LANE_RIGHT, SLOWER
from rhs_common.validation import build, check_int, check_range, check_types

__all__ = [
    "RadarShield", "ShieldAction", "ShieldConfig", "ShieldedPolicy", "check_shield_env", "nearest_object", "objects",
    "road_offsets", "shield_record",
]


@dataclass(frozen=True)
class ShieldConfig:
    """The gaps, objects and tracks of the module docstring (m, s, m/s)."""

    front_gap_m: float = 4.0  # d in the ego's path
    front_time_s: float = 1.2  # T in the ego's path
    lane_gap_m: float = 4.0  # d in a target lane, ahead and behind
    lane_time_s: float = 1.5  # T in a target lane
    ego_half_length_m: float = 2.5  # from the ego's centre to its bumper
    path_half_width_m: float = 1.8  # the ego's path: its half width 1 m + 0.8 m (points on a car one lane over
    # reach 1.9 m from the ego's axis in 1 % of the scans)
    lane_width_m: float = 4.0  # highway-env's lane width
    lane_band_m: float = 3.5  # how far past a lane line a target lane's points are looked for
    min_points: int = 2  # points that make an object
    cluster_m: float = 3.0  # along-road reach of an object's points
    alongside_m: float = 5.0  # |X| within which one point in a target lane blocks a lane change (0: off)
    lane_body_m: float = 0.0  # how far past a target-lane car's near end its points may lie (its flank), m
    track_steps: int = 5  # leader gaps in its closing-speed fit
    track_jump_m: float = 3.0  # a gap change that starts a new leader track
    dt_s: float = 0.2  # env step (the envs' 5 Hz)
    speed_step_mps: float = 5.0  # one FASTER's rise of the target speed (the env's target_speeds spacing)
    rearm_steps: int = 3  # env steps from one SLOWER to the next shield SLOWER (3 = 0.6 s at 5 Hz)

    def __post_init__(self) -> None:
        check_types(self)
        for name in ("front_gap_m", "lane_gap_m", "ego_half_length_m", "alongside_m", "lane_body_m"):
            check_range(name, getattr(self, name), 0.0, 100.0)
        for name in ("front_time_s", "lane_time_s"):
            check_range(name, getattr(self, name), 0.0, 10.0)
        for name in ("path_half_width_m", "lane_width_m", "lane_band_m", "cluster_m", "track_jump_m"):
            check_range(name, getattr(self, name), 0.0, 50.0, low_open=True)
        check_range("dt_s", self.dt_s, 0.0, 10.0, low_open=True)
        check_range("speed_step_mps", self.speed_step_mps, 0.0, 50.0)
        check_int("min_points", self.min_points, 1, 100)
        check_int("track_steps", self.track_steps, 3, 100)
        check_int("rearm_steps", self.rearm_steps, 1, 1000)


def road_offsets(obs: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The observed points' road-aligned offsets ``X``, ``Y`` (m), radial velocities (m/s), and the SLAM
    lateral offset ``p_y`` (m; see the module docstring). Without a ``pose`` key: heading and offset 0."""
    points = np.asarray(obs["points"], dtype=float)
    points = points[np.asarray(obs["points_mask"]) > 0]
    pose = np.asarray(obs.get("pose", np.zeros(3)), dtype=float)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    x, y = points[:, 0], points[:, 1]
    return x * c - y * s, x * s + y * c, points[:, 2], float(pose[1])


def objects(x: np.ndarray, closing: np.ndarray, min_points: int, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """The points of one region (along-road offsets ``x``, m) that have at least ``min_points`` points within
    ``reach`` m (themselves included), and each one's median closing speed over those points (m/s).

    >>> objects(np.array([10.0, 11.0, 30.0]), np.array([2.0, 4.0, 9.0]), 2, 3.0)
    (array([10., 11.]), array([3., 3.]))
    """
    near = np.abs(x[:, None] - x[None, :]) <= reach
    keep = near.sum(axis=1) >= min_points
    if not keep.any():
        return x[:0], closing[:0]
    return x[keep], np.nanmedian(np.where(near[keep], closing[None, :], np.nan), axis=1)


def nearest_object(x: np.ndarray, closing: np.ndarray, min_points: int, reach: float,
                   half_length: float) -> tuple[float, float] | None:
    """The gap ``min(X) - half_length`` (m) to the nearest of :func:`objects` and its median closing speed (m/s),
    or None when the points hold no object."""
    xs, cs = objects(x, closing, min_points, reach)
    if len(xs) == 0:
        return None
    i = int(np.argmin(xs))
    return float(xs[i]) - half_length, float(cs[i])


class RadarShield:
    """The shield of the module docstring, one episode at a time: :meth:`reset`, then :meth:`filter` each step."""

    def __init__(self, config: ShieldConfig | dict[str, Any] | None = None):
        self.config = build(ShieldConfig, config, "shield")
        self.reset()

    def reset(self) -> None:
        """A new episode: no leader track, the next SLOWER armed, the override counts at 0."""
        self.since_slower = self.config.rearm_steps  # env steps since the last SLOWER sent
        self.track: deque[float] = deque(maxlen=self.config.track_steps)
        self.overrides = {"front": 0, "faster": 0, "lane": 0}

    def leader(self, x: np.ndarray, closing: np.ndarray) -> tuple[float, float] | None:
        """The leader's gap (m) and closing speed (m/s) from the path's points (``x`` m, Doppler ``closing``
        m/s), the track updated; None (and the track dropped) when the path holds no object."""
        cfg = self.config
        nearest = nearest_object(x, closing, cfg.min_points, cfg.cluster_m, cfg.ego_half_length_m)
        if nearest is None:
            self.track.clear()
            return None
        gap, doppler = nearest
        if self.track and abs(gap - self.track[-1]) > cfg.track_jump_m:
            self.track.clear()
        self.track.append(gap)
        if len(self.track) < 3:
            return gap, doppler
        t = cfg.dt_s * np.arange(len(self.track))
        return gap, -float(np.polyfit(t, np.asarray(self.track), 1)[0])

    def _lane_blocked(self, big_x: np.ndarray, closing: np.ndarray) -> bool:
        cfg = self.config
        if cfg.alongside_m > 0 and np.any(np.abs(big_x) <= cfg.alongside_m):  # one point beside the ego: its flank
            return True
        xs, cs = objects(big_x, closing, cfg.min_points, cfg.cluster_m)
        gap = np.abs(xs) - cfg.ego_half_length_m - cfg.lane_body_m
        return bool(np.any(gap < cfg.lane_gap_m + cfg.lane_time_s * np.maximum(cs, 0.0)))

    def filter(self, obs: dict[str, np.ndarray], action: int) -> tuple[int, str | None]:
        """The action to send for ``action`` in ``obs``, and why it was replaced (``"lane"``, ``"faster"``,
        ``"front"``) or None. Call once per env step: it tracks the leader and counts the steps since a SLOWER."""
        cfg = self.config
        self.since_slower += 1
        big_x, big_y, v_r, p_y = road_offsets(obs)
        closing = -v_r  # the range shrinks: ahead a slower car, behind a faster one
        reason = None
        path = (big_x > 0) & (np.abs(big_y) < cfg.path_half_width_m)
        lead = self.leader(big_x[path], closing[path])
        if action in (LANE_LEFT, LANE_RIGHT):
            w = cfg.lane_width_m
            lateral = (big_y + (p_y - w * np.round(p_y / w))) * (1.0 if action == LANE_LEFT else -1.0)
            in_lane = (lateral > w / 2) & (lateral < w / 2 + cfg.lane_band_m)
            if self._lane_blocked(big_x[in_lane], closing[in_lane]):
                action, reason = IDLE, "lane"
        if lead is not None:
            gap, c = lead
            if action == FASTER and gap < cfg.front_gap_m + cfg.front_time_s * max(c + cfg.speed_step_mps, 0.0):
                action, reason = IDLE, "faster"
            if (action in (IDLE, FASTER) and self.since_slower >= cfg.rearm_steps
                    and gap < cfg.front_gap_m + cfg.front_time_s * max(c, 0.0)):
                action, reason = SLOWER, "front"
        if action == SLOWER:
            self.since_slower = 0
        if reason is not None:
            self.overrides[reason] += 1
        return action, reason


class ShieldedPolicy:
    """A policy (``predict(obs, deterministic)``) whose every action goes through a :class:`RadarShield`.

    Wrap it outside :class:`agents.policies.decision.HeldPolicy`, so the steps between decisions are shielded
    too. :func:`agents.evaluate.run_episode` calls :meth:`reset` at each episode start.

    Examples:
        >>> import numpy as np
        >>> class Faster:
        ...     def predict(self, obs, deterministic=True):
        ...         return FASTER, None
        >>> policy = ShieldedPolicy(Faster())
        >>> far = {"points": np.array([[60.0, 0.0, -1.0, 1.0]] * 2), "points_mask": np.ones(2), "pose": np.zeros(3)}
        >>> near = {**far, "points": np.array([[9.0, 0.0, -3.0, 1.0]] * 2)}  # 6.5 m gap, needs 4 + 1.2 * 3 = 7.6 m
        >>> [policy.predict(o)[0] for o in (far, near, near)], policy.shield.overrides  # SLOWER re-arms in 3 steps
        ([3, 4, 1], {'front': 1, 'faster': 1, 'lane': 0})
    """

    def __init__(self, model, config: ShieldConfig | dict[str, Any] | None = None):
        self.model = model
        self.shield = RadarShield(config)

    def reset(self) -> None:
        self.shield.reset()
        if hasattr(self.model, "reset"):
            self.model.reset()

    def predict(self, obs, *args, **kwargs):
        action, state = self.model.predict(obs, *args, **kwargs)
        return self.shield.filter(obs, int(np.asarray(action).reshape(-1)[0]))[0], state

    def __getattr__(self, name):
        return getattr(self.model, name)


class ShieldAction(gym.Wrapper):
    """The shield inside an env (for training under it): each step's action is filtered on the last observation;
    ``info["shield"]`` is the reason of a replacement or None. Wrap it inside :class:`agents.policies.decision.HoldAction`.

    Examples:
        >>> import gymnasium as gym, rhs_env
        >>> env = ShieldAction(gym.make("rhs-highway-radar-v0", vehicles_count=5))
        >>> _ = env.reset(seed=0)
        >>> _, _, _, _, info = env.step(IDLE)
        >>> info["shield"] in (None, "front")
        True
    """

    def __init__(self, env: gym.Env, config: ShieldConfig | dict[str, Any] | None = None):
        super().__init__(env)
        check_shield_env(env.observation_space)
        self.shield = RadarShield(config)
        self._obs: dict[str, np.ndarray] | None = None

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.shield.reset()
        self._obs = obs
        return obs, info

    def step(self, action):
        reason = None
        if self._obs is not None:
            action, reason = self.shield.filter(self._obs, int(np.asarray(action).reshape(-1)[0]))
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._obs = obs
        return obs, reward, terminated, truncated, {**info, "shield": reason}


def check_shield_env(space: gym.Space) -> None:
    """``ValueError`` unless the observation ``space`` has the radar's ``points`` and ``points_mask``."""
    keys = getattr(space, "spaces", {})
    if "points" not in keys or "points_mask" not in keys:
        raise ValueError("the radar shield needs the radar envs' 'points' and 'points_mask' observation "
                         "(rhs-highway-radar-v0, rhs-highway-slam-v0, ...); this env has none")


def shield_record(config: ShieldConfig | dict[str, Any] | None) -> dict[str, Any] | None:
    """A shield entry (a config, or a YAML / JSON dict of its fields, validated: errors name ``shield.<field>``) as
    the record beside a policy keeps it, every field named; None for no shield."""
    return None if config is None else asdict(build(ShieldConfig, config, "shield"))
