"""Reinforcement learning on top of imitation: the PPO fine-tune of the DAgger student against its controls.

Arms (same env-step budget each, ``--timesteps``, on ``rhs-highway-slam-v0`` with the student's env kwargs,
decisions at 1 Hz in pulse mode; :mod:`agents.algos.finetune`):

* ``finetune``: PPO from the student with the privileged critic, the class-prior correction and the KL anchor
  decaying to zero at half the run (``agents/hyperparams/finetune.yml``);
* ``finetune_no_anchor``: the same without the anchor (``anchor_coef: 0``);
* ``finetune_horizon``: the fine-tune with a longer horizon (``gamma: 0.95`` at one decision per second: a crash
  then costs about 20 s of lost reward instead of 5) and the time-to-collision shaping of :mod:`agents.algos.shaping`;
* ``dagger_continue``: DAgger going on from the student, the expert labelling the states it reaches
  (``agents/hyperparams/dagger_continue.yml``);
* ``finetune_horizon_80k`` and ``dagger_continue_80k``: the longer-horizon fine-tune and its DAgger control with
  four times the budget (80k env steps each); the targets judge this pair when it was evaluated;
* ``dagger_lookahead``: DAgger going on from the student with the lookahead teacher
  (:class:`agents.policies.lookahead.LookaheadDriver`: each meta-action forecast on a copy of the true traffic, the best
  taken; ``agents/hyperparams/dagger_lookahead.yml``, 48k env steps), judged by the same targets against the 80k
  DAgger continuation of the headway expert;
* ``scratch``: PPO from scratch with the privileged critic (``finetune.yml`` without a student, with PPO's usual
  learning rate 5e-4, clip range 0.2, an entropy bonus 0.01 and the time-to-collision shaping of
  :mod:`agents.algos.shaping`), on request (``--arms ... scratch``).

Arms under the radar safety shield (:mod:`agents.policies.shield`), from the shield student (``shipped``: the 30 m/s DAgger
student that drives behind the shield, :data:`agents.evaluate.DAGGER_CRUISE30_CLOSE_POLICY`) instead of the student
above, and
evaluated behind the shield their records keep:

* ``shield_finetune``: the fine-tune under the shield (``agents/hyperparams/finetune_shielded.yml``: gamma 0.95 and
  the time-to-collision shaping, as ``finetune_horizon``), 20k env steps;
* ``shield_warmup``: the same with a critic warm-up (the first 20 % of the run trains the critic alone), larger
  rollouts, a bolder step and no shaping (``agents/hyperparams/finetune_warmup.yml``), 60k env steps;
* ``shield_explore``: the warm-up fine-tune without the anchor, with an entropy bonus of 0.02 and learning rate
  3e-4 (exploration the shield makes safe), 40k env steps;
* ``shield_flank_explore``: ``shield_explore`` trained again under the shield with its flank rule (one radar point
  beside the ego blocks a lane change, :mod:`agents.policies.shield`), which the arms above were trained without (they are
  driven behind it);
* ``shield_dagger``: their DAgger control, DAgger going on from the shield student with its own teacher, the
  student's actions driven through the shield (``agents/hyperparams/dagger_shielded.yml``), 40k env steps;
* ``shield_scratch``: PPO from scratch under the shield (``finetune_shielded.yml`` without a student, on the shipped
  policy's env kwargs), 60k env steps;
* ``shield_scratch_explore``: the same with the ``scratch`` arm's PPO settings (learning rate 5e-4, clip range 0.2,
  entropy bonus 0.01), 60k env steps;
* ``shield_scratch_cost``: ``shield_scratch_explore`` with a cost of 0.5 for every env step whose action the shield
  replaced (:mod:`agents.algos.shaping`'s ``shield_cost``: the braking and the vetoes left to the shield become the
  policy's loss), 60k env steps.

Evaluation on ``--episodes`` seeds from ``--seed`` (3000..: never used in training, where the envs draw seeds
0.. and 20000.., nor in any earlier selection), every policy on the same seeds; the scripted references
(always SLOWER, IDM + MOBIL, the headway expert and the lookahead teacher deciding at 1 Hz) on ``rhs-highway-v0``, which meets the same
traffic for the same seed and actions. Each row: mean return with its t interval, collisions with a Wilson
interval, mean speed; paired return differences (t intervals over the common seeds) against the student and the
DAgger continuation. The learning curves (return and collision rate of the training episodes against env steps)
come from each run's ``monitor/`` files; ``results/rl_finetune.png`` draws them.

Targets for the fine-tune on the held-out seeds: return >= 1.08x IDM + MOBIL, collisions <= 2 per 100, mean speed
>= 24 m/s, a paired gain over its start (the student, or the shield student for the shield arms) >= +3 with its 95 %
interval above 0, and more than the DAgger continuation (``shield_dagger`` for the shield arms). Paired
differences in the table are against each row's start.

    OMP_NUM_THREADS=1 python scripts/rl_finetune.py --train            # train the missing arms, then evaluate
    OMP_NUM_THREADS=1 python scripts/rl_finetune.py --runs runs/rl     # evaluate trained arms
    OMP_NUM_THREADS=1 python scripts/rl_finetune.py --arms dagger_lookahead --keep student idm ...  # one new arm

:mod:`rhs_studies.driving.rl_confirm` repeats the choice between the best shield arms and their test on fresh seeds.

``--keep ROW ...`` takes those rows' episodes from the existing ``results/rl_finetune.json`` (same seeds) instead of
driving them again: for policies and code unchanged since (the fingerprint test says whether the code changed); the
result names the commit each kept row was driven at.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluate import resolve_env
from rhs_studies.kit.driving import (
    ARMS,
    ENV_ID,
    HYPERPARAMS,
    LABELS,
    ROOT,
    SHIELD_ARMS,
    SHIELD_CONTROL,
    SHIPPED_DIR,
    SHIPPED_START,
    SLIM_KEYS,
    STARTS,
    STUDENT,
    Arm,
    evaluate_rows,
    rl_fingerprint,
    start_of,
    targets,
)
from rhs_studies.kit.provenance import git_state, write_json
from rhs_studies.kit.seeds import first
from rhs_studies.kit.tables import paired, paired_text, row_summary
from rhs_studies.kit.tables import table_row as _table_row

#: training episodes per point of a learning curve (a rolling window)
CURVE_WINDOW = 20


def hyperparams_file(spec: str, run_dir: Path, arm: str) -> Path:
    """``NAME.yml`` of agents/hyperparams, or ``NAME.yml:key=value;key=value``: a copy with those keys set (values
    in YAML), written to ``run_dir/ARM.yml``."""
    import yaml

    name, _, overrides = spec.partition(":")
    path = HYPERPARAMS / name
    if not overrides:
        return path
    table = yaml.safe_load(path.read_text())
    changes = {k.strip(): yaml.safe_load(v) for k, v in (item.split("=", 1) for item in overrides.split(";"))}
    for entry in table.values():
        entry.update(changes)
    out = run_dir / f"{arm}.yml"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(yaml.safe_dump(table, sort_keys=False))
    return out


def _rel(path: Path) -> str:
    """``path`` from the repository root when it lies inside it (commands recorded in results name no machine)."""
    path = Path(path).resolve()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def train_command(arm: str, runs: Path, timesteps: int, seed: int) -> list[str]:
    """``python -m rhs_slam train ...`` for ``arm`` into ``runs/arm`` (``timesteps`` env steps unless the arm sets
    its own): from its start with ``--init-policy``, or from scratch on the start's env kwargs."""
    algo, spec, from_student, own_steps, start = ARMS[arm]
    out = runs / arm
    steps = own_steps or timesteps
    cmd = [sys.executable, "-m", "rhs_slam", "train", "--algo", algo, "--env", ENV_ID, "--timesteps", str(steps),
           "--seed", str(seed), "--out", _rel(out), "--no-progress", "--hyperparams", _rel(hyperparams_file(spec, runs, arm))]
    if from_student:
        cmd += ["--init-policy", str(STARTS[start].relative_to(ROOT))]
    elif start != "student":  # from scratch on the start's env (its action set and radar)
        cmd += ["--env-kwargs", json.dumps(resolve_env(str(STARTS[start]))[1])]
    return cmd


