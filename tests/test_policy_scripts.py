"""scripts/train_policy.py and scripts/evaluate_policies.py: targets, env kwargs, intervals, the antenna table."""

from __future__ import annotations

from pathlib import Path

import pytest

from rhs_studies import evaluate_policies, train_policy

SCRIPTS = Path(__file__).resolve().parent.parent / "scripts"


def test_targets_merge_the_radar_settings_and_ship_where_evaluate_looks():
    from agents.evaluate import DAGGER_POLICY, PPO_POLICY, SHIPPED_POLICY, SHIPPED_TRUTH_POLICY, policy_metadata
    from rhs_studies.rl_finetune import SHIPPED_DIR

    grid = {"radar": {"scan": {"grid_deg": 5}}}
    assert train_policy.target_env_kwargs("slam", grid) == grid
    assert train_policy.target_env_kwargs("truth", grid) == {}
    assert train_policy.target_env_kwargs("dense_phased", grid) == {"radar": {"scan": {"grid_deg": 5}, "antenna": "phased"}}
    assert train_policy.target_path("dagger", "slam") == DAGGER_POLICY
    # the shipped policy (the RL fine-tune) continues that student (through the study's DAgger continuation and the
    # 30 m/s teacher's two students), where the study ships its arms; every link of the chain is shipped
    # the shipped policy has a role name; its record names the experiment it is a byte copy of, shipped by the study
    import agents

    assert SHIPPED_POLICY == agents.SHIPPED_POLICY and SHIPPED_POLICY.name == "shipped.zip"
    experiment = train_policy.ROOT / policy_metadata(SHIPPED_POLICY)["lineage"]["experiment"]
    assert experiment.parent == SHIPPED_DIR and SHIPPED_POLICY.read_bytes() == experiment.read_bytes()
    chain, link = [], SHIPPED_POLICY
    while link.resolve() != DAGGER_POLICY.resolve() and len(chain) < 6:
        chain.append(link)
        link = train_policy.ROOT / policy_metadata(link)["init_policy"]
        assert link.exists(), f"{chain[-1]} continues {link}, which is not shipped"
    assert link.resolve() == DAGGER_POLICY.resolve() and len(chain) == 4
    assert [p.name for p in chain] == ["shipped.zip", "dagger_cruise30_close.zip",
                                       "dagger_cruise30_gap.zip", "dagger_continue_80k.zip"]
    shipped = policy_metadata(SHIPPED_POLICY)
    assert shipped["shield"]["min_points"] >= 2 and shipped["algo"] == "finetune"  # RL, behind the radar shield
    # the shipped fine-tune is the study's arm behind the lane rule its study chose and tested: same weights, the
    # record the arm's but for the shield's rule and the study named
    arm = SHIPPED_DIR / shipped["shipped_by"]["copied_from"]
    assert SHIPPED_POLICY.read_bytes() == arm.read_bytes()
    rule = shipped["shipped_by"]["shield_rule"]
    assert shipped["shield"] == {**policy_metadata(arm)["shield"], **rule} and rule
    assert train_policy.target_path("dagger", "truth") == SHIPPED_TRUTH_POLICY
    assert train_policy.target_path("ppo", "slam") == PPO_POLICY
    assert train_policy.target_env_kwargs("truth_all_around", grid)["observation"]["see_behind"] is True
    assert train_policy.target_path("dagger", "slam_phased").parent.name == "antenna"
    # --env-kwargs (every target's: the action set) lies under the radar and observation settings
    fine = train_policy.FINE_SPEEDS
    assert train_policy.target_env_kwargs("truth", grid, fine) == fine
    assert train_policy.target_env_kwargs("slam", grid, fine) == {**fine, **grid}
    assert train_policy.target_env_kwargs("truth_all_around", grid, fine)["action"] == fine["action"]
    assert set(train_policy.ANTENNA_STUDY) <= set(train_policy.TARGETS)


def test_antenna_study_pairs_differ_only_in_the_antenna():
    """Goal 2 compares students trained alike: same env steps, expert, hyperparameters and action set; only the
    ``radar.antenna`` of their env kwargs differs."""
    from agents.evaluate import policy_metadata

    pairs = [("slam_rhs", "slam_phased"), ("dense", "dense_phased")]
    trained = [(a, b) for a, b in pairs if all(train_policy.target_path("dagger", n).exists() for n in (a, b))]
    assert trained, "no antenna-study pair is shipped (scripts/train_policy.py --only slam_rhs slam_phased)"
    for a, b in trained:
        ma, mb = (policy_metadata(train_policy.target_path("dagger", n)) for n in (a, b))
        for key in ("env_id", "timesteps", "n_envs", "hyperparams", "expert", "decision_interval"):
            assert ma[key] == mb[key], (a, b, key)
        ka, kb = ({**m["env_kwargs"], "radar": {k: v for k, v in m["env_kwargs"]["radar"].items() if k != "antenna"}}
                  for m in (ma, mb))
        assert ka == kb and mb["env_kwargs"]["radar"]["antenna"] == "phased"


