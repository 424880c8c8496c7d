"""Checks of highway-env's own config keys, run when an env is made (``gym.make``).

highway-env reads its config lazily: a bad value passes ``gym.make`` and fails
later, deep inside (``target_speeds=[]`` is an ``IndexError`` at the first step,
``other_vehicles_type="no.such.Vehicle"`` a ``ModuleNotFoundError`` at reset,
``centering_position="x"`` a ``TypeError`` at the first render), or never fails
and does something else than asked (``reward_speed_range=[30, 20]`` rewards slow
driving, ``policy_frequency=0.7`` with 15 Hz simulation steps 21 frames = 1.4 s
per action instead of 1/0.7 s). :data:`CHECKS` maps each such key to its check;
:func:`check_highway_config` runs them all with the messages of the project's own
configs: ``TypeError`` for a wrong type, ``ValueError`` for a wrong value, both
naming the key path (``action.target_speeds must be ...``).

Numpy values (arrays, numpy scalars) are accepted where lists and Python numbers
are, and stored back as plain Python values (the config pickles and serialises).
The scalar keys whose default is a bool or a number are checked by
:func:`rhs_env.envs.check_config_types` and the ranges in ``RHSHighwayEnv._validate_config``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, MutableMapping
from typing import Any

import numpy as np

from rhs_common.validation import check_choice, check_int, check_range

__all__ = [
    "ACTION_TYPES", "CHECKS", "COMPILED_NEEDS", "KINEMATICS_FEATURES", "MAX_OBSERVED_VEHICLES", "MAX_SPEED_MPS", "OBSERVATION_TYPES",
    "SIMS", "check_highway_config", "check_numbers", "compiled_unsupported", "merge_config", "plain", "same_value",
]

#: highway-env's action and observation types (``action_factory`` / ``observation_factory``) that these
#: single-ego highway scenes support: ``MultiAgentAction`` (one action per controlled vehicle; the radar and the
#: SLAM follow one ego), ``KinematicsGoal`` (needs the parking env's goal) and ``ExitObservation`` (the exit
#: env's lanes) are refused with this list
ACTION_TYPES = ("ContinuousAction", "DiscreteAction", "DiscreteMetaAction")
OBSERVATION_TYPES = ("TimeToCollision", "Kinematics", "OccupancyGrid", "GrayscaleObservation",
                     "AttributesObservation", "MultiAgentObservation", "TupleObservation", "LidarObservation")
#: the columns a Kinematics observation can hold (``highway_env.vehicle.kinematics.Vehicle.to_dict``)
KINEMATICS_FEATURES = ("presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h", "cos_d", "sin_d", "long_off",
                       "lat_off", "ang_off")
#: target speeds of a meta-action, m/s: 100 m/s = 360 km/h, above any road vehicle
MAX_SPEED_MPS = 100.0
#: vehicles a Kinematics observation lists (its rows); the env holds at most 500 (``vehicles_count``)
MAX_OBSERVED_VEHICLES = 500


def plain(value: Any) -> Any:
    """``value`` with numpy arrays and scalars turned into lists and Python numbers (recursively)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, list):
        return [plain(v) for v in value]
    if isinstance(value, tuple):
        return tuple(plain(v) for v in value)
    return value


def check_numbers(field: str, value: Any, count: int | None = None, low: float | None = None,
                  high: float | None = None) -> list[float]:
    """``value`` as a list of finite numbers in ``[low, high]`` (``count`` of them when given).

    A list, tuple or 1-D numpy array; ``TypeError`` for anything else (a string, a
    number alone, booleans), ``ValueError`` for a wrong length or value, naming
    ``field`` and the element (``reward_speed_range[1]``).
    """
    if isinstance(value, np.ndarray):
        if value.ndim != 1:
            raise TypeError(f"{field} must be a list of numbers, got an array of shape {value.shape}")
        value = value.tolist()
    if not isinstance(value, (list, tuple)):
        what = f"{count} numbers" if count else "a list of numbers"
        raise TypeError(f"{field} must be {what}, got {value!r} ({type(value).__name__})")
    if count is not None and len(value) != count:
        raise ValueError(f"{field} must be {count} numbers, got {len(value)}: {value!r}")
    for i, v in enumerate(value):
        check_range(f"{field}[{i}]", v, low, high)
    return [float(v) for v in value]


def _check_increasing(field: str, values: list[float], what: str) -> None:
    if any(b <= a for a, b in zip(values, values[1:], strict=False)):
        raise ValueError(f"{field} must be strictly increasing ({what}), got {values!r}")


