"""Paired comparison of two ``slam_accuracy.py --parts drivers`` runs, drive by drive.

A radar or SLAM setting is judged on the same drives as the default: run the drivers part twice
on the same seeds, once with the setting (``--radar JSON`` or ``--slam JSON``), and compare the
two results files here. Every drive (env, driver, seed) present in both is a pair; for each group
of drivers and each env the table gives

* the mean and worst episode position RMSE of each run, m;
* the paired difference ``d = RMSE_new - RMSE_base`` averaged over the drives, with its 95 %
  Student-t interval (:func:`rhs_common.stats.paired_difference`, the studies' one definition): an interval
  that excludes 0 says the setting moved the error on these drives;
* the geometric mean of ``RMSE_new / RMSE_base`` (a typical drive's factor, which the few worst
  drives do not dominate);
* the pooled 3-dof pose NEES inside its 95 % chi-square interval, % of cycles, each run.

    python scripts/slam_accuracy.py --parts drivers --driver-seeds $(seq 1000 1019) --workers 2 --out /tmp/rhs-slam/base
    python scripts/slam_accuracy.py --parts drivers --driver-seeds $(seq 1000 1019) --workers 2 --out /tmp/rhs-slam/new \\
        --radar '{"estimation": {"oversampling": 2, "newton_steps": 1}}'
    python scripts/compare_drives.py /tmp/rhs-slam/base.json /tmp/rhs-slam/new.json [--json /tmp/rhs-slam/compare.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from rhs_common.stats import paired_difference

#: the rows of the table: driver groups (IDM and policy together: the drives the accuracy goal is about)
GROUPS: tuple[tuple[str, ...], ...] = (("idm", "policy"), ("idm",), ("policy",), ("random",))

Drive = tuple[str, str, int]  # (env, driver, seed)


def load_drives(path: str | Path) -> dict[Drive, dict]:
    """The per-drive records of a slam_accuracy results file, keyed by (env, driver, seed).

    Raises ``ValueError`` naming the file when it has no drivers part.
    """
    data = json.loads(Path(path).read_text())
    try:
        combos = data["parts"]["drivers"]["combos"]
    except (KeyError, TypeError):
        raise ValueError(f"{path}: no drivers part (run slam_accuracy.py with --parts drivers)") from None
    return {(c["env"], c["driver"], int(r["seed"])): r for c in combos.values() for r in c["runs"]}


@dataclass(frozen=True)
class PairedRow:
    """One driver group on one env (``env = "both"``: pooled over the envs)."""

    drivers: str
    env: str
    drives: int
    base_mean_m: float
    new_mean_m: float
    base_worst_m: float
    new_worst_m: float
    paired_mean_m: float
    paired_ci95_m: tuple[float, float]
    geometric_ratio: float
    base_nees_inside: float
    new_nees_inside: float


def _nees_inside(runs: list[dict]) -> float:
    """Pooled fraction of cycles whose pose NEES is inside its 95 % interval (nan without NEES cycles)."""
    cycles = sum(r.get("nees_cycles", 0) for r in runs)
    return sum(r.get("nees_inside", 0) for r in runs) / cycles if cycles else float("nan")


def paired_row(base: dict[Drive, dict], new: dict[Drive, dict], drivers: tuple[str, ...],
               env: str | None) -> PairedRow | None:
    """The paired statistics of the drives both runs share in one group (None when they share none).

    ``d_i = RMSE_new,i - RMSE_base,i`` with its Student-t interval (:func:`paired_difference`; NaN for one drive);
    the geometric ratio is ``exp(mean(log(new / base)))``.
    """
    keys = sorted(k for k in base if k in new and k[1] in drivers and (env is None or k[0] == env))
    if not keys:
        return None
    x = np.array([base[k]["position_rmse_m"] for k in keys])
    y = np.array([new[k]["position_rmse_m"] for k in keys])
    d = paired_difference(y, x)
    return PairedRow("+".join(drivers), env or "both", len(keys), float(x.mean()), float(y.mean()),
                     float(x.max()), float(y.max()), d.mean, (d.low, d.high),
                     float(np.exp(np.mean(np.log(np.maximum(y, 1e-9) / np.maximum(x, 1e-9))))),
                     _nees_inside([base[k] for k in keys]), _nees_inside([new[k] for k in keys]))


def compare(base: dict[Drive, dict], new: dict[Drive, dict]) -> list[PairedRow]:
    """Every driver group of ``GROUPS`` on each env the runs share, then on both envs pooled."""
    envs = sorted({k[0] for k in base} & {k[0] for k in new})
    rows = (paired_row(base, new, g, e) for g in GROUPS for e in [*envs, None])
    return [r for r in rows if r is not None]


def markdown(rows: list[PairedRow]) -> str:
    """The table, one row per group and env."""
    head = ("| drivers | env | drives | RMSE mean base -> new (m) | worst base -> new (m) | paired new - base (m), 95 % CI "
            "| geometric ratio | NEES inside base -> new |\n|---|---|---:|---|---|---|---:|---|\n")
    return head + "".join(
        f"| {r.drivers} | {r.env} | {r.drives} | {r.base_mean_m:.3f} -> {r.new_mean_m:.3f} | "
        f"{r.base_worst_m:.3f} -> {r.new_worst_m:.3f} | {r.paired_mean_m:+.3f} "
        f"[{r.paired_ci95_m[0]:+.3f}, {r.paired_ci95_m[1]:+.3f}] | {r.geometric_ratio:.2f} | "
        f"{100 * r.base_nees_inside:.1f} % -> {100 * r.new_nees_inside:.1f} % |\n" for r in rows)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("base", help="slam_accuracy results JSON of the reference setting")
    p.add_argument("new", help="slam_accuracy results JSON of the setting under test (same seeds)")
    p.add_argument("--json", help="also write the rows to this JSON file")
    args = p.parse_args(argv)
    try:
        base, new = load_drives(args.base), load_drives(args.new)
    except (OSError, ValueError) as err:
        p.error(str(err))
    rows = compare(base, new)
    if not rows:
        p.error("the two runs share no drive (env, driver, seed): run them on the same seeds")
    print(markdown(rows), end="")
    if args.json:
        Path(args.json).write_text(json.dumps([asdict(r) for r in rows], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
