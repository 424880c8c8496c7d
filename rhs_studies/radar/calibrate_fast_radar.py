"""Calibrate the fast radar (:mod:`rhs_env.fast_radar`) on the exact radar's measured detector.

``python scripts/calibrate_fast_radar.py [--radar JSON] [--seeds 100] [--first-seed 100000] [--steps 40]
[--out PATH]`` runs the exact radar (:class:`rhs_env.radar.RadarSystem`) on ``--seeds`` highway episodes of
``--steps`` steps (random meta-actions, mostly IDLE), matches every scan's points to the visible scatterers
(:func:`rhs_env.fast_radar_calibration.match_scan`) and writes the table
(:class:`rhs_env.fast_radar_calibration.FastRadarTable`):

* the default radar (no ``--radar``): the package's shipped table, ``rhs_env/data/fast_radar_<key>.npz``;
* other settings (``--radar '{"scan": {"grid_deg": 2}}'``, the fields of ``RadarConfig``): the user cache,
  where ``radar_model="fast"`` finds it.

The calibration seeds (default 100000-100099) must stay disjoint from the fidelity check's
(``scripts/fast_radar_fidelity.py``, 200000 on).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from rhs_studies.kit.seeds import first, seed_set

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--radar", default=None, help="radar settings as JSON (RadarConfig fields); default: the default radar")
    p.add_argument("--seeds", type=int, default=100)
    p.add_argument("--first-seed", type=int, default=first("fast_radar_calibration"))
    p.add_argument("--steps", type=int, default=40)
    p.add_argument("--out", default=None, help="table path (default: shipped for the default radar, else the cache)")
    a = p.parse_args(argv)
    if a.seeds < 1 or a.steps < 1:
        p.error(f"--seeds and --steps must be >= 1, got {a.seeds} and {a.steps}")
    # the fidelity check's radar and SLAM seed sets, named in the ledger (rhs_studies.kit.seeds)
    radar, slam = seed_set("fast_radar_fidelity"), seed_set("fast_radar_slam")
    if a.first_seed <= slam.last and a.first_seed + a.seeds > radar.first:
        p.error(f"--first-seed {a.first_seed} with --seeds {a.seeds} overlaps the fidelity check's seeds "
                f"({radar.first}-{slam.last}); calibrate below {radar.first}")
    from rhs_env.fast_radar import calibrate
    from rhs_env.fast_radar_calibration import cached_table_path, shipped_table_path
    from rhs_env.wrappers import make_radar_config

    try:
        settings = json.loads(a.radar) if a.radar else None
    except json.JSONDecodeError as exc:
        p.error(f"--radar is not JSON ({exc}); write it like '{{\"scan\": {{\"grid_deg\": 2}}}}'")
    try:
        config = make_radar_config(settings)
    except (TypeError, ValueError) as exc:
        p.error(f"--radar: {exc}")
    out = Path(a.out) if a.out else (shipped_table_path(config) if settings is None else cached_table_path(config))
    started = time.time()
    table = calibrate(config, range(a.first_seed, a.first_seed + a.seeds), a.steps, progress=True)
    table.meta["wall_s"] = round(time.time() - started, 1)
    table.save(out)
    print(json.dumps({"table": str(out), **table.meta}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
