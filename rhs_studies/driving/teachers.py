"""The privileged teachers on validation seeds: the headway driver against faster settings of itself and lookahead
variants, and why a student cannot copy the fastest lookahead.

Every teacher drives ``rhs-highway-v0`` with the students' target speeds ([10, 15, 20, 25, 30] m/s), deciding once a
second in pulse mode (IDLE between), as the radar + SLAM students drive, on the validation seeds (4000..: never used
in training, where the envs draw seeds 0.. and 20000.., nor by the held-out evaluations 1000-1049, 2000-2049,
3000-3099; the lookahead's settings were chosen on 4000-4009). Variants of :class:`agents.policies.lookahead.LookaheadDriver`:

* ``lookahead``: as shipped (6 s forecasts, a 0.6 s time-gap margin, ``tie_margin`` 0.5), the teacher of
  ``agents/hyperparams/dagger_lookahead.yml``;
* ``lookahead_no_margin``: no time-gap margin (it may follow at any gap that does not crash);
* ``lookahead_margin_1s``: a 1 s margin;
* ``lookahead_tie_1``: the headway driver's action unless another forecast returns 1 more.

And variants of the headway driver itself (:class:`agents.policies.expert.HeadwayDriverConfig`): ``headway_cruise30`` chooses
target speeds up to 30 m/s (cruise speed 30 instead of 25) and accelerates with a 1 m/s margin (instead of 2);
``headway_cruise30_h1.2`` also holds a 1.2 s time gap (instead of 1.5); ``headway_cruise30_gap`` a 2.0 s time gap and
1.5 s (instead of 1.0 s) to a faster follower in a lane it changes into (the teacher of
``agents/hyperparams/dagger_cruise30_gap.yml``), and ``headway_cruise30_gap_d5`` the same with a 5 m standstill gap
``d0`` (instead of 8 m). A student that sees the road through radar
points copied the headway driver to within 1 of its return; copying the 30 m/s one, it crashed in 7 of 50 validation
episodes after 40k env steps and again after 80k (``agents/hyperparams/dagger_cruise30.yml`` has the runs): 5 m/s
faster than the traffic, its mistakes crash.

Per variant: mean return with its t interval, collisions with a Wilson interval, mean speed, seconds per decision.
At every decision of the lookahead variants' own drives: the share where the teacher differs from the headway
driver, and the share where its action's forecast beats the next best by less than 1 (return units over the
horizon, about 0.03 per step): near ties, which a student that sees the scene through radar points cannot tell apart.

    python scripts/teachers.py                     # 20 seeds per variant, 2 workers (~8 min)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from rhs_studies.kit.pool import map_seeds
from rhs_studies.kit.provenance import write_json
from rhs_studies.kit.seeds import first
from rhs_studies.kit.tables import paired, row_summary

ROOT = Path(__file__).resolve().parents[2]
ENV_ID = "rhs-highway-v0"
ACTION = {"type": "DiscreteMetaAction", "target_speeds": [10, 15, 20, 25, 30]}
DECISION_STEPS = 5  # env steps per decision (1 Hz at highway-env's 5 Hz)
#: variant -> (driver, config): "headway" a :class:`agents.policies.expert.HeadwayDriver` with these
#: :class:`agents.policies.expert.HeadwayDriverConfig` fields, "lookahead" a :class:`agents.policies.lookahead.LookaheadDriver`
_CRUISE30 = {"cruise_speed_mps": 30.0, "margin_mps": 1.0}
_CRUISE30_GAP = {**_CRUISE30, "headway_s": 2.0, "rear_headway_s": 1.5}
VARIANTS: dict[str, tuple[str, dict[str, float]]] = {
    "headway": ("headway", {}),
    "headway_cruise30": ("headway", _CRUISE30),
    "headway_cruise30_h1.2": ("headway", {**_CRUISE30, "headway_s": 1.2}),
    "headway_cruise30_gap": ("headway", _CRUISE30_GAP),
    "headway_cruise30_gap_d5": ("headway", {**_CRUISE30_GAP, "standstill_gap_m": 5.0}),
    "lookahead": ("lookahead", {}),
    "lookahead_no_margin": ("lookahead", {"min_headway_s": 0.0, "unsafe_penalty": 0.0}),
    "lookahead_margin_1s": ("lookahead", {"min_headway_s": 1.0}),
    "lookahead_tie_1": ("lookahead", {"tie_margin": 1.0}),
}
LABELS = {
    "headway": "HeadwayDriver (the shipped students' expert)",
    "headway_cruise30": "HeadwayDriver up to 30 m/s, 1 m/s margin",
    "headway_cruise30_h1.2": "HeadwayDriver up to 30 m/s, 1 m/s margin, 1.2 s headway",
    "headway_cruise30_gap": "HeadwayDriver up to 30 m/s, 1 m/s margin, 2.0 s headway, 1.5 s to a follower",
    "headway_cruise30_gap_d5": "HeadwayDriver up to 30 m/s, 1 m/s margin, 2.0 s headway, 1.5 s to a follower, 5 m "
                               "standstill gap",
    "lookahead": "LookaheadDriver, 0.6 s margin (as shipped)",
    "lookahead_no_margin": "LookaheadDriver without a time-gap margin",
    "lookahead_margin_1s": "LookaheadDriver, 1 s margin",
    "lookahead_tie_1": "LookaheadDriver, tie margin 1",
}
NEAR_TIE = 1.0  # return units over the forecast horizon


def drive(variant: str, seed: int, duration: float | None = None) -> dict[str, Any]:
    """One episode of ``variant`` on ``seed``: return, crashed, mean speed, decisions, wall per decision and, for a
    lookahead, per decision whether it differs from the headway driver and its forecast gap to the next best."""
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids)
    from agents.policies.decision import IDLE
    from agents.policies.expert import HeadwayDriver
    from agents.policies.lookahead import LookaheadDriver

    kwargs: dict[str, Any] = {"action": ACTION}
    if duration is not None:
        kwargs["duration"] = duration
    env = gym.make(ENV_ID, **kwargs)
    env.reset(seed=seed)
    base: Any = env.unwrapped
    driver, config = VARIANTS[variant]
    ahead = LookaheadDriver(env, config) if driver == "lookahead" else None
    headway = HeadwayDriver(env, config) if ahead is None else ahead.base_driver
    total, speeds, differs, gaps, decide_s = 0.0, [], [], [], 0.0
    crashed, k = False, 0
    while True:
        action = IDLE
        if k % DECISION_STEPS == 0:
            t0 = time.perf_counter()
            if ahead is None:
                action = headway.act()
            else:
                action, default, q = ahead.decide()
                differs.append(action != default)
                others = [v for a, v in q.items() if a != action]
                gaps.append(float(q[action] - max(others)) if others else float("inf"))
            decide_s += time.perf_counter() - t0
        _, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        speeds.append(float(base.vehicle.speed))
        k += 1
        if terminated or truncated:
            crashed = bool(info.get("crashed", False))
            break
    env.close()
    decisions = -(-k // DECISION_STEPS)
    return {"seed": seed, "return": total, "crashed": crashed, "mean_speed": float(np.mean(speeds)), "steps": k,
            "decisions": decisions, "s_per_decision": decide_s / decisions, "differs": differs, "gaps": gaps}


def drive_chunk(seeds: list[int], variant: str, duration: float | None = None) -> list[dict[str, Any]]:
    """Episodes of ``variant`` on ``seeds`` in this process (one chunk of :func:`run_variant`)."""
    return [drive(variant, s, duration) for s in seeds]


def run_variant(variant: str, seeds: list[int], workers: int, duration: float | None = None) -> list[dict[str, Any]]:
    """Episodes of ``variant`` on ``seeds`` (``duration`` s, None: the env's 40 s), split over ``workers`` processes
    (:func:`rhs_studies.kit.pool.map_seeds`)."""
    return map_seeds(drive_chunk, seeds, workers, variant, duration)


def summarize(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """:func:`rhs_studies.kit.tables.row_summary` (return, collisions, speed), the seconds per decision and the
    decision statistics of a lookahead."""
    out = row_summary(runs)
    out["s_per_decision"] = float(np.mean([r["s_per_decision"] for r in runs]))
    differs = [d for r in runs for d in r["differs"]]
    gaps = np.array([g for r in runs for g in r["gaps"]])
    if differs:
        out["decisions"] = len(differs)
        out["differs_from_headway"] = float(np.mean(differs))
        out["near_ties"] = float(np.mean(gaps < NEAR_TIE))
    return out


def markdown(result: dict[str, Any]) -> str:
    seeds = result["seeds"]
    lines = [f"Validation seeds {seeds[0]}-{seeds[-1]} ({len(seeds)} episodes per teacher, {ENV_ID}, target speeds "
             f"{ACTION['target_speeds']} m/s, one decision per second, IDLE between).", "",
             "| teacher | return (95 % CI) | vs headway (paired, 95 % CI) | collisions [Wilson 95 %] | speed m/s | "
             "differs from headway | near ties (< 1) | s per decision |",
             "|---|---|---|---|---|---|---|---|"]
    for key, s in result["rows"].items():
        lo, hi = s["collision_interval"]
        vs = result["vs_headway"].get(key)
        vs_text = "" if vs is None else f"{vs['mean']:+.1f} [{vs['low']:+.1f}, {vs['high']:+.1f}]"
        differ = f"{100 * s['differs_from_headway']:.0f} %" if "differs_from_headway" in s else ""
        ties = f"{100 * s['near_ties']:.0f} %" if "near_ties" in s else ""
        lines.append(f"| {LABELS[key]} | {s['return']['mean']:.1f} +- {s['return']['half']:.1f} | {vs_text} | "
                     f"{s['collisions']}/{s['episodes']} [{100 * lo:.0f}-{100 * hi:.0f} %] | "
                     f"{s['mean_speed_mps']['mean']:.1f} | {differ} | {ties} | {s['s_per_decision']:.3f} |")
    lines += ["", "Near ties: decisions where the teacher's action's forecast returns less than 1 more than the next "
              "best action's over the 6 s horizon (about 0.03 per step)."]
    return "\n".join(lines) + "\n"


def fingerprint() -> list[float]:
    """The headway driver and the shipped lookahead teacher, one 2-second episode (10 steps) each on seed 4000."""
    out: list[float] = []
    for variant in ("headway", "lookahead"):
        run = drive(variant, 4000, duration=2)
        out += [run["return"], float(run["crashed"]), run["mean_speed"], float(sum(run["differs"]))]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--seed", type=int, default=first("shield_validation"), help="first validation seed")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--duration", type=float, default=None, help="episode length, s (default: the env's, 40 s)")
    ap.add_argument("--out-dir", type=Path, default=ROOT / "results")
    args = ap.parse_args(argv)
    if args.episodes < 2:
        ap.error("--episodes must be >= 2 (intervals need two episodes)")
    if "headway" not in args.variants:
        ap.error("--variants must include headway (the reference of the paired differences)")
    started = time.time()
    seeds = list(range(args.seed, args.seed + args.episodes))
    runs = {}
    for variant in args.variants:
        t0 = time.perf_counter()
        runs[variant] = run_variant(variant, seeds, args.workers, args.duration)
        print(f"teachers: {variant}: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    result = {
        "env_id": ENV_ID, "action": ACTION, "seeds": seeds,
        "variants": {k: {"driver": VARIANTS[k][0], "config": VARIANTS[k][1]} for k in args.variants},
        "rows": {k: summarize(v) for k, v in runs.items()},
        "vs_headway": {k: paired(v, runs["headway"]) for k, v in runs.items() if k != "headway"},
        "runs": {k: [{f: r[f] for f in ("seed", "return", "crashed", "mean_speed", "steps")} for r in v]
                 for k, v in runs.items()},
    }
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "teachers.json", result, __file__, args, started, fingerprint, argv)
    (out / "teachers.md").write_text(markdown(result))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
