"""Fit the calibrated pose covariance's factors of SLAM env configurations (:mod:`slam.gym.pose_calibration`).

``python scripts/calibrate_pose_covariance.py [--configs default grid5 dense fast] [--seeds 13000 ...]
[--cycles 80] [--out-dir slam/data/pose_calibration] [--spread 4 --spread-out results/pose_calibration_spread.json]``

Writes ``pose_cov_<key>.json`` per configuration (:data:`slam.gym.pose_calibration.SHIPPED_CONFIGS`): the
files the package ships, which the envs made with ``pipeline={"pose_covariance": "calibrated"}`` load instead of
calibrating at first use. ``tests/test_pose_calibration.py`` checks that this reproduces the shipped fast-radar
calibration.

``--spread K`` also splits the seeds into ``K`` disjoint sets of consecutive seeds, fits each set alone and
scores it on the other sets' drives (NEES coverage, :func:`slam.core.pose_calibration.nees_coverage`): how much a
calibration on ``len(seeds) / K`` drives varies, and how well it carries to drives it did not see, measured on
calibration seeds only (no held-out seed).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from rhs_common.output_files import write_text_atomic
from slam.gym.pose_calibration import (
    CALIBRATION_CYCLES,
    CALIBRATION_SEEDS,
    DATA_DIR,
    SHIPPED_CONFIGS,
    calibrate_env_drives,
    calibration_from_rows,
)


def spread(drives: list[np.ndarray], seeds: list[int], k: int) -> list[dict[str, Any]]:
    """Each of ``k`` disjoint sets of consecutive drives fitted alone and scored on the others (module docstring)."""
    from slam.core.pose_calibration import fit_calibration, nees_coverage, row_nees

    out = []
    for part in np.array_split(np.arange(len(drives)), k):
        mine = [int(i) for i in part]
        factors, used = fit_calibration(np.vstack([drives[i] for i in mine]))
        rest = np.vstack([d for i, d in enumerate(drives) if i not in mine])
        rest = rest[rest[:, 17] < 0.5]  # the cycles a fit uses: not lost
        cov = nees_coverage(row_nees(rest, factors))
        out.append({"seeds": [seeds[int(part[0])], seeds[int(part[-1])]], "factors": [float(f"{v:.6g}") for v in factors],
                    "fit_cycles": used, "others": {n: cov[n] for n in ("cycles", "below", "inside", "above", "anees")}})
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--configs", nargs="+", default=list(SHIPPED_CONFIGS), choices=list(SHIPPED_CONFIGS))
    p.add_argument("--seeds", nargs="+", type=int, default=list(CALIBRATION_SEEDS))
    p.add_argument("--cycles", type=int, default=CALIBRATION_CYCLES)
    p.add_argument("--out-dir", default=str(DATA_DIR))
    p.add_argument("--spread", type=int, default=0, help="also fit K disjoint sets of the seeds alone (0: no)")
    p.add_argument("--spread-out", type=Path, default=Path("results/pose_calibration_spread.json"))
    a = p.parse_args(argv)
    if a.cycles < 10:
        p.error(f"--cycles must be >= 10, got {a.cycles}")
    if a.spread and not 2 <= a.spread <= len(a.seeds):
        p.error(f"--spread must be 0 or in [2, {len(a.seeds)}] (the number of seeds), got {a.spread}")
    import rhs_env  # noqa: F401  (registers the env ids)

    started, spreads, fitted = time.time(), {}, []
    for name in a.configs:
        env_id, kw = SHIPPED_CONFIGS[name]
        t0 = time.perf_counter()
        drives, key, setup = calibrate_env_drives(env_id, kw, tuple(a.seeds), a.cycles)
        cal = calibration_from_rows(np.vstack(drives), key, tuple(a.seeds), a.cycles, setup)
        fitted.append(cal)
        print(f"{name}: {[float(f'{v:.4g}') for v in cal.factors]} ({cal.fit_cycles} cycles, "
              f"{time.perf_counter() - t0:.0f} s)", flush=True)
        if a.spread:
            spreads[name] = {"key": key, "factors": cal.factors.tolist(), "sets": spread(drives, list(a.seeds), a.spread)}
            for s in spreads[name]["sets"]:
                print(f"  seeds {s['seeds'][0]}-{s['seeds'][1]} alone: {[float(f'{v:.3g}') for v in s['factors']]}, "
                      f"on the others inside {s['others']['inside']:.3f} above {s['others']['above']:.3f}", flush=True)
    if a.spread:
        from rhs_studies.kit.provenance import write_json

        write_json(a.spread_out, {"cycles": a.cycles, "seeds": list(a.seeds), "sets": a.spread, "configs": spreads},
                   "scripts/calibrate_pose_covariance.py", vars(a), started, argv=argv)
        print(f"wrote {a.spread_out}")
    for cal in fitted:  # after the results file: its provenance sees the tree the calibrations were fitted from
        path = Path(a.out_dir) / f"pose_cov_{cal.key}.json"
        write_text_atomic(path, cal.to_json())
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
