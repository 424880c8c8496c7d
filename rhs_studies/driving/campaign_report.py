"""The campaign's page: the throughput floor, the learning curves over training seeds, the shield table.

* :func:`floor`: env steps/s of the fast SLAM env alone (the native vector env, one env, in this process) and of
  the exact env, measured here, beside the campaign's PPO rates (env steps per second of ``learn``, per chunk, from
  the runs' ``state.json``), and the hours ``steps x seeds x recipes`` need at the PPO rate on one core. The machine's
  load average is recorded with them (the rates are those of a shared machine).
* :func:`markdown`: the page from ``results/campaign_<recipe>.json`` (:func:`rhs_studies.driving.campaign.curves`),
  ``results/shield_table.json`` (:mod:`rhs_studies.driving.shield_table`), the imitation + RL recipe's
  ``results/shield_table_student.json`` (its own env settings, each run paired against its start) and the floor.

    OMP_NUM_THREADS=1 python scripts/campaign_report.py floor
    python scripts/campaign_report.py page
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from rhs_env.registration import HIGHWAY_SLAM_FAST_ID, HIGHWAY_SLAM_ID

__all__ = ["env_rate", "floor", "main", "markdown"]

RESULTS = Path(__file__).resolve().parents[2] / "results"


def env_rate(env_id: str, steps: int, env_kwargs: dict[str, Any], seed: int = 21_500) -> dict[str, float]:
    """Env steps per wall second and per CPU second of this process (``time.process_time``: what one free core
    gives on a shared machine) of ``env_id`` alone (uniform random actions, seeded), after one warm-up step."""
    import gymnasium as gym

    import rhs_env  # noqa: F401

    vec = gym.make_vec(env_id, num_envs=1, vectorization_mode="vector_entry_point", **env_kwargs)
    rng = np.random.default_rng(seed)
    try:
        vec.reset(seed=seed)
        vec.step(np.array([1]))
        t, cpu = time.perf_counter(), time.process_time()
        for _ in range(steps):
            vec.step(rng.integers(0, 5, size=1))
        return {"wall": steps / (time.perf_counter() - t), "cpu": steps / max(time.process_time() - cpu, 1e-9)}
    finally:
        vec.close()


def ppo_rate(recipe_name: str, steps: int) -> dict[str, float]:
    """Env steps per wall / CPU second of the recipe's PPO ``learn`` on its vector env (collection and updates),
    from a fresh model, after a first rollout (kernel warm-up) that is not timed."""
    from rhs_studies.driving.campaign import RECIPES, make_train_env, new_model

    recipe = RECIPES[recipe_name]
    venv = make_train_env(recipe)
    try:
        model = new_model(recipe, venv, 0)
        rollout = int(model.n_steps) * recipe.n_envs
        model.learn(total_timesteps=rollout)
        t, cpu = time.perf_counter(), time.process_time()
        model.learn(total_timesteps=max(rollout, steps // recipe.decision_interval), reset_num_timesteps=False)
        done = (int(model.num_timesteps) - rollout) * recipe.decision_interval
        return {"wall": done / (time.perf_counter() - t), "cpu": done / max(time.process_time() - cpu, 1e-9),
                "env_steps": done}
    finally:
        venv.close()


def floor(root: str | Path, recipes: list[str], seeds: list[int], steps: int = 400, target_steps: int = 2_000_000,
          env_kwargs: dict[str, Any] | None = None, ppo_steps: int = 1280) -> dict[str, Any]:
    """The throughput floor (see the module docstring).

    Args:
        root: the campaign folder.
        recipes: the recipes whose runs' PPO rates are read (and counted in the hours).
        seeds: the training seeds per recipe.
        steps: env steps timed per env.
        target_steps: the env steps per run the hours are for.
        env_kwargs: the envs' kwargs (default: the campaign's).
        ppo_steps: env steps of the timed PPO ``learn`` (:func:`ppo_rate`, the first recipe; 0: none).

    Returns:
        The fast and exact env's steps per wall and per CPU second, the PPO rate measured here
        (``ppo_measured``) and the campaign chunks' wall rates (``ppo_steps_per_s``: median, min, max), the hours
        ``target_steps x len(seeds) x len(recipes)`` need on one free core at the PPO CPU rate and at the env's alone,
        the load average.
    """
    from rhs_studies.driving.campaign import CAMPAIGN_ENV_KWARGS, load_state, run_dir

    kwargs = dict(CAMPAIGN_ENV_KWARGS if env_kwargs is None else env_kwargs)
    load = list(os.getloadavg())
    fast = env_rate(HIGHWAY_SLAM_FAST_ID, steps, kwargs)
    exact = env_rate(HIGHWAY_SLAM_ID, max(steps // 4, 10), kwargs)
    ppo_now = ppo_rate(recipes[0], ppo_steps) if ppo_steps else None
    rates = [p["steps_per_s"] for r in recipes for s in seeds if (st := load_state(run_dir(root, r, s)))
             for p in st["curve"]]
    ppo = float(np.median(rates)) if rates else None
    total = target_steps * len(seeds) * len(recipes)
    per_core = ppo_now["cpu"] if ppo_now else None
    return {"fast_env_steps_per_s": round(fast["wall"], 2), "fast_env_steps_per_cpu_s": round(fast["cpu"], 2),
            "exact_env_steps_per_s": round(exact["wall"], 2), "exact_env_steps_per_cpu_s": round(exact["cpu"], 2),
            "ppo_measured": ppo_now,
            "ppo_steps_per_s": None if ppo is None else {"median": round(ppo, 2), "min": min(rates),
                                                         "max": max(rates), "chunks": len(rates)},
            "target": {"steps_per_run": target_steps, "seeds": len(seeds), "recipes": len(recipes),
                       "env_steps": total},
            "hours_one_core_at_ppo_rate": None if not per_core else round(total / per_core / 3600, 1),
            "hours_one_core_at_env_rate": round(total / fast["cpu"] / 3600, 1),
            "loadavg_before": load, "loadavg_after": list(os.getloadavg()), "cores": os.cpu_count()}


def _floor_lines(f: dict[str, Any]) -> list[str]:
    p, m = f.get("ppo_steps_per_s") or {}, f.get("ppo_measured") or {}
    return ["## Throughput floor", "",
            f"- fast SLAM env alone: **{f['fast_env_steps_per_cpu_s']:.1f}** env steps per CPU second "
            f"({f['fast_env_steps_per_s']:.1f} per wall second); exact env {f['exact_env_steps_per_cpu_s']:.1f} "
            f"({f['exact_env_steps_per_s']:.1f}); one env, this process, load average {f['loadavg_before'][0]:.1f} on "
            f"{f['cores']} cores while measured (CPU seconds: what one free core gives);",
            f"- PPO on the fast env (the recipe's native vector env, collection and updates): "
            f"**{_fmt(m.get('cpu'))}** env steps per CPU second ({_fmt(m.get('wall'))} per wall second, "
            f"{m.get('env_steps', 0)} env steps timed); the campaign's chunks ran at a median "
            f"{_fmt(p.get('median'))} per wall second ({p.get('chunks', 0)} chunks, min {_fmt(p.get('min'))}, "
            f"max {_fmt(p.get('max'))}) on the shared machine;",
            f"- {f['target']['steps_per_run']:,} env steps x {f['target']['seeds']} seeds x "
            f"{f['target']['recipes']} recipe(s) = {f['target']['env_steps']:,} env steps: "
            f"**{_fmt(f['hours_one_core_at_ppo_rate'])} h** of one free core at the PPO rate "
            f"({_fmt(f['hours_one_core_at_env_rate'])} h at the env's own rate, no learning).", ""]


def _fmt(x: Any, nd: int = 1) -> str:
    return "-" if x is None else f"{x:.{nd}f}"


def _curve_lines(cur: dict[str, Any]) -> list[str]:
    lines = ["| run | env steps | train wall (s) | PPO env steps/s | validation return (last) | best checkpoint "
             "(env steps, validation return) |", "|---|---:|---:|---:|---:|---|"]
    for s, r in cur["runs"].items():
        b = r["best"]
        lines.append(f"| seed {s} | {r['env_steps'][-1]} | {r['train_wall_s'][-1]:.0f} | "
                     f"{np.median(r['steps_per_s']):.1f} | {r['validation_return'][-1]:.1f} | "
                     f"{b['env_steps']}, {b['validation_return']:.1f} |")
    g = cur.get("by_env_steps")
    if g:
        lines += ["", "Validation return over the seeds (mean [min, max]) against env steps:", "",
                  "| env steps | " + " | ".join(f"{x:.0f}" for x in g["env_steps"][::max(1, len(g['env_steps']) // 6)])
                  + " |", "|---|" + "---:|" * len(g["env_steps"][::max(1, len(g['env_steps']) // 6)]),
                  "| return | " + " | ".join(f"{m:.1f} [{lo:.1f}, {hi:.1f}]" for m, lo, hi in
                                           list(zip(g["mean"], g["min"], g["max"]))[::max(1, len(g['env_steps']) // 6)])
                  + " |"]
    w = cur.get("by_wall_s")
    if w:
        step = max(1, len(w["train_wall_s"]) // 6)
        lines += ["", "Against the training wall-clock (hours of one core; mean [min, max] over the seeds):", "",
                  "| train wall (h) | " + " | ".join(f"{x / 3600:.2f}" for x in w["train_wall_s"][::step]) + " |",
                  "|---|" + "---:|" * len(w["train_wall_s"][::step]),
                  "| return | " + " | ".join(f"{m:.1f} [{lo:.1f}, {hi:.1f}]" for m, lo, hi in
                                           list(zip(w["mean"], w["min"], w["max"]))[::step]) + " |"]
    lines += _window_lines(cur)
    chosen = {s: r["selection"] for s, r in cur["runs"].items() if r.get("selection")}
    if chosen:
        lines += ["", "The checkpoint each run is tested with (`scripts/campaign.py select`: the chunks' best and the "
                  "latest, driven on more validation seeds; the higher mean return wins):", "",
                  "| run | validation seeds | candidate (env steps): return, collisions | chosen |", "|---|---|---|---|"]
        for s, sel in chosen.items():
            cands = "; ".join(f"{k} ({c['env_steps']}): {c['return']:.1f}, {c['collisions']}/{c['episodes']}"
                              for k, c in sel["candidates"].items())
            lines.append(f"| seed {s} | {sel['seeds'][0]}-{sel['seeds'][1]} | {cands} | {sel['chosen']} |")
    return lines


#: the campaign's targets, shield off on the exact env: (label, recipe, return / IDM + MOBIL's, max collisions per
#: 100, min mean speed m/s or None)
TARGETS = (("PPO from scratch", "ppo_scratch", 1.05, 2, None), ("imitation + RL", "ppo_student", 1.10, 1, 24.0))


def _target_lines(table: dict[str, Any], reference: str = "idm") -> list[str]:
    """Each tested run, shield off on the exact env, against its recipe's target (:data:`TARGETS`)."""
    ref = table.get(reference, {}).get("exact", {}).get("off")
    if ref is None:
        return []
    lines = []
    for label, recipe, ratio, crashes, speed in TARGETS:
        arms = sorted(a for a in table if a.startswith(f"campaign:{recipe}:") and "off" in table[a].get("exact", {}))
        for arm in arms:
            r = table[arm]["exact"]["off"]
            per100 = 100 * r["collisions"] / r["episodes"]
            met = (r["return"] >= ratio * ref["return"] and per100 <= crashes
                   and (speed is None or (r["mean_speed"] or 0.0) >= speed))
            target = f">= {ratio:.2f} x, <= {crashes}/100" + (f", >= {speed:.0f} m/s" if speed is not None else "")
            lines.append(f"| {label} | {arm.split(':')[-1]} | {r['return']:.1f} ({r['return'] / ref['return']:.3f} x) | "
                         f"{r['collisions']}/{r['episodes']} | {_fmt(r['mean_speed'])} | {target} | "
                         f"{'met' if met else 'not met'} |")
    if not lines:
        return []
    return [f"Targets, shield off on the exact env (IDM + MOBIL: {ref['return']:.1f}, {ref['collisions']}/"
            f"{ref['episodes']}):", "", "| recipe | run | return (/ IDM + MOBIL) | collisions | mean speed (m/s) | "
            "target | |", "|---|---|---:|---:|---:|---|---|", *lines, ""]


