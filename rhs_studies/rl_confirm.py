"""A fresh test of the RL study's shield arms (the fine-tune, PPO from scratch): chosen on new validation seeds,
judged once on new test seeds.

The RL study (:mod:`rhs_studies.rl_finetune`) judged its shield fine-tunes on seeds 3000-3099 after it had looked
at them more than once (the shield changed between looks), and chose between its two exploring fine-tunes on only
50 validation episodes. This study repeats the choice and the test on seeds nothing has been trained, chosen, tuned
or judged on, with a protocol fixed before any of them was driven:

1. **Choice** on the validation seeds (``--validation-seed``, 7000..): the start (the shield student, shipped then) and each
   candidate (:data:`CANDIDATES`); the candidate with the highest paired return gain over the start (the same as
   the highest mean return: the seeds are common) is chosen. Nothing else is read from these seeds.
2. **Test** on the test seeds (``--seed``, 6000..), driven once: the chosen arm, its start, the DAgger control of the
   same budget (:data:`rhs_studies.rl_finetune.SHIELD_CONTROL`) and IDM + MOBIL. The targets are the RL study's
   (:func:`rhs_studies.rl_finetune.targets`): return >= 1.08x IDM + MOBIL, collisions <= 2 per 100, mean speed
   >= 24 m/s, a paired gain over the start >= +3 with its 95 % interval above 0, more than the DAgger control.

The same for PPO from scratch under the shield (``--parts scratch``): its greedy policies are one-action reflexes
(the RL study's table), so the policy judged is the one PPO optimises, actions sampled (seeded by the episode's
seed, :func:`agents.evaluate.seed_sampling`):

3. **Choice** on the validation seeds between :data:`SCRATCH_CANDIDATES`, sampled: the highest mean return.
4. **Test** on the test seeds: the chosen arm sampled and greedy, against IDM + MOBIL. Targets: return >= 1.0x
   IDM + MOBIL (:data:`SCRATCH_VS_IDM`) with collisions <= 4 per 100 (:data:`SCRATCH_COLLISIONS`).

The arms are the RL study's shipped zips (``agents/data/rl``), each driven behind the shield its record keeps.
``--parts`` runs some of the two parts; the other's result is kept from the existing ``rl_confirm.json`` (same
seeds; the result names the commit it was driven at).

    OMP_NUM_THREADS=1 python scripts/rl_confirm.py                     # 100 + 100 episodes per row, ~1 h
    OMP_NUM_THREADS=1 python scripts/rl_confirm.py --parts scratch     # PPO from scratch only, ~30 min
    OMP_NUM_THREADS=1 python scripts/rl_confirm.py --episodes 4 --validation-episodes 4 --out-dir /tmp/c
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rhs_studies.kit.driving import (
    LABELS,
    SHIELD_CONTROL,
    SHIPPED_DIR,
    FreshSeeds,
    arm_policies,
    check_zips,
    drive_arm,
    evaluate_rows,
    rl_fingerprint,
    run_policy,
    targets,
)
from rhs_studies.kit.runner import Study, option, run_study
from rhs_studies.kit.tables import mean_return, paired, paired_text, row_summary, slim_runs, table_row, targets_line

#: the exploring fine-tunes the choice is between (the RL study's two best shield arms on its seeds)
CANDIDATES = ("shield_explore", "shield_flank_explore")
#: the rows besides the candidates: their start, on both seed sets
START = "shipped"
#: PPO from scratch under the shield, the RL study's three arms
SCRATCH_CANDIDATES = ("shield_scratch", "shield_scratch_explore", "shield_scratch_cost")
#: PPO from scratch's targets: return vs IDM + MOBIL, collisions per episode
SCRATCH_VS_IDM, SCRATCH_COLLISIONS = 1.0, 0.04
PARTS = ("finetune", "scratch")


def choose(runs: dict[str, list[dict]], candidates: tuple[str, ...] = CANDIDATES) -> tuple[str, dict[str, Any]]:
    """The candidate with the highest paired gain over :data:`START` on the validation episodes ``runs``, and
    each candidate's gain.

    >>> ep = lambda *r: [{"seed": s, "return": x} for s, x in enumerate(r)]
    >>> choose({"shipped": ep(1, 2), "a": ep(2, 3), "b": ep(3, 3)}, ("a", "b"))[0]
    'b'
    """
    gains = {arm: paired(runs[arm], runs[START]) for arm in candidates}
    return max(candidates, key=lambda arm: gains[arm]["mean"]), gains


def markdown(result: dict[str, Any]) -> str:
    """The choice and the test, one paragraph and one table."""
    v, t = result["validation"], result["test"]
    gains = "; ".join(f"{LABELS.get(a, a)} {paired_text(g)}"
                      for a, g in v["gains"].items())
    lines = [f"Choice on validation seeds {v['seeds'][0]}-{v['seeds'][-1]} ({len(v['seeds'])} episodes), paired gain "
             f"over the shield student: {gains}. Chosen: **{LABELS.get(v['chosen'], v['chosen'])}**.", "",
             f"Test on seeds {t['seeds'][0]}-{t['seeds'][-1]} ({len(t['seeds'])} episodes, driven once):", "",
             "| policy | return (95 % CI) | collisions [Wilson 95 %] | speed m/s | vs the shield student (paired, 95 % CI) |",
             "|---|---|---|---|---|"]
    lines += [table_row(LABELS.get(key, key), s, t["vs_start"].get(key)) for key, s in t["rows"].items()]
    lines += ["", targets_line(t["targets"], "the chosen arm")]
    if "scratch" in result:
        lines += ["", *scratch_markdown(result["scratch"])]
    kept = result.get("kept_parts") or {}
    if kept:
        lines += ["", "Parts kept from an earlier run of this script on the same seeds: "
                  + ", ".join(f"{part} ({commit[:7] if commit else 'unknown commit'})" for part, commit in kept.items())
                  + "."]
    return "\n".join(lines) + "\n"


def scratch_markdown(part: dict[str, Any]) -> list[str]:
    """The PPO-from-scratch part: its choice, its test table and its targets."""
    v, t = part["validation"], part["test"]
    means = "; ".join(f"{LABELS.get(a, a)} {r['return']['mean']:.1f} ({r['collisions']}/{r['episodes']})"
                      for a, r in v["rows"].items())
    name = LABELS.get(v["chosen"], v["chosen"])
    lines = [f"PPO from scratch under the shield, actions sampled, on the validation seeds {v['seeds'][0]}-"
             f"{v['seeds'][-1]}: {means}. Chosen: **{name}**.", "",
             f"Test on seeds {t['seeds'][0]}-{t['seeds'][-1]} ({len(t['seeds'])} episodes):", "",
             "| policy | return (95 % CI) | collisions [Wilson 95 %] | speed m/s | vs IDM + MOBIL (paired, 95 % CI) |",
             "|---|---|---|---|---|"]
    label = {"sampled": f"{name}, actions sampled", "greedy": f"{name}, greedy actions", "idm": LABELS["idm"]}
    lines += [table_row(label[key], s, t["vs_idm"].get(key)) for key, s in t["rows"].items()]
    tg = t["targets"]
    met = ", ".join(f"{k} {'met' if ok else 'not met'}" for k, ok in tg["met"].items())
    lines += ["", f"Targets judged on the chosen arm, actions sampled: {tg['return_vs_idm']:.3f}x IDM + MOBIL "
              f"(>= {SCRATCH_VS_IDM:g}), {100 * tg['collision_rate']:.0f} % collisions (<= {100 * SCRATCH_COLLISIONS:g} %); "
              f"targets: {met}."]
    return lines


def confirm(validation_seeds: list[int], test_seeds: list[int], workers: int, ship_dir: Path = SHIPPED_DIR,
            candidates: tuple[str, ...] = CANDIDATES) -> dict[str, Any]:
    """Steps 1 and 2 of the protocol (the module's docstring); the result without provenance."""
    t0 = time.perf_counter()
    val = evaluate_rows(arm_policies((START, *candidates), ship_dir), validation_seeds, workers,
                        skip=("slower", "idm", "headway", "lookahead"))
    chosen, gains = choose(val, candidates)
    print(f"rl_confirm: chose {chosen} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    test = evaluate_rows(arm_policies((START, chosen, SHIELD_CONTROL), ship_dir), test_seeds, workers,
                         skip=("slower", "headway", "lookahead"))
    rows = {k: row_summary(r) for k, r in test.items()}
    return {
        "candidates": list(candidates),
        "validation": {"seeds": validation_seeds, "gains": gains, "chosen": chosen,
                       "rows": {k: row_summary(r) for k, r in val.items()},
                       "runs": slim_runs(val)},
        "test": {"seeds": test_seeds, "rows": rows,
                 "vs_start": {k: paired(r, test[START]) for k, r in test.items() if k not in (START, "idm")},
                 "targets": targets(rows, test, chosen, SHIELD_CONTROL),
                 "runs": slim_runs(test)},
    }


def confirm_scratch(validation_seeds: list[int], test_seeds: list[int], workers: int, ship_dir: Path = SHIPPED_DIR,
                    idm: list[dict] | None = None, candidates: tuple[str, ...] = SCRATCH_CANDIDATES) -> dict[str, Any]:
    """Steps 3 and 4 of the protocol (the module's docstring); ``idm``: IDM + MOBIL's test episodes when driven
    already (the first part's), else driven here."""
    val = {arm: drive_arm(arm, validation_seeds, workers, ship_dir, False) for arm in candidates}
    chosen = max(candidates, key=lambda arm: mean_return(val[arm]))
    print(f"rl_confirm: chose {chosen} from scratch", file=sys.stderr)
    test = {"sampled": drive_arm(chosen, test_seeds, workers, ship_dir, False),
            "greedy": drive_arm(chosen, test_seeds, workers, ship_dir, True),
            "idm": idm if idm is not None else run_policy("idm", "rhs-highway-v0", {}, test_seeds, workers)}
    rows = {k: row_summary(r) for k, r in test.items()}
    s = rows["sampled"]
    vs_idm = s["return"]["mean"] / rows["idm"]["return"]["mean"]
    return {
        "candidates": list(candidates),
        "validation": {"seeds": validation_seeds, "chosen": chosen,
                       "rows": {k: row_summary(r) for k, r in val.items()}, "runs": slim_runs(val)},
        "test": {"seeds": test_seeds, "rows": rows, "vs_idm": {k: paired(r, test["idm"]) for k, r in test.items()
                                                              if k != "idm"},
                 "targets": {"arm": chosen, "return_vs_idm": vs_idm, "collision_rate": s["collision_rate"],
                             "met": {"return_vs_idm": vs_idm >= SCRATCH_VS_IDM,
                                     "collisions": s["collision_rate"] <= SCRATCH_COLLISIONS}},
                 "runs": slim_runs(test)},
    }


def kept_parts(path: Path, parts: list[str], validation: list[int], test: list[int]) -> tuple[dict, dict[str, str]]:
    """The ``parts`` of an earlier result ``path`` on the same seeds, and the commit each was driven at;
    ``ValueError`` when the file, a part or a seed is missing."""
    if not parts:
        return {}, {}
    if not path.exists():
        raise ValueError(f"--parts: {path} does not exist, so {parts} cannot be kept (run every part)")
    old = json.loads(path.read_text())
    commit = old.get("provenance", {}).get("commit")
    result: dict[str, Any] = {}
    kept: dict[str, str] = {}
    for part in parts:
        block = {k: old[k] for k in ("candidates", "validation", "test") if k in old} if part == "finetune" \
            else old.get("scratch")
        if not block or block["validation"]["seeds"] != validation or block["test"]["seeds"] != test:
            raise ValueError(f"--parts: {path} has no {part} part on the validation seeds {validation[0]}-"
                             f"{validation[-1]} and test seeds {test[0]}-{test[-1]}")
        result.update(block if part == "finetune" else {"scratch": block})
        kept[part] = (old.get("kept_parts") or {}).get(part, commit)
    return result, kept


def _idm_runs(result: dict[str, Any], test: list[int]) -> list[dict] | None:
    """IDM + MOBIL's test episodes from the fine-tune part, when it has them on ``test``."""
    runs = result.get("test", {}).get("runs", {}).get("idm")
    return runs if runs and [e["seed"] for e in runs] == test else None


def fingerprint() -> list[float]:
    """The RL study's: the same starts and shipped zips on one short episode (this study drives nothing else)."""
    return rl_fingerprint()


@dataclass(frozen=True)
class Options(FreshSeeds):
    """This study's options: :class:`FreshSeeds` (test seeds from 6000) and the parts driven."""

    parts: tuple[str, ...] = option(PARTS, "the parts driven (the others kept from the existing rl_confirm.json, "
                                    "same seeds)", choices=PARTS)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.parts or any(p not in PARTS for p in self.parts):
            raise ValueError(f"--parts must be some of {list(PARTS)}")


def check(opts: Options) -> None:
    """The zips of the parts driven are present and the parts kept are on the same seeds (:func:`kept_parts`)."""
    arms = [*CANDIDATES, SHIELD_CONTROL] * ("finetune" in opts.parts) + [*SCRATCH_CANDIDATES] * ("scratch" in opts.parts)
    check_zips(opts.ship_dir, arms)
    kept_parts(Path(opts.out_dir) / "rl_confirm.json", [p for p in PARTS if p not in opts.parts], *opts.seed_sets())


def run(opts: Options) -> dict[str, Any]:
    """The parts of ``opts`` driven, the others kept (:func:`kept_parts`); the result without provenance."""
    val, test = opts.seed_sets()
    result, kept = kept_parts(Path(opts.out_dir) / "rl_confirm.json", [p for p in PARTS if p not in opts.parts],
                              val, test)
    if "finetune" in opts.parts:
        result.update(confirm(val, test, opts.workers, Path(opts.ship_dir)))
    if "scratch" in opts.parts:
        result["scratch"] = confirm_scratch(val, test, opts.workers, Path(opts.ship_dir), idm=_idm_runs(result, test))
    if kept:
        result["kept_parts"] = kept
    return result


STUDY = Study("rl_confirm", "scripts/rl_confirm.py", Options, run, markdown, fingerprint, __doc__, check)


def main(argv: list[str] | None = None) -> int:
    return run_study(STUDY, argv)


if __name__ == "__main__":
    sys.exit(main())