def train_arm(arm: str, runs: Path, timesteps: int, seed: int) -> dict[str, Any]:
    """Train ``arm`` with :func:`train_command` in a subprocess; its record (command, commit, wall)."""
    cmd = train_command(arm, runs, timesteps, seed)
    print(f"rl_finetune: training {arm}: {' '.join(cmd[1:])}", file=sys.stderr)
    state = git_state()  # the code the run starts from
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, cwd=ROOT)
    record = {"command": cmd[1:], "commit": state.get("commit"), "dirty": state.get("dirty"),
              "wall_s": round(time.perf_counter() - t0, 1)}
    (runs / arm / "run.json").write_text(json.dumps(record, indent=1))
    return record


def run_record(runs: Path, arm: str) -> dict[str, Any] | None:
    """How the arm was trained: ``runs/ARM/run.json`` (written by ``--train``) or, for a run started by hand,
    the ``runs/ARM.command`` (the arguments of ``rhs-slam train``) / ``runs/ARM.commit`` files beside its folder;
    None when neither is there."""
    run = runs / arm / "run.json"
    if run.exists():
        return json.loads(run.read_text())
    command, commit = runs / f"{arm}.command", runs / f"{arm}.commit"
    if command.exists() and commit.exists():
        return {"command": ["rhs_slam", "train", *command.read_text().split()], "commit": commit.read_text().strip()}
    return None


