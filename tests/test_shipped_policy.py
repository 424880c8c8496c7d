"""The shipped policy under its role name (agents/data/shipped.zip) and the tool that puts a policy there."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from agents import SHIPPED_POLICY
from agents.policies.policy_record import read_record
from rhs_studies.upkeep import ship_policy

ROOT = Path(__file__).resolve().parent.parent


def test_the_shipped_policy_is_its_lineage_experiment_with_the_same_record():
    record = read_record(SHIPPED_POLICY)
    lineage = record["lineage"]
    experiment = ROOT / lineage["experiment"]
    assert SHIPPED_POLICY.read_bytes() == experiment.read_bytes()
    # what it is driven with is the experiment's record; only the model path and the lineage differ
    assert {k: v for k, v in record.items() if k not in ("model", "lineage")} == \
        {k: v for k, v in read_record(experiment).items() if k != "model"}
    assert record["model"] == "agents/data/shipped.zip"
    assert (ROOT / lineage["study"]).is_file() and lineage["test_seeds"] and lineage["trained_commit"]
    assert lineage["recipe"][:2] == ["rhs_slam", "train"]
    # the files are what the tool writes from that experiment (nothing out of date)
    assert ship_policy.ship_policy(experiment, check=True) == []


def test_ship_policy_copies_a_shipped_experiment_and_refuses_one_no_study_shipped(tmp_path):
    experiment = ROOT / read_record(SHIPPED_POLICY)["lineage"]["experiment"]
    role = tmp_path / "data" / "shipped.zip"
    assert ship_policy.ship_policy(experiment, role, check=True) == [role, role.with_suffix(".json")]
    assert ship_policy.ship_policy(experiment, role) == [role, role.with_suffix(".json")]
    assert role.read_bytes() == experiment.read_bytes()
    assert json.loads(role.with_suffix(".json").read_text())["lineage"]["experiment"] == str(
        experiment.relative_to(ROOT))
    assert ship_policy.ship_policy(experiment, role, check=True) == []
    role.with_suffix(".json").write_text("{}")
    assert ship_policy.ship_policy(experiment, role, check=True) == [role.with_suffix(".json")]
    # an arm no study chose and tested (no shipped_by in its record) is refused, naming the step that ships it
    arm = tmp_path / "arm.zip"
    shutil.copyfile(experiment, arm)
    record = read_record(experiment)
    del record["shipped_by"]
    arm.with_suffix(".json").write_text(json.dumps(record))
    with pytest.raises(ValueError, match="no 'shipped_by'.*--ship"):
        ship_policy.shipped_record(arm)
    assert ship_policy.main([str(arm), "--check"]) == 2


def test_every_user_of_the_default_policy_reads_the_one_constant():
    from agents import demo, evaluate, record

    assert evaluate.SHIPPED_POLICY is SHIPPED_POLICY
    for module in (demo, record):
        assert module.SHIPPED_POLICY is SHIPPED_POLICY
    # the experiment's old path still drives the same policy (recorded commands name it)
    assert evaluate.RL_FINETUNE_POLICY.read_bytes() == SHIPPED_POLICY.read_bytes()