def _shield_lines(table: dict[str, Any]) -> list[str]:
    lines = ["| arm | env | shield | return | collisions | mean speed (m/s) | overrides / step | episodes with an "
             "override | shield: return gain [95 %] | prevented | caused |",
             "|---|---|---|---:|---:|---:|---:|---:|---|---:|---:|"]
    for arm, row in table.items():
        for env in ("exact", "fast"):
            if env not in row:
                continue
            eff = row[env].get("shield_effect")
            for sh in ("off", "on"):
                if sh not in row[env]:
                    continue
                a = row[env][sh]
                gain = (f"{eff['return_gain']:+.1f} [{eff['interval'][0]:+.1f}, {eff['interval'][1]:+.1f}]"
                        if eff and sh == "on" else "")
                lines.append(f"| {arm} | {env} | {sh} | {a['return']:.1f} | {a['collisions']}/{a['episodes']} | "
                             f"{_fmt(a['mean_speed'])} | {_fmt(a.get('override_rate_step'), 3)} | "
                             f"{_fmt(a.get('override_rate_episode'), 2)} | {gain} | "
                             f"{eff['collisions_prevented'] if eff and sh == 'on' else ''} | "
                             f"{eff['collisions_caused'] if eff and sh == 'on' else ''} |")
    return lines