def test_goal_references_drive_on_the_action_set_the_goal_was_issued_with():
    """results/policies.json: the students drive on their own action set, always SLOWER and IDM + MOBIL on
    highway-env's default one (always SLOWER then holds 20 m/s, not the students' lowest target speed)."""
    import json

    rows = {r["key"]: r for r in json.loads((SCRIPTS.parent / "results" / "policies.json").read_text())["rows"]}
    default = evaluate_policies.target_speeds({})
    assert default == [20.0, 25.0, 30.0]  # highway-env's MDPVehicle.DEFAULT_TARGET_SPEEDS
    for key in ("slower", "idm"):
        assert evaluate_policies.target_speeds(rows[key]["env_kwargs"]) == default, key
    assert rows["slower"]["summary"]["mean_speed_mps"]["mean"] == pytest.approx(20.0, abs=0.5)
    student = evaluate_policies.target_speeds(rows["slam"]["env_kwargs"])
    assert student == evaluate_policies.target_speeds(rows["truth"]["env_kwargs"])
    assert evaluate_policies.target_speeds(rows["headway_teacher"]["env_kwargs"]) == student


def test_antenna_table_states_the_paired_verdict():
    row = {"env_id": "rhs-highway-slam-v0", "timesteps": 40000, "return_ci": (150.0, 3.0), "collision_ci": (0.0, 0.07),
           "summary": {"collision_rate": 0.0, "collisions": 0, "episodes": 50, "mean_speed_mps": {"mean": 23.0, "std": 1.0},
                       "position_rmse_m": {"mean": 0.2, "std": 0.1, "max": 104.23}}}  # fmt: skip
    fine = {"env_kwargs": train_policy.FINE_SPEEDS}
    study = {"episodes": 50, "seeds": list(range(1000, 1050)), "missing": ["dense"],
             "rows": [{**row, "antenna": "rhs", "env_kwargs": {}}, {**row, "antenna": "phased", **fine}],
             "pairs": [{"env_id": "rhs-highway-slam-v0", "return_diff_rhs_minus_phased": (4.0, 1.0)}]}  # fmt: skip
    text = evaluate_policies.antenna_markdown(study)
    assert "| `rhs-highway-slam-v0` | rhs | 20, 25, 30 | 40000 | 150.0 ± 3.0 | 0.00 (0/50; 0.00-0.07)" in text
    assert "| phased | 10, 15, 20, 25, 30 | 40000 |" in text  # the action set each student drove with
    assert "| 0.20 ± 0.10 | 104.23 |" in text  # a lost track shows in the worst episode, not in the mean's spread
    assert "+4.0 ± 1.0 (RHS higher)" in text and "Not trained yet" in text and "dense" in text


def _row(ret: float, collisions: float, speed: float) -> dict:
    return {"return": {"mean": ret}, "collision_rate": collisions, "mean_speed_mps": {"mean": speed}}


def test_goal_compares_each_slam_policy_with_the_better_truth_policy_of_its_algorithm():
    by = {"slower": _row(140.0, 0.0, 20.0), "slam": _row(160.0, 0.04, 24.0), "truth": _row(150.0, 0.1, 24.0),
          "truth_all_around": _row(170.0, 0.1, 24.0), "ppo_slam": _row(140.0, 0.0, 20.0), "ppo_truth": _row(120.0, 0.3, 21.0)}  # fmt: skip
    goal = evaluate_policies.goal_of(by, "slam")
    assert goal["truth_reference"] == "truth_all_around" and goal["return_vs_slower"] == pytest.approx(160 / 140)
    assert goal["met"]  # 1.14x SLOWER, 4 % collisions, faster, 0.94 of the best truth policy
    assert not evaluate_policies.goal_of({**by, "slam": _row(160.0, 0.06, 24.0)}, "slam")["met"]  # collisions
    ppo = evaluate_policies.goal_of(by, "ppo_slam")
    assert ppo["truth_reference"] == "ppo_truth" and not ppo["met"]  # no faster than always-SLOWER


