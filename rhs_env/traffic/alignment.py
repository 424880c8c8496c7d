"""Alignment of the compiled traffic with highway-env (EnvPool's practice): the same scene, the same actions.

:func:`align_episode` builds one scene twice (``sim="highway-env"`` and ``sim="compiled"``, the same seed),
drives both with the same uniformly random meta-actions for ``steps`` steps (on past a termination: the
crashed ego brakes to a stop and the traffic goes on, as highway-env keeps simulating) and compares after
every step:

* the discrete decisions: every vehicle's lane and target lane, crash flags, ``terminated`` / ``truncated``;
* every vehicle's position (m) and speed (m/s), as long as the discrete decisions agreed so far;
* the rewards.

The test suite runs a few short episodes (``tests/test_traffic_core.py``), ``scripts/traffic_alignment.py``
the full 50 seeds x 200 steps.
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = ["SCENES", "EpisodeAlignment", "align_episode", "make_scene"]

#: scene name -> (env class path, config): the straight-road scenes of the rhs ids, whose default traffic is the
#: compiled core (their traffic; the radar and SLAM wrappers of the ``-radar`` / ``-slam`` ids do not touch it).
#: ``paper`` is the paper's scene with 10 IDM vehicles added, ``paper-default`` ``rhs-paper-v0`` as shipped (the ego
#: alone beside its five obstacles: the obstacles are radar landmarks, not highway-env road objects, so they do not
#: collide and the traffic does not see them)
SCENES: dict[str, tuple[str, dict[str, Any]]] = {
    "highway": ("rhs_env.envs:RHSHighwayEnv", {}),
    "dense": ("rhs_env.envs:RHSDenseEnv", {}),
    "paper": ("rhs_env.envs:RHSPaperEnv", {"vehicles_count": 10}),
    "paper-default": ("rhs_env.envs:RHSPaperEnv", {}),
}
#: a base observation that costs nothing (the comparison reads the road)
CHEAP_OBSERVATION = {"type": "AttributesObservation", "attributes": []}


@dataclass
class EpisodeAlignment:
    """One seed's comparison (see the module docstring)."""

    scene: str
    seed: int
    steps: int
    #: the first step (1-based) at which a discrete decision differed; 0 if none did
    first_discrete_mismatch: int
    #: largest |difference| of positions (m) and speeds (m/s) over the steps before any discrete mismatch
    max_position_diff_m: float
    max_speed_diff_mps: float
    max_reward_diff: float
    #: step (1-based) at which highway-env's episode terminated (0: not within ``steps``), and the core's
    terminated_at: int
    terminated_at_compiled: int
    #: target-lane changes of all vehicles and vehicles crashed at the end, counted on highway-env's run
    lane_changes: int
    crashed_vehicles: int

    @property
    def agrees(self) -> bool:
        """The same discrete decisions at every step."""
        return self.first_discrete_mismatch == 0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def make_scene(scene: str, sim: str, **config: Any) -> Any:
    """The env of ``scene`` (:data:`SCENES`) with ``sim`` and the cheap base observation."""
    import importlib

    path, defaults = SCENES[scene]
    module, name = path.split(":")
    cls = getattr(importlib.import_module(module), name)
    return cls(config={"observation": dict(CHEAP_OBSERVATION), **defaults, **config, "sim": sim})


def _road_arrays(env: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    vehicles = env.road.vehicles
    xy = np.array([v.position for v in vehicles], dtype=float)
    speed = np.array([v.speed for v in vehicles], dtype=float)
    discrete = np.array([(v.lane_index[2], v.target_lane_index[2], bool(v.crashed)) for v in vehicles], dtype=int)
    return xy, speed, discrete


def align_episode(scene: str, seed: int, steps: int, **config: Any) -> EpisodeAlignment:
    """Drive ``scene`` with both sims for ``steps`` random meta-actions from ``seed`` and compare (module docstring).

    Args:
        scene: a key of :data:`SCENES`.
        seed: the reset seed and the seed of the actions.
        steps: env steps (policy steps) to drive.
        **config: extra env config keys (``vehicles_count=...``).

    Returns:
        The comparison.
    """
    envs = [make_scene(scene, sim, **config) for sim in ("highway-env", "compiled")]
    for env in envs:
        env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    n_actions = int(envs[0].action_space.n)
    mismatch = 0
    dx = dv = dr = 0.0
    ended = [0, 0]
    lane_changes = 0
    last_target = _road_arrays(envs[0])[2][:, 1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # the steps after a termination
        for t in range(1, steps + 1):
            action = int(rng.integers(n_actions))
            out = [env.step(action) for env in envs]
            (xa, va, da), (xb, vb, db) = (_road_arrays(env) for env in envs)
            for e in range(2):
                if out[e][2] and not ended[e]:
                    ended[e] = t
            lane_changes += int(np.count_nonzero(da[:, 1] != last_target)) if len(da) == len(last_target) else 0
            last_target = da[:, 1]
            same = (da.shape == db.shape and bool(np.array_equal(da, db)) and out[0][2] == out[1][2]
                    and out[0][3] == out[1][3])
            if not same and not mismatch:
                mismatch = t
            if not mismatch:
                dx = max(dx, float(np.abs(xa - xb).max(initial=0.0)))
                dv = max(dv, float(np.abs(va - vb).max(initial=0.0)))
                dr = max(dr, abs(float(out[0][1]) - float(out[1][1])))
    crashed = int(_road_arrays(envs[0])[2][:, 2].sum())
    for env in envs:
        env.close()
    return EpisodeAlignment(scene, seed, steps, mismatch, dx, dv, dr, ended[0], ended[1], lane_changes, crashed)
