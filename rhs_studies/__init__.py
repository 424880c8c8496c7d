"""The research kit: the studies behind ``results/`` as importable modules, on top of the packages.

Each study is a module with a ``main(argv)`` (run it as ``python -m rhs_studies.ROOM.NAME`` or, as every results
file's ``provenance.command`` records, ``python scripts/NAME.py``: the files in ``scripts/`` launch these modules)
and, where it writes results, a small-config ``fingerprint()`` that :mod:`rhs_studies.upkeep.reproduce` checks against
``results/fingerprints.json``. The studies live in topic rooms (:data:`ROOMS`: ``radar``, ``patterns``, ``slam``,
``driving``, ``bench``, ``upkeep``); what they share is the kit, :mod:`rhs_studies.kit` (the study runner, the pool,
the seed ledger, tables, the RL arms, provenance, episodes and scenes). A study imports the kit and the packages,
never another study (``tests/test_architecture.py``). The studies read and write the repository's ``results/``,
so they run from a source checkout.

A module's path before the rooms (``rhs_studies.NAME``: a study, or one of the shared modules now in the kit,
:data:`KIT_MODULES`) still imports it: the same module object (:class:`_MovedStudies`, :data:`MOVED`), and
``python -m rhs_studies.NAME`` still runs it, so code and commands written before keep working. The top of the
package holds no module but this one (``tests/test_architecture.py``).

Layering: the top layer, above ``rhs_slam``; it imports the packages, nothing imports it.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
from types import CodeType, ModuleType

#: room -> its study modules (a module of a room is ``rhs_studies.ROOM.NAME``)
ROOMS: dict[str, tuple[str, ...]] = {
    "radar": ("radar_quality", "radar_profiles", "detection_curves", "fig5b_pointcloud_vs_elements",
              "calibrate_fast_radar", "fast_radar_fidelity"),
    "patterns": ("build_patterns", "compare_pattern_methods", "pattern_sidelobe_limits"),
    "slam": ("fig5a_slam_rmse", "fig5c_trajectory_map", "low_snr_slam", "registration_in_loop", "train_registration",
             "compare_drives", "claim_study", "claim_study_report", "long_drive", "racetrack_loops", "slam_accuracy",
             "pose_covariance"),
    "driving": ("train_policy", "evaluate_policies", "ablate_policy", "rl_finetune", "rl_confirm",
                "rl_lane_rule_trial", "teachers", "crash_analysis", "shield_sensing", "comparisons", "campaign",
                "campaign_report", "shield_table", "bc_from_dataset"),
    "bench": ("benchmark", "benchmark_radar", "benchmark_patterns", "benchmark_rllib", "traffic_alignment",
              "startup_fresh_clone"),
    "upkeep": ("write_results_pages", "fingerprint_tolerance", "refresh_constraints", "ship_policy", "make_video",
               "reproduce", "kit_counts"),
}
#: the shared modules that moved from the top of the package into the kit (``rhs_studies.NAME`` ->
#: ``rhs_studies.kit.NAME``): provenance, the episodes, the scenes, a subprocess's environment
KIT_MODULES: tuple[str, ...] = ("provenance", "episodes", "scenes", "subprocess_env")
#: a module's name before the rooms -> its module path now: a study's in its room, a shared module's in the kit
MOVED: dict[str, str] = {
    **{name: f"{__name__}.{room}.{name}" for room, names in ROOMS.items() for name in names},
    **{name: f"{__name__}.kit.{name}" for name in KIT_MODULES},
}


class _Alias(importlib.abc.Loader):
    """Loads ``rhs_studies.NAME`` as the module ``target`` itself (one module object under both names)."""

    def __init__(self, target: str) -> None:
        self.target = target

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        return importlib.import_module(self.target)

    def exec_module(self, module: ModuleType) -> None:
        """Nothing: the target ran when it was imported."""

    def get_code(self, fullname: str) -> CodeType | None:
        """The target's code: what ``python -m rhs_studies.NAME`` (runpy) runs as ``__main__``."""
        spec = importlib.util.find_spec(self.target)
        return spec.loader.get_code(self.target) if spec and isinstance(spec.loader, importlib.abc.InspectLoader) else None


class _MovedStudies(importlib.abc.MetaPathFinder):
    """Finds the moved modules (studies, the kit's shared modules) by their names before the rooms (:data:`MOVED`)."""

    def find_spec(self, fullname: str, path: object = None, target: object = None) -> importlib.machinery.ModuleSpec | None:
        parent, _, name = fullname.rpartition(".")
        if parent != __name__ or name not in MOVED:
            return None
        target = importlib.util.find_spec(MOVED[name])
        return importlib.util.spec_from_loader(fullname, _Alias(MOVED[name]), origin=target.origin if target else None)


if not any(isinstance(f, _MovedStudies) for f in sys.meta_path):
    sys.meta_path.append(_MovedStudies())

__all__ = ["KIT_MODULES", "MOVED", "ROOMS"]