def ship_arm(arm: str, runs: Path, ship_dir: Path = SHIPPED_DIR) -> Path:
    """Copy the arm's actor zip and training record to ``ship_dir/ARM.zip`` / ``.json``; the zip's path."""
    ship_dir.mkdir(parents=True, exist_ok=True)
    src = runs / arm
    dst = ship_dir / f"{arm}.zip"
    shutil.copyfile(src / "model.zip", dst)
    record = json.loads((src / "model.json").read_text())
    record["trained_by"] = run_record(runs, arm)
    record["model"] = str(dst.relative_to(ROOT)) if dst.is_relative_to(ROOT) else str(dst)
    dst.with_suffix(".json").write_text(json.dumps(record, indent=2) + "\n")
    return dst


def learning_curve(monitor_dir: Path, window: int = CURVE_WINDOW) -> dict[str, list[float]]:
    """Return and collision rate of the training episodes (rolling mean of ``window``) against env steps.

    Reads stable-baselines3's ``*.monitor.csv`` files (one per env; columns r, l, t, crashed), orders the
    episodes by their end time and counts env steps as the sum of the lengths of the episodes ended so far.
    """
    rows = []
    for path in sorted(Path(monitor_dir).glob("*.monitor.csv")):
        lines = path.read_text().splitlines()[1:]  # the first line is the monitor's JSON header
        if len(lines) < 2:
            continue
        header = lines[0].split(",")
        for line in lines[1:]:
            values = dict(zip(header, line.split(","), strict=False))
            rows.append((float(values["t"]), float(values["r"]), int(values["l"]),
                         float(values.get("crashed", "False") in ("True", "1", "1.0"))))
    if not rows:
        return {"env_steps": [], "return": [], "collision_rate": []}
    rows.sort()
    steps = np.cumsum([r[2] for r in rows])
    w = min(window, len(rows))

    def rolling(x: np.ndarray) -> list[float]:
        c = np.concatenate([[0.0], np.cumsum(x)])
        return ((c[w:] - c[:-w]) / w).tolist()

    return {"env_steps": steps[w - 1:].tolist(), "return": rolling(np.array([r[1] for r in rows])),
            "collision_rate": rolling(np.array([r[3] for r in rows]))}


#: (fine-tune arm, its DAgger control of the same budget), the first pair present is the one the targets judge
HEADLINE_PAIRS = (("finetune_horizon_80k", "dagger_continue_80k"), ("finetune", "dagger_continue"))


#: the student of the lookahead teacher, judged by the same targets against the DAgger continuation of the headway
#: expert with the most env steps
TEACHER_PAIR = ("dagger_lookahead", "dagger_continue_80k")


