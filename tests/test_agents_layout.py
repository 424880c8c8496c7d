"""The agents package grouped by concern (agents.policies, agents.algos), its old flat module paths kept working."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import agents

ROOT = Path(__file__).resolve().parents[1]
#: agents.run_setup's names before it was split (the old module's ``__all__``)
RUN_SETUP_NAMES = (
    "ALGOS", "EnvFactory", "FORKSERVER_PRELOAD", "HP_NUMBERS", "HP_SCHEDULES", "HYPERPARAMS_DIR", "META_KEYS",
    "RunSettings", "WARM_STEPS", "check_env_kwargs", "check_hyperparams", "check_train_args", "eval_policy_kwargs",
    "limit_threads", "load_hyperparams", "make_vec_env", "metadata_path", "parse_env_kwargs", "policy_kwargs_by_name",
    "resolve_policy_kwargs", "run_record", "run_settings", "run_summary", "shield_setting",
    "start_forkserver_ignoring_sigint", "tensorboard_available", "update_threads_for", "warm_kernels", "worker_env_id",
    "write_summary",
)


def test_every_flat_module_is_an_entry_module_or_an_old_path():
    """agents/ holds the modules users run and the old paths; the rest lives in the subpackages."""
    flat = {f"agents.{p.stem}" for p in (ROOT / "agents").glob("*.py") if p.stem != "__init__"}
    assert flat - set(agents.OLD_PATHS) == {"agents.evaluate", "agents.record", "agents.demo"}
    for new in agents.OLD_PATHS.values():
        for name in new:
            assert (ROOT / Path(*name.split("."))).with_suffix(".py").exists(), name


@pytest.mark.parametrize("old", sorted(name for name, new in agents.OLD_PATHS.items() if len(new) == 1))
def test_an_old_path_is_the_module_itself(old):
    (new,) = agents.OLD_PATHS[old]
    module = importlib.import_module(old)
    assert module is importlib.import_module(new) and sys.modules[old] is module


def test_the_old_run_setup_re_exports_its_names_from_its_parts():
    import agents.run_setup as old

    assert tuple(old.__all__) == RUN_SETUP_NAMES
    parts = [importlib.import_module(name) for name in agents.OLD_PATHS["agents.run_setup"]]
    for name in RUN_SETUP_NAMES:
        owners = [p for p in parts if name in p.__all__]
        assert len(owners) == 1 and getattr(old, name) is getattr(owners[0], name), name
    assert sorted(n for p in parts for n in p.__all__) == sorted(RUN_SETUP_NAMES)


def test_a_pickle_naming_the_old_class_path_loads_in_a_fresh_interpreter():
    """The shipped policy zips pickle ``agents.features.PointSetExtractor`` (their policy_kwargs); a fresh process
    that has imported nothing of agents resolves it to the class of agents.policies.features."""
    code = ("import pickle; cls = pickle.loads(b'cagents.features\\nPointSetExtractor\\n.'); "
            "import agents.policies.features as f; print(cls is f.PointSetExtractor, cls.__module__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.split() == ["True", "agents.policies.features"]


def test_the_zoo_expression_names_the_extractor_under_both_paths():
    from agents.algos.policy_kwargs import parse_policy_kwargs
    from agents.policies.features import PointSetExtractor

    for module in ("agents.features", "agents.policies.features"):
        kw = parse_policy_kwargs(f"dict(features_extractor_class=importlib.import_module('{module}').PointSetExtractor)")
        assert kw["features_extractor_class"] is PointSetExtractor