def _gap_lines(table: dict[str, Any]) -> list[str]:
    lines = ["| arm | shield | return exact - fast [95 %] | crashed on exact only | on fast only |",
             "|---|---|---|---:|---:|"]
    for arm, row in table.items():
        for sh, g in row.get("sim_to_sim", {}).items():
            lines.append(f"| {arm} | {sh} | {g['return_diff']:+.2f} [{g['interval'][0]:+.2f}, {g['interval'][1]:+.2f}]"
                         f" | {g['only_a_crashed']} | {g['only_b_crashed']} |")
    return lines


def _stats_lines(stats: dict[str, Any]) -> list[str]:
    lines = ["| env, shield | runs | IQM [95 %] | mean [95 %] | optimality gap [95 %] |", "|---|---:|---|---|---|"]
    for key, s in stats.items():
        if s is None:
            continue
        cell = [f"{s[m]['value']:.3f} [{s[m]['low']:.3f}, {s[m]['high']:.3f}]" for m in ("iqm", "mean",
                                                                                        "optimality_gap")]
        lines.append(f"| {key.replace('_', ', shield ')} | {len(s['runs'])} | " + " | ".join(cell) + " |")
    return lines


def _versus_lines(v: dict[str, Any] | None) -> list[str]:
    """Each run against the policy its recipe started from (:func:`rhs_studies.driving.shield_table.versus`)."""
    if not v:
        return []
    lines = [f"Each run against `{v['reference']}`, the policy it started from (same seeds; return difference run - "
             "start, 95 % bootstrap interval over the seeds; pooled: per seed the runs' mean):", "",
             "| env, shield | run | return difference [95 %] | crashed: run only | start only |", "|---|---|---|---:|---:|"]
    for key, row in v.items():
        if key == "reference":
            continue
        for arm, p in row.items():
            crashes = ("", "") if arm == "pooled" else (p["only_a_crashed"], p["only_b_crashed"])
            name = f"pooled over {p['runs']} runs" if arm == "pooled" else arm.split(":")[-1]
            lines.append(f"| {key.replace('_', ', shield ')} | {name} | {p['return_diff']:+.2f} "
                         f"[{p['interval'][0]:+.2f}, {p['interval'][1]:+.2f}] | {crashes[0]} | {crashes[1]} |")
    return [*lines, ""]


