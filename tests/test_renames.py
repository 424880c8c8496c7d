"""Renamed modules keep their old names working: recorded commands rerun and old imports resolve.

* ``scripts/update_readme.py`` runs :mod:`rhs_studies.write_results_pages` (its new name), as
  ``scripts/write_results_pages.py`` does;
* ``scripts/rl_lane_test.py``, the command ``results/rl_lane_test.json`` records and the study's key in
  ``results/fingerprints.json``, runs :mod:`rhs_studies.rl_lane_rule_trial`, and ``reproduce`` finds that module's
  ``fingerprint()`` through it;
* ``slam.gym.wrapper`` (now :mod:`slam.gym.wrappers`, like ``rhs_env.wrappers``) still gives the same objects, with a
  ``DeprecationWarning``.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

from rhs_studies import provenance, reproduce

ROOT = Path(__file__).resolve().parents[1]


def _launched_module(script: str) -> str:
    """The module whose ``main`` ``scripts/<script>`` imports."""
    tree = ast.parse((ROOT / "scripts" / script).read_text())
    (module,) = [n.module for n in tree.body if isinstance(n, ast.ImportFrom) and any(a.name == "main" for a in n.names)]
    return module or ""


@pytest.mark.parametrize(("script", "module"), [
    ("update_readme.py", "rhs_studies.upkeep.write_results_pages"),
    ("write_results_pages.py", "rhs_studies.upkeep.write_results_pages"),
    ("rl_lane_test.py", "rhs_studies.driving.rl_lane_rule_trial"),
])
def test_old_and_new_launchers_run_the_renamed_module(script, module):
    assert _launched_module(script) == module


def test_the_old_page_writer_command_still_runs():
    proc = subprocess.run([sys.executable, "scripts/update_readme.py", "--check"], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode in (0, 1), proc.stderr  # 1: a page is out of date, which test_results_fresh reports


def test_the_lane_rule_study_keeps_its_recorded_command_and_fingerprint_key():
    from rhs_studies import rl_lane_rule_trial

    step = reproduce.BY_NAME["rl_lane_test"]
    assert reproduce.load_script(step.script) is rl_lane_rule_trial
    assert reproduce.fingerprint_fn(step) is rl_lane_rule_trial.fingerprint
    assert provenance.command_line(rl_lane_rule_trial.LAUNCHER, [])[1] == f"scripts/{step.script}"
    assert provenance.script_name(rl_lane_rule_trial.LAUNCHER) in provenance.load_fingerprints()
    recorded = json.loads((provenance.RESULTS / "rl_lane_test.json").read_text())["provenance"]["command"]
    assert recorded[1] == f"scripts/{step.script}"


def test_the_old_wrapper_module_gives_the_same_objects_with_a_warning():
    import slam.gym.wrapper as old
    import slam.gym.wrappers as new

    with pytest.warns(DeprecationWarning, match="slam.gym.wrappers"):
        assert old.SlamObservation is new.SlamObservation
    assert old.__all__ == new.__all__ and "SlamObservation" in new.__all__
    namespace: dict = {}
    with pytest.warns(DeprecationWarning):
        exec("from slam.gym.wrapper import *", namespace)
    assert {n: namespace[n] for n in new.__all__} == {n: getattr(new, n) for n in new.__all__}
    with pytest.raises(AttributeError):
        old.no_such_name  # noqa: B018
