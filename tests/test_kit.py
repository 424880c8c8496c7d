"""The research kit (rhs_studies.kit): the seed ledger, the one pool, the tables, the Study runner."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pytest

from rhs_studies.kit import pool, runner, seeds, tables

ROOT = Path(__file__).resolve().parent.parent


def test_the_ledger_names_every_driven_set_and_refuses_a_driven_set_as_fresh():
    assert [s.name for s in seeds.overlap(range(6050, 6150))] == ["rl_confirm_test"]
    assert [s.name for s in seeds.overlap([5, 7099, 8000])] == ["training", "rl_confirm_validation", "lane_rule_test"]
    assert seeds.overlap(range(9000, 9100)) == [] and seeds.overlap([8000], allow=("lane_rule_test",)) == []
    with pytest.raises(ValueError, match=r"the test seeds 3050-3149 overlap .*rl_finetune_heldout \(3000-3099\)"):
        seeds.check_fresh(list(range(3050, 3150)), "the test seeds")
    seeds.check_fresh(list(range(9000, 9100)), "the test seeds")
    # the sets the lane-rule trial refused before the ledger, unchanged
    assert seeds.USED_SEEDS == ((0, 999), (1000, 1099), (3000, 3099), (4000, 4099), (5000, 5059), (6000, 6099),
                                (7000, 7099), (10000, 10999))
    with pytest.raises(ValueError, match="seed set 'nope' is not in the ledger"):
        seeds.seed_set("nope")
    with pytest.raises(ValueError, match="seed set bad.last"):
        seeds.SeedSet("bad", 10, 9, "")
    ranges = sorted((s.first, s.last) for s in seeds.LEDGER)
    assert all(a[1] < b[0] for a, b in zip(ranges, ranges[1:], strict=False)), "ledger sets are disjoint"


def test_the_studies_seed_defaults_are_read_from_named_sets_with_the_numbers_published():
    from rhs_studies.driving import crash_analysis, rl_lane_rule_trial
    from rhs_studies.kit import driving

    assert seeds.first("policies_table") == 1000 and seeds.first("shield_validation", 50) == 4050
    assert crash_analysis.DEFAULT_SEEDS == (1000, 2000)
    assert (driving.FreshSeeds.validation_seed, driving.FreshSeeds.seed) == (7000, 6000)
    assert rl_lane_rule_trial.Options.seed == 8000
    assert seeds.seed_set("fast_radar_calibration").first == 100_000 and seeds.first("scenes") == 0
    with pytest.raises(ValueError, match="offset"):
        seeds.first("lane_analysis", 60)  # past the set's last seed
    # the scene sets are named, but outside the driving ledger's freshness check
    assert not {s.name for s in seeds.SCENE_SETS} & set(seeds.BY_NAME)
    assert seeds.overlap(range(100_000, 100_010)) == []


def _chunk_threads(chunk: list[int], tag: str) -> list[tuple[int, str, int]]:
    from threadpoolctl import threadpool_info

    threads = max((p["num_threads"] for p in threadpool_info()), default=1)
    return [(s, tag, threads) for s in chunk]


def test_the_pool_keeps_seed_order_and_runs_single_threaded_workers():
    assert pool.seed_chunks(list(range(7)), 3) == [[0, 1, 2], [3, 4, 5], [6]]
    assert pool.seed_chunks([4], 2) == [[4]]
    out = pool.map_seeds(_chunk_threads, list(range(5)), 2, "x")
    assert [s for s, _, _ in out] == list(range(5)) and {t for _, t, _ in out} == {"x"}
    assert {n for _, _, n in out} == {1}  # one BLAS thread in each worker, as the studies' pools had
    got: list[int] = []
    done = pool.map_jobs(divmod, [(7, 2), (9, 4)], 2, on_result=lambda r: got.append(r[0]))
    assert sorted(done) == [(2, 1), (3, 1)] and sorted(got) == [2, 3]
    with pytest.raises(ValueError, match="workers"):
        pool.seed_chunks([1], 0)


def test_the_tables_render_the_rl_pages_unchanged_from_their_json():
    """The tables of the RL studies, written by the kit, are the results' pages to the byte."""
    from rhs_studies import rl_confirm, rl_finetune, rl_lane_rule_trial

    for module, name in ((rl_confirm, "rl_confirm"), (rl_lane_rule_trial, "rl_lane_test"), (rl_finetune, "rl_finetune")):
        result = json.loads((ROOT / "results" / f"{name}.json").read_text())
        assert module.markdown(result) == (ROOT / "results" / f"{name}.md").read_text(), name
    row = {"episodes": 2, "return": {"mean": 1.0, "half": 0.5}, "collisions": 1, "collision_interval": [0.1, 0.9],
           "mean_speed_mps": {"mean": 20.0}}
    assert tables.table_row("x", row, None) == "| x | 1.0 +- 0.5 | 1/2 [10-90 %] | 20.0 |  |"


