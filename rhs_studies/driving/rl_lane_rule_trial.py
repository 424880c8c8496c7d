"""The RL fine-tune behind a stricter lane-change rule of the radar shield: the rule chosen on validation seeds,
the choice tested once on seeds nothing has touched.

The fresh test of the RL stage (:mod:`rhs_studies.driving.rl_confirm`, seeds 6000-6099) met every target of the fine-tune
but collisions: 3 in 100 against <= 2. Two of the three were lane changes into a car a few metres ahead in the target
lane that the radar saw with two points. The shield's lane rule (:class:`agents.policies.shield.ShieldConfig`) vetoes a lane
change when an object in the target lane is nearer than ``lane_gap_m + lane_time_s * closing speed``; this study asks
whether a stricter rule closes the gap, with a protocol fixed before any of its seeds was driven:

1. **Choice** on the validation seeds (``--validation-seed``, 7000.., where :mod:`rhs_studies.driving.rl_confirm` chose the
   fine-tune): :data:`FINETUNE` behind each rule of :data:`LANE_RULES` (each changes one field of the shield saved
   in the fine-tune's record). The rule with the fewest collisions is chosen, ties broken by the higher mean return.
   The fine-tune behind its own rule on the same seeds (from ``rl_confirm.json``) is shown beside them, not chosen.
2. **Test** on the test seeds (``--seed``, 8000..), driven once: the fine-tune behind the chosen rule, its start
   (the shield student, shipped then, behind its own shield), the DAgger control of the same budget
   (:data:`rhs_studies.driving.rl_finetune.SHIELD_CONTROL`, behind its own shield) and IDM + MOBIL. The targets are the RL
   study's (:func:`rhs_studies.driving.rl_finetune.targets`): return >= 1.08x IDM + MOBIL, collisions <= 2 per 100, mean
   speed >= 24 m/s, a paired gain over the start >= +3 with its 95 % interval above 0, more than the DAgger control.

``--ship`` (after the test, from its ``rl_lane_test.json``) ships the fine-tune behind the chosen rule when every
target was met: its zip copied to ``agents/data/rl/<fine-tune>_<rule>.zip`` with its record, the shield changed to the
rule's and the study that chose it named (:func:`ship`); :data:`agents.evaluate.SHIPPED_POLICY` points there.

Test seeds that overlap a set the project's policies were chosen, tuned or judged on (the seed ledger,
:mod:`rhs_studies.kit.seeds`) are refused.

    OMP_NUM_THREADS=1 python scripts/rl_lane_test.py                 # 2 x 100 + 4 x 100 episodes, ~45 min
    OMP_NUM_THREADS=1 python scripts/rl_lane_test.py --episodes 4 --validation-episodes 4 --out-dir /tmp/l
"""

from __future__ import annotations

import json
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agents.evaluate import policy_metadata
from rhs_studies.kit.driving import LABELS, ROOT, SHIELD_CONTROL, SHIPPED_DIR, FreshSeeds, check_zips, rl_fingerprint
from rhs_studies.kit.protocol import Drive, load_spec, row_driver, run_comparison
from rhs_studies.kit.runner import Study, option, parse_options, parser_for, run_study
from rhs_studies.kit.seeds import USED_SEEDS, check_fresh, first
from rhs_studies.kit.tables import row_summary, table_row, targets_line

#: the launcher of this study: the command its results record and its key in results/fingerprints.json (the module
#: was called rl_lane_test like it; renamed so that no module of the kit matches pytest's test-file pattern)
LAUNCHER = "scripts/rl_lane_test.py"
#: the trial as a comparison (rhs_studies/driving/specs/rl_lane_rule_trial.yml), run by the kit's one protocol
SPEC = load_spec(Path(__file__).resolve().parent / "specs" / "rl_lane_rule_trial.yml")
#: the fine-tune under test: the one :mod:`rhs_studies.driving.rl_confirm` chose on seeds 7000-7099
FINETUNE = SPEC.candidates[0].policy
#: the candidate lane rules, each one field of the shield (defaults: lane_gap_m 4.0, lane_time_s 1.5); measured on
#: the analysis seeds 5000-5059 before this study: each removed one lane-change crash of two, -0.2 and -0.7 in return
LANE_RULES: dict[str, dict[str, float]] = {r.name: dict(r.shield or {}) for r in SPEC.candidates}
#: the rows besides the fine-tune on the test seeds: its start (the shield student, shipped then)
START = "shipped"


