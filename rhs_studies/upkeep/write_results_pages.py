"""Copy measured results from ``results/`` into README.md and the documentation pages.

Each block between ``<!-- results:NAME -->`` and ``<!-- /results:NAME -->`` in README.md
or in a page under ``docs/`` is replaced by ``results/NAME.md`` (written by the script that
measured it), so every number shown comes from a script a user can run. A heading on the
file's first line is dropped: the page around the block has its own. Blocks whose file
does not exist are left as they are.

Some blocks are built here instead of copied: ``headline`` (the README's short table of
headline results, each row linking to its results page), ``unverified`` (the list of results
not verified against the code), ``tolerances`` (each fingerprint's measured tolerance) and
``reproduce.STEP`` (a page's "how to reproduce" line: the :mod:`rhs_studies.upkeep.reproduce` step
``STEP``'s command and the script it runs, so a page cannot name a command that is gone).

When ``results/NAME.json`` is not verified against the code (written before provenance
existed, or the code's fingerprint changed since the run, see ``rhs_studies/kit/provenance.py``),
the block ends with a visible warning saying why and which step to rerun.

    python scripts/write_results_pages.py            # rewrite README.md and docs/**/*.md in place
    python scripts/write_results_pages.py --check    # exit 1 if any of them is out of date
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from collections.abc import Callable
from pathlib import Path

from rhs_studies.kit.provenance import load_fingerprints, verification

ROOT = Path(__file__).resolve().parents[2]

DOCS = ROOT / "docs"
BLOCK = re.compile(r"(<!-- results:(?P<name>[\w.-]+) -->\n)(?P<body>.*?)(<!-- /results:(?P=name) -->)", re.DOTALL)


def pages(root: Path = ROOT) -> list[Path]:
    """The files whose result blocks this script fills: README.md and every page under docs/."""
    return [root / "README.md", *sorted((root / "docs").rglob("*.md"))]


def warning(name: str, results_dir: Path, fingerprints: dict) -> str:
    """A warning line when ``results/NAME.json`` is unverified, else ``""``."""
    from rhs_studies.upkeep.reproduce import step_for_result

    f = results_dir / f"{name}.json"
    if not f.exists():
        return ""
    ok, why = verification(f, fingerprints)
    if ok:
        return ""
    step = step_for_result(name)
    rerun = f"python scripts/reproduce.py --only {step.name}" if step else "its script"
    return f"\n> **Unverified:** {why}. These numbers may not match the code; rerun `{rerun}`.\n"


HEADING = re.compile(r"\A#{1,6} [^\n]*\n+")


def block_text(md: str) -> str:
    """A results ``.md`` as a page block: without its leading heading (the page's section has one)."""
    return HEADING.sub("", md.strip(), count=1).rstrip()


# --------------------------------------------------------------------------- the headline table
#: the docs page of each study, relative to the repository root (the README links to them)
PAGE = {
    "fig5a": "docs/results/fig5a.md",
    "slam_accuracy": "docs/results/slam-accuracy.md",
    "registration": "docs/results/registration.md",
    "policies": "docs/results/driving/policies.md",
    "rl_finetune": "docs/results/driving/rl-finetune.md",
    "rl_confirm": "docs/results/driving/rl-confirm.md",
    "rl_lane_test": "docs/results/driving/rl-lane-rule-trial.md",
    "benchmark": "docs/results/speed.md",
    "detection_curves": "docs/results/detection.md",
    "shield_table": "docs/results/campaign.md",
    "shield_table_student": "docs/results/campaign.md",
    "pose_covariance": "docs/results/pose-covariance.md",
}


def _load(results_dir: Path, name: str) -> dict:
    return json.loads((results_dir / f"{name}.json").read_text())


def _fig5a(d: dict) -> tuple[str, str]:
    r = next(x for x in d["ratios"] if x["antenna"] == "rhs" and x["tx_power_dbm"] == max(d["settings"]["powers_dbm"]))
    return (f"SLAM vehicle RMSE, RHS / same-cost phased array (paper scene, {r['tx_power_dbm']:g} dBm)",
            f"{r['vehicle_rmse_ratio']:.2f} (paper: {d['paper_ratio']:.2f})")


def _dense(d: dict) -> tuple[str, str]:
    s = d["parts"]["dense"]["summary"]
    return ("SLAM trajectory error, RHS / phased array, landmark pairs a few degrees apart",
            f"{s['ratio_rhs_phased']['mean']:.3f} ± {s['ratio_rhs_phased']['ci95']:.3f} "
            f"({s['rhs_ate_m']['mean']:.3f} m vs {s['phased_ate_m']['mean']:.2f} m)")


def _highway(d: dict) -> tuple[str, str]:
    s = d["parts"]["highway"]["summary"]
    n = d["parts"]["highway"]["summary"]["position_rmse_m"]["n"]
    return (f"SLAM position RMSE on the highway env ({s['cycles']['mean']:.0f} cycles, {n} seeds)",
            f"{s['position_rmse_m']['mean']:.3f} ± {s['position_rmse_m']['ci95']:.3f} m")


def _pose_covariance(d: dict) -> tuple[str, str] | None:
    """The calibrated pose covariance's NEES on the default env, and how many configurations meet the goal."""
    configs = d["configs"]
    s = configs.get("default", {}).get("summary", {}).get("calibrated")
    if not s or not s.get("cycles"):
        return None
    runs = len(configs["default"]["runs"])
    met = [n for n, c in configs.items() if c["summary"].get("calibrated", {}).get("goal_met")]
    missed = [n for n in configs if n not in met]
    return (f"SLAM pose covariance, `pipeline={{\"pose_covariance\": \"calibrated\"}}`, default env ({runs} held-out "
            f"IDM + MOBIL drives of {d['cycles']} cycles): NEES below / inside / above its 95 % band (goal: inside >= "
            "90 %, each tail <= 7 %); the configurations that meet it",
            f"{100 * s['below']:.1f} % / {100 * s['inside']:.1f} % / {100 * s['above']:.1f} %; {len(met)} of "
            f"{len(configs)}" + (f" (not: {', '.join(missed)})" if missed else ""))


def _slam_drivers(d: dict) -> tuple[str, str]:
    part = d["parts"]["drivers"]
    combos = part["combos"].values()
    random = [r for c in combos if c["driver"] == "random" for r in c["runs"]]
    worst = max(c["summary"]["worst_rmse_m"] for c in combos if c["driver"] != "random")
    lost = sum(r["lost_episode"] for r in random)
    above = sum(r["cycles_above_lost"] for c in combos for r in c["runs"])
    flagged = sum(r["cycles_above_lost_flagged"] for c in combos for r in c["runs"])
    good = sum(r["cycles_below_good"] for c in combos for r in c["runs"])
    alarms = sum(r["cycles_below_good_flagged"] for c in combos for r in c["runs"])
    hit = f"{flagged}/{above}" if above else "none"
    return (f"SLAM driven by IDM + MOBIL, a DAgger student, random actions ({len(part['seeds'])} held-out seeds each, "
            "highway and dense env): worst episode RMSE (IDM, policy); random episodes lost (error > "
            f"{part['lost_m']:g} m); lost cycles flagged; false alarms",
            f"{worst:.3f} m; {lost}/{len(random)}; {hit}; {alarms}/{good}")  # 3 decimals: the goal is 1 m


def _registration(d: dict) -> tuple[str, str]:
    return ("Scan registration on held-out pairs, translation RMSE: ICP / the paper's CNN",
            f"{d['icp']['translation_rmse_m']:.3f} m / {d['cnn']['translation_rmse_m']:.3f} m")


def _detection(d: dict) -> tuple[str, str]:
    import numpy as np

    from rhs_studies.kit.tables import snr_at

    def snr(detector: str) -> str:
        v = snr_at(d["measured"]["rhs"][detector], np.asarray(d["snr_db"], float), 0.9)
        return "n/a" if v is None else f"{v:.1f} dB"

    return ("SNR for 90 % detection (RHS): beam-matched vs the paper's slot-summed detector",
            f"{snr('footprint')} vs {snr('summed')}")


def _policies(d: dict) -> tuple[str, str]:
    rows = {r["key"]: r["summary"] for r in d["rows"]}
    key = "shipped" if "shipped" in rows else "slam"
    shielded = next(r for r in d["rows"] if r["key"] == key).get("shield") is not None
    s, slower, idm = rows[key], rows["slower"], rows["idm"]
    shield = "behind its radar shield" if shielded else "shield off"
    return (f"Driving on radar + SLAM (shipped policy, {shield}, {s['episodes']} seeds): return, collisions",
            f"{s['return']['mean']:.1f}, {s['collisions']}/{s['episodes']} "
            f"(always-SLOWER: {slower['return']['mean']:.1f}, {slower['collisions']}/{slower['episodes']}; "
            f"IDM + MOBIL: {idm['return']['mean']:.1f}, {idm['collisions']}/{idm['episodes']})")


def _rl_confirm(d: dict) -> tuple[str, str]:
    from rhs_studies.kit.driving import ARMS
    from rhs_studies.kit.tables import paired_text

    v, t = d["validation"], d["test"]
    arm, tg = v["chosen"], t["targets"]
    s, gain, control = t["rows"][arm], tg["gain_over_student"], tg["gain_over_control"]
    return (f"PPO fine-tune of the DAgger student behind the radar shield ({ARMS[arm].timesteps} env "
            f"steps; chosen on {len(v['seeds'])} validation seeds, tested once on {len(t['seeds'])} fresh seeds, "
            "behind the shield it trained with): return, collisions, paired gain over its start and over DAgger at "
            "the same budget",
            f"{s['return']['mean']:.1f}, {s['collisions']}/{s['episodes']}, {paired_text(gain)}; vs the DAgger "
            f"control: {paired_text(control)} (start: {t['rows']['shipped']['return']['mean']:.1f}; "
            f"IDM + MOBIL: {t['rows']['idm']['return']['mean']:.1f})")


def _rl_lane_test(d: dict) -> tuple[str, str]:
    from rhs_studies.kit.tables import paired_text

    v, t = d["validation"], d["test"]
    tg = t["targets"]
    s, gain, control = t["rows"][d["finetune"]], tg["gain_over_student"], tg["gain_over_control"]
    rule = ", ".join(f"{k} {x:g}" for k, x in v["rule"].items())
    return (f"The same fine-tune behind a stricter lane rule of the shield ({rule}, chosen on {len(v['seeds'])} "
            f"validation seeds, tested once on {len(t['seeds'])} fresh seeds; the shipped policy): return, "
            "collisions, speed, paired gain over its start and over the DAgger control",
            f"{s['return']['mean']:.1f}, {s['collisions']}/{s['episodes']}, {s['mean_speed_mps']['mean']:.1f} m/s, "
            f"{paired_text(gain)}; vs the DAgger control: {paired_text(control)} (start: "
            f"{t['rows']['shipped']['return']['mean']:.1f}, {t['rows']['shipped']['collisions']}/"
            f"{t['rows']['shipped']['episodes']}; IDM + MOBIL: {t['rows']['idm']['return']['mean']:.1f})")


def _benchmark(d: dict) -> tuple[str, str]:
    e, st = d["envs"], d.get("start")
    label = "Env steps per second, radar + SLAM env (ground-truth env), single env, one BLAS thread"
    value = f"{e['rhs-highway-slam-v0']['steps_per_s']:.1f} ({e['rhs-highway-v0']['steps_per_s']:.1f})"
    if st:
        label += "; its first step in a new process, empty / warm kernel cache"
        value += f"; {st['cold_s']:.1f} s / {st['warm_s']:.1f} s"
    return label, value


def _campaign_test(d: dict) -> tuple[str, str] | None:
    """The campaign's PPO-from-scratch runs on the test seeds, shield off on the exact env (None before they join
    the shield table)."""
    arms = sorted(a for a in d["table"] if a.startswith("campaign:ppo_scratch:"))
    idm = d["table"].get("idm", {}).get("exact", {}).get("off")
    if not arms or idm is None:
        return None
    rows = [d["table"][a]["exact"] for a in arms]
    steps = [d.get("policies", {}).get(a, {}).get("timesteps") for a in arms]
    budget = f"{min(steps) / 1e6:.2f}-{max(steps) / 1e6:.2f}M" if all(steps) else "?"
    stats = (d.get("training_seeds") or {}).get("exact_off")
    iqm = (f"; IQM {stats['iqm']['value']:.3f} x [{stats['iqm']['low']:.3f}, {stats['iqm']['high']:.3f}] (it trims the "
           f"crashed episodes), mean {stats['mean']['value']:.3f} x [{stats['mean']['low']:.3f}, {stats['mean']['high']:.3f}]"
           if stats else "")
    shielded = [r["on"] for r in rows if "on" in r]
    on = (" / ".join(f"{r['return'] / idm['return']:.3f} x" for r in shielded) + ", "
          + " / ".join(f"{r['collisions']}/{r['episodes']}" for r in shielded))
    met = all(r["off"]["return"] >= 1.05 * idm["return"] and r["off"]["collisions"] <= 0.02 * r["off"]["episodes"]
              for r in rows)
    return (f"PPO from scratch on the fast SLAM env ({len(arms)} training seeds; checkpoints at {budget} env steps, "
            f"chosen on validation seeds, tested once on {idm['episodes']} fresh seeds on the exact env, shield off): "
            "return / IDM + MOBIL's per seed, collisions (target >= 1.05 x, <= 2 / 100)",
            " / ".join(f"{r['off']['return'] / idm['return']:.3f} x" for r in rows) + ", "
            + " / ".join(f"{r['off']['collisions']}/{r['off']['episodes']}" for r in rows)
            + f"{iqm}: target {'met' if met else 'not met'} (IDM + MOBIL: {idm['return']:.1f}, "
            f"{idm['collisions']}/{idm['episodes']}; behind the shield: {on})")


def _campaign_student(d: dict) -> tuple[str, str] | None:
    """The campaign's imitation + RL runs (PPO from the DAgger student's weights) on the test seeds, shield off on the
    exact env, against their target and paired against their start (None before they join the table)."""
    def paired_text(p: dict) -> str:
        return f"{p['return_diff']:+.1f} [{p['interval'][0]:+.1f}, {p['interval'][1]:+.1f}]"

    arms = sorted(a for a in d["table"] if a.startswith("campaign:ppo_student:"))
    idm = d["table"].get("idm", {}).get("exact", {}).get("off")
    start_arm = (d.get("versus") or {}).get("reference")
    start = d["table"].get(start_arm, {}).get("exact", {}) if start_arm else {}
    if not arms or idm is None or "off" not in start:
        return None
    rows = [d["table"][a]["exact"] for a in arms]
    steps = [d.get("policies", {}).get(a, {}).get("timesteps") for a in arms]
    budget = f"{min(steps) / 1e6:.2f}-{max(steps) / 1e6:.2f}M" if all(steps) else "?"
    met = all(r["off"]["return"] >= 1.10 * idm["return"] and r["off"]["collisions"] <= 0.01 * r["off"]["episodes"]
              and (r["off"]["mean_speed"] or 0.0) >= 24.0 for r in rows)
    pooled = {sh: d["versus"].get(f"exact_{sh}", {}).get("pooled") for sh in ("off", "on")}
    on = " / ".join(f"{r['on']['collisions']}/{r['on']['episodes']}" for r in rows if "on" in r)
    so = start["off"]
    shipped = d["table"].get("agents/data/shipped.zip", {}).get("exact", {})
    unsafe = "off" in shipped and shipped["off"]["collisions"] > 0.01 * shipped["off"]["episodes"]
    needs = (f"; the shipped policy{', which needs its shield' if unsafe else ''}: shield off "
             f"{shipped['off']['return'] / idm['return']:.3f} x, "
             f"{shipped['off']['collisions']}/{shipped['off']['episodes']}, behind it "
             f"{shipped['on']['return'] / idm['return']:.3f} x, {shipped['on']['collisions']}/{shipped['on']['episodes']}"
             if "off" in shipped and "on" in shipped else "")
    return (f"Imitation + RL on the fast SLAM env (PPO from the DAgger student's weights; {len(arms)} training seeds; "
            f"checkpoints at {budget} env steps, chosen on validation seeds, tested once on {idm['episodes']} fresh "
            "seeds on the exact env, shield off): return / IDM + MOBIL's per seed, collisions, mean speed (target "
            ">= 1.10 x, <= 1 / 100, >= 24 m/s); paired gain over its start, pooled over the runs",
            " / ".join(f"{r['off']['return'] / idm['return']:.3f} x" for r in rows) + ", "
            + " / ".join(f"{r['off']['collisions']}/{r['off']['episodes']}" for r in rows) + ", "
            + " / ".join(f"{r['off']['mean_speed']:.1f}" for r in rows) + f" m/s: target {'met' if met else 'not met'}"
            + (f"; over its start, pooled: {paired_text(pooled['off'])}" if pooled["off"] else "")
            + f" (start: {so['return'] / idm['return']:.3f} x, {so['collisions']}/{so['episodes']}, "
            f"{so['mean_speed']:.1f} m/s; behind the shield: "
            + (f"{paired_text(pooled['on'])}, " if pooled["on"] else "") + f"{on}){needs}")


#: (results file, row builder): the rows of the README's headline table, in order
HEADLINE: tuple[tuple[str, Callable[[dict], tuple[str, str] | None]], ...] = (
    ("fig5a", _fig5a),
    ("slam_accuracy", _dense),
    ("slam_accuracy", _highway),
    ("slam_accuracy", _slam_drivers),
    ("pose_covariance", _pose_covariance),
    ("registration", _registration),
    ("detection_curves", _detection),
    ("policies", _policies),
    ("rl_confirm", _rl_confirm),
    ("rl_lane_test", _rl_lane_test),
    ("shield_table", _campaign_test),
    ("shield_table_student", _campaign_student),
    ("benchmark", _benchmark),
)
#: rows of results a study has not written yet (skipped until it has; a builder returning None skips its row too)
OPTIONAL_HEADLINE: frozenset[str] = frozenset({"shield_table", "shield_table_student"})


def headline(results_dir: Path, fingerprints: dict) -> str | None:
    """The README's headline table from the results JSONs (None when one is missing)."""
    lines = ["| result | measured | details |", "|---|---|---|"]
    unverified = []
    for name, row in HEADLINE:
        if not (results_dir / f"{name}.json").exists():
            if name in OPTIONAL_HEADLINE:
                continue
            return None
        built = row(_load(results_dir, name))
        if built is None:
            continue
        what, value = built
        lines.append(f"| {what} | {value} | [{Path(PAGE[name]).stem}]({PAGE[name]}) |")
        ok, why = verification(results_dir / f"{name}.json", fingerprints)
        if not ok and name not in unverified:
            unverified.append(name)
    text = "\n".join(lines)
    for name in unverified:
        text += warning(name, results_dir, fingerprints)
    return text


def unverified_list(results_dir: Path, fingerprints: dict) -> str:
    """Every results JSON that is not verified against the code, with the reason."""
    rows = []
    for f in sorted(results_dir.glob("*.json")):
        if f.name == "fingerprints.json" or f.name.endswith(".partial.json"):
            continue
        ok, why = verification(f, fingerprints)
        if not ok:
            rows.append(f"- `results/{f.name}`: {why}.")
    return "\n".join(rows) if rows else "Every result is verified against the code."


def tolerance_table(results_dir: Path, fingerprints: dict) -> str | None:
    """Each fingerprint's measured spread and tolerance (``scripts/fingerprint_tolerance.py``), one row a step."""
    rows = ["| fingerprint | values | largest round-off spread | rtol | atol | values allowed to flip |",
            "|---|---:|---:|---:|---:|---:|"]
    for name, fp in sorted(fingerprints.items()):
        tol = fp.get("tolerance")
        if not tol:
            rows.append(f"| `{name}` | {len(fp['values'])} | not measured | | | |")
            continue
        spread = max(v["max_rel"] for v in tol["spread"].values())
        rows.append(f"| `{name}` | {len(fp['values'])} | {spread:.1e} | {tol['rtol']:.1e} | {tol['atol']:.1e} "
                    f"| {len(tol['may_flip'])} |")
    return "\n".join(rows) if fingerprints else None


GENERATED: dict[str, Callable[[Path, dict], str | None]] = {"headline": headline, "unverified": unverified_list,
                                                             "tolerances": tolerance_table}

#: a block ``reproduce.STEP`` is the "how to reproduce" line of step ``STEP`` (:func:`reproduce_line`)
REPRODUCE = "reproduce."


def reproduce_line(step_name: str) -> str:
    """The "how to reproduce" line of the :mod:`rhs_studies.upkeep.reproduce` step ``step_name``.

    Args:
        step_name: a step of ``rhs_studies.upkeep.reproduce.STEPS``.

    Returns:
        One markdown line: ``python scripts/reproduce.py --only STEP``, the script command it runs and the results
        files it writes.

    Raises:
        ValueError: no step of that name (the page names a command that does not exist).
    """
    from rhs_studies.upkeep.reproduce import STEPS

    step = next((s for s in STEPS if s.name == step_name), None)
    if step is None:
        raise ValueError(f"results block reproduce.{step_name}: no step {step_name!r} in rhs_studies/upkeep/reproduce.py "
                         f"(steps: {', '.join(s.name for s in STEPS)})")
    command = " ".join(["python", f"scripts/{step.script}", *step.args])
    writes = ", ".join(f"`results/{r}`" for r in step.results)
    return (f"**How to reproduce:** `python scripts/reproduce.py --only {step.name}` (it runs `{command}`"
            + (f", which writes {writes}" if writes else "") + ", then rewrites the tables on this page).")


def figure_links(md: str, page: Path | None) -> str:
    """``md`` with its links to ``results/NAME.png`` made relative to ``page``.

    A results ``.md`` links its figures from the repository root (``results/NAME.png``), as
    README.md does. On the documentation site those figures are served as
    ``results/NAME.png`` beside the results pages (``docs/hooks/site.py``), so a page under
    ``docs/`` links them relative to its own folder.
    """
    if page is None or DOCS not in page.parents:
        return md
    rel = Path(os.path.relpath(DOCS / "results", page.parent)).as_posix()
    return md.replace("](results/", "](" + ("" if rel == "." else rel + "/"))


def render(text: str, results_dir: Path, page: Path | None = None) -> str:
    """``text`` (the contents of ``page``) with every results block filled from ``results_dir``."""
    fingerprints = load_fingerprints(results_dir / "fingerprints.json")

    def sub(m: re.Match) -> str:
        name = m.group("name")
        if name.startswith(REPRODUCE):
            return f"{m.group(1)}{reproduce_line(name[len(REPRODUCE):])}\n{m.group(4)}"
        if name in GENERATED:
            body = GENERATED[name](results_dir, fingerprints)
            return m.group(0) if body is None else f"{m.group(1)}{body.rstrip()}\n{m.group(4)}"
        f = results_dir / f"{name}.md"
        if not f.exists():
            return m.group(0)
        warn = warning(name, results_dir, fingerprints)
        return f"{m.group(1)}{figure_links(block_text(f.read_text()), page)}\n{warn}{m.group(4)}"

    return BLOCK.sub(sub, text)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="only check that the pages are up to date")
    args = ap.parse_args()
    stale = []
    for page in pages():
        old = page.read_text()
        new = render(old, ROOT / "results", page)
        if new == old:
            continue
        stale.append(page.relative_to(ROOT))
        if not args.check:
            page.write_text(new)
            print(f"updated {page.relative_to(ROOT)}")
    if args.check and stale:
        print(f"{', '.join(map(str, stale))} out of date with results/: run python scripts/write_results_pages.py", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