def test_antenna_only_reruns_the_study_and_keeps_the_tables_and_their_provenance(tmp_path, monkeypatch):
    import json

    rows = [{"key": "slam", "policy": "p.zip", "runs": [{"return": 1.0}]}]
    old = {"episodes": 3, "seeds": [1000, 1001, 1002], "rows": rows, "provenance": {"commit": "abc"}}
    (tmp_path / "policies.json").write_text(json.dumps(old))
    seen = {}

    def study(episodes, seed, workers, done):
        seen.update(episodes=episodes, seed=seed, done=done)
        return {"rows": [], "pairs": []}

    monkeypatch.setattr(evaluate_policies, "antenna_study", study)
    monkeypatch.setattr(evaluate_policies, "markdown", lambda result: "table\n")
    monkeypatch.setattr(evaluate_policies, "antenna_markdown", lambda study: "antenna\n")
    monkeypatch.setattr(evaluate_policies, "fingerprint", lambda: [1.0])
    args = ["--antenna-only", "--antenna-episodes", "3", "--out-dir", str(tmp_path)]
    assert evaluate_policies.main(args) == 0
    new = json.loads((tmp_path / "policies.json").read_text())
    assert seen == {"episodes": 3, "seed": 1000, "done": {"p.zip": [{"return": 1.0}]}}  # the goal table's episodes
    assert new["rows"] == rows and new["antenna"] == {"rows": [], "pairs": []}
    assert new["tables_provenance"] == {"commit": "abc"} and "--antenna-only" in new["provenance"]["command"]
    assert evaluate_policies.main(args) == 0  # a second rerun keeps the provenance of the tables' run
    assert json.loads((tmp_path / "policies.json").read_text())["tables_provenance"] == {"commit": "abc"}
    with pytest.raises(SystemExit, match="needs the seeds"):
        evaluate_policies.main(["--antenna-only", "--antenna-episodes", "50", "--out-dir", str(tmp_path)])


def test_ablations_train_and_evaluate_each_algorithm_into_a_table_with_provenance(tmp_path, monkeypatch):
    """ablate_policy: a DAgger variant and a scripted reference land in ``records`` with their commit, the file
    carries the run's provenance, the table names the algorithm and how decisions are filled; --fresh starts over."""
    import json

    from rhs_studies import ablate_policy

    assert set(ablate_policy.REPRODUCE) <= {*ablate_policy.VARIANTS, *ablate_policy.DAGGER_VARIANTS,
                                            *ablate_policy.REFERENCES}
    out = tmp_path / "ablations.json"
    with pytest.raises(SystemExit):
        ablate_policy.main(["no_such_variant", "--out", str(out)])
    ablate_policy.main(["ref_slower", "--episodes", "2", "--out", str(out)])
    legacy = json.loads(out.read_text())["records"]  # the layout of before the provenance block: records at the top
    out.write_text(json.dumps(legacy))
    ablate_policy.main(["dagger_hold_truth", "--timesteps", "100", "--episodes", "2", "--n-envs", "1",
                        "--out", str(out)])
    data = json.loads(out.read_text())
    assert set(data["records"]) == {"dagger_hold_truth/seed0/100", "ref_slower/2"}
    assert data["provenance"]["command"][1] == "scripts/ablate_policy.py"
    rec = data["records"]["dagger_hold_truth/seed0/100"]
    assert rec["algo"] == "dagger" and rec["hyperparams"]["decision_mode"] == "hold"
    assert len(rec["runs"]) == 2 and rec["commit"] and rec["dagger_iterations"]
    table = out.with_suffix(".md").read_text()
    assert "| dagger | `rhs-highway-v0` |" in table and "5 (hold)" in table and "| scripted |" in table
    assert ablate_policy.REFERENCES["ref_headway_fine_speeds"][2] == 200  # its rate is a few %: 200 seeds, always
    monkeypatch.setitem(ablate_policy.REFERENCES, "ref_headway_fine_speeds",
                        (*ablate_policy.REFERENCES["ref_headway_fine_speeds"][:2], None))  # here: --episodes
    ablate_policy.main(["ref_headway_fine_speeds", "--episodes", "2", "--out", str(out), "--fresh"])
    fine = json.loads(out.read_text())["records"]
    assert set(fine) == {"ref_headway_fine_speeds/2"}
    assert fine["ref_headway_fine_speeds/2"]["eval_env_kwargs"]["action"]["target_speeds"][0] == 10
    assert "headway:5 on {\"action\"" in out.with_suffix(".md").read_text()
    import gymnasium as gym

    import rhs_env  # noqa: F401

    env = gym.make("rhs-highway-v0", vehicles_count=2, **ablate_policy.FINE_SPEEDS)
    env.reset(seed=0)
    assert list(env.unwrapped.vehicle.target_speeds) == [10, 15, 20, 25, 30]  # the ego's SLOWER goes below 20 m/s