def _check_mapping(field: str, value: Any) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise TypeError(f"{field} must be a dict with a 'type', got {value!r} ({type(value).__name__})")
    return value


# --------------------------------------------------------------------------- the checks, one per key
def _check_action(c: MutableMapping[str, Any]) -> None:
    a = _check_mapping("action", c["action"])
    check_choice("action.type", a.get("type"), ACTION_TYPES)
    if a["type"] == "DiscreteMetaAction" and a.get("target_speeds") is not None:
        speeds = check_numbers("action.target_speeds", a["target_speeds"], None, 0.0, MAX_SPEED_MPS)
        if not speeds:
            raise ValueError("action.target_speeds must hold at least one speed (m/s), got []")
        _check_increasing("action.target_speeds", speeds, "the meta-actions FASTER / SLOWER step through them in order")
        if isinstance(a["target_speeds"], np.ndarray) or any(isinstance(v, np.generic) for v in a["target_speeds"]):
            c["action"] = {**a, "target_speeds": plain(a["target_speeds"])}
    for key in ("longitudinal", "lateral"):
        if key in a and not isinstance(a[key], (bool, np.bool_)):
            raise TypeError(f"action.{key} must be True or False, got {a[key]!r} ({type(a[key]).__name__})")


def _check_observation(c: MutableMapping[str, Any]) -> None:
    o = _check_mapping("observation", c["observation"])
    check_choice("observation.type", o.get("type"), OBSERVATION_TYPES)
    if o["type"] == "Kinematics":
        if "vehicles_count" in o:
            check_int("observation.vehicles_count", o["vehicles_count"], 1, MAX_OBSERVED_VEHICLES)
        if "features" in o:
            f = o["features"]
            if not isinstance(f, (list, tuple)) or not f or not all(isinstance(x, str) for x in f):
                raise TypeError(f"observation.features must be a non-empty list of names from "
                                f"{', '.join(KINEMATICS_FEATURES)}; got {f!r}")
            unknown = [x for x in f if x not in KINEMATICS_FEATURES]
            if unknown:
                raise ValueError(f"observation.features has unknown name(s) {', '.join(map(repr, unknown))}; "
                                 f"allowed: {', '.join(KINEMATICS_FEATURES)}")


def _check_reward_speed_range(c: MutableMapping[str, Any]) -> None:
    lo_hi = check_numbers("reward_speed_range", c["reward_speed_range"], 2, 0.0, MAX_SPEED_MPS)
    _check_increasing("reward_speed_range", lo_hi, "[low, high] m/s: the speed reward rises from low to high")
    c["reward_speed_range"] = plain(c["reward_speed_range"])


def _check_other_vehicles_type(c: MutableMapping[str, Any]) -> None:
    from highway_env.vehicle.kinematics import Vehicle

    path = c["other_vehicles_type"]
    if not isinstance(path, str) or "." not in path:
        raise TypeError(f"other_vehicles_type must be a class path 'module.Class', got {path!r} "
                        f"({type(path).__name__})")
    module, name = path.rsplit(".", 1)
    try:
        cls = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"other_vehicles_type {path!r} cannot be imported ({exc}); e.g. "
                         "'highway_env.vehicle.behavior.IDMVehicle'") from None
    if not (isinstance(cls, type) and issubclass(cls, Vehicle)):
        raise ValueError(f"other_vehicles_type {path!r} is not a highway-env Vehicle class")  # noqa: TRY004  (a value)


def _check_initial_lane_id(c: MutableMapping[str, Any]) -> None:
    lane = c["initial_lane_id"]
    if lane is None:
        return
    n = int(c["lanes_count"])
    try:
        check_int("initial_lane_id", lane, 0, n - 1)
    except ValueError:
        raise ValueError(f"initial_lane_id must be None or a lane in [0, {n - 1}] (lanes_count={n}), "
                         f"got {lane!r}") from None
    c["initial_lane_id"] = int(lane)


def _check_centering_position(c: MutableMapping[str, Any]) -> None:
    check_numbers("centering_position", c["centering_position"], 2, 0.0, 1.0)
    c["centering_position"] = plain(c["centering_position"])


def _check_policy_frequency(c: MutableMapping[str, Any]) -> None:
    sim, pol = float(c["simulation_frequency"]), float(c["policy_frequency"])
    ratio = sim / pol
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise ValueError(
            f"policy_frequency must divide simulation_frequency={sim:g} Hz (each action lasts a whole number of "
            f"simulation steps), got {pol:g} Hz ({ratio:.4g} steps); e.g. "
            + ", ".join(f"{sim / k:g}" for k in range(1, 6) if sim / k >= 1))


