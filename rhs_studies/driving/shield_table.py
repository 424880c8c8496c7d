"""The radar shield as a measured feature: every arm driven with and without it, on the exact and the fast env, on
the same fresh seeds.

Arms (``--arms``): the campaign's runs (``campaign:<recipe>:seed<k>``: the checkpoint chosen on the validation seeds,
:mod:`rhs_studies.driving.campaign`), highway-env's IDM + MOBIL (``idm``), the privileged headway driver
(``headway``, :class:`agents.policies.expert.HeadwayDriver`: IDM-like following and lane changes that act through the
meta-actions), always IDLE (``constant:1``) and always FASTER (``constant:3``), or any policy
:func:`agents.evaluate.load_policy` takes. Each arm is driven on each seed four times: shield off / on
(:class:`agents.policies.shield.ShieldedPolicy`, its default config) on the exact env (``rhs-highway-slam-v0``) and on the fast
env (``rhs-highway-slam-fast-v0``), with the campaign's env settings.

Per arm, env and shield: mean return, collisions, mean speed (m/s); with the shield, the override rate per step
(overridden steps / steps) and per episode (episodes with at least one override / episodes), by reason.
Paired over seeds (same seed, same env): collisions the shield **prevents** (off crashed, on did not) and
**causes** (on crashed, off did not), the return gain on - off with its 95 % bootstrap interval; the sim-to-sim
gap exact - fast, paired, per arm and shield. highway-env's IDM + MOBIL drives its own ``IDMVehicle`` in the ego's
seat and ignores the meta-actions, so a shield cannot act on it: it is driven shield off only (the headway driver
is the scripted arm the shield can lift).

Over the campaign's training seeds (rliable's statistics, :mod:`rhs_studies.kit.stats`): each run's return on each
seed divided by IDM + MOBIL's on the same seed and env is a score, the seeds the tasks: the IQM, mean and optimality
gap with stratified bootstrap intervals, and the performance profile.

The seeds (``--seed``, ``--episodes``) must be fresh: :func:`rhs_studies.kit.seeds.check_fresh` refuses any set of
the ledger but this study's own (:data:`OWN_SETS`: ``campaign_pilot_test``, the pilot's 10 seeds, and
``campaign_test``, the 100 seeds of the table; it may drive them again to reproduce).

    OMP_NUM_THREADS=1 python scripts/shield_table.py --episodes 10 --envs exact
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rhs_env.registration import HIGHWAY_SLAM_FAST_ID, HIGHWAY_SLAM_ID

__all__ = ["DEFAULT_ARMS", "OWN_SETS", "arm_policy", "drive_arm", "main", "paired", "summarize_arm", "table",
           "test_seeds", "versus"]

#: the ledger sets this study drives (and may drive again): the pilot's and the table's
OWN_SETS = ("campaign_pilot_test", "campaign_test")
#: the arms of the pilot: the three PPO-from-scratch runs, the scripted drivers, the trivial policies
DEFAULT_ARMS = ("campaign:ppo_scratch:seed0", "campaign:ppo_scratch:seed1", "campaign:ppo_scratch:seed2", "idm",
                "headway", "constant:1", "constant:3")
ENVS = {"exact": HIGHWAY_SLAM_ID, "fast": HIGHWAY_SLAM_FAST_ID}
#: drivers whose meta-actions the env ignores (a shield cannot act on them)
UNSHIELDABLE = ("idm",)


def test_seeds(first: int, episodes: int) -> list[int]:
    """``episodes`` seeds from ``first``, refused (``ValueError``) when they touch a driven set other than
    :data:`OWN_SETS` (:func:`rhs_studies.kit.seeds.check_fresh`)."""
    from rhs_studies.kit.seeds import check_fresh, consecutive

    seeds = consecutive(first, episodes)
    check_fresh(seeds, "--seed", allow=OWN_SETS)
    return seeds


def arm_policy(arm: str, root: str | Path | None = None) -> str:
    """The policy :func:`agents.evaluate.load_policy` takes for ``arm`` (``campaign:<recipe>:seed<k>``: the run's
    checkpoint chosen on the validation seeds, :func:`rhs_studies.driving.campaign.chosen_policy`, in ``root``, the
    campaign folder by default)."""
    if not arm.startswith("campaign:"):
        return arm
    from rhs_studies.driving.campaign import CAMPAIGN_DIR, chosen_policy

    parts = arm.split(":")
    if len(parts) != 3 or not parts[2].startswith("seed") or not parts[2][4:].isdigit():
        raise ValueError(f"arm {arm!r}: a campaign arm is campaign:<recipe>:seed<k>")
    return str(chosen_policy(root or CAMPAIGN_DIR, parts[1], int(parts[2][4:])))


def arm_record(arm: str, root: str | Path | None = None) -> dict[str, Any]:
    """The record beside a campaign arm's zip (:func:`arm_policy`): recipe, training seed, env steps, training wall
    time, commit and, for a selected checkpoint, the selection."""
    path = Path(arm_policy(arm, root)).with_suffix(".json")
    rec = json.loads(path.read_text())
    keys = ("recipe", "seed", "timesteps", "train_wall_s", "commit", "train_env_id", "env_id", "selection")
    return {"model": str(path.with_suffix(".zip").name), **{k: rec[k] for k in keys if k in rec}}


def _merged_records(paths: Sequence[Path]) -> dict[str, Any]:
    """The policy records of earlier results ``paths`` (the campaign arms they drove)."""
    out: dict[str, Any] = {}
    for path in paths:
        out.update(json.loads(Path(path).read_text()).get("policies", {}))
    return out


def _merged_provenance(paths: Sequence[Path]) -> list[dict[str, Any]]:
    """The provenance of each run whose episodes earlier results ``paths`` hold (theirs, and the runs they merged)."""
    out: list[dict[str, Any]] = []
    for path in paths:
        old = json.loads(Path(path).read_text())
        out += old.get("runs_provenance", []) + ([old["provenance"]] if "provenance" in old else [])
    return out


def _episode(env: Any, policy: Any, seed: int) -> dict[str, Any]:
    """One episode of ``policy`` (:func:`agents.evaluate.run_episode`), kept small: return, crash, speed, steps and
    the shield's overrides (None unshielded)."""
    from agents.evaluate import run_episode

    r = run_episode(env, policy, seed)
    return {"seed": seed, "return": float(r["return"]), "crashed": bool(r["crashed"]), "steps": int(r["steps"]),
            "mean_speed": r["mean_speed"], "overrides": r["shield_overrides"]}