def test_adopt_ships_another_runs_policies_and_merges_their_records(tmp_path):
    """--adopt: a run kept apart (its own --data-dir / --record) is shipped as it is: zip and metadata copied where
    train_policy ships them, its record merged with ``run`` naming the command and commit; nothing is trained."""
    import json
    import shutil

    from agents.algos.train import metadata_path

    shipped = train_policy.target_path("dagger", "slam_rhs")
    run_zip = tmp_path / "run" / "antenna" / "dagger_rhs_highway_dense.zip"
    run_zip.parent.mkdir(parents=True)
    shutil.copyfile(shipped, run_zip)
    metadata_path(run_zip).write_text(json.dumps({"env_id": "rhs-dense-v0", "model": str(run_zip)}))
    source = tmp_path / "run" / "train_policy.json"
    run = {"commit": "abc123", "command": ["python", "scripts/train_policy.py", "--only", "dense"]}
    source.write_text(json.dumps({"dagger_dense": {"env_id": "rhs-dense-v0", "timesteps": 40000, "model": str(run_zip)},
                                  "machine": {"cpus": 2}, "provenance": run}))
    record = tmp_path / "record.json"
    record.write_text(json.dumps({"dagger_slam": {"timesteps": 80000}}))
    ship = tmp_path / "data"

    assert train_policy.main(["--adopt", str(source), "--only", "dense", "--record", str(record),
                              "--data-dir", str(ship)]) == 0
    target = ship / "antenna" / "dagger_rhs_highway_dense.zip"
    assert target.read_bytes() == shipped.read_bytes()
    assert json.loads(metadata_path(target).read_text())["model"] == str(target)
    merged = json.loads(record.read_text())
    assert merged["dagger_slam"] == {"timesteps": 80000}  # the other entries stay
    assert merged["dagger_dense"]["model"] == str(target) and merged["dagger_dense"]["timesteps"] == 40000
    assert merged["dagger_dense"]["run"] == run and merged["provenance"]["config"]["adopt"] == str(source)
    own = {"commit": "def456", "command": ["python", "scripts/train_policy.py", "--only", "dense"]}
    source.write_text(json.dumps({"dagger_dense": {"model": str(run_zip), "run": own}, "provenance": run}))
    train_policy.main(["--adopt", str(source), "--only", "dense", "--record", str(record), "--data-dir", str(ship)])
    assert json.loads(record.read_text())["dagger_dense"]["run"] == own  # stamped by its training run: kept
    with pytest.raises(SystemExit):  # a policy the run did not train
        train_policy.main(["--adopt", str(source), "--only", "dense_phased", "--record", str(record),
                           "--data-dir", str(ship)])


def test_each_trained_entry_keeps_the_run_that_made_it(tmp_path, monkeypatch):
    """A run with --only writes its entry stamped with its own command and commit (``run``); a later --only run
    rewrites the record's provenance but not the earlier entry's ``run`` (--adopt keeps it: the test above)."""
    import json

    monkeypatch.setattr(train_policy, "train_one", lambda name, args, kwargs: {"env_id": name, "timesteps": 7,
                                                                              "model": f"{name}.zip"})
    monkeypatch.setattr(train_policy, "_registration_weights", lambda: {})
    record = tmp_path / "record.json"
    common = ["--timesteps", "7", "--record", str(record), "--no-progress"]
    assert train_policy.main(["--only", "dense", *common]) == 0
    first = json.loads(record.read_text())
    assert first["dagger_dense"]["run"]["command"][-len(common) - 2 :][:2] == ["--only", "dense"]
    assert train_policy.main(["--only", "dense_phased", *common]) == 0
    both = json.loads(record.read_text())
    assert both["dagger_dense"]["run"] == first["dagger_dense"]["run"]  # not re-attributed to the later run
    assert "dense_phased" in both["dagger_dense_phased"]["run"]["command"]
    assert "dense_phased" in both["provenance"]["command"]