def break_even_hazard(gain: float, reward: float, gamma: float, penalty: float = 0.0) -> float:
    """The crash hazard per decision up to which a speed gain pays (:mod:`agents.algos.shaping`):
    ``h* = g (1 - gamma) / (r gamma + P (1 - gamma))``, with ``g`` the per-decision reward gain, ``r`` the
    per-decision reward without it, ``gamma`` the discount per decision and ``P`` the crash penalty.

    >>> round(break_even_hazard(0.75, 4.05, 0.8), 4), round(break_even_hazard(0.75, 4.05, 0.95, 500.0), 5)
    (0.0463, 0.0013)
    """
    return gain * (1.0 - gamma) / (reward * gamma + penalty * (1.0 - gamma))


def _mean_of(key: str, episodes: list[dict[str, Any]]) -> str:
    """The mean of ``key`` over the episodes that have it, formatted; "-" when none does."""
    vals = [e[key] for e in episodes if e[key] is not None]
    return _fmt(float(np.mean(vals))) if vals else "-"


def hazard_lines(episodes: dict[str, Any], recipe_name: str, start: str, env: str = "exact") -> list[str]:
    """Why a recipe's runs crash, shield off: their crash and crash-free episodes apart, the crash hazard per
    decision they drive with (collisions / decisions driven), and the break-even hazard of their speed gain over
    ``start`` (:func:`break_even_hazard` with ``r`` the start's reward per decision and ``g`` the runs' gain per
    decision in crash-free episodes, at the recipe's discount and crash penalty)."""
    from rhs_studies.driving.campaign import RECIPES

    recipe = RECIPES[recipe_name]
    k = recipe.decision_interval
    gamma = float(recipe.ppo_args()["gamma"])
    shaping = recipe.shaping_config()
    penalty = 0.0 if shaping is None else float(shaping.crash_penalty)
    ref = episodes.get(start, {}).get(env, {}).get("off")
    if not ref:
        return []
    r = float(np.mean([e["return"] for e in ref])) * k / float(np.mean([e["steps"] for e in ref]))
    lines = []
    for arm in sorted(a for a in episodes if a.startswith(f"campaign:{recipe_name}:")):
        eps = episodes[arm].get(env, {}).get("off")
        if not eps:
            continue
        crash = [e for e in eps if e["crashed"]]
        free = [e for e in eps if not e["crashed"]]
        if not free:
            continue
        decisions = sum(e["steps"] for e in eps) / k
        g = float(np.mean([e["return"] for e in free])) * k / float(np.mean([e["steps"] for e in free])) - r
        h_star = break_even_hazard(g, r, gamma, penalty) if g > 0 else 0.0
        lines.append(f"| {arm.split(':')[-1]} | {len(crash)}/{len(eps)} | {_mean_of('return', crash)} | "
                     f"{_fmt(float(np.median([e['steps'] for e in crash]))) if crash else '-'} | "
                     f"{_mean_of('return', free)} | {_mean_of('mean_speed', free)} | {100 * len(crash) / decisions:.2f} % | "
                     f"{g:+.2f} | {100 * h_star:.2f} % |")
    if not lines:
        return []
    return [f"Why the runs crash ({env} env, shield off; against `{start}`, {r:.2f} reward per decision; "
            f"gamma {gamma:g} per decision of {k} env steps, crash penalty {penalty:g}): a run whose crash hazard "
            "lies below the break-even hazard of its speed gain is paid for crashing by its training reward.", "",
            "| run | crashed | return, crash episodes | crash env step (median) | return, crash-free | mean speed, "
            "crash-free (m/s) | crash hazard / decision | speed gain / decision | break-even hazard |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|", *lines, ""]


