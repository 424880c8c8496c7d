"""Put a chosen and tested policy under the shipped policy's role name, ``agents/data/shipped.zip``.

``rhs-slam demo`` and ``rhs-slam evaluate`` drive :data:`agents.SHIPPED_POLICY` by default: a file named for its
role, not for the experiment that made it, so the default path does not change when a new policy is shipped. This
tool copies an experiment's zip there byte for byte and writes the record beside it (``shipped.json``): the
experiment's record (env, env kwargs, decision interval, shield: what the policy is driven with) with ``model``
set to the role path and ``lineage`` added, naming

* ``experiment``: the zip it is a copy of (it stays where it is: results and recorded commands name it);
* ``study``: the results file of the study that chose and tested it, and that study's commit and seed sets;
* ``trained_commit`` and ``recipe``: the commit and the command that trained it (from its ``trained_by``).

Only a policy a study has shipped may be promoted: its record must carry ``shipped_by`` (written by a study's
``--ship``, e.g. ``python scripts/rl_lane_test.py --ship``, which refuses unless every target was met on the test
seeds). The output depends only on the experiment's files, so promoting the same experiment again writes the same
bytes (``--check`` compares instead of writing).

    python scripts/ship_policy.py agents/data/rl/shield_flank_explore_lane_time.zip
    python scripts/ship_policy.py agents/data/rl/shield_flank_explore_lane_time.zip --check
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path
from typing import Any

from agents import SHIPPED_POLICY
from agents.policies.policy_record import read_record, sidecar_path

__all__ = ["main", "shipped_record", "ship_policy"]

ROOT = Path(__file__).resolve().parents[2]


def _rel(path: Path) -> str:
    path = path.resolve()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def shipped_record(experiment: str | Path, role: Path = SHIPPED_POLICY) -> dict[str, Any]:
    """The record of ``role`` when it is a copy of ``experiment``.

    Args:
        experiment: a policy zip whose record carries ``shipped_by`` (a study chose and tested it).
        role: the role path the copy is written to.

    Returns:
        ``experiment``'s record with ``model`` set to ``role`` and ``lineage`` naming the experiment, the study,
        the training commit and command.

    Raises:
        ValueError: the experiment has no record, or its record no ``shipped_by`` (no study shipped it).
    """
    experiment = Path(experiment)
    record = read_record(experiment)
    if "shipped_by" not in record:
        raise ValueError(f"{experiment}: its record has no 'shipped_by': only a policy a study chose and tested may "
                         "be shipped (run the study's --ship first, e.g. python scripts/rl_lane_test.py --ship)")
    by, trained = dict(record["shipped_by"]), dict(record.get("trained_by") or {})
    lineage = {"experiment": _rel(experiment), "study": by.get("study"), "study_commit": by.get("commit"),
               "validation_seeds": by.get("validation_seeds"), "test_seeds": by.get("test_seeds"),
               "trained_commit": trained.get("commit"), "recipe": trained.get("command")}
    return {**record, "model": _rel(role), "lineage": lineage}


def ship_policy(experiment: str | Path, role: Path = SHIPPED_POLICY, check: bool = False) -> list[Path]:
    """Copy ``experiment`` to ``role`` and write its record (:func:`shipped_record`) beside it.

    Args:
        experiment: the policy zip to ship.
        role: where (default :data:`agents.SHIPPED_POLICY`).
        check: write nothing; return the files that differ from what would be written.

    Returns:
        The files written (``check``: the files out of date).
    """
    experiment, role = Path(experiment), Path(role)
    text = json.dumps(shipped_record(experiment, role), indent=2) + "\n"
    out = sidecar_path(role)
    if check:
        stale = [] if role.is_file() and role.read_bytes() == experiment.read_bytes() else [role]
        return stale + ([] if out.is_file() and out.read_text() == text else [out])
    role.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(experiment, role)
    out.write_text(text)
    return [role, out]


def main(argv: list[str] | None = None) -> int:
    """``python scripts/ship_policy.py EXPERIMENT.zip [--check]``."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("experiment", help="the policy zip a study shipped (its record has 'shipped_by')")
    ap.add_argument("--check", action="store_true", help="exit 1 if the shipped policy is not that copy")
    args = ap.parse_args(argv)
    try:
        files = ship_policy(args.experiment, check=args.check)
    except (ValueError, OSError) as err:
        print(f"ship_policy: {err}", file=sys.stderr)
        return 2
    for f in files:
        print(f"{'out of date' if args.check else 'wrote'}: {_rel(f)}")
    return 1 if args.check and files else 0


if __name__ == "__main__":
    sys.exit(main())