def headline_arm(runs: dict[str, list[dict]]) -> tuple[str, str]:
    """The fine-tune the targets judge and its DAgger control: the longest budget evaluated."""
    for arm, control in HEADLINE_PAIRS:
        if arm in runs:
            return arm, control
    return HEADLINE_PAIRS[-1]


def plot(curves: dict[str, dict[str, list[float]]], path: Path) -> None:
    """Return and collision rate of the training episodes against env steps, one line per arm; one row of panels
    per start (the DAgger student's arms, the shield arms)."""
    import matplotlib.pyplot as plt

    starts = [s for s in STARTS if any(start_of(arm) == s for arm in curves)] or ["student"]
    fig, axes = plt.subplots(len(starts), 2, figsize=(11, 4.6 * len(starts)), squeeze=False,
                             gridspec_kw={"hspace": 0.8, "wspace": 0.25})
    for (ax_r, ax_c), start in zip(axes, starts, strict=True):
        for arm, curve in curves.items():
            if curve["env_steps"] and start_of(arm) == start:
                ax_r.plot(curve["env_steps"], curve["return"], label=LABELS.get(arm, arm))
                ax_c.plot(curve["env_steps"], curve["collision_rate"], label=LABELS.get(arm, arm))
        where = "from the DAgger student" if start == "student" else "under the shield"
        ax_r.set(xlabel="env steps", ylabel=f"episode return (mean of {CURVE_WINDOW})",
                 title=f"Training episodes {where}: return")
        ax_c.set(xlabel="env steps", ylabel=f"collision rate (of {CURVE_WINDOW})",
                 title=f"Training episodes {where}: collisions")
        for ax in (ax_r, ax_c):
            ax.xaxis.set_major_formatter(lambda x, _: f"{x / 1000:.0f}k")
        ax_r.legend(fontsize=7, loc="upper center", bbox_to_anchor=(1.12, -0.2), ncol=2)  # under both panels
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def table_row(key: str, s: dict[str, Any], gain: dict[str, float] | None, label: str | None = None) -> str:
    """One row of the table: :func:`rhs_studies.kit.tables.table_row` labelled ``label``, else by :data:`LABELS`."""
    return _table_row(label or LABELS.get(key, key), s, gain)


def markdown(result: dict[str, Any]) -> str:
    """The results table: one row per policy, paired differences against each row's start (:func:`start_of`)."""
    lines = [f"Held-out seeds {result['seeds'][0]}-{result['seeds'][-1]} ({result['episodes']} episodes, "
             f"{ENV_ID}); each arm {result['timesteps']} env steps from the DAgger student unless its label gives "
             "another budget or start; the shield arms start from the shield student and drive behind the shield. "
             "Paired differences are against each row's start (the DAgger student for the references).", "",
             "| policy | return (95 % CI) | collisions [Wilson 95 %] | speed m/s | vs its start (paired, 95 % CI) |",
             "|---|---|---|---|---|"]
    for key, s in result["rows"].items():
        lines.append(table_row(key, s, result["vs_student"].get(key)))
    kept = result.get("kept_rows") or {}
    if kept:
        lines += ["", "Rows kept from an earlier run of this script on the same seeds (policy and code unchanged since): "
                  + ", ".join(f"{LABELS.get(k, k)} ({c[:7] if c else 'unknown commit'})" for k, c in kept.items()) + "."]
    for t in (result.get("targets") or {}, result.get("targets_teacher") or {}, result.get("targets_shield") or {}):
        if not t:
            continue
        met = ", ".join(f"{k} {'met' if v else 'not met'}" for k, v in t["met"].items())
        name = LABELS.get(t.get("arm", "finetune"), t.get("arm", "finetune"))
        against = t.get("gain_over_control")
        gain = t["gain_over_student"]
        vs = f" ({paired_text(gain)} over its start"
        vs += ")" if against is None else f"; {paired_text(against)} over {LABELS.get(t['control'], t['control'])})"
        lines += ["", f"Targets judged on {name}: {t['return_vs_idm']:.3f}x IDM + MOBIL, {100 * t['collision_rate']:.0f} % collisions, "
                  f"{t['mean_speed_mps']:.1f} m/s{vs}; targets: {met}."]
    return "\n".join(lines) + "\n"


