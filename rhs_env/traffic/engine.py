"""The compiled traffic of one env: packs highway-env's scene, steps it (:func:`rhs_env.traffic.core.simulate`).

:class:`CompiledTraffic` replaces ``AbstractEnv._simulate`` and ``HighwayEnv._reward`` of an env made with
``sim="compiled"`` or (the default) ``sim="auto"``. highway-env builds the scene at reset; the first step after it
(or after the vehicle list, the controlled vehicle or the road changed: :func:`rhs_env.traffic.state.scene_key`)
packs it into arrays, and every step writes the arrays back into the vehicle objects
(:func:`rhs_env.traffic.sync.write_back`), so that the observation, ``info``, rendering, the radar's scatterers
and a user's ``env.unwrapped.road`` read the stepped state; before every step the vehicles' state is read in again
(:func:`rhs_env.traffic.sync.read_in`), so that what a user or a driver set on a vehicle between steps (its
position, speed, target lane or target speed) is stepped as highway-env would step it. Adding, removing or
replacing a vehicle repacks; the per-vehicle parameters (lengths, gains, IDM constants) are read at packing.

A scene the core does not port (:func:`rhs_env.traffic.state.unsupported`: road objects, a vehicle class other than
``IDMVehicle`` / ``MDPVehicle``, ...) is an :class:`UnsupportedScene` error with ``strict`` (``sim="compiled"``);
without it (``sim="auto"``) :meth:`CompiledTraffic.supports` is False and the env steps it with highway-env's own
code, from the objects (which the core kept up to date), for as long as the scene stays so; as it does while the
kernels compile in a background process on a cold cache (:mod:`rhs_env.traffic.warm`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rhs_env.highway_config import SIMS
from rhs_env.traffic import core, warm
from rhs_env.traffic.state import TrafficState, pack, scene_key, unsupported
from rhs_env.traffic.sync import read_in, write_back

__all__ = ["CompiledTraffic", "SIMS", "UnsupportedScene"]


class UnsupportedScene(ValueError):
    """The scene uses highway-env features the compiled core does not port (use ``sim="highway-env"``)."""


class CompiledTraffic:
    """Steps an env's traffic with the compiled core (see the module docstring)."""

    def __init__(self, strict: bool = True) -> None:
        self.state: TrafficState | None = None
        #: an unported scene raises (``sim="compiled"``) rather than falling back (``sim="auto"``)
        self.strict = strict
        #: :func:`scene_key` of the last scene found unported (not strict): not checked again while it stays
        self._unsupported_key: tuple[int, ...] | None = None

    def supports(self, env: Any) -> bool:
        """Whether the core steps ``env``'s current scene (packing it if new); an unported scene is an
        :class:`UnsupportedScene` error when :attr:`strict`, else False."""
        controlled = env.action_type.controlled_vehicle
        key = scene_key(env.road, controlled)
        if self.state is not None and self.state.key == key:
            return True
        if not self.strict and not warm.ready():  # the kernels compile in the background: highway-env meanwhile
            return False
        if key == self._unsupported_key:
            return False
        why = unsupported(env.road, controlled)
        if why:
            if self.strict:
                raise UnsupportedScene(f"sim='compiled' cannot step this scene: {why}; use sim='highway-env' or "
                                       "sim='auto' (highway-env's own code where the core does not port the scene)")
            self.state, self._unsupported_key = None, key
            return False
        self.state, self._unsupported_key = pack(env.road, controlled), None
        return True

    def _state(self, env: Any) -> TrafficState:
        if not self.supports(env) or self.state is None:
            raise UnsupportedScene("the compiled traffic does not step this scene (CompiledTraffic.supports is False)")
        return self.state

    def simulate(self, env: Any, action: Any) -> bool:
        """``AbstractEnv._simulate(action)`` on the arrays (``env.steps`` advanced), then written back.

        Returns:
            True; False, with nothing stepped, when the scene read in is no longer one the core ports (not
            :attr:`strict`: the caller steps it with highway-env's code).
        """
        c = env.config
        frames = int(c["simulation_frequency"] // c["policy_frequency"])
        s = self._state(env)
        if not read_in(s):  # a vehicle left the road's edge: check the scene and pack it again
            self.state = None
            if not self.supports(env):
                return False
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
        return True

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
