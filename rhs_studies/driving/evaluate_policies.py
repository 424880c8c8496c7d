"""Shipped SLAM policy vs a random policy vs the ground-truth policy, on the same seeds.

Rows (every policy meets the same traffic: episode k uses seed ``--seed + k``):

* ``DAgger, continued, radar shield (shipped)``: ``agents/data/rl/dagger_cruise30_close.zip``, the
  shipped policy (:data:`agents.evaluate.SHIPPED_POLICY`): the radar + SLAM student below continued
  with DAgger for 80k env steps, then 40k + 40k with the headway driver at 30 m/s (2.0 s gap, then
  5 m standstill gap), driven behind the radar safety shield (:mod:`agents.policies.shield`, saved in its record);
* ``DAgger, continued 80k (shipped before)``: ``agents/data/rl/dagger_continue_80k.zip``, the first
  continuation alone;
* ``DAgger``: ``agents/data/dagger_rhs_highway_slam.zip`` (a student of
  the HeadwayDriver, :mod:`agents.algos.imitation`) on ``rhs-highway-slam-v0`` with the
  env kwargs saved beside it (SLAM in the loop), at the ground-truth student's budget;
* ``DAgger (ground truth)``: ``agents/data/dagger_rhs_highway_truth.zip`` on
  ``rhs-highway-v0`` (highway-env Kinematics observation of the same scene), and
  on an all-around Kinematics observation (``agents/data/truth/``), when trained;
* ``PPO`` on either observation (``agents/data/ppo_rhs_highway_{slam,truth}.zip``,
  the same env-step budget);
* ``random``: uniformly random actions on the SLAM env and config;
* ``HeadwayDriver``: the DAgger expert (:class:`agents.policies.expert.HeadwayDriver`, a
  scripted time-gap driver on the simulator state), on ``rhs-highway-v0``, deciding
  every step and, as it taught the students, every k steps with IDLE between
  (``headway:<k>``, k the students' decision interval);
* ``always SLOWER``: a scripted reference, action 4 (SLOWER) at every step, i.e.
  the lowest target speed (20 m/s) in the current lane, on ``rhs-highway-v0`` with
  highway-env's action set, as the driving targets were set (the students' env kwargs may
  widen the target speeds, ``train_policy.FINE_SPEEDS``: the reference does not);
* ``IDM + MOBIL``: a strong scripted reference, highway-env's own ``IDMVehicle``
  (IDM car following, MOBIL lane changes, desired speed 30 m/s) in the ego's
  seat (``agents.evaluate.IDMMobilPolicy``), on ``rhs-highway-v0``.

Same seed and same actions give the same traffic and reward on both env ids (the
radar and SLAM wrappers draw their noise from child streams).

Reward is highway-env's default (normalized to [0, 1] per step, 5 steps per
second); a collision (``info["crashed"]``) ends the episode. Writes
``results/policies.json`` (every episode) and ``results/policies.md`` (the
README table; collision rates with 95 % Wilson intervals, returns paired by seed with
IDM + MOBIL's), and checks the aim: SLAM policy >= 80 % of the ground-truth
policy's mean return with a collision rate <= 1.5x its rate, and the goal of
the driving targets: SLAM policy >= 1.1x the always-SLOWER return, collision rate <= 4 %,
a higher mean speed than always-SLOWER, and within 10 % of the ground-truth
policy's return (for the shipped policy, the same-budget student and PPO).

    OMP_NUM_THREADS=1 python scripts/evaluate_policies.py [--episodes 100] [--seed 1000] [--workers 2]
    python scripts/evaluate_policies.py --keep-episodes --keep-antenna   # drive only what the last run lacks
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from agents.policies.decision import SLOWER
from rhs_common.stats import mean_interval, paired_difference, wilson_interval
from rhs_studies.kit.driving import ANTENNA_STUDY, TARGETS, drive_seeds, run_policy, target_path
from rhs_studies.kit.provenance import write_json
from rhs_studies.kit.seeds import first
from rhs_studies.kit.tables import paired

ROOT = Path(__file__).resolve().parents[2]

REWARD_AIM, COLLISION_AIM = 0.8, 1.5
#: the driving targets: return vs always-SLOWER, collision rate, return vs the ground-truth policy
GOAL_VS_SLOWER, GOAL_COLLISIONS, GOAL_VS_TRUTH = 1.1, 0.04, 0.9


def _same_policy(a: str, b: str) -> bool:
    """Whether two policy strings name the same policy (a scripted name, or one file wherever the checkout lies)."""
    if a == b:
        return True
    pa, pb = Path(a), Path(b)
    return pa.suffix == ".zip" and pb.suffix == ".zip" and pa.parts[-3:] == pb.parts[-3:]


def _contiguous(seeds: list[int]) -> list[list[int]]:
    """``seeds`` split into runs of consecutive integers (what :func:`run_policy` drives in one call)."""
    parts: list[list[int]] = []
    for s in seeds:
        if parts and s == parts[-1][-1] + 1:
            parts[-1].append(s)
        else:
            parts.append([s])
    return parts


def saved_shield(policy: str) -> dict[str, Any] | None:
    """The radar shield a policy drives behind (:func:`agents.policies.shield.shield_record` of its record's ``shield``: every
    field, the present defaults filled in), or None."""
    from agents.evaluate import policy_metadata
    from agents.policies.shield import shield_record

    return shield_record(policy_metadata(policy).get("shield"))


def kept_runs(previous: dict, policy: str, env_id: str, kwargs: dict,
              shield: dict[str, Any] | None = None) -> dict[int, dict]:
    """Seed -> episode of an earlier ``policies.json`` row that drove the same policy on the same env and kwargs,
    behind the same shield (``shield``: :func:`saved_shield`; a row without a ``shield`` entry drove none, or one
    from before its fields were recorded, and is driven again)."""
    for row in previous.get("rows", []):
        if (_same_policy(row["policy"], policy) and row["env_id"] == env_id and row["env_kwargs"] == kwargs
                and row.get("shield") == shield):
            return {run["seed"]: run for run in row["runs"]}
    return {}


def fingerprint() -> list[float]:
    """The shipped policy, the DAgger SLAM and ground-truth students, the all-around student and the PPO policies,
    one 2-second episode (10 steps) each, seed 1000."""
    from agents.evaluate import (
        DAGGER_POLICY,
        PPO_POLICY,
        PPO_TRUTH_POLICY,
        SHIPPED_POLICY,
        SHIPPED_TRUTH_POLICY,
        resolve_env,
    )

    out = []
    others = [p for p in (target_path("dagger", "truth_all_around"), PPO_POLICY, PPO_TRUTH_POLICY) if p.exists()]
    for policy in dict.fromkeys((SHIPPED_POLICY, DAGGER_POLICY, SHIPPED_TRUTH_POLICY, *others)):
        env_id, kwargs = resolve_env(str(policy))
        run = drive_seeds([1000], str(policy), env_id, {**kwargs, "duration": 2})[0]
        out += [run[k] for k in sorted(run) if isinstance(run[k], (int, float)) and not k.endswith("_s")]
    return out


def antenna_study(episodes: int, seed: int, workers: int, done: dict[str, list[dict]] | None = None) -> dict:
    """The antenna study: DAgger students on RHS and phased-array observations, same budget, same seeds.

    For each env (highway, dense roadside) both policies drive the same seeds; the RHS - phased return
    difference is paired over seeds (95 % t-interval), collision rates get Wilson intervals. ``done``
    maps a policy path to episodes already run on these seeds and its own env (the goal-1 table's), reused.
    """
    from agents.evaluate import policy_metadata, resolve_env, summarize

    seeds = list(range(seed, seed + episodes))
    rows, pairs = [], []
    missing = [name for name in ANTENNA_STUDY if not target_path("dagger", name).exists()]
    for name in missing:
        print(f"evaluate_policies: antenna study: {target_path('dagger', name)} is missing (train it with "
              f"python scripts/train_policy.py --only {name}); its row is left out", file=sys.stderr)
    for name in (n for n in ANTENNA_STUDY if n not in missing):
        policy = target_path("dagger", name)
        env_id, kwargs = resolve_env(str(policy))
        print(f"evaluate_policies: antenna study: {name} on {env_id}, {episodes} episodes ...", file=sys.stderr)
        t0 = time.perf_counter()
        reuse = (done or {}).get(str(policy))
        runs = reuse if reuse is not None and len(reuse) == episodes else run_policy(str(policy), env_id, kwargs, seeds, workers)
        meta = policy_metadata(policy)
        antenna = (kwargs.get("radar") or {}).get("antenna", "rhs")
        summary = summarize(runs)
        rows.append({"name": name, "policy": str(policy.relative_to(ROOT)), "env_id": env_id, "env_kwargs": kwargs,
                     "antenna": antenna, "timesteps": meta.get("timesteps"), "wall_s": round(time.perf_counter() - t0, 1),
                     "summary": summary, "return_ci": mean_interval([r["return"] for r in runs]).mean_and_half(),
                     "collision_ci": wilson_interval(summary["collisions"], len(runs)),
                     "returns": [r["return"] for r in runs]})  # fmt: skip
    for env_id in dict.fromkeys(r["env_id"] for r in rows):
        rhs = next((r for r in rows if r["env_id"] == env_id and r["antenna"] == "rhs"), None)
        phased = next((r for r in rows if r["env_id"] == env_id and r["antenna"] == "phased"), None)
        if rhs is None or phased is None:
            continue
        diff = paired_difference(rhs["returns"], phased["returns"]).mean_and_half()
        pairs.append({"env_id": env_id, "return_diff_rhs_minus_phased": diff})
    return {"episodes": episodes, "seeds": seeds, "targets": {n: TARGETS[n][0] for n in ANTENNA_STUDY},
            "rows": rows, "pairs": pairs, "missing": missing}


def target_speeds(env_kwargs: dict) -> list[float]:
    """The meta-actions' target speeds (m/s) of an env made with ``env_kwargs``: its ``action`` config's, else
    highway-env's default (``MDPVehicle.DEFAULT_TARGET_SPEEDS``, what ``DiscreteMetaAction`` then uses)."""
    from highway_env.vehicle.controller import MDPVehicle

    speeds = (env_kwargs.get("action") or {}).get("target_speeds", MDPVehicle.DEFAULT_TARGET_SPEEDS)
    return [float(v) for v in speeds]


def speeds_text(speeds: list[float]) -> str:
    """``10, 15, 20`` (m/s)."""
    return ", ".join(f"{v:g}" for v in speeds)


def antenna_markdown(study: dict) -> str:
    lines = [
        (
            f"Does the antenna matter for driving? DAgger students (same expert, same env-step budget per env) on RHS "
            f"and on phased-array observations, {study['episodes']} seeds ({study['seeds'][0]}..{study['seeds'][-1]}) "
            "each: return mean ± 95 % t-interval; collision rates with 95 % Wilson intervals; speed and SLAM "
            "position RMSE mean ± standard deviation over episodes, and the RMSE's worst episode (a lost track "
            "shows there, not in the mean's interval)."
        ),
        "",
        "| env | antenna | target speeds (m/s) | training env steps | return | collision rate | mean speed (m/s) "
        "| SLAM position RMSE (m) | worst episode's RMSE (m) |",
        "|---|---|---|---:|---|---|---|---|---:|",
    ]
    for r in study["rows"]:
        s = r["summary"]
        lo, hi = r["collision_ci"]
        m, h = r["return_ci"]
        lines.append(
            f"| `{r['env_id']}` | {r['antenna']} | {speeds_text(target_speeds(r['env_kwargs']))} "
            f"| {r['timesteps']} | {m:.1f} ± {h:.1f} | {s['collision_rate']:.2f} "
            f"({s['collisions']}/{s['episodes']}; {lo:.2f}-{hi:.2f}) | {_fmt(s['mean_speed_mps'])} "
            f"| {_fmt(s['position_rmse_m'], 2)} | {_worst(s['position_rmse_m'])} |"
        )
    lines.append("")
    for p in study["pairs"]:
        m, h = p["return_diff_rhs_minus_phased"]
        verdict = "RHS higher" if m - h > 0 else ("phased higher" if m + h < 0 else "no significant difference")
        lines.append(f"`{p['env_id']}`: return RHS - phased, paired over seeds: {m:+.1f} ± {h:.1f} ({verdict}).  ")
    if study.get("missing"):
        lines.append(f"Not trained yet, so not in the table: {', '.join(study['missing'])} "
                     "(`python scripts/train_policy.py --only NAME`).")
    return "\n".join(lines) + "\n"


def learned_specs(slam_policy: str, truth_policy: str, shipped_only: bool = False,
                  shipped_policy: str | None = None) -> list[tuple]:
    """(key, label, observation, policy, env id, env kwargs) of the learned policies: the shipped policy (a DAgger
    student continued past the students' budget) where it is not ``slam_policy``, the DAgger pair at one budget
    (radar + SLAM and ground truth), the all-around DAgger student and PPO with the same budget."""
    shipped_policy = shipped_policy or slam_policy
    from agents.evaluate import PPO_POLICY, PPO_TRUTH_POLICY, resolve_env

    slam_obs, truth_obs = "radar point cloud + SLAM", "highway-env Kinematics (truth)"
    specs = [
        ("slam", "DAgger", slam_obs, slam_policy, *resolve_env(slam_policy)),
        ("truth", "DAgger (ground truth)", truth_obs, truth_policy, *resolve_env(truth_policy)),
    ]
    if Path(shipped_policy).resolve() != Path(slam_policy).resolve():
        from agents.evaluate import DAGGER_CONTINUED_POLICY, DAGGER_CRUISE30_CLOSE_POLICY

        before = [(k, str(p)) for k, p in (("shield_student", DAGGER_CRUISE30_CLOSE_POLICY),
                                           ("continued_80k", DAGGER_CONTINUED_POLICY))
                  if p.exists() and p.resolve() != Path(shipped_policy).resolve()]
        specs = [("shipped", f"{continued_label(shipped_policy)} (shipped)", slam_obs, shipped_policy,
                  *resolve_env(shipped_policy)),
                 *((key, f"{continued_label(path)} (shipped before)", slam_obs, path, *resolve_env(path))
                   for key, path in before), *specs]
    others = [("truth_all_around", "DAgger (ground truth, all around)", "Kinematics, 8 vehicles incl. behind (truth)",
               target_path("dagger", "truth_all_around"), "dagger"), ("ppo_slam", "PPO", slam_obs, PPO_POLICY, "ppo"),
              ("ppo_truth", "PPO (ground truth)", truth_obs, PPO_TRUTH_POLICY, "ppo")]  # fmt: skip
    for key, label, obs, path, algo in [] if shipped_only else others:
        if Path(path).exists():
            specs.append((key, label, obs, str(path), *resolve_env(str(path))))
        else:
            print(f"evaluate_policies: {path} is missing (scripts/train_policy.py --algo {algo}); row left out",
                  file=sys.stderr)
    return specs


def continued_label(policy: str) -> str:
    """The policies table's name of a policy that continues the DAgger student: its algorithm, budget and shield."""
    from agents.evaluate import policy_metadata

    meta = policy_metadata(policy)
    shield = ", radar shield" if meta.get("shield") is not None else ""
    if meta.get("algo") == "finetune":
        return f"PPO fine-tune of the DAgger student{shield}"
    return f"DAgger, continued{shield}" if shield else f"DAgger, continued {meta.get('timesteps', 0) // 1000}k"


def goal_of(by: dict[str, dict], key: str) -> dict:
    """The driving targets for the SLAM policy ``key``: against always-SLOWER and the better ground-truth policy of the
    same algorithm (PPO: ``ppo_truth``; DAgger: ``truth`` or the all-around one, whichever returns more)."""
    truths = ["ppo_truth"] if key == "ppo_slam" else [k for k in ("truth", "truth_all_around") if k in by]
    ref = max(truths, key=lambda k: by[k]["return"]["mean"])
    s, slower = by[key], by["slower"]
    goal = {
        "policy": key,
        "return_vs_slower": s["return"]["mean"] / slower["return"]["mean"],
        "collision_rate": s["collision_rate"],
        "speed_gain_mps": s["mean_speed_mps"]["mean"] - slower["mean_speed_mps"]["mean"],
        "truth_reference": ref,
        "return_vs_best_truth": s["return"]["mean"] / by[ref]["return"]["mean"],
    }
    goal["met"] = bool(goal["return_vs_slower"] >= GOAL_VS_SLOWER and goal["collision_rate"] <= GOAL_COLLISIONS
                       and goal["speed_gain_mps"] > 0 and goal["return_vs_best_truth"] >= GOAL_VS_TRUTH)
    return goal


def _worst(stats: dict) -> str:
    """The largest value of an episode statistic (``max`` of its summary), or n/a."""
    return "n/a" if stats.get("max") is None else f"{stats['max']:.2f}"


def _fmt(stats: dict, digits: int = 1, spread: bool = True) -> str:
    if stats.get("mean") is None:
        return "n/a"
    text = f"{stats['mean']:.{digits}f}"
    if spread and stats.get("std") is not None:
        text += f" ± {stats['std']:.{digits}f}"
    return text


def _collisions(summary: dict) -> str:
    """``rate (k/n) [low-high %]``: the collision rate with its 95 % Wilson interval."""
    k, n = summary["collisions"], summary["episodes"]
    low, high = wilson_interval(k, n)
    return f"{summary['collision_rate']:.2f} ({k}/{n}) [{100 * low:.0f}-{100 * high:.0f} %]"


def _vs_reference(row: dict, rows: list[dict], reference: str = "idm") -> str:
    """The row's return minus the reference row's, paired over the seeds both drove (mean [low, high], 95 % t)."""
    ref = next((r for r in rows if r["key"] == reference), None)
    if ref is None or row is ref:
        return ""
    d = paired(row["runs"], ref["runs"])
    return "n/a" if d["n"] < 2 else f"{d['mean']:+.1f} [{d['low']:+.1f}, {d['high']:+.1f}]"


def _shipped_vs_start(rows: list[dict]) -> list[str]:
    """The shipped policy against the student it continues (``slam``), paired over the seeds; [] without both."""
    by = {r["key"]: r for r in rows}
    if "shipped" not in by or "slam" not in by:
        return []
    shipped, start = by["shipped"], by["slam"]
    diff = _vs_reference(shipped, rows, reference="slam")
    k1, k0, n = shipped["summary"]["collisions"], start["summary"]["collisions"], shipped["summary"]["episodes"]
    return ["", f"{shipped['label']} - {start['label']} (its start), paired over the seeds: return {diff} (95 % CI); "
            f"collisions {k1} against {k0} of {n}."]


def markdown(result: dict) -> str:
    rows = result["rows"]
    lines = [
        (
            f"Same {result['episodes']} seeds ({result['seeds'][0]}..{result['seeds'][-1]}) for every policy; "
            "mean ± standard deviation over episodes. Reward: highway-env default, normalized to [0, 1] per step, "
            f"{result['max_steps']} steps (40 s at 5 Hz) at most; a collision ends the episode."
        ),
        "",
        (
            "| policy | observation | return | return - IDM + MOBIL (paired, 95 % CI) | collision rate [Wilson 95 %] "
            "| mean speed (m/s) | episode length (steps) | SLAM position RMSE (m) | SLAM map RMSE (m) |"
        ),
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        s = r["summary"]
        lines.append(
            f"| {r['label']} | {r['observation']} | {_fmt(s['return'])} | {_vs_reference(r, rows)} "
            f"| {_collisions(s)} | {_fmt(s['mean_speed_mps'])} | {_fmt(s['episode_length'], 0)} "
            f"| {_fmt(s['position_rmse_m'], 2)} | {_fmt(s['map_rmse_m'], 2)} |"
        )
    slam_row = next(r for r in rows if r["key"] == "slam")
    kw = slam_row["env_kwargs"]
    lines += [
        "",
        f"The SLAM and random rows run on `{slam_row['env_id']}` "
        + (
            f"with env kwargs `{json.dumps(kw)}` (saved beside the policy, used by `rhs-slam demo` / `evaluate`)"
            if kw
            else "with its default configuration"
        )
        + f"; the ground-truth and scripted rows on `{next(r for r in rows if r['key'] == 'truth')['env_id']}`: "
        "the same scene and traffic (same seed and actions give the same episode on both ids), observed through "
        'highway-env\'s Kinematics table. "Always SLOWER" (lowest target speed, 20 m/s, never changing lane) is '
        "a scripted reference for the learned policies; \"IDM + MOBIL\" is highway-env's own driver model "
        "(the traffic's) in the ego's seat with a desired speed of 30 m/s: a strong scripted reference. "
        "\"HeadwayDriver\" is the DAgger expert (agents/expert.py): meta-actions chosen from the true gaps "
        "and speeds; the DAgger students see only their observation. Same budget: both DAgger students and "
        "both PPO policies saw the env-step counts listed under Training; the shipped policy and those shipped "
        "before it continue the radar + SLAM student past that budget (DAgger, then for the shipped one a PPO "
        "fine-tune; its start's steps plus its own). highway-env's default Kinematics "
        "observation lists the 4 nearest vehicles *ahead*: it hides the followers the expert checks before "
        "a lane change, which the radar's 360-degree point cloud shows; the all-around row observes 8 "
        "vehicles, behind as well.",
    ]
    speeds, default = target_speeds(kw), target_speeds({})
    if speeds != default:
        lines += [
            "",
            f"The learned policies and the HeadwayDriver rows choose among target speeds [{speeds_text(speeds)}] m/s "
            f"(env kwargs `action`); always SLOWER and IDM + MOBIL keep highway-env's [{speeds_text(default)}], the "
            f"set the driving targets are set against (on the wider set, always SLOWER would hold {speeds[0]:g} m/s and "
            "return less).",
        ]
    lines += _shipped_vs_start(rows)
    aim = result["aim"]
    ref = next((r for r in rows if r["key"] == "slower"), None)
    learned = [r for r in rows if r["key"] in ("slam", "truth")]
    if ref is not None and all(r["summary"]["return"]["mean"] < ref["summary"]["return"]["mean"] for r in learned):
        why = ""
        if all(r["summary"]["collision_rate"] > 0 for r in learned):
            why = " (both still crash in some episodes, and a collision forfeits the rest of the episode's reward)"
        lines += ["", f"Neither learned policy reaches the scripted reference's return yet{why}."]
    lines += [
        "",
        (
            f"SLAM policy / ground-truth policy: mean return ratio **{aim['return_ratio']:.2f}** "
            f"(aim >= {REWARD_AIM}), collision rate ratio **{aim['collision_ratio_text']}** "
            f"(aim <= {COLLISION_AIM}): aim {'met' if aim['met'] else 'NOT met'}."
        ),
    ]
    for goal in (result.get("goals") or {"slam": result["goal"]}).values():
        label = next(r["label"] for r in rows if r["key"] == goal.get("policy", "slam"))
        lines += [
            "",
            (
                f"Driving target ({label}, radar + SLAM): return / always-SLOWER **{goal['return_vs_slower']:.2f}** "
                f"(aim >= {GOAL_VS_SLOWER}), collision rate **{goal['collision_rate']:.2f}** (aim <= {GOAL_COLLISIONS}), "
                f"mean speed {goal['speed_gain_mps']:+.2f} m/s vs always-SLOWER (aim > 0), return / ground-truth "
                f"policy **{goal.get('return_vs_best_truth', goal.get('return_vs_truth', float('nan'))):.2f}** "
                f"(`{goal.get('truth_reference', 'truth')}`; aim >= {GOAL_VS_TRUTH}): goal "
                f"{'met' if goal['met'] else 'NOT met'}."
            ),
        ]
    lines += [
        "",
        f"Training (scripts/train_policy.py; the continuation: scripts/rl_finetune.py): {result['training_text']}",
    ]
    kept = result.get("kept_episodes")
    if kept:
        labels = {r["key"]: r["label"] for r in rows}
        what = [f"{labels.get(k, k)} ({n} seeds)" for k, n in kept["rows"].items()] + (
            ["the antenna study below"] if kept.get("antenna") else [])
        lines += ["", f"Episodes kept from the run at {kept['commit'][:7]} (same policy, env and seeds; the results "
                  f"fingerprint guards the code): {', '.join(what)}; the other episodes were driven at this file's commit."]
    if result.get("antenna"):
        lines += ["", antenna_markdown(result["antenna"]).rstrip("\n")]
    return "\n".join(lines) + "\n"


def rerun_antenna(args: argparse.Namespace, started: float, argv: list[str] | None) -> int:
    """``--antenna-only``: the antenna study again, the goal tables of ``policies.json`` kept (their episodes are
    reused where a study policy is one of them); the earlier run's provenance is kept as ``tables_provenance``."""
    out = Path(args.out_dir)
    result = json.loads((out / "policies.json").read_text())
    if result["episodes"] != args.antenna_episodes or result["seeds"][0] != args.seed:
        raise SystemExit("evaluate_policies: --antenna-only needs the seeds of policies.json "
                         f"({result['episodes']} from {result['seeds'][0]})")
    tables = result.pop("provenance")
    result.setdefault("tables_provenance", tables)  # the run that made the goal tables, not an earlier --antenna-only
    done = {r["policy"]: r["runs"] for r in result["rows"]}
    result["antenna"] = antenna_study(args.antenna_episodes, args.seed, args.workers, done)
    write_json(out / "policies.json", result, __file__, args, started, fingerprint, argv)
    (out / "policies.md").write_text(markdown(result))
    print(antenna_markdown(result["antenna"]))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--seed", type=int, default=first("policies_table"), help="first seed (training used 0.. and 10000..)")
    ap.add_argument("--workers", type=int, default=2, help="processes per policy")
    ap.add_argument("--slam-policy", default=None,
                    help="the radar + SLAM student compared with --truth-policy at the same budget "
                    "(default: agents/data/dagger_rhs_highway_slam.zip; the shipped policy gets its own row)")
    ap.add_argument("--truth-policy", default=None, help="default: agents/data/dagger_rhs_highway_truth.zip")
    ap.add_argument("--shipped-only", action="store_true", help="skip the all-around and PPO rows")
    ap.add_argument("--no-antenna", action="store_true", help="skip the antenna study (RHS vs phased-array students)")
    ap.add_argument("--antenna-episodes", type=int, default=50, help="seeds per policy in the antenna study")
    ap.add_argument("--out-dir", default=str(ROOT / "results"))
    ap.add_argument("--render-only", action="store_true", help="rewrite policies.md from policies.json, no runs")
    ap.add_argument("--keep-episodes", action="store_true",
                    help="reuse the episodes of --out-dir's policies.json for rows driving the same policy, env and env "
                    "kwargs on the same seeds (policy and code unchanged since: the results fingerprint guards the "
                    "code); drive only the missing seeds. The result names the rows and the commit they came from")
    ap.add_argument("--keep-antenna", action="store_true",
                    help="keep the antenna study of --out-dir's policies.json (same seeds), as --keep-episodes")
    ap.add_argument("--antenna-only", action="store_true",
                    help="rerun only the antenna study (e.g. after training its policies) into the existing policies.json")
    args = ap.parse_args(argv)
    started = time.time()
    if args.render_only:
        result = json.loads((Path(args.out_dir) / "policies.json").read_text())
        (Path(args.out_dir) / "policies.md").write_text(markdown(result))
        print(markdown(result))
        return 0
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if args.antenna_only:
        return rerun_antenna(args, started, argv)

    from agents.evaluate import (
        DAGGER_POLICY,
        SHIPPED_POLICY,
        SHIPPED_TRUTH_POLICY,
        is_scripted,
        policy_metadata,
        resolve_env,
        summarize,
    )

    slam_policy = args.slam_policy or str(DAGGER_POLICY)
    truth_policy = args.truth_policy or str(SHIPPED_TRUTH_POLICY)
    slam_env, slam_kwargs = resolve_env(slam_policy)
    truth_env, truth_kwargs = resolve_env(truth_policy)
    seeds = list(range(args.seed, args.seed + args.episodes))
    # the expert as the DAgger students learned from it: deciding at their decision interval, pulsed
    teacher_k = int(policy_metadata(SHIPPED_POLICY).get("decision_interval") or 1) if SHIPPED_POLICY.exists() else 1
    # the goal's references as issued: highway-env's action set (always SLOWER holds 20 m/s, not the students' 10)
    issued_kwargs = {k: v for k, v in truth_kwargs.items() if k != "action"}
    specs = learned_specs(slam_policy, truth_policy, args.shipped_only, str(SHIPPED_POLICY)) + [
        ("random", "random", "(none)", "random", slam_env, slam_kwargs),
        ("headway", "HeadwayDriver (DAgger expert, scripted, 5 Hz)", "(simulator state)", "headway", truth_env,
         truth_kwargs),
        ("headway_teacher", f"HeadwayDriver every {teacher_k} steps, IDLE between (as it taught)", "(simulator state)",
         f"headway:{teacher_k}", truth_env, truth_kwargs),
        ("slower", "always SLOWER (scripted)", "(none)", f"constant:{SLOWER}", truth_env, issued_kwargs),
        ("idm", "IDM + MOBIL (highway-env, scripted)", "(simulator state)", "idm", truth_env, issued_kwargs),
    ]
    previous = json.loads((Path(args.out_dir) / "policies.json").read_text()) if args.keep_episodes else {}
    rows, kept = [], {}
    for key, label, obs, policy, env_id, kwargs in specs:
        shield = saved_shield(policy)
        old = kept_runs(previous, policy, env_id, kwargs, shield)
        todo = [s for s in seeds if s not in old]
        print(f"evaluate_policies: {label} on {env_id}, {len(todo)} episodes"
              + (f" ({len(seeds) - len(todo)} kept)" if len(todo) < len(seeds) else "") + " ...", file=sys.stderr)
        t0 = time.perf_counter()
        new = {run["seed"]: run for part in _contiguous(todo) for run in run_policy(policy, env_id, kwargs, part, args.workers)}
        runs = [new[s] if s in new else old[s] for s in seeds]
        if len(todo) < len(seeds):
            kept[key] = len(seeds) - len(todo)
        wall = time.perf_counter() - t0
        summary = summarize(runs)
        print(
            f"  return {_fmt(summary['return'])}, collisions {summary['collision_rate']:.2f} ({wall:.0f} s)",
            file=sys.stderr,
        )
        slim = [{k: v for k, v in r.items() if k not in ("true_xy", "estimated_xy", "landmarks_true",
                                                          "landmarks_est", "position_error_m")} for r in runs]  # fmt: skip
        rows.append({"key": key, "label": label, "observation": obs, "policy": policy, "env_id": env_id,
                     "env_kwargs": kwargs, "shield": shield, "wall_s": round(wall, 1), "summary": summary,
                     "runs": slim})  # fmt: skip
    by = {r["key"]: r["summary"] for r in rows}
    ret_ratio = by["slam"]["return"]["mean"] / by["truth"]["return"]["mean"]
    c_slam, c_truth = by["slam"]["collision_rate"], by["truth"]["collision_rate"]
    if c_truth > 0:
        c_ratio, c_text, c_ok = c_slam / c_truth, f"{c_slam / c_truth:.2f}", c_slam <= COLLISION_AIM * c_truth
    else:
        c_ratio, c_text, c_ok = None, ("0/0" if c_slam == 0 else f"{c_slam:.2f} vs 0"), c_slam == 0
    goals = {key: goal_of(by, key) for key in ("shipped", "slam", "ppo_slam") if key in by}
    goal = next((g for g in goals.values() if g["met"]), goals.get("shipped", goals["slam"]))
    training = {}
    for key, _, _, policy, _, _ in specs:
        if is_scripted(policy):
            continue
        meta = policy_metadata(policy)
        training[key] = {
            k: meta.get(k)
            for k in ("algo", "env_id", "env_kwargs", "timesteps", "n_envs", "wall_time_s", "steps_per_s", "init_policy")
        }
    training_text = "; ".join(
        f"{k} ({v['algo'] or 'ppo'}): {v['timesteps']} env steps on {v['env_id']} with {v['n_envs']} subprocess envs "
        + (f"continuing {v['init_policy']} " if v.get("init_policy") else "")
        + f"in {v['wall_time_s']} s "
        f"({v['steps_per_s']} steps/s)" + (f", env kwargs `{json.dumps(v['env_kwargs'])}`" if v["env_kwargs"] else "")
        for k, v in training.items()
    )
    max_steps = None
    try:
        import gymnasium as gym

        import rhs_env  # noqa: F401  (registers the ids)

        base: Any = gym.make(truth_env, **truth_kwargs).unwrapped  # highway-env's AbstractEnv (untyped)
        cfg = base.config
        max_steps = round(cfg["duration"] * cfg["policy_frequency"])
    except Exception:
        pass
    result = {
        "episodes": args.episodes,
        "seeds": seeds,
        "max_steps": max_steps,
        "rows": rows,
        "aim": {
            "return_ratio": ret_ratio,
            "collision_ratio": c_ratio,
            "collision_ratio_text": c_text,
            "return_ok": ret_ratio >= REWARD_AIM,
            "collision_ok": bool(c_ok),
            "met": bool(ret_ratio >= REWARD_AIM and c_ok),
        },
        "goal": goal,
        "goals": goals,
        "training": training,
        "training_text": training_text,
    }
    keep_antenna = args.keep_antenna and previous.get("antenna", {}).get("seeds") == list(
        range(args.seed, args.seed + args.antenna_episodes))
    if kept or keep_antenna:  # episodes of the same policies on the same seeds, driven at an earlier commit
        result["kept_episodes"] = {"rows": kept, "antenna": keep_antenna, "commit": previous["provenance"]["commit"]}
    if keep_antenna:
        result["antenna"] = previous["antenna"]
    elif not args.no_antenna:
        # every learned row already ran on its policy's own env (learned_specs resolves it)
        done = {r["policy"]: r["runs"] for r in rows if not is_scripted(r["policy"])}
        result["antenna"] = antenna_study(args.antenna_episodes, args.seed, args.workers, done)
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "policies.json", result, __file__, args, started, fingerprint, argv)
    (out / "policies.md").write_text(markdown(result))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