@dataclass(frozen=True)
class _Options:
    seed: int = runner.option(9000, "first seed")
    names: tuple[str, ...] = runner.option(("a", "b"))
    quick: bool = runner.option(False)
    out_dir: Path = runner.option(Path("results"))

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ValueError("--seed must be >= 0")


def test_the_runner_parses_the_options_dataclass_runs_and_writes_json_and_page(tmp_path, capsys):
    opts = runner.parse_options(_Options, ["--seed", "9001", "--names", "c", "--quick"])
    assert opts == _Options(9001, ("c",), True, Path("results"))
    with pytest.raises(SystemExit):
        runner.parse_options(_Options, ["--seed", "-1"])
    assert "--seed must be >= 0" in capsys.readouterr().err
    study = runner.Study("toy", "scripts/toy.py", _Options, lambda o: {"seed": o.seed, "names": list(o.names)},
                         lambda r: f"seed {r['seed']}\n", lambda: [1.0])
    assert runner.run_study(study, ["--out-dir", str(tmp_path), "--seed", "9002"]) == 0
    result = json.loads((tmp_path / "toy.json").read_text())
    assert result["seed"] == 9002 and result["provenance"]["config"]["names"] == ["a", "b"]
    assert result["provenance"]["command"][:2] == ["python", "scripts/toy.py"]
    assert (tmp_path / "toy.md").read_text() == "seed 9002\n" and "seed 9002" in capsys.readouterr().out


SMOKE = """\
name: smoke_scripted
title: always SLOWER or the headway expert, against IDM + MOBIL
validation_seeds: {first: 12000, episodes: 2}
test_seeds: {first: 12100, episodes: 2}
candidates:
  - {policy: slower}
  - {policy: headway}
choice: {rule: mean_return}
test:
  - {policy: $chosen}
  - {policy: idm}
paired: {against: idm, key: vs_idm}
targets: {kind: vs_idm, return_vs_idm: 0.5, collision_rate: 0.5}
"""


def test_a_new_comparison_is_a_yaml_file_alone(tmp_path, capsys):
    """A spec file, no module: chosen on fresh validation seeds, tested once, JSON + page written (2 short episodes
    per row on rhs-highway-v0)."""
    from rhs_studies.driving import comparisons

    spec = tmp_path / "smoke.yml"
    spec.write_text(SMOKE)
    assert comparisons.main(["--spec", str(spec), "--episode-s", "2", "--workers", "1", "--out-dir", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "smoke_scripted.json").read_text())
    v, t = result["validation"], result["test"]
    assert v["seeds"] == [12000, 12001] and t["seeds"] == [12100, 12101]
    assert v["chosen"] in ("slower", "headway") and list(t["rows"]) == [v["chosen"], "idm"]
    assert list(t["vs_idm"]) == [v["chosen"]] and set(t["targets"]["met"]) == {"return_vs_idm", "collisions"}
    assert [e["seed"] for e in t["runs"]["idm"]] == [12100, 12101]
    assert result["provenance"]["command"][1] == "scripts/compare_policies.py"
    assert "Chosen: **" in (tmp_path / "smoke_scripted.md").read_text()
    # a test set already driven is refused, naming the file and the set
    spec.write_text(SMOKE.replace("first: 12100", "first: 6050"))
    with pytest.raises(SystemExit):
        comparisons.main(["--spec", str(spec), "--out-dir", str(tmp_path)])
    assert "rl_confirm_test (6000-6099)" in capsys.readouterr().err


