"""A fresh test of the RL study's shield arms (the fine-tune, PPO from scratch): chosen on new validation seeds,
judged once on new test seeds.

The RL study (:mod:`rhs_studies.driving.rl_finetune`) judged its shield fine-tunes on seeds 3000-3099 after it had looked
at them more than once (the shield changed between looks), and chose between its two exploring fine-tunes on only
50 validation episodes. This study repeats the choice and the test on seeds nothing has been trained, chosen, tuned
or judged on, with a protocol fixed before any of them was driven:

1. **Choice** on the validation seeds (``--validation-seed``, 7000..): the start (the shield student, shipped then) and each
   candidate (:data:`CANDIDATES`); the candidate with the highest paired return gain over the start (the same as
   the highest mean return: the seeds are common) is chosen. Nothing else is read from these seeds.
2. **Test** on the test seeds (``--seed``, 6000..), driven once: the chosen arm, its start, the DAgger control of the
   same budget (:data:`rhs_studies.driving.rl_finetune.SHIELD_CONTROL`) and IDM + MOBIL. The targets are the RL study's
   (:func:`rhs_studies.driving.rl_finetune.targets`): return >= 1.08x IDM + MOBIL, collisions <= 2 per 100, mean speed
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rhs_studies.kit.driving import LABELS, SHIELD_CONTROL, SHIPPED_DIR, FreshSeeds, check_zips, rl_fingerprint
from rhs_studies.kit.protocol import Drive, load_spec, row_driver, run_comparison
from rhs_studies.kit.runner import Study, option, run_study
from rhs_studies.kit.seeds import check_fresh
from rhs_studies.kit.tables import paired_text, table_row, targets_line

#: the two parts of the study as comparisons (rhs_studies/driving/specs/: the arms, the choice rule, the rows, the
#: targets), each run by the kit's one select-then-test protocol (:func:`rhs_studies.kit.protocol.run_comparison`)
SPECS = Path(__file__).resolve().parent / "specs"
FINETUNE_SPEC = load_spec(SPECS / "rl_confirm_finetune.yml")
SCRATCH_SPEC = load_spec(SPECS / "rl_confirm_scratch.yml")
#: the exploring fine-tunes the choice is between (the RL study's two best shield arms on its seeds)
CANDIDATES = tuple(r.name for r in FINETUNE_SPEC.candidates)
#: the rows besides the candidates: their start, on both seed sets
START = FINETUNE_SPEC.choice.reference
#: PPO from scratch under the shield, the RL study's three arms
SCRATCH_CANDIDATES = tuple(r.name for r in SCRATCH_SPEC.candidates)
#: PPO from scratch's targets: return vs IDM + MOBIL, collisions per episode
SCRATCH_VS_IDM, SCRATCH_COLLISIONS = SCRATCH_SPEC.targets.return_vs_idm, SCRATCH_SPEC.targets.collision_rate
PARTS = ("finetune", "scratch")


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
            drive: Drive | None = None) -> dict[str, Any]:
    """Steps 1 and 2 of the protocol (the module's docstring: :data:`FINETUNE_SPEC` run by
    :func:`rhs_studies.kit.protocol.run_comparison`); ``drive``: drives one row (default: the shipped arms); the
    result without provenance."""
    out = run_comparison(FINETUNE_SPEC, drive or row_driver(workers, ship_dir), validation_seeds, test_seeds,
                         log="rl_confirm")
    return {"candidates": list(CANDIDATES), **out}


def confirm_scratch(validation_seeds: list[int], test_seeds: list[int], workers: int, ship_dir: Path = SHIPPED_DIR,
                    idm: list[dict] | None = None, drive: Drive | None = None) -> dict[str, Any]:
    """Steps 3 and 4 of the protocol (:data:`SCRATCH_SPEC`); ``idm``: IDM + MOBIL's test episodes when driven
    already (the first part's), else driven here."""
    out = run_comparison(SCRATCH_SPEC, drive or row_driver(workers, ship_dir), validation_seeds, test_seeds,
                         given={"idm": idm} if idm is not None else None, log="rl_confirm")
    return {"candidates": list(SCRATCH_CANDIDATES), **out}


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
    """The zips of the parts driven are present, the test seeds touch no set of the seed ledger but this study's own
    (``rl_confirm_test``), and the parts kept are on the same seeds (:func:`kept_parts`)."""
    arms = [*CANDIDATES, SHIELD_CONTROL] * ("finetune" in opts.parts) + [*SCRATCH_CANDIDATES] * ("scratch" in opts.parts)
    check_zips(opts.ship_dir, arms)
    check_fresh(opts.seed_sets()[1], "the test seeds", allow=FINETUNE_SPEC.test_seeds.allow)
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
