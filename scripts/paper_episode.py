"""What the paper-figure scripts (fig5a, fig5c) share: their ``rhs-paper-v0`` episode and its options.

An episode drives the paper scene (SPEC 7) with the IDLE action, one SLAM cycle per
``1 / POLICY_HZ`` s, for ``--cycles`` cycles, with the default radar changed only by
the options added here (noise figure, beam grid, RHS elements) and the script's own
antenna and Tx power.
"""

from __future__ import annotations

import argparse
from typing import Any

from rhs_env.array_models import ANTENNA_KINDS
from slam.registration import DEFAULT_REGISTRATION, REGISTRATIONS

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
