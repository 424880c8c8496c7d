"""Fit the calibrated pose covariance's factors of SLAM env configurations (:mod:`slam.gym.pose_calibration`).

``python scripts/calibrate_pose_covariance.py [--configs default grid5 dense fast] [--seeds 13000 ...]
[--cycles 80] [--out-dir slam/data/pose_calibration]``

Writes ``pose_cov_<key>.json`` per configuration (:data:`slam.gym.pose_calibration.SHIPPED_CONFIGS`): the
files the package ships, which the envs made with ``pipeline={"pose_covariance": "calibrated"}`` load instead of
calibrating at first use. ``tests/test_pose_calibration.py`` checks that this reproduces the shipped fast-radar
calibration.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from rhs_common.output_files import write_text_atomic
from slam.gym.pose_calibration import CALIBRATION_CYCLES, CALIBRATION_SEEDS, DATA_DIR, SHIPPED_CONFIGS, calibrate_env


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--configs", nargs="+", default=list(SHIPPED_CONFIGS), choices=list(SHIPPED_CONFIGS))
    p.add_argument("--seeds", nargs="+", type=int, default=list(CALIBRATION_SEEDS))
    p.add_argument("--cycles", type=int, default=CALIBRATION_CYCLES)
    p.add_argument("--out-dir", default=str(DATA_DIR))
    a = p.parse_args(argv)
    if a.cycles < 10:
        p.error(f"--cycles must be >= 10, got {a.cycles}")
    import rhs_env  # noqa: F401  (registers the env ids)

    for name in a.configs:
        env_id, kw = SHIPPED_CONFIGS[name]
        t0 = time.perf_counter()
        cal = calibrate_env(env_id, kw, tuple(a.seeds), a.cycles)
        path = Path(a.out_dir) / f"pose_cov_{cal.key}.json"
        write_text_atomic(path, cal.to_json())
        print(f"{name}: {[float(f'{v:.4g}') for v in cal.factors]} ({cal.fit_cycles} cycles, {time.perf_counter() - t0:.0f} s) "
              f"-> {path}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
