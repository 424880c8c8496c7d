"""The calibrated pose covariance of one SLAM env configuration: keyed, shipped, cached or fitted at first use.

``pipeline={"pose_covariance": "calibrated"}`` scales the adaptive model's terms by four factors and adds the
map's start with a fifth (:mod:`slam.core.pose_calibration`), fitted for the configuration the user made. The configuration is named by
:func:`calibration_key`: a sha256 of the scene (its class and its settings), the resolved radar settings
(``RadarConfig.flat_dict``; the kernels and the synthesis path left out, as the fast radar's table key does),
the SLAM, ICP and pipeline settings (the covariance model itself left out) and the registration: everything that
changes how accurately the filter tracks, nothing that only changes what it reports or draws.

:func:`attach` (called by :func:`slam.gym.envs.make_slam_env`) finds the factors, in this order:

1. shipped with the package (``slam/data/pose_calibration/<key>.json``: the default env, the 5-degree grid of
   the shipped policies, the dense env, the fast radar; ``scripts/calibrate_pose_covariance.py`` made them);
2. the user cache (:func:`rhs_common.cache_dir.cache_subdir` ``pose_calibration``) from an earlier first use;
3. else :func:`calibrate` now (a :class:`PoseCalibrationWarning` says so): :data:`CALIBRATION_SEEDS` drives of
   :data:`CALIBRATION_CYCLES` cycles of the configuration with the adaptive model, highway-env's IDM + MOBIL
   driver in the ego's seat (the scripted reference of the studies), their rows fitted
   (:func:`slam.core.pose_calibration.fit_calibration`) and written to the cache atomically
   (:func:`rhs_common.output_files.write_text_atomic`). On the default radar that takes about a minute, once.

The calibration seeds (13000-13039) are not evaluation seeds (``rhs_studies.kit.seeds``). Forty drives, not ten: fits
on disjoint sets of ten of them differ by up to 10x in a factor (``scripts/calibrate_pose_covariance.py --spread 4``,
``results/pose_calibration_spread.json``), and a drive of 50 cycles takes about a second on the exact radar.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from rhs_env.idm_driver import swap_ego_for_idm
from slam.core.pose_calibration import ROW_COLUMNS, PoseCalibration, fit_calibration

__all__ = [
    "CALIBRATION_CYCLES",
    "CALIBRATION_SEEDS",
    "PoseCalibrationWarning",
    "SHIPPED_CONFIGS",
    "attach",
    "cached_path",
    "calibrate",
    "calibrate_env",
    "calibrate_env_drives",
    "calibration_drives",
    "calibration_from_rows",
    "calibration_key",
    "calibration_rows",
    "find_calibration",
    "shipped_path",
    "slam_wrapper",
]

#: the calibration drives' seeds (disjoint from every evaluation seed set: rhs_studies.kit.seeds)
CALIBRATION_SEEDS = tuple(range(13000, 13040))
#: cycles per calibration drive
CALIBRATION_CYCLES = 50
#: the configurations whose calibrations the package ships (name -> env id, gym.make settings): the default env,
#: the 5-degree grid of the shipped policies (their ``action`` setting does not enter the key), the dense env, the
#: fast radar, and the claim study's other radars: the phased array, the random patterns and the low-SNR link
SHIPPED_CONFIGS: dict[str, tuple[str, dict[str, Any]]] = {
    "default": ("rhs-highway-slam-v0", {}),
    "grid5": ("rhs-highway-slam-v0", {"radar": {"scan": {"grid_deg": 5}}}),
    "dense": ("rhs-dense-v0", {}),
    "fast": ("rhs-highway-slam-fast-v0", {}),
    "phased": ("rhs-highway-slam-v0", {"antenna": "phased"}),
    "random": ("rhs-highway-slam-v0", {"antenna": "random"}),
    "low_snr": ("rhs-highway-slam-v0", {"radar": {"link": {"tx_power_dbm": 20.0}}}),
}
DATA_DIR = Path(__file__).resolve().parent.parent / "data" / "pose_calibration"
#: gym.make settings that change only what the env reports, renders, how fast it runs, how long an episode lasts
#: or how the ego is driven (left out of the key)
_KEY_EXCLUDED = frozenset({"render_mode", "blas_threads", "stage_times_in_info", "health_in_obs", "velocity_in_obs",
                           "max_landmarks", "action", "duration", "radar", "slam", "icp", "pipeline", "registration", "screen_width",
                           "screen_height", "offscreen_rendering", "show_trajectories"})
_RADAR_EXCLUDED = ("kernels", "fidelity")


class PoseCalibrationWarning(UserWarning):
    """A configuration's pose covariance is being calibrated at first use (it takes minutes, once)."""


