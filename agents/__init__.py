"""Driving agents: training, evaluation, policies, the demo.

The package is grouped by concern: :mod:`agents.policies` holds the drivers and the parts of a policy (the scripted
drivers, the decision interval, the shield, the feature extractor, the privileged critic's input, a policy file's
record), :mod:`agents.algos` the training algorithms and their plumbing (PPO / DQN, DAgger, fine-tuning, RLlib,
the run's hyperparameters, vector envs, checks, threads and records, callbacks, resuming, reward shaping). The
modules users run stay here: :mod:`agents.evaluate` (``rhs-slam evaluate``, ``load_policy``), :mod:`agents.record`
(``rhs-slam record``) and :mod:`agents.demo` (``rhs-slam demo``).

The modules' paths before the subpackages (:data:`OLD_PATHS`) still import: ``agents.features`` is the module
``agents.policies.features`` itself (so the policy zips that pickle ``agents.features.PointSetExtractor`` load), and
``agents.run_setup`` re-exports the names of the five modules it was split into.
"""

from pathlib import Path

#: the shipped policy, under its role name: what ``rhs-slam demo`` and ``rhs-slam evaluate`` drive by default. Its
#: record (``shipped.json`` beside it) is the experiment's, with ``lineage`` naming the experiment it is a byte copy
#: of (``agents/data/rl/shield_flank_explore_lane_time.zip``, kept where results and recorded commands name it), the
#: study that chose and tested it, and the commit and command that trained it. ``python scripts/ship_policy.py
#: EXPERIMENT.zip`` replaces it (CONTRIBUTING.md, "The shipped policy").
SHIPPED_POLICY = Path(__file__).parent / "data" / "shipped.zip"

#: a module's path before the subpackages -> the module(s) it is now; each old path is a module of its own that
#: imports as before (the same module object, or for ``agents.run_setup`` the re-export of its parts)
OLD_PATHS: dict[str, tuple[str, ...]] = {
    **{f"agents.{name}": (f"agents.policies.{name}",) for name in (
        "decision", "expert", "features", "lookahead", "policy_record", "privileged", "rllib_policy", "shield")},
    **{f"agents.{name}": (f"agents.algos.{name}",) for name in (
        "callbacks", "finetune", "imitation", "policy_kwargs", "resume", "rllib", "shaping", "train")},
    "agents.run_setup": tuple(f"agents.algos.{name}" for name in (
        "hyperparams", "vec_env", "run_checks", "run_records", "threads")),
}

__all__ = ["OLD_PATHS", "SHIPPED_POLICY"]