def overlap(seeds: list[int]) -> list[tuple[int, int]]:
    """The sets of :data:`rhs_studies.kit.seeds.USED_SEEDS` that ``seeds`` touch (this study's own test set,
    ``lane_rule_test`` of the ledger, is not among them: the study reruns on it).

    >>> overlap(list(range(8000, 8100))), overlap([6099, 6100])
    ([], [(6000, 6099)])
    """
    return [(a, b) for a, b in USED_SEEDS if any(a <= s <= b for s in seeds)]


def lane_test(validation_seeds: list[int], test_seeds: list[int], workers: int, ship_dir: Path = SHIPPED_DIR,
              baseline: list[dict] | None = None, drive: Drive | None = None) -> dict[str, Any]:
    """Steps 1 and 2 of the protocol (the module's docstring: :data:`SPEC` run by
    :func:`rhs_studies.kit.protocol.run_comparison`); ``baseline``: the fine-tune behind its own rule on the
    validation seeds, shown beside the rules; ``drive``: drives one row (default: the shipped arms). The result
    without provenance."""
    out = run_comparison(SPEC, drive or row_driver(workers, ship_dir), validation_seeds, test_seeds,
                         log="rl_lane_test")
    v = out["validation"]
    rows = {**({"own_rule": row_summary(baseline)} if baseline else {}), **v["rows"]}
    validation = {"seeds": v["seeds"], "chosen": v["chosen"], "rule": LANE_RULES[v["chosen"]], "rows": rows,
                  "runs": v["runs"]}
    return {"finetune": FINETUNE, "lane_rules": LANE_RULES, "validation": validation, "test": out["test"]}


def confirmed_baseline(path: Path, seeds: list[int]) -> list[dict] | None:
    """The fine-tune's episodes behind its own rule on ``seeds`` from :mod:`rhs_studies.driving.rl_confirm`'s result, when
    it drove them."""
    if not path.exists():
        return None
    runs = json.loads(path.read_text()).get("validation", {}).get("runs", {}).get(FINETUNE)
    return runs if runs and [e["seed"] for e in runs] == seeds else None


def rule_text(rule: dict[str, float]) -> str:
    """``{"lane_time_s": 2.5}`` as ``lane_time_s 2.5``."""
    return ", ".join(f"{k} {v:g}" for k, v in rule.items())


def markdown(result: dict[str, Any]) -> str:
    """The choice and the test, one paragraph and one table."""
    v, t = result["validation"], result["test"]
    rules = result["lane_rules"]
    name = LABELS.get(result["finetune"], result["finetune"])
    shown = "; ".join(f"{rule_text(rules[k]) if k in rules else 'its own rule (not a candidate)'}: "
                      f"{r['return']['mean']:.1f}, {r['collisions']}/{r['episodes']}" for k, r in v["rows"].items())
    lines = [f"{name} on validation seeds {v['seeds'][0]}-{v['seeds'][-1]} behind each lane rule (return, "
             f"collisions): {shown}. Chosen: **{rule_text(v['rule'])}**.", "",
             f"Test on seeds {t['seeds'][0]}-{t['seeds'][-1]} ({len(t['seeds'])} episodes, driven once):", "",
             "| policy | return (95 % CI) | collisions [Wilson 95 %] | speed m/s | vs the shield student (paired, 95 % CI) |",
             "|---|---|---|---|---|"]
    label = {result["finetune"]: f"{name}, shield with {rule_text(v['rule'])}"}
    lines += [table_row(label.get(key) or LABELS.get(key, key), s, t["vs_start"].get(key)) for key, s in t["rows"].items()]
    lines += ["", targets_line(t["targets"], "the fine-tune behind the chosen rule")]
    return "\n".join(lines) + "\n"