def slam_wrapper(env: gym.Env) -> Any:
    """The env's ``SlamObservation`` wrapper (the one with ``pipeline_config``)."""
    e: Any = env
    while not hasattr(e, "pipeline_config"):
        if not hasattr(e, "env"):
            raise ValueError("the env has no SLAM wrapper (slam.gym.wrappers.SlamObservation)")
        e = e.env
    return e


def _setup(scene: str, kwargs: dict[str, Any], env: gym.Env) -> dict[str, Any]:
    """What the key is made of (module docstring), JSON-ready."""
    w = slam_wrapper(env)
    radar_cfg = getattr(w.env, "radar_config", None) or getattr(env, "radar_config", None)
    radar = {} if radar_cfg is None else {k: v for k, v in radar_cfg.flat_dict().items() if k not in _RADAR_EXCLUDED}
    pipeline = {k: v for k, v in dataclasses.asdict(w.pipeline_config).items() if k != "pose_covariance"}
    rest = {k: v for k, v in kwargs.items() if k not in _KEY_EXCLUDED}
    return json.loads(json.dumps({
        "scene": scene, "settings": rest, "radar": radar, "slam": dataclasses.asdict(w.slam_config),
        "icp": dataclasses.asdict(w.icp_config), "pipeline": pipeline, "registration": w.registration_kind,
    }, sort_keys=True, default=str))