def drive_arm(arm: str, env_id: str, env_kwargs: dict[str, Any], seeds: Sequence[int], shield: bool,
              root: str | Path | None = None) -> list[dict[str, Any]]:
    """``arm`` driven on ``seeds`` on ``env_id`` with (``shield``) or without the default radar shield."""
    from agents.evaluate import load_policy, make_env
    from agents.policies.shield import ShieldedPolicy

    env = make_env(env_id, env_kwargs)
    try:
        policy = load_policy(arm_policy(arm, root), env)
        if isinstance(policy, ShieldedPolicy):  # a record's own shield: the table sets it
            policy = policy.model
        if shield:
            policy = ShieldedPolicy(policy, {})
        return [_episode(env, policy, s) for s in seeds]
    finally:
        env.close()


def summarize_arm(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean return, collisions, mean speed; with a shield, the override rates per step and per episode."""
    speeds = [r["mean_speed"] for r in runs if r["mean_speed"] is not None]
    out: dict[str, Any] = {"episodes": len(runs), "return": float(np.mean([r["return"] for r in runs])),
                           "collisions": int(sum(r["crashed"] for r in runs)),
                           "mean_speed": float(np.mean(speeds)) if speeds else None,
                           "steps": int(sum(r["steps"] for r in runs))}
    counts = [r["overrides"] for r in runs if r["overrides"] is not None]
    if counts:
        total = {k: int(sum(c[k] for c in counts)) for k in counts[0]}
        overridden = sum(total.values())
        out["overrides"] = total
        out["override_rate_step"] = overridden / max(out["steps"], 1)
        out["override_rate_episode"] = float(np.mean([sum(c.values()) > 0 for c in counts]))
    return out


def _interval(diffs: np.ndarray, reps: int = 2000, seed: int = 0) -> list[float]:
    """The 95 % percentile bootstrap interval of the mean of ``diffs`` (over seeds)."""
    rng = np.random.default_rng(seed)
    means = diffs[rng.integers(0, diffs.size, size=(reps, diffs.size))].mean(axis=1)
    return [float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))]


def paired(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> dict[str, Any]:
    """``a`` against ``b`` on the same seeds: the mean return difference ``a - b`` with its interval, the seeds
    where only ``b`` crashed (``a`` avoided) and only ``a`` crashed."""
    by_b = {r["seed"]: r for r in b}
    pairs = [(r, by_b[r["seed"]]) for r in a if r["seed"] in by_b]
    if not pairs:
        raise ValueError("paired: no seed in common")
    d = np.asarray([x["return"] - y["return"] for x, y in pairs])
    return {"seeds": len(pairs), "return_diff": float(d.mean()), "interval": _interval(d),
            "only_b_crashed": int(sum(y["crashed"] and not x["crashed"] for x, y in pairs)),
            "only_a_crashed": int(sum(x["crashed"] and not y["crashed"] for x, y in pairs))}


def _shield_effect(on: list[dict[str, Any]], off: list[dict[str, Any]]) -> dict[str, Any]:
    p = paired(on, off)
    return {"return_gain": p["return_diff"], "interval": p["interval"], "collisions_prevented": p["only_b_crashed"],
            "collisions_caused": p["only_a_crashed"], "seeds": p["seeds"]}


def table(episodes: dict[str, dict[str, dict[str, list[dict[str, Any]]]]]) -> dict[str, Any]:
    """Per arm / env / shield the summary, the shield's paired effect, and the paired exact - fast gap.

    Args:
        episodes: ``episodes[arm][env]["off" | "on"]``, the episode records.
    """
    rows: dict[str, Any] = {}
    for arm, by_env in episodes.items():
        row: dict[str, Any] = {}
        for env, by_shield in by_env.items():
            row[env] = {k: summarize_arm(v) for k, v in by_shield.items()}
            if "on" in by_shield and "off" in by_shield:
                row[env]["shield_effect"] = _shield_effect(by_shield["on"], by_shield["off"])
        if "exact" in by_env and "fast" in by_env:
            row["sim_to_sim"] = {k: paired(by_env["exact"][k], by_env["fast"][k])
                                 for k in by_env["exact"] if k in by_env["fast"]}
        rows[arm] = row
    return rows


def training_seed_stats(episodes: dict[str, Any], recipe: str, env: str, shield: str, reference: str = "idm",
                        reps: int = 2000) -> dict[str, Any] | None:
    """rliable's statistics over the training seeds of ``recipe``: scores ``return / reference's return`` per run and
    seed (the seeds the tasks), their IQM / mean / optimality gap with stratified bootstrap intervals and the
    performance profile (None without two runs or the reference)."""
    from rhs_studies.kit.stats import aggregate, performance_profile

    arms = [a for a in episodes if a.startswith(f"campaign:{recipe}:")]
    ref = episodes.get(reference, {}).get(env, {}).get("off")
    if len(arms) < 2 or ref is None:
        return None
    base = {r["seed"]: r["return"] for r in ref}
    seeds = sorted(base)
    scores = np.asarray([[{r["seed"]: r["return"] for r in episodes[a][env][shield]}[s] / base[s] for s in seeds]
                         for a in arms])
    return {"runs": arms, "reference": reference, "env": env, "shield": shield, "seeds": seeds,
            "scores": scores.round(4).tolist(), **aggregate(scores, reps=reps),
            "profile": performance_profile(scores, np.linspace(0.5, 1.3, 17).round(3).tolist(), reps=reps)}


def versus(episodes: dict[str, Any], recipe: str, reference: str) -> dict[str, Any] | None:
    """Each run of ``recipe`` against the arm ``reference`` (the policy it started from, say) on the same seeds, per
    env and shield: :func:`paired` per run, and pooled over the runs (per seed the runs' mean return minus the
    reference's, its 95 % bootstrap interval over the seeds). None when the reference was not driven.

    Example:
        >>> ep = lambda r, c=False: {"seed": 0, "return": r, "crashed": c}
        >>> episodes = {"campaign:x:seed0": {"exact": {"off": [ep(3.0)]}},
        ...             "campaign:x:seed1": {"exact": {"off": [ep(1.0, True)]}}, "ref": {"exact": {"off": [ep(1.5)]}}}
        >>> v = versus(episodes, "x", "ref")["exact_off"]
        >>> v["pooled"]["return_diff"], v["campaign:x:seed1"]["only_a_crashed"]
        (0.5, 1)
    """
    if reference not in episodes:
        return None
    arms = [a for a in episodes if a.startswith(f"campaign:{recipe}:")]
    out: dict[str, Any] = {}
    for env, by_shield in episodes[reference].items():
        for shield, ref in by_shield.items():
            runs = [a for a in arms if shield in episodes[a].get(env, {})]
            if not runs:
                continue
            row: dict[str, Any] = {a: paired(episodes[a][env][shield], ref) for a in runs}
            base = {r["seed"]: r["return"] for r in ref}
            by_run = [{r["seed"]: r["return"] for r in episodes[a][env][shield]} for a in runs]
            seeds = [s for s in base if all(s in b for b in by_run)]
            d = np.asarray([np.mean([b[s] for b in by_run]) - base[s] for s in seeds])
            row["pooled"] = {"runs": len(runs), "seeds": len(seeds), "return_diff": float(d.mean()),
                             "interval": _interval(d)}
            out[f"{env}_{shield}"] = row
    return {"reference": reference, **out}


def drive_all(arms: Sequence[str], envs: Sequence[str], seeds: Sequence[int], env_kwargs: dict[str, Any],
              root: str | Path | None = None, log: Callable[[str], None] = print,
              done: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """Every arm on every env with the shield off and on (:data:`UNSHIELDABLE` off only); ``done`` sees the
    episodes after each arm (to write partial results). The exact env drops a fast radar's ``radar_model``
    (:func:`rhs_studies.driving.campaign.exact_env_kwargs`)."""
    from rhs_studies.driving.campaign import exact_env_kwargs

    episodes: dict[str, Any] = {}
    for arm in arms:
        for env in envs:
            for shield in (("off",) if arm in UNSHIELDABLE else ("off", "on")):
                t = time.time()
                kwargs = exact_env_kwargs(env_kwargs) if env == "exact" else env_kwargs
                runs = drive_arm(arm, ENVS[env], kwargs, seeds, shield == "on", root)
                episodes.setdefault(arm, {}).setdefault(env, {})[shield] = runs
                s = summarize_arm(runs)
                log(f"shield_table: {arm} {env} shield {shield}: return {s['return']:.2f}, {s['collisions']} "
                    f"collisions, {s.get('override_rate_step', 0):.3f} overrides/step, {time.time() - t:.0f} s")
        if done is not None:
            done(episodes)
    return episodes


def _merged(paths: Sequence[Path], seeds: list[int], env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The episodes of earlier results ``paths``; ``ValueError`` when one drove other seeds or env settings."""
    out: dict[str, Any] = {}
    for path in paths:
        old = json.loads(Path(path).read_text())
        if old["seeds"] != seeds or old["env_kwargs"] != env_kwargs:
            raise ValueError(f"--merge {path}: other seeds or env settings than this run's; the table pairs seeds")
        out.update(old["episodes"])
    return out


def main(argv: list[str] | None = None) -> int:
    """``scripts/shield_table.py``: drive the arms, write ``results/<name>.json``."""
    import argparse

    from rhs_studies.driving.campaign import CAMPAIGN_DIR, RECIPES
    from rhs_studies.kit.provenance import write_json

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--arms", nargs="*", default=list(DEFAULT_ARMS), help="none: only --merge")
    ap.add_argument("--envs", nargs="+", choices=sorted(ENVS), default=["exact", "fast"])
    ap.add_argument("--seed", type=int, default=21000)
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--recipe", choices=sorted(RECIPES), default="ppo_scratch", help="the env settings' recipe")
    ap.add_argument("--root", type=Path, default=CAMPAIGN_DIR)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[2] / "results" / "shield_table.json")
    ap.add_argument("--versus", default=None,
                    help="an arm each campaign run is paired against (the policy its recipe starts from, say)")
    ap.add_argument("--merge", type=Path, nargs="*", default=[],
                    help="results of earlier runs (same seeds and env settings) whose arms join the table")
    args = ap.parse_args(argv)
    seeds = test_seeds(args.seed, args.episodes)
    env_kwargs = dict(RECIPES[args.recipe].env_kwargs)
    started = time.time()
    earlier = _merged(args.merge, seeds, env_kwargs)

    merged_provenance = _merged_provenance(args.merge)
    records = {**_merged_records(args.merge),
               **{arm: arm_record(arm, args.root) for arm in args.arms if arm.startswith("campaign:")}}

    def write(episodes: dict[str, Any]) -> None:
        episodes = {**earlier, **episodes}
        stats = {f"{env}_{sh}": training_seed_stats(episodes, args.recipe, env, sh)
                 for env in args.envs for sh in ("off", "on")}
        result: dict[str, Any] = {"seeds": seeds, "env_kwargs": env_kwargs, "arms": list(episodes),
                  "policies": {a: r for a, r in records.items() if a in episodes},
                  "runs_provenance": merged_provenance, "table": table(episodes),
                  "training_seeds": stats, "episodes": episodes}
        if args.versus is not None:
            result["versus"] = versus(episodes, args.recipe, args.versus)
        write_json(args.out, result, "scripts/shield_table.py", vars(args), started, argv=argv)

    write(drive_all(args.arms, args.envs, seeds, env_kwargs, args.root, log=lambda s: print(s, flush=True),
                    done=write))
    print(json.dumps({"wrote": str(args.out)}))
    return 0