def shipped_path(result: dict[str, Any], ship_dir: Path = SHIPPED_DIR) -> Path:
    """Where :func:`ship` writes the fine-tune behind the chosen rule: ``<fine-tune>_<rule>.zip``."""
    return ship_dir / f"{result['finetune']}_{result['validation']['chosen']}.zip"


def ship(result: dict[str, Any], results_file: Path, ship_dir: Path = SHIPPED_DIR) -> Path:
    """The fine-tune of ``result`` behind its chosen rule as a policy of its own (:func:`shipped_path`): the zip
    copied, the record the fine-tune's with the shield's rule fields changed and ``shipped_by`` naming the study;
    ``ValueError`` unless every target was met on the test seeds."""
    failed = [k for k, ok in result["test"]["targets"]["met"].items() if not ok]
    if failed:
        raise ValueError(f"{results_file}: targets not met on the test seeds: {failed}; nothing shipped")
    source, out = ship_dir / f"{result['finetune']}.zip", shipped_path(result, ship_dir)
    record = policy_metadata(source)
    rule = result["validation"]["rule"]
    record["shield"] = {**record["shield"], **rule}
    record["model"] = str(out.relative_to(ROOT)) if out.is_relative_to(ROOT) else str(out)
    t = result["test"]
    record["shipped_by"] = {"study": str(results_file.relative_to(ROOT)) if results_file.is_relative_to(ROOT)
                            else str(results_file), "copied_from": str(source.name), "shield_rule": rule,
                            "commit": result.get("provenance", {}).get("commit"),
                            "validation_seeds": [result["validation"]["seeds"][0], result["validation"]["seeds"][-1]],
                            "test_seeds": [t["seeds"][0], t["seeds"][-1]]}
    shutil.copyfile(source, out)
    out.with_suffix(".json").write_text(json.dumps(record, indent=2) + "\n")
    return out


def fingerprint() -> list[float]:
    """The RL study's: the same starts and shipped zips on one short episode."""
    return rl_fingerprint()


@dataclass(frozen=True)
class Options(FreshSeeds):
    """This study's options: :class:`rhs_studies.kit.driving.FreshSeeds` with test seeds from 8000, and ``--ship``."""

    seed: int = option(first("lane_rule_test"), "first test seed")
    ship: bool = option(False, "drive nothing: ship the fine-tune behind the rule chosen in --out-dir's "
                        "rl_lane_test.json, if it met every target")


def check(opts: Options) -> None:
    """The zips are present and the test seeds fresh: no set of the seed ledger but this study's own."""
    check_zips(opts.ship_dir, [FINETUNE, SHIELD_CONTROL])
    check_fresh(opts.seed_sets()[1], "the test seeds", allow=("lane_rule_test",))


def run(opts: Options) -> dict[str, Any]:
    """The protocol on the options' seeds (:func:`lane_test`)."""
    val, test = opts.seed_sets()
    return lane_test(val, test, opts.workers, Path(opts.ship_dir),
                     baseline=confirmed_baseline(ROOT / "results" / "rl_confirm.json", val))


STUDY = Study("rl_lane_test", LAUNCHER, Options, run, markdown, fingerprint, __doc__, check)


def main(argv: list[str] | None = None) -> int:
    ap = parser_for(Options, __doc__)
    opts = parse_options(Options, argv, parser=ap)
    if not opts.ship:
        return run_study(STUDY, argv)
    path = Path(opts.out_dir) / "rl_lane_test.json"
    if not path.exists():
        ap.error(f"--ship: {path} does not exist (run the study first)")
    try:
        print(f"rl_lane_test: shipped {ship(json.loads(path.read_text()), path, Path(opts.ship_dir))}")
    except ValueError as err:
        ap.error(str(err))
    return 0


if __name__ == "__main__":
    sys.exit(main())
