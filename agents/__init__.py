"""Driving agents: training, evaluation, policies, the demo."""

from pathlib import Path

#: the shipped policy, under its role name: what ``rhs-slam demo`` and ``rhs-slam evaluate`` drive by default. Its
#: record (``shipped.json`` beside it) is the experiment's, with ``lineage`` naming the experiment it is a byte copy
#: of (``agents/data/rl/shield_flank_explore_lane_time.zip``, kept where results and recorded commands name it), the
#: study that chose and tested it, and the commit and command that trained it. ``python scripts/ship_policy.py
#: EXPERIMENT.zip`` replaces it (CONTRIBUTING.md, "The shipped policy").
SHIPPED_POLICY = Path(__file__).parent / "data" / "shipped.zip"

__all__ = ["SHIPPED_POLICY"]
