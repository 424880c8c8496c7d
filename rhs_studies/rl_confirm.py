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

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluate import resolve_env
from rhs_studies.evaluate_policies import paired, run_policy
from rhs_studies.provenance import write_json
from rhs_studies.rl_finetune import (
    LABELS,
    SHIELD_CONTROL,
    SHIPPED_DIR,
    STARTS,
    evaluate_rows,
    paired_text,
    row_summary,
    table_row,
    targets,
)
from rhs_studies.rl_finetune import fingerprint as study_fingerprint

ROOT = Path(__file__).resolve().parent.parent
#: the exploring fine-tunes the choice is between (the RL study's two best shield arms on its seeds)
CANDIDATES = ("shield_explore", "shield_flank_explore")
#: the rows besides the candidates: their start, on both seed sets
START = "shipped"
#: PPO from scratch under the shield, the RL study's three arms
SCRATCH_CANDIDATES = ("shield_scratch", "shield_scratch_explore", "shield_scratch_cost")
#: PPO from scratch's targets: return vs IDM + MOBIL, collisions per episode
SCRATCH_VS_IDM, SCRATCH_COLLISIONS = 1.0, 0.04
SLIM = ("seed", "return", "crashed", "mean_speed")
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


def arm_policies(rows: tuple[str, ...], ship_dir: Path) -> dict[str, Path]:
    """The policy file of each row: a start's, else the arm's zip in ``ship_dir``."""
    return {row: STARTS[row] if row in STARTS else ship_dir / f"{row}.zip" for row in rows}


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
    lines += [table_row(key, s, t["vs_start"].get(key)) for key, s in t["rows"].items()]
    lines += ["", targets_line(t["targets"], "the chosen arm")]
    if "scratch" in result:
        lines += ["", *scratch_markdown(result["scratch"])]
    kept = result.get("kept_parts") or {}
    if kept:
        lines += ["", "Parts kept from an earlier run of this script on the same seeds: "
                  + ", ".join(f"{part} ({commit[:7] if commit else 'unknown commit'})" for part, commit in kept.items())
                  + "."]
    return "\n".join(lines) + "\n"


def targets_line(tg: dict[str, Any], judged: str) -> str:
    """The fine-tune's targets (:func:`rhs_studies.rl_finetune.targets`) on the test seeds, judged on ``judged``."""
    met = ", ".join(f"{k} {'met' if ok else 'not met'}" for k, ok in tg["met"].items())
    return (f"Targets judged on {judged}: {tg['return_vs_idm']:.3f}x IDM + MOBIL, "
            f"{100 * tg['collision_rate']:.0f} % collisions, {tg['mean_speed_mps']:.1f} m/s, "
            f"{paired_text(tg['gain_over_student'])} over the shield student, "
            f"{paired_text(tg['gain_over_dagger_continue'])} over the DAgger control; targets: {met}.")


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
    lines += [table_row(key, s, t["vs_idm"].get(key), label[key]) for key, s in t["rows"].items()]
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


def slim_runs(runs: dict[str, list[dict]]) -> dict[str, list[dict]]:
    """Each row's episodes with only the fields the results keep (:data:`SLIM`)."""
    return {k: [{f: e.get(f) for f in SLIM} for e in r] for k, r in runs.items()}


def drive_arm(arm: str, seeds: list[int], workers: int, ship_dir: Path = SHIPPED_DIR, deterministic: bool = True,
              shield: dict[str, Any] | None = None) -> list[dict]:
    """The arm's zip in ``ship_dir`` on ``seeds``, on its saved env; greedy or sampled actions, behind ``shield``
    (None: the shield its record keeps; :func:`rhs_studies.evaluate_policies.run_policy`)."""
    path = str(ship_dir / f"{arm}.zip")
    env_id, kwargs = resolve_env(path)
    return run_policy(path, env_id, kwargs, seeds, workers, deterministic, shield)


def confirm_scratch(validation_seeds: list[int], test_seeds: list[int], workers: int, ship_dir: Path = SHIPPED_DIR,
                    idm: list[dict] | None = None, candidates: tuple[str, ...] = SCRATCH_CANDIDATES) -> dict[str, Any]:
    """Steps 3 and 4 of the protocol (the module's docstring); ``idm``: IDM + MOBIL's test episodes when driven
    already (the first part's), else driven here."""
    val = {arm: drive_arm(arm, validation_seeds, workers, ship_dir, False) for arm in candidates}
    chosen = max(candidates, key=lambda arm: float(np.mean([e["return"] for e in val[arm]])))
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
    return study_fingerprint()


def study_arguments(ap: argparse.ArgumentParser, test_seed: int) -> None:
    """The options of a study on fresh seeds (this one, :mod:`rhs_studies.rl_lane_rule_trial`): its validation and test
    seeds, workers and folders."""
    ap.add_argument("--validation-seed", type=int, default=7000, help="first validation seed (the choice)")
    ap.add_argument("--validation-episodes", type=int, default=100)
    ap.add_argument("--seed", type=int, default=test_seed, help="first test seed")
    ap.add_argument("--episodes", type=int, default=100, help="test episodes")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--ship-dir", type=Path, default=SHIPPED_DIR, help="the RL study's shipped arms")
    ap.add_argument("--out-dir", type=Path, default=ROOT / "results")


def seed_sets(ap: argparse.ArgumentParser, args: argparse.Namespace, arms: list[str]) -> tuple[list[int], list[int]]:
    """The validation and test seeds of :func:`study_arguments`' options; ``ap.error`` when a set has fewer than two
    episodes, the sets overlap, or an arm of ``arms`` has no zip in ``--ship-dir``."""
    if args.episodes < 2 or args.validation_episodes < 2:
        ap.error("--episodes and --validation-episodes must be >= 2 (intervals need two episodes)")
    val = list(range(args.validation_seed, args.validation_seed + args.validation_episodes))
    test = list(range(args.seed, args.seed + args.episodes))
    if set(val) & set(test):
        ap.error(f"the validation seeds {val[0]}-{val[-1]} overlap the test seeds {test[0]}-{test[-1]}")
    missing = [a for a in arms if not (Path(args.ship_dir) / f"{a}.zip").exists()]
    if missing:
        ap.error(f"no shipped zip for {missing} in {args.ship_dir}: run scripts/rl_finetune.py first")
    return val, test


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    study_arguments(ap, test_seed=6000)
    ap.add_argument("--parts", nargs="+", choices=PARTS, default=list(PARTS),
                    help="the parts driven (the others kept from the existing rl_confirm.json, same seeds)")
    args = ap.parse_args(argv)
    arms = [*CANDIDATES, SHIELD_CONTROL] * ("finetune" in args.parts) + [*SCRATCH_CANDIDATES] * ("scratch" in args.parts)
    val, test = seed_sets(ap, args, arms)
    out = Path(args.out_dir)
    try:
        result, kept = kept_parts(out / "rl_confirm.json", [p for p in PARTS if p not in args.parts], val, test)
    except ValueError as err:
        ap.error(str(err))
    started = time.time()
    if "finetune" in args.parts:
        result.update(confirm(val, test, args.workers, Path(args.ship_dir)))
    if "scratch" in args.parts:
        result["scratch"] = confirm_scratch(val, test, args.workers, Path(args.ship_dir), idm=_idm_runs(result, test))
    if kept:
        result["kept_parts"] = kept
    write_json(out / "rl_confirm.json", result, __file__, args, started, fingerprint, argv)
    text = markdown(result)
    (out / "rl_confirm.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
