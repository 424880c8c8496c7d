"""Privileged ground truth for a critic: the true road state around the ego, as one vector.

An asymmetric actor-critic (Pinto et al., 2018, "Asymmetric Actor Critic for
Image-Based Robot Learning") trains an actor on the sensor observation and a
critic that may also read the simulator's state: the critic is thrown away after
training, so the deployed policy still needs only its sensors. Here the actor
sees the env's observation (radar points and the SLAM estimate) and the critic
also sees :data:`PRIVILEGED_KEY`, the vector :func:`privileged_features` builds:

* the ego: speed / V, its target-speed index / (n - 1), its lane / (lanes - 1);
* for the own lane and the lanes left and right of it (``lane_exists`` 0 where
  there is none): the bumper gap to the leader and to the follower,
  ``min(g, G) / G``, and their speeds relative to the ego, ``clip(dv / V, -1, 1)``;
* the time left in the episode, ``1 - t / duration``;
* the headway expert's action there (one-hot, :class:`agents.policies.expert.HeadwayDriver`).

with ``V`` = :data:`SPEED_SCALE_MPS` and ``G`` = :data:`GAP_SCALE_M`. A lane with
no leader (follower) within ``G`` reads gap 1 and relative speed 0.

:class:`PrivilegedObservation` adds the vector to a Dict observation under
:data:`PRIVILEGED_KEY`; :func:`without_privileged` is the actor's view of the space.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from agents.policies.expert import HeadwayDriver, bumper_gap

__all__ = [
    "GAP_SCALE_M", "LANE_FEATURES", "N_ACTIONS", "PRIVILEGED_DIM", "PRIVILEGED_KEY", "PrivilegedObservation",
    "SPEED_SCALE_MPS", "privileged_features", "without_privileged",
]

#: the observation key the critic reads and the actor never sees
PRIVILEGED_KEY = "privileged"
#: speed scale V of the features, m/s (highway-env's top target speed)
SPEED_SCALE_MPS = 30.0
#: gap scale G of the features, m (the headway expert's lookahead is 60 m)
GAP_SCALE_M = 100.0
#: per lane: exists, leader gap, leader relative speed, follower gap, follower relative speed
LANE_FEATURES = 5
#: the meta-actions (highway-env's DiscreteMetaAction: LANE_LEFT, IDLE, LANE_RIGHT, FASTER, SLOWER)
N_ACTIONS = 5
#: length of :func:`privileged_features`: ego (3) + 3 lanes + time left (1) + expert action (one-hot)
PRIVILEGED_DIM = 3 + 3 * LANE_FEATURES + 1 + N_ACTIONS


def _lane_features(road, ego, lane_index) -> list[float]:
    """[exists, leader gap, leader dv, follower gap, follower dv] of ``lane_index`` (zeros where there is no lane)."""
    if lane_index is None:
        return [0.0] * LANE_FEATURES
    front, rear = road.neighbour_vehicles(ego, lane_index)
    out = [1.0]
    for other in (front, rear):
        if other is None:
            out += [1.0, 0.0]
        else:
            out += [min(max(bumper_gap(ego, other), 0.0), GAP_SCALE_M) / GAP_SCALE_M,
                    float(np.clip((other.speed - ego.speed) / SPEED_SCALE_MPS, -1.0, 1.0))]
    return out


def _side_lanes(road, lane_index) -> tuple[Any, Any]:
    """The lane indices left and right of ``lane_index`` on the same road segment (None where there is none)."""
    left = right = None
    for side in road.network.side_lanes(lane_index):
        if side[2] < lane_index[2]:
            left = side
        elif side[2] > lane_index[2]:
            right = side
    return left, right


def privileged_features(env: gym.Env, expert: HeadwayDriver | None = None) -> np.ndarray:
    """The critic's ground-truth vector of the module docstring (float32, length :data:`PRIVILEGED_DIM`).

    Examples:
        >>> import gymnasium as gym, rhs_env
        >>> env = gym.make("rhs-highway-v0")
        >>> _ = env.reset(seed=0)
        >>> v = privileged_features(env)
        >>> v.shape, bool(((v >= -1) & (v <= 1)).all())
        ((24,), True)
    """
    base: Any = env.unwrapped
    expert = expert if expert is not None else HeadwayDriver(env)
    ego, road = base.vehicle, base.road
    speeds = np.asarray(getattr(ego, "target_speeds", [SPEED_SCALE_MPS]), dtype=float)
    lanes = road.network.graph[ego.lane_index[0]][ego.lane_index[1]]
    own = ego.lane_index
    left, right = _side_lanes(road, own)
    features = [
        float(np.clip(ego.speed / SPEED_SCALE_MPS, -1.0, 1.0)),
        float(getattr(ego, "speed_index", 0)) / max(1, len(speeds) - 1),
        own[2] / max(1, len(lanes) - 1),
    ]
    for lane in (own, left, right):
        features += _lane_features(road, ego, lane)
    duration = float(base.config.get("duration", 0) or 0)
    features.append(float(np.clip(1.0 - base.time / duration, 0.0, 1.0)) if duration > 0 else 0.0)
    action = np.zeros(N_ACTIONS)
    action[expert.act()] = 1.0
    return np.asarray(features + action.tolist(), dtype=np.float32)


def without_privileged(space: gym.spaces.Dict) -> gym.spaces.Dict:
    """``space`` without :data:`PRIVILEGED_KEY`: what the actor sees."""
    return gym.spaces.Dict({k: v for k, v in space.spaces.items() if k != PRIVILEGED_KEY})


class PrivilegedObservation(gym.ObservationWrapper):
    """Add :func:`privileged_features` to a Dict observation under :data:`PRIVILEGED_KEY` (for a critic).

    Examples:
        >>> import gymnasium as gym, rhs_env
        >>> env = PrivilegedObservation(gym.make("rhs-highway-radar-v0", radar={"scan": {"grid_deg": 5}}))
        >>> obs, _ = env.reset(seed=0)
        >>> obs[PRIVILEGED_KEY].shape, PRIVILEGED_KEY in env.observation_space.spaces
        ((24,), True)
    """

    def __init__(self, env: gym.Env, expert: dict[str, Any] | None = None):
        super().__init__(env)
        if not isinstance(env.observation_space, gym.spaces.Dict):
            raise ValueError(f"PrivilegedObservation needs a Dict observation space, got {env.observation_space}")  # noqa: TRY004
        if PRIVILEGED_KEY in env.observation_space.spaces:
            raise ValueError(f"the observation already has a {PRIVILEGED_KEY!r} key")
        self.expert = HeadwayDriver(env, expert)
        box = gym.spaces.Box(-1.0, 1.0, shape=(PRIVILEGED_DIM,), dtype=np.float32)
        self.observation_space = gym.spaces.Dict({**env.observation_space.spaces, PRIVILEGED_KEY: box})

    def observation(self, observation):
        return {**observation, PRIVILEGED_KEY: privileged_features(self.env, self.expert)}

