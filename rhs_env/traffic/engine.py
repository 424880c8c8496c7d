"""The compiled traffic of one env: packs highway-env's scene, runs :func:`rhs_env.traffic.core.simulate`, writes back.

:class:`CompiledTraffic` replaces ``AbstractEnv._simulate`` and ``HighwayEnv._reward`` of an env made with
``sim="compiled"``. highway-env builds the scene at reset; the first step after it (or after the vehicle list,
the controlled vehicle or the road changed: :func:`rhs_env.traffic.state.scene_key`) packs it into arrays, and
every step writes the arrays back into the vehicle objects (:func:`rhs_env.traffic.sync.write_back`), so that the
observation, ``info``, rendering, the radar's scatterers and a user's ``env.unwrapped.road`` read the stepped
state. Edits to a vehicle's attributes between steps are not read back (add, remove or replace the vehicle
instead: that repacks).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rhs_env.traffic import core
from rhs_env.traffic.state import TrafficState, pack, scene_key, unsupported
from rhs_env.traffic.sync import write_back

__all__ = ["CompiledTraffic", "SIMS", "UnsupportedScene"]

#: the values of the ``sim`` config key: highway-env's own Python (the reference) or the compiled core
SIMS = ("highway-env", "compiled")


class UnsupportedScene(ValueError):
    """The scene uses highway-env features the compiled core does not port (use ``sim="highway-env"``)."""


class CompiledTraffic:
    """Steps an env's traffic with the compiled core (see the module docstring)."""

    def __init__(self) -> None:
        self.state: TrafficState | None = None

    def _state(self, env: Any) -> TrafficState:
        controlled = env.action_type.controlled_vehicle
        if self.state is None or self.state.key != scene_key(env.road, controlled):
            why = unsupported(env.road, controlled)
            if why:
                raise UnsupportedScene(f"sim='compiled' cannot step this scene: {why}; use sim='highway-env'")
            self.state = pack(env.road, controlled)
        return self.state

    def simulate(self, env: Any, action: Any) -> None:
        """``AbstractEnv._simulate(action)`` on the arrays (``env.steps`` advanced), then written back."""
        c = env.config
        frames = int(c["simulation_frequency"] // c["policy_frequency"])
        s = self._state(env)
        code, action_frame = -1, -1
        if action is not None and not c["manual_control"]:
            action_frame = next((fr for fr in range(frames) if (env.steps + fr) % frames == 0), -1)
            code = core.ACTION_CODES[env.action_type.actions[int(action)]]
        dt = 1 / c["simulation_frequency"]
        viewer = getattr(env, "viewer", None)
        if viewer is not None and env.enable_auto_render:  # intermediate frames rendered: one frame at a time
            for frame in range(frames):
                core.simulate(s.f, s.k, s.p, s.lanes, s.speeds, 1, 0 if frame == action_frame else -1, code,
                              s.ctrl, dt)
                env.steps += 1
                write_back(s)
                if frame < frames - 1:
                    env._automatic_rendering()
        else:
            core.simulate(s.f, s.k, s.p, s.lanes, s.speeds, frames, action_frame, code, s.ctrl, dt)
            env.steps += frames
            write_back(s)
        env.enable_auto_render = False

    def rewards(self, env: Any) -> dict[str, float]:
        """``HighwayEnv._rewards`` of the controlled vehicle from the arrays."""
        s = self._state(env)
        lo, hi = (float(x) for x in env.config["reward_speed_range"])
        collision, right, speed, road = core.reward_terms(s.f, s.k, s.lanes, s.ctrl, lo, hi)
        return {"collision_reward": collision, "right_lane_reward": right, "high_speed_reward": speed,
                "on_road_reward": road}

    def reward(self, env: Any) -> float:
        """``HighwayEnv._reward``: the weighted sum of :meth:`rewards`, normalised, times ``on_road``."""
        c = env.config
        rewards = self.rewards(env)
        reward = sum(c.get(name, 0) * r for name, r in rewards.items())
        if c["normalize_reward"]:
            lo, hi = c["collision_reward"], c["high_speed_reward"] + c["right_lane_reward"]
            reward = 0 + (reward - lo) * (1 - 0) / (hi - lo)
        return float(reward * rewards["on_road_reward"])


def scene_arrays(env: Any) -> dict[str, np.ndarray]:
    """Positions, headings, speeds, lanes, target lanes and crash flags of ``env.unwrapped.road.vehicles``."""
    vehicles = env.unwrapped.road.vehicles
    return {
        "position": np.array([v.position for v in vehicles], dtype=float),
        "heading": np.array([v.heading for v in vehicles], dtype=float),
        "speed": np.array([v.speed for v in vehicles], dtype=float),
        "lane": np.array([v.lane_index[2] for v in vehicles], dtype=int),
        "target_lane": np.array([v.target_lane_index[2] for v in vehicles], dtype=int),
        "crashed": np.array([bool(v.crashed) for v in vehicles]),
    }