def table_order(runs: dict[str, Any]) -> dict[str, Any]:
    """``runs`` in the table's order: the starts, the arms (as :data:`ARMS` lists them), then the references.

    >>> list(table_order({"idm": 0, "shield_explore": 0, "shipped": 0, "finetune": 0}))
    ['shipped', 'finetune', 'shield_explore', 'idm']
    """
    order = [*STARTS, *ARMS, *LABELS]
    return dict(sorted(runs.items(), key=lambda kv: order.index(kv[0]) if kv[0] in order else len(order)))


def keep_rows(path: Path, rows: list[str], seeds: list[int]) -> dict[str, Any]:
    """The episodes (``runs``) and learning curves of ``rows`` from an earlier result ``path`` on the same ``seeds``,
    and the commit each was measured at (``commits``); ``ValueError`` when the file, a row or a seed is missing."""
    if not path.exists():
        raise ValueError(f"--keep: {path} does not exist")
    old = json.loads(path.read_text())
    missing = [r for r in rows if r not in old.get("runs", {})]
    if missing:
        raise ValueError(f"--keep: {path} has no rows {missing} (it has {sorted(old.get('runs', {}))})")
    for r in rows:
        if sorted(e["seed"] for e in old["runs"][r]) != sorted(seeds):
            raise ValueError(f"--keep: row {r} of {path} was driven on other seeds than {seeds[0]}-{seeds[-1]}")
    measured = old.get("provenance", {}).get("commit") or old.get("commit")
    commits = {r: (old.get("kept_rows") or {}).get(r, measured) for r in rows}  # a row kept before keeps its commit
    return {"runs": {r: old["runs"][r] for r in rows}, "curves": {r: c for r, c in old.get("curves", {}).items() if r in rows},
            "commits": commits}


