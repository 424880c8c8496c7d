"""The ``Example:`` blocks of the public wrappers and helpers run as tests."""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = (
    "rhs_common.validation",
    "rhs_common.timing",
    "rhs_common.jit",
    "rhs_env.radar_config",
    "rhs_env.wrappers",
    "slam.gym.wrappers",
    "slam.gym.metrics_info",
    "agents.policies.decision",
    "agents.policies.shield",
    "rhs_studies.driving.rl_finetune",
    "rhs_studies.driving.rl_lane_rule_trial",
    "rhs_studies.kit.seeds",
    "rhs_studies.kit.pool",
    "rhs_studies.kit.tables",
)


@pytest.mark.parametrize("name", MODULES)
def test_examples_run(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0, f"{name} has no Example: block"
    assert result.failed == 0