def test_kept_episodes_match_policy_env_and_kwargs_and_split_missing_seeds_into_runs():
    from rhs_studies import evaluate_policies as ep

    previous = {"rows": [
        {"policy": "/elsewhere/agents/data/rl/x.zip", "env_id": "E", "env_kwargs": {"a": 1},
         "runs": [{"seed": 1000, "return": 1.0}, {"seed": 1001, "return": 2.0}]},
        {"policy": "idm", "env_id": "E", "env_kwargs": {}, "runs": [{"seed": 1000, "return": 3.0}]},
    ]}
    assert set(ep.kept_runs(previous, "/work/agents/data/rl/x.zip", "E", {"a": 1})) == {1000, 1001}
    assert ep.kept_runs(previous, "/work/agents/data/rl/x.zip", "E", {"a": 2}) == {}  # other kwargs: driven again
    assert ep.kept_runs(previous, "/work/agents/data/rl/y.zip", "E", {"a": 1}) == {}
    assert ep.kept_runs(previous, "idm", "E", {})[1000]["return"] == 3.0
    assert ep.kept_runs({}, "idm", "E", {}) == {}
    # behind the radar shield: kept only behind the same shield, every field recorded
    from agents.policies.shield import shield_record

    shield = shield_record({})
    previous["rows"][0]["shield"] = shield_record({"alongside_m": 0.0})
    assert ep.kept_runs(previous, "/work/agents/data/rl/x.zip", "E", {"a": 1}, shield) == {}  # another shield
    previous["rows"][0]["shield"] = shield
    assert set(ep.kept_runs(previous, "/work/agents/data/rl/x.zip", "E", {"a": 1}, shield)) == {1000, 1001}
    assert ep.kept_runs(previous, "/work/agents/data/rl/x.zip", "E", {"a": 1}) == {}  # a shielded row, none asked
    assert ep.saved_shield("idm") is None
    assert ep.saved_shield(str(ep.ROOT / "agents/data/rl/dagger_cruise30_close.zip")) == shield  # the shipped one
    assert ep._contiguous([1002, 1003, 1005, 1006, 1009]) == [[1002, 1003], [1005, 1006], [1009]]
    assert ep._contiguous([]) == []


def test_policies_table_pairs_returns_with_idm_by_seed_and_gives_wilson_intervals():
    from rhs_studies import evaluate_policies as ep

    idm = {"key": "idm", "runs": [{"seed": s, "return": 150.0 + s % 3} for s in range(10)]}
    row = {"key": "x", "runs": [{"seed": s, "return": 155.0 + s % 3} for s in reversed(range(10))]}
    assert ep._vs_reference(row, [row, idm]) == "+5.0 [+5.0, +5.0]"  # paired by seed, whatever the order
    assert ep._vs_reference(idm, [row, idm]) == ""
    assert ep._collisions({"collisions": 2, "episodes": 100, "collision_rate": 0.02}) == "0.02 (2/100) [1-7 %]"
    # the shipped policy against the student it continues, on the same seeds
    shipped = {"key": "shipped", "label": "S", "summary": {"collisions": 4, "episodes": 10}, "runs": row["runs"]}
    start = {"key": "slam", "label": "D", "summary": {"collisions": 1, "episodes": 10}, "runs": idm["runs"]}
    assert ep._shipped_vs_start([shipped, start, idm]) == [
        "", "S - D (its start), paired over the seeds: return +5.0 [+5.0, +5.0] (95 % CI); collisions 4 against 1 of 10."]
    assert ep._shipped_vs_start([start, idm]) == []


def test_the_policies_table_names_the_shipped_policy_and_those_shipped_before_it():
    """The shipped RL fine-tune heads the table, the policies shipped before it follow, each named from its record."""
    from agents.evaluate import DAGGER_POLICY, SHIPPED_POLICY, SHIPPED_TRUTH_POLICY

    specs = evaluate_policies.learned_specs(str(DAGGER_POLICY), str(SHIPPED_TRUTH_POLICY), True, str(SHIPPED_POLICY))
    assert [s[0] for s in specs] == ["shipped", "shield_student", "continued_80k", "slam", "truth"]
    assert [s[1] for s in specs[:3]] == ["PPO fine-tune of the DAgger student, radar shield (shipped)",
                                         "DAgger, continued, radar shield (shipped before)",
                                         "DAgger, continued 80k (shipped before)"]
    # the student itself shipped: no continuation rows
    assert [s[0] for s in evaluate_policies.learned_specs(str(DAGGER_POLICY), str(SHIPPED_TRUTH_POLICY), True)] == \
        ["slam", "truth"]