def _window_lines(cur: dict[str, Any], width: int = 250_000) -> list[str]:
    """Per run, the validation collisions and mean return of the chunks in each window of ``width`` env steps (a
    chunk's 5 validation episodes cannot see a crash rate of a few percent; a window pools dozens of them)."""
    runs = {s: r for s, r in cur["runs"].items() if r.get("validation_collisions") and r.get("env_steps")}
    if not runs:
        return []
    top = max(r["env_steps"][-1] for r in runs.values())
    edges = list(range(0, top + width, width))
    lines = ["", f"Validation collisions per window of {width:,} env steps (the window's chunks pooled; mean return "
             "beside):", "", "| run | " + " | ".join(f"{a / 1e6:.2f}-{b / 1e6:.2f}M" for a, b in zip(edges, edges[1:]))
             + " |", "|---|" + "---:|" * (len(edges) - 1)]
    for s, r in runs.items():
        steps = np.asarray(r["env_steps"])
        crashes = np.asarray(r["validation_collisions"])
        returns = np.asarray(r["validation_return"])
        n = int(r.get("validation_episodes") or 1)
        cells = []
        for a, b in zip(edges, edges[1:]):
            inside = (steps > a) & (steps <= b)
            k = int(inside.sum())
            cells.append(f"{int(crashes[inside].sum())}/{k * n} ({returns[inside].mean():.0f})" if k else "")
        lines.append(f"| seed {s} | " + " | ".join(cells) + " |")
    return lines


def _recipe_lines(recipe: dict[str, Any] | None) -> list[str]:
    """The recipe's start, hyperparameters and training-reward shaping, one line."""
    if not recipe:
        return []
    start = recipe.get("init_policy") or "scratch"
    shaping = recipe.get("reward_shaping")
    return [f"Start `{start}`; PPO {json.dumps(recipe.get('hyperparams', {}))}; training reward "
            + (f"shaped {json.dumps(shaping)} (`agents.algos.shaping`; validation keeps highway-env's reward)"
               if shaping else "highway-env's") + ".", ""]


def _shield_section(title: str, shield: dict[str, Any]) -> list[str]:
    return [f"## {title} (seeds {shield['seeds'][0]}-{shield['seeds'][-1]}, fresh; env settings "
            f"`{json.dumps(shield.get('env_kwargs', {}))}`)", "",
            *_target_lines(shield["table"]), *_shield_lines(shield["table"]), "",
            "Sim-to-sim gap (same seed, same arm):", "",
            *_gap_lines(shield["table"]), "",
            "Over the training seeds (score: return / IDM + MOBIL's on the same seed and env; stratified "
            "bootstrap):", "", *_stats_lines(shield.get("training_seeds", {})), "",
            *_versus_lines(shield.get("versus")), *_hazards(shield)]


