"""The studies' episodes: one runner on :func:`agents.evaluate.run_episode`, and the paper scene's episode.

* :func:`drive` runs one episode with a fixed meta-action (IDLE by default) and returns the
  ``(obs, info)`` of the reset and of every step, for a study to read what it measures;
* the paper-figure studies (Fig. 5a, Fig. 5c, the registration in the loop) drive the paper
  scene with the IDLE action, one SLAM cycle per ``1 / POLICY_HZ`` s, for ``--cycles``
  cycles, with the default radar changed only by the options :func:`add_episode_args` adds
  (noise figure, beam grid, RHS elements) and the study's own antenna and Tx power
  (:func:`make_paper_env`); :func:`paper_slam_episode` is such an episode's error summary.

The scenes (:mod:`rhs_studies.kit.scenes`) and a study subprocess's environment (:mod:`rhs_studies.kit.subprocess_env`)
are importable from here too, as before they moved into the kit.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from agents.policies.decision import IDLE
from rhs_common.geometry import wrap_angle
from rhs_env.array_models import ANTENNA_KINDS
from rhs_studies.kit.scenes import landmark_scene, typical_scene
from rhs_studies.kit.subprocess_env import study_env
from slam.core.registration import DEFAULT_REGISTRATION, REGISTRATIONS

POLICY_HZ = 5  # rhs-paper-v0: one SLAM cycle per 0.2 s
ANTENNAS = ANTENNA_KINDS


def add_episode_args(p: argparse.ArgumentParser, quick_help: str) -> None:
    """The options every paper-figure script takes (``--quick`` is described by ``quick_help``)."""
    p.add_argument("--registration", choices=REGISTRATIONS, default=DEFAULT_REGISTRATION,
                   help=f"SLAM registration, default {DEFAULT_REGISTRATION} (the SLAM env's default)")
    p.add_argument("--noise-figure", type=float, default=10.0, help="receiver noise figure (dB), held fixed")
    p.add_argument("--grid-deg", type=float, default=1.0, help="beam grid (deg), default 1")
    p.add_argument("--elements", type=int, default=60, help="RHS elements M, default 60")
    p.add_argument("--cycles", type=int, default=50, help="SLAM cycles per episode (paper: 50)")
    p.add_argument("--map-gate", type=float, default=2.0, help="Hungarian matching gate of the map RMSE (m)")
    p.add_argument("--out-dir", default="results")
    p.add_argument("--quick", action="store_true", help=quick_help)
    p.add_argument("--no-progress", action="store_true")


def make_paper_env(args: argparse.Namespace, antenna: str, tx_power_dbm: float, **kwargs: Any) -> Any:
    """``rhs-paper-v0`` for ``args.cycles`` cycles with the radar of ``args`` (extra ``kwargs`` to ``gym.make``)."""
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids)

    radar = {
        "link": {"tx_power_dbm": float(tx_power_dbm), "noise_figure_db": float(args.noise_figure)},
        "scan": {"grid_deg": float(args.grid_deg)},
        "rhs": {"elements": int(args.elements)},
    }
    return gym.make(
        "rhs-paper-v0",
        antenna=antenna,
        radar=radar,
        registration=args.registration,
        map_gate_m=float(args.map_gate),
        landmarks_in_info=True,
        duration=args.cycles / POLICY_HZ,
        **kwargs,
    )


def drive(env: Any, seed: int, action: int = IDLE, bar: Any = None) -> list[tuple[Any, dict]]:
    """One episode of ``env`` from ``reset(seed=seed)`` with ``action`` at every step (no policy file).

    Returns the ``(obs, info)`` of the reset, then of each step; ``bar`` (tqdm) advances a step at a time.
    """
    from agents.evaluate import ConstantPolicy, run_episode

    trace: list[tuple[Any, dict]] = []
    run_episode(env, ConstantPolicy(env.action_space, action), int(seed), trace=trace, bar=bar)
    return trace


def paper_slam_episode(antenna: str, seed: int, tx_power_dbm: float, args: argparse.Namespace) -> dict:
    """One ``rhs-paper-v0`` episode (:func:`make_paper_env`); its errors (map frame) and mean SLAM stage times.

    Vehicle RMSE ``sqrt(mean_k |p_k - p_k^true|^2)`` over the cycles (m), heading RMSE (rad), the
    final and largest position errors, the map's RMSE over the matched landmarks (``obstacle_rmse_m``,
    None when none matched within the gate) and its matched / missed / spurious counts.
    """
    env = make_paper_env(args, antenna, tx_power_dbm, stage_times_in_info=True)
    t0 = time.perf_counter()
    steps = [info for _, info in drive(env, seed)[1:]]
    env.close()
    stages: dict[str, float] = {}
    for info in steps:
        for k, v in info["slam_stage_times"].items():
            stages[k] = stages.get(k, 0.0) + v
    true = np.asarray([info["true_pose"] for info in steps])
    est = np.asarray([info["estimated_pose"] for info in steps])
    pos_err = np.hypot(est[:, 0] - true[:, 0], est[:, 1] - true[:, 1])
    head_err = wrap_angle(est[:, 2] - true[:, 2])
    n, last = len(true), steps[-1]
    return {
        "antenna": antenna,
        "seed": int(seed),
        "tx_power_dbm": float(tx_power_dbm),
        "cycles": n,
        "vehicle_rmse_m": float(np.sqrt(np.mean(pos_err**2))),
        "vehicle_max_error_m": float(np.max(pos_err)),
        "final_position_error_m": float(pos_err[-1]),
        "heading_rmse_rad": float(np.sqrt(np.mean(head_err**2))),
        "obstacle_rmse_m": last.get("map_rmse_m"),  # None when nothing matched within the gate
        "map_matched": int(last["map_matched"]),
        "map_missed": int(last["map_missed"]),
        "map_spurious": int(last["map_spurious"]),
        "slam_stage_times_ms": {k: 1e3 * v / n for k, v in stages.items()},
        "wall_s": time.perf_counter() - t0,
    }


def start_study(parse_args: Callable[[list[str] | None], argparse.Namespace],
                argv: list[str] | None) -> tuple[argparse.Namespace, float, Path]:
    """A paper-figure study's start: headless rendering, its options, the start time (s) and its output folder
    (``--out-dir``, created)."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    a = parse_args(argv)
    started = time.time()
    out = Path(a.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return a, started, out


__all__ = ["ANTENNAS", "POLICY_HZ", "add_episode_args", "drive", "landmark_scene", "make_paper_env",
           "paper_slam_episode", "start_study", "study_env", "typical_scene"]