def calibration_key(scene: str, kwargs: dict[str, Any], env: gym.Env) -> str:
    """12 hex digits naming the configuration's calibration (module docstring).

    Args:
        scene: the scene's class name (``RHSHighwayEnv``, ``RHSRacetrackEnv``, ...: :func:`slam.gym.envs.scene_class`).
        kwargs: the ``gym.make`` settings the env was made with.
        env: the env they made (its resolved radar, SLAM and pipeline settings enter the key).

    Returns:
        The key.
    """
    text = json.dumps(_setup(scene, kwargs, env), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def shipped_path(key: str) -> Path:
    """``slam/data/pose_calibration/pose_cov_<key>.json``."""
    return DATA_DIR / f"pose_cov_{key}.json"


def cached_path(key: str) -> Path:
    """The user cache's ``pose_calibration/pose_cov_<key>.json``."""
    from rhs_common.cache_dir import cache_subdir

    return cache_subdir("pose_calibration") / f"pose_cov_{key}.json"


def calibration_rows(env: gym.Env, seed: int, cycles: int, policy: Any = None) -> np.ndarray:
    """One drive's rows (T, 27) (:data:`slam.core.pose_calibration.ROW_COLUMNS`).

    Args:
        env: a SLAM env whose pipeline runs the adaptive or calibrated model.
        seed: the episode's seed.
        cycles: at most this many cycles (fewer if the episode ends).
        policy: an object with ``predict(obs, deterministic=True) -> (action, state)``; None: IDM + MOBIL
            (:func:`rhs_env.idm_driver.swap_ego_for_idm` at its default target speed).

    Returns:
        The rows: pose error (estimated minus true, heading wrapped), particles' variances, drift, scale,
        estimated heading, lost, map-start term.
    """
    from rhs_common.geometry import wrap_angle

    pipe = slam_wrapper(env).pipeline
    obs, info = env.reset(seed=seed)
    rows = []
    ignored = np.zeros(env.action_space.shape, env.action_space.dtype) if isinstance(env.action_space, gym.spaces.Box) else 1
    for _ in range(cycles):
        if policy is None:
            swap_ego_for_idm(env)
            action: Any = ignored
        else:
            action = np.asarray(policy.predict(obs, deterministic=True)[0])
            action = int(action) if action.ndim == 0 else action
        obs, _, term, trunc, info = env.step(action)
        e = np.asarray(info["estimated_pose"], float) - np.asarray(info["true_pose"], float)
        e[2] = float(wrap_angle(e[2]))
        var = np.square(np.asarray(pipe.slam.last_estimate.pose_std, float))
        rows.append([*e, *var, *pipe.measured_drift.cov.ravel(), pipe.residual_scale, pipe.heading,
                     float(bool(info["slam_lost"])), *pipe.map_start.cov.ravel()])
        if term or trunc:
            break
    return np.asarray(rows, dtype=float).reshape(-1, len(ROW_COLUMNS))


def calibrate(scene: str, kwargs: dict[str, Any], seeds: tuple[int, ...] = CALIBRATION_SEEDS,
              cycles: int = CALIBRATION_CYCLES, env: gym.Env | None = None,
              make: Callable[[str, dict[str, Any]], gym.Env] | None = None) -> PoseCalibration:
    """Fit the configuration's factors on ``seeds`` drives of ``cycles`` cycles (module docstring).

    Args:
        scene: the scene's class name (:func:`slam.gym.envs.scene_class`).
        kwargs: the ``gym.make`` settings of the configuration.
        seeds: the calibration drives' seeds.
        cycles: cycles per drive.
        env: an env made with ``kwargs`` whose model measures the drift (adaptive or calibrated): the drives run
            on it (the rows do not depend on the model); None, or one with the drift densities: a new env.
        make: ``make(scene, kwargs)`` makes a SLAM env (:func:`slam.gym.envs.make_slam_env`); needed when
            ``env`` cannot be driven.

    Returns:
        The :class:`slam.core.pose_calibration.PoseCalibration`.
    """
    drives, key, setup = calibration_drives(scene, kwargs, seeds, cycles, env, make)
    return calibration_from_rows(np.vstack(drives), key, seeds, cycles, setup)


def calibration_drives(scene: str, kwargs: dict[str, Any], seeds: tuple[int, ...] = CALIBRATION_SEEDS,
                       cycles: int = CALIBRATION_CYCLES, env: gym.Env | None = None,
                       make: Callable[[str, dict[str, Any]], gym.Env] | None = None
                       ) -> tuple[list[np.ndarray], str, dict[str, Any]]:
    """The calibration drives of :func:`calibrate` (same arguments): each seed's rows (at most ``cycles``, in
    the order of ``seeds``), the configuration's key and what the key was made of."""
    kw = dict(kwargs)
    own = env is None or slam_wrapper(env).pipeline_config.pose_covariance == "drift-constants"
    if own and make is None:
        raise ValueError("calibrate needs make (a SLAM env factory) or an env whose model measures the drift")
    drive_env = make(scene, _adaptive_kwargs(kw)) if own and make is not None else env
    assert drive_env is not None
    setup = _setup(scene, kw, drive_env)
    key = calibration_key(scene, kw, drive_env)
    try:
        drives = [calibration_rows(drive_env, int(s), int(cycles)) for s in seeds]
    finally:
        if own:
            drive_env.close()
    return drives, key, setup


def calibration_from_rows(rows: np.ndarray, key: str, seeds: tuple[int, ...], cycles: int,
                          setup: dict[str, Any] | None = None) -> PoseCalibration:
    """The :class:`slam.core.pose_calibration.PoseCalibration` fitted on drives' ``rows`` (factors to 6 digits)."""
    factors, used = fit_calibration(rows)
    k = [float(f"{v:.6g}") for v in factors]
    return PoseCalibration(particles=k[0], along=k[1], cross=k[2], heading=k[3], map_heading=k[4], key=key,
                           seeds=tuple(int(s) for s in seeds),
                           cycles=int(cycles), fit_cycles=used, setup=dict(setup or {}))


def _adaptive_kwargs(kwargs: dict[str, Any]) -> dict[str, Any]:
    """``kwargs`` whose ``pipeline`` (absent, a dict or a ``PipelineConfig``) has ``pose_covariance="adaptive"``
    (the calibration drives' model: the rows do not depend on it, the covariance is report-only)."""
    p = kwargs.get("pipeline")
    if dataclasses.is_dataclass(p) and not isinstance(p, type):
        return {**kwargs, "pipeline": dataclasses.replace(p, pose_covariance="adaptive")}
    given: dict[str, Any] = dict(p) if isinstance(p, dict) else {}
    return {**kwargs, "pipeline": {**given, "pose_covariance": "adaptive"}}


def find_calibration(key: str) -> PoseCalibration | None:
    """The shipped calibration of ``key``, else the cached one, else None (a stale or unreadable cache file is
    ignored: it is fitted again)."""
    for path in (shipped_path(key), cached_path(key)):
        if path.is_file():
            try:
                cal = PoseCalibration.from_json(path.read_text(encoding="utf-8"))
            except (ValueError, TypeError, KeyError):
                continue
            if cal.key == key:
                return cal
    return None


def calibrate_env(env_id: str, kwargs: dict[str, Any], seeds: tuple[int, ...] = CALIBRATION_SEEDS,
                  cycles: int = CALIBRATION_CYCLES) -> PoseCalibration:
    """:func:`calibrate` the configuration ``gym.make(env_id, **kwargs)`` (any SLAM env id, the fast one too).

    Args:
        env_id: a registered SLAM env id.
        kwargs: its ``gym.make`` settings (a ``pipeline`` setting's covariance model is replaced by ``adaptive``).
        seeds: the calibration drives' seeds.
        cycles: cycles per drive.

    Returns:
        The calibration (its ``key`` is the one :func:`attach` looks up for ``kwargs``).
    """
    drives, key, setup = calibrate_env_drives(env_id, kwargs, seeds, cycles)
    return calibration_from_rows(np.vstack(drives), key, seeds, cycles, setup)


def calibrate_env_drives(env_id: str, kwargs: dict[str, Any], seeds: tuple[int, ...] = CALIBRATION_SEEDS,
                         cycles: int = CALIBRATION_CYCLES) -> tuple[list[np.ndarray], str, dict[str, Any]]:
    """:func:`calibration_drives` of the configuration ``gym.make(env_id, **kwargs)`` (:func:`calibrate_env`)."""
    env = gym.make(env_id, **_adaptive_kwargs(dict(kwargs)))
    try:
        scene, made = env.get_wrapper_attr("slam_make_args")
        return calibration_drives(scene, made, seeds, cycles, env=env)
    finally:
        env.close()


def attach(env: gym.Env, scene: str, kwargs: dict[str, Any],
           make: Callable[[str, dict[str, Any]], gym.Env]) -> PoseCalibration:
    """Give the env's pipeline the configuration's calibration (shipped, cached or fitted now: module docstring).

    Args:
        env: a SLAM env made with ``kwargs`` and ``pose_covariance="calibrated"``.
        scene: the scene's class name (:func:`slam.gym.envs.scene_class`).
        kwargs: its ``gym.make`` settings.
        make: ``make(scene, kwargs)`` makes a SLAM env (:func:`slam.gym.envs.make_slam_env`): the calibration's.

    Returns:
        The calibration attached (``SlamPipeline.pose_calibration``).
    """
    from rhs_common.output_files import write_text_atomic

    key = calibration_key(scene, kwargs, env)
    cal = find_calibration(key)
    if cal is None:
        warnings.warn(f"pose covariance: no calibration for this configuration (key {key}); calibrating it now on "
                      f"{len(CALIBRATION_SEEDS)} drives of {CALIBRATION_CYCLES} cycles (minutes, once; cached in "
                      f"{cached_path(key).parent})", PoseCalibrationWarning, stacklevel=3)
        t0 = time.perf_counter()
        cal = calibrate(scene, kwargs, make=make)  # on its own env: the user's is left as made
        cal = dataclasses.replace(cal, setup={**cal.setup, "calibration_s": round(time.perf_counter() - t0, 1)})
        write_text_atomic(cached_path(key), cal.to_json())
    slam_wrapper(env).pipeline.pose_calibration = cal
    return cal