def _check_offscreen_rendering(c: MutableMapping[str, Any]) -> None:
    v = c["offscreen_rendering"]
    if v is not None and not isinstance(v, (bool, np.bool_)):
        raise TypeError(f"offscreen_rendering must be None, True or False, got {v!r} ({type(v).__name__})")


#: the values of the ``sim`` key (:mod:`rhs_env.traffic`): ``"auto"`` (the default: the compiled core where it ports
#: the config and the scene, highway-env's own Python elsewhere), highway-env's own Python, or the compiled core
SIMS = ("auto", "highway-env", "compiled")
#: the config the compiled core ports: key -> the one value it supports
COMPILED_NEEDS: dict[str, Any] = {
    "action.type": "DiscreteMetaAction",
    "controlled_vehicles": 1,
    "other_vehicles_type": "highway_env.vehicle.behavior.IDMVehicle",
    "show_trajectories": False,
    "manual_control": False,
}


def compiled_unsupported(c: Mapping[str, Any]) -> str:
    """Why the compiled core cannot step a scene of config ``c`` ("" when it can): the first key of
    :data:`COMPILED_NEEDS` whose value differs, as ``"needs action.type='DiscreteMetaAction', got 'ContinuousAction'"``."""
    action = c.get("action")
    values = {
        "action.type": action.get("type") if isinstance(action, Mapping) else None,
        "controlled_vehicles": c.get("controlled_vehicles", 1),
        "other_vehicles_type": c.get("other_vehicles_type"),
        "show_trajectories": bool(c.get("show_trajectories", False)),
        "manual_control": bool(c.get("manual_control", False)),
    }
    for key, wanted in COMPILED_NEEDS.items():
        if values[key] != wanted:
            return f"needs {key}={wanted!r}, got {values[key]!r}"
    return ""


def _check_sim(c: MutableMapping[str, Any]) -> None:
    """``sim``: one of :data:`SIMS`; ``"compiled"`` needs what the core ports (:data:`COMPILED_NEEDS`:
    ``DiscreteMetaAction``, one controlled vehicle, IDM traffic, no trajectories, no manual control), else a
    ``ValueError``; ``"auto"`` then takes highway-env's own code, without an error."""
    check_choice("sim", c["sim"], SIMS)
    why = compiled_unsupported(c) if c["sim"] == "compiled" else ""
    if why:
        raise ValueError(f"sim='compiled' {why}; use sim='highway-env' (highway-env's own code) or sim='auto' "
                         "(the compiled core where it ports the config) for this config")


def _check_screen(key: str) -> Callable[[MutableMapping[str, Any]], None]:
    def check_pixels(c: MutableMapping[str, Any]) -> None:
        check_int(key, c[key], 1, 4096)  # pixels

    return check_pixels


#: key -> check of the config (in this order: ``initial_lane_id`` after ``lanes_count`` is known valid)
CHECKS: dict[str, Callable[[MutableMapping[str, Any]], None]] = {
    "action": _check_action,
    "observation": _check_observation,
    "reward_speed_range": _check_reward_speed_range,
    "other_vehicles_type": _check_other_vehicles_type,
    "initial_lane_id": _check_initial_lane_id,
    "centering_position": _check_centering_position,
    "policy_frequency": _check_policy_frequency,
    "offscreen_rendering": _check_offscreen_rendering,
    "sim": _check_sim,
    "screen_width": _check_screen("screen_width"),
    "screen_height": _check_screen("screen_height"),
}


def check_highway_config(config: MutableMapping[str, Any]) -> None:
    """Run every check of :data:`CHECKS` whose key is in ``config`` (numpy values are stored back as plain ones)."""
    for key, check in CHECKS.items():
        if key in config:
            check(config)


def same_value(a: Any, b: Any) -> bool:
    """``a == b`` for config values, numpy arrays and numbers included (``[1, 2] == np.array([1, 2])``)."""
    try:
        return bool(np.array_equal(np.asarray(plain(a), dtype=object), np.asarray(plain(b), dtype=object)))
    except (TypeError, ValueError):
        return a == b


def merge_config(config: Mapping[str, Any] | None, kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """``config`` updated by ``kwargs``; a key given both ways with different values is a ``ValueError`` naming both."""
    merged = dict(config or {})
    for key, value in kwargs.items():
        if key in merged and not same_value(merged[key], value):
            raise ValueError(f"{key} given twice with different values: config={{{key!r}: {merged[key]!r}}} and "
                             f"{key}={value!r}; give it once")
        merged[key] = value
    return merged

