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