def test_the_specs_are_validated_with_the_field_path_and_the_file(tmp_path):
    from rhs_studies.kit.protocol import load_spec

    for path in sorted((ROOT / "rhs_studies" / "driving" / "specs").glob("*.yml")):
        assert load_spec(path).name == path.stem  # every shipped spec loads
    bad = tmp_path / "bad.yml"
    cases = [("policy: slower}", "policy: nope}", r"bad.yml: candidates\[0\]\.policy"),
             ("rule: mean_return", "rule: best", r"bad.yml: choice\.rule"),
             ("first: 12100, episodes: 2", "first: 12001, episodes: 2", "overlap the validation seeds"),
             ("  - {policy: $chosen}\n", "", r"\$chosen"),
             ("title:", "colour: red\ntitle:", r"bad.yml: unknown fields \['colour'\]")]
    for old, new, message in cases:
        bad.write_text(SMOKE.replace(old, new))
        with pytest.raises(ValueError, match=message):
            load_spec(bad)


def test_the_protocol_replaces_the_three_copies_with_the_same_blocks():
    """rl_confirm's two parts and the lane rule trial are their spec files run by the one protocol: the blocks
    their pages render (keys in order), the choice rule of each, the rows driven."""
    from rhs_studies.driving import rl_confirm, rl_lane_rule_trial

    def drive(row, seeds):
        ret = {"shield_explore": 1.0, "shield_flank_explore": 2.0, "lane_time": 0.0}.get(row.name, 0.5)
        return [{"seed": s, "return": ret + (s % 2), "crashed": row.name == "lane_gap", "mean_speed": 24.0} for s in seeds]

    val, test = list(range(7000, 7004)), list(range(6000, 6004))
    fine = rl_confirm.confirm(val, test, 1, drive=drive)
    saved = json.loads((ROOT / "results" / "rl_confirm.json").read_text())
    assert list(fine) == ["candidates", "validation", "test"] == [k for k in saved if k in fine]
    assert list(fine["validation"]) == list(saved["validation"]) and list(fine["test"]) == list(saved["test"])
    assert list(fine["test"]["targets"]) == list(saved["test"]["targets"])
    scratch = rl_confirm.confirm_scratch(val, test, 1, drive=drive)
    assert list(scratch["validation"]) == list(saved["scratch"]["validation"])
    assert list(scratch["test"]) == list(saved["scratch"]["test"]) and list(scratch["test"]["rows"]) == ["sampled", "greedy", "idm"]
    assert list(scratch["test"]["targets"]) == list(saved["scratch"]["test"]["targets"])
    lane = rl_lane_rule_trial.lane_test(val, list(range(8000, 8004)), 1, drive=drive)
    saved = json.loads((ROOT / "results" / "rl_lane_test.json").read_text())
    assert [k for k in saved if k != "provenance"] == list(lane) and lane["validation"]["chosen"] == "lane_time"
    assert list(lane["validation"]) == list(saved["validation"]) and list(lane["test"]) == list(saved["test"])
    assert list(lane["test"]["rows"]) == list(saved["test"]["rows"]) and lane["lane_rules"] == saved["lane_rules"]


def test_the_fresh_seed_studies_refuse_a_test_set_already_driven(tmp_path, capsys):
    """rl_confirm and the lane rule trial check their test seeds against the ledger (their own set allowed)."""
    from rhs_studies.driving import rl_confirm, rl_lane_rule_trial

    for module, flags in ((rl_confirm, ["--seed", "3000"]), (rl_lane_rule_trial, ["--seed", "3050"])):
        with pytest.raises(SystemExit):
            module.main([*flags, "--out-dir", str(tmp_path)])
        assert "rl_finetune_heldout (3000-3099)" in capsys.readouterr().err
    rl_confirm.check(rl_confirm.Options(out_dir=tmp_path, parts=("finetune", "scratch")))  # its own set: fine