def _hazards(shield: dict[str, Any]) -> list[str]:
    """:func:`hazard_lines` of each recipe whose runs the table holds, against the arm they are paired with."""
    start = (shield.get("versus") or {}).get("reference")
    if start is None:
        return []
    recipes = sorted({a.split(":")[1] for a in shield.get("episodes", {}) if a.startswith("campaign:")})
    return [line for r in recipes for line in hazard_lines(shield["episodes"], r, start)]


def markdown(curves: dict[str, Any] | None, shield: dict[str, Any] | None, floor_result: dict[str, Any] | None,
             student: dict[str, Any] | None = None, student_shield: dict[str, Any] | None = None,
             others: dict[str, dict[str, Any]] | None = None) -> str:
    """The campaign page (any part may be missing): ``curves`` PPO from scratch's, ``student`` the imitation + RL
    recipe's (``ppo_student``: PPO from the DAgger student's weights); ``shield`` and ``student_shield`` their shield
    tables (the student's drives its own env settings); ``others`` the curves of further recipes, by name."""
    out = ["# Training campaign: pilot", "",
           "Generated by `python scripts/campaign_report.py page` from `results/campaign_ppo_scratch.json`, "
           "`results/shield_table.json` (until the campaign's runs join it: `results/shield_table_scripted.json`, the "
           "scripted and trivial arms), `results/campaign_ppo_student.json`, `results/shield_table_student.json` and "
           "`results/campaign_floor.json`, with `results/campaign_<recipe>.json` of the further recipes (each records its "
           "commit and command).", ""]
    if floor_result:
        out += _floor_lines(floor_result)
    if curves:
        out += ["## Learning curves (PPO from scratch, fast env, validation seeds 20000..)", "", *_curve_lines(curves),
                ""]
    if student:
        out += ["## Learning curves (PPO from the DAgger student: imitation + RL, fast env, validation seeds 20000..)",
                "", *_curve_lines(student), ""]
    from rhs_studies.driving.campaign import RECIPES

    for name, other in (others or {}).items():
        out += [f"## Learning curves (`{name}`, fast env, validation seeds 20000..)", "",
                *_recipe_lines(RECIPES[name].record() if name in RECIPES else None), *_curve_lines(other), ""]
    if shield:
        out += _shield_section("The shield, measured", shield)
    if student_shield:
        out += _shield_section("Imitation + RL, the shield measured", student_shield)
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    """``floor``: measure and write ``results/campaign_floor.json``; ``page``: write ``results/campaign_pilot.md``."""
    import argparse

    from rhs_studies.driving.campaign import CAMPAIGN_DIR
    from rhs_studies.kit.provenance import write_json

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("command", choices=("floor", "page"))
    ap.add_argument("--root", type=Path, default=CAMPAIGN_DIR)
    ap.add_argument("--recipes", nargs="+", default=["ppo_scratch"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--steps", type=int, default=400, help="floor: env steps timed per env")
    ap.add_argument("--ppo-steps", type=int, default=1280, help="floor: env steps of the timed PPO learn")
    ap.add_argument("--results", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    if args.command == "floor":
        started = time.time()
        result = floor(args.root, args.recipes, args.seeds, args.steps, ppo_steps=args.ppo_steps)
        write_json(args.results / "campaign_floor.json", result, "scripts/campaign_report.py", vars(args), started,
                   argv=argv)
        print(json.dumps(result))
        return 0

    def read(name: str) -> dict[str, Any] | None:
        path = args.results / name
        return json.loads(path.read_text()) if path.exists() else None
    shield = read("shield_table.json") or read("shield_table_scripted.json")  # the scripted arms until the runs join
    from rhs_studies.driving.campaign import RECIPES

    others = {name: c for name in RECIPES if name not in (args.recipes[0], "ppo_student")
              if (c := read(f"campaign_{name}.json")) is not None}
    page = markdown(read(f"campaign_{args.recipes[0]}.json"), shield, read("campaign_floor.json"),
                    read("campaign_ppo_student.json"), read("shield_table_student.json"), others)
    (args.results / "campaign_pilot.md").write_text(page + "\n")
    print(page)
    return 0