def fingerprint() -> list[float]:
    """The starts and each shipped arm, one 2-second episode (10 steps) on seed 3000 (the other zips beside the
    arms are not this study's): :func:`rhs_studies.kit.driving.rl_fingerprint`."""
    return rl_fingerprint()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=Path, default=ROOT / "runs" / "rl",
                    help="training runs folder (one subfolder per arm)")
    ap.add_argument("--arms", nargs="+", default=list(ARMS), choices=list(ARMS))
    ap.add_argument("--train", action="store_true", help="train the arms whose run folder has no model.zip")
    ap.add_argument("--timesteps", type=int, default=20000, help="env steps per arm")
    ap.add_argument("--train-seed", type=int, default=first("training"))
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--seed", type=int, default=first("rl_finetune_heldout"), help="first held-out evaluation seed")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out-dir", type=Path, default=ROOT / "results")
    ap.add_argument("--ship-dir", type=Path, default=SHIPPED_DIR, help="where the arms' actor zips are copied")
    ap.add_argument("--keep", nargs="+", default=[], metavar="ROW",
                    help="rows (student, shipped, arms, slower, idm, headway, lookahead) taken from the existing "
                         "rl_finetune.json of --out-dir instead of driven again: same seeds, for policies and code "
                         "unchanged since (the result names the commit they were measured at)")
    ap.add_argument("--redrive", nargs="+", default=[], metavar="ARM", choices=list(ARMS),
                    help="arms driven again from their shipped zips in --ship-dir, their training records and learning "
                         "curves taken from the existing rl_finetune.json: for trained policies whose evaluation code "
                         "changed (e.g. the shield they drive behind); no run folder needed")
    ap.add_argument("--render-only", action="store_true",
                    help="rewrite rl_finetune.md and .png from rl_finetune.json, no runs")
    args = ap.parse_args(argv)
    if args.render_only:
        result = json.loads((Path(args.out_dir) / "rl_finetune.json").read_text())
        text = markdown(result)
        (Path(args.out_dir) / "rl_finetune.md").write_text(text)
        plot(result.get("curves") or {}, Path(args.out_dir) / "rl_finetune.png")
        print(text)
        return 0
    if args.episodes < 2:
        ap.error("--episodes must be >= 2 (intervals need two episodes)")
    started = time.time()
    runs_dir = Path(args.runs)
    kept = [row for row in args.keep if row in args.arms]
    if kept:
        ap.error(f"--keep {' '.join(kept)}: a row kept cannot be in --arms (those are shipped and driven again)")
    both = [row for row in args.redrive if row in args.arms or row in args.keep]
    if both:
        ap.error(f"--redrive {' '.join(both)}: an arm driven again cannot be in --arms or --keep as well")
    missing = [row for row in args.redrive if not (Path(args.ship_dir) / f"{row}.zip").exists()]
    if missing:
        ap.error(f"--redrive {' '.join(missing)}: no shipped zip in {args.ship_dir} (train and ship the arm first)")
    seeds = list(range(args.seed, args.seed + args.episodes))
    try:
        previous = keep_rows(Path(args.out_dir) / "rl_finetune.json", args.keep, seeds) if args.keep else {}
    except ValueError as err:
        ap.error(str(err))
    for arm in args.arms:
        if args.train and not (runs_dir / arm / "model.zip").exists():
            train_arm(arm, runs_dir, args.timesteps, args.train_seed)
        if not (runs_dir / arm / "model.zip").exists():
            ap.error(f"{runs_dir / arm}/model.zip is missing: train it (--train) or leave {arm} out of --arms")
    shipped = {arm: ship_arm(arm, runs_dir, Path(args.ship_dir)) for arm in args.arms}
    shipped.update({arm: Path(args.ship_dir) / f"{arm}.zip" for arm in args.redrive})
    for row in args.keep:  # a kept arm's zip and training record are the shipped ones
        if row in ARMS:
            shipped[row] = Path(args.ship_dir) / f"{row}.zip"
    runs = evaluate_rows({**STARTS, **shipped}, seeds, args.workers, skip=tuple(args.keep))
    runs = table_order({**previous.get("runs", {}), **runs})
    rows = {key: row_summary(r) for key, r in runs.items()}
    curves = {arm: learning_curve(runs_dir / arm / "monitor") for arm in args.arms}
    earlier = dict(previous.get("curves", {}))  # the kept rows'
    if args.redrive:  # the arms driven again keep the curves of their training, from the earlier result
        saved = json.loads((Path(args.out_dir) / "rl_finetune.json").read_text()).get("curves", {})
        earlier.update({k: v for k, v in saved.items() if k in args.redrive})
    curves = {**earlier, **curves}
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    plot(curves, out / "rl_finetune.png")
    training = {arm: {k: json.loads(p.with_suffix(".json").read_text()).get(k) for k in
                      ("algo", "timesteps", "wall_time_s", "steps_per_s", "trained_by", "class_prior", "finetune")}
                for arm, p in shipped.items()}
    result = {
        "env_id": ENV_ID, "episodes": args.episodes, "seeds": seeds, "timesteps": args.timesteps,
        "rows": rows,
        "vs_student": {k: paired(runs[k], runs[start_of(k)]) for k in runs if k != "student"},
        "targets": targets(rows, runs, *headline_arm(runs)),
        "targets_teacher": targets(rows, runs, *TEACHER_PAIR) if TEACHER_PAIR[0] in rows else {},
        "targets_shield": next((targets(rows, runs, arm, SHIELD_CONTROL) for arm in SHIELD_ARMS if arm in rows), {}),
        "training": training,
        "curves": curves,
        "runs": {k: [{f: r.get(f) for f in SLIM_KEYS} for r in v] for k, v in runs.items()},
    }
    if args.keep:
        result["kept_rows"] = previous["commits"]  # row -> the commit its episodes were driven at
    write_json(out / "rl_finetune.json", result, __file__, args, started, fingerprint, argv)
    (out / "rl_finetune.md").write_text(markdown(result))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["ARMS", "HYPERPARAMS", "LABELS", "SHIELD_ARMS", "SHIELD_CONTROL", "SHIPPED_DIR", "SHIPPED_START", "STARTS",
           "STUDENT", "Arm", "evaluate_rows", "fingerprint", "headline_arm", "hyperparams_file", "keep_rows",
           "learning_curve", "main", "markdown", "paired", "paired_text", "plot", "row_summary", "ship_arm",
           "start_of", "table_order", "table_row", "targets", "train_command"]
