"""Why a student crashes: its last decisions against the expert's, and whether the radar saw what it hit.

What limits learning to drive on radar SLAM? This script replays
policies (default: the radar + SLAM DAgger student, 80k env steps, the shipped policy's start; then the
budget ablation) on held-out seeds with the
DAgger expert (:class:`agents.policies.expert.HeadwayDriver`, on the simulator state)
labelling every state it reaches. For each collision it takes the student's last
``--window`` decisions before the crash (decisions every ``decision_interval`` env
steps, :class:`agents.policies.decision.HeldPolicy`), and the first of them where the
student's action differs from the expert's (the last one when none does), and reports:

* the student's and the expert's meta-actions over the window, and at that decision;
* the hazard: the vehicle it hit (highway-env flags both vehicles of a collision),
  and how many radar points of that decision's observation lie in the hit vehicle's
  box (its 5 m x 2 m outline in the ego frame, grown by ``--margin-m`` each side);
* a category: ``expert too`` (the expert would have chosen the same actions),
  ``seen, student disagreed`` (the hazard had points in the observation: the policy,
  not the sensing, failed), ``not seen`` (no point on it: a sensing miss).

Also, over every episode, the share of the student's decisions that match the
expert's (agreement on its own states). Points are the observation's ``points``
rows (x forward, y left, vehicle frame, m); highway-env's lateral axis points right,
so a vehicle at highway offset (dx, dy) from the ego lies at (dx, -dy) in that frame
(both rotated by the ego heading).

Several ``--policy`` are replayed on the same seeds, the first being the reference
(default: the 80k DAgger student and the same recipe at half its budget,
``agents/data/budget/``: the budget ablation); the collision counts of
each against the first's are compared with Fisher's exact test (two-sided).

    OMP_NUM_THREADS=1 python scripts/crash_analysis.py                   # student + budget ablation, seeds 1000-1049 and 2000-2049
    python scripts/crash_analysis.py --policy agents/data/dagger_rhs_highway_slam.zip --seeds 2000 --episodes 20

Writes ``results/crash_analysis.json`` (per policy: every episode's decisions summary and
every crash) and ``results/crash_analysis.md`` (the README tables).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from rhs_studies.kit.pool import map_seeds
from rhs_studies.kit.provenance import write_json
from rhs_studies.kit.seeds import first

ROOT = Path(__file__).resolve().parents[2]

DEFAULT_POLICY = "agents/data/dagger_rhs_highway_slam.zip"
#: the same recipe (agents/hyperparams/dagger.yml, FINE_SPEEDS, 5-degree grid) at half the DAgger student's env steps
BUDGET_ABLATION = "agents/data/budget/dagger_rhs_highway_slam_40k.zip"
DEFAULT_SEEDS = (first("policies_table"), first("heldout_2000"))
CATEGORIES = ("seen, student disagreed", "not seen", "expert too")
#: vehicles within this distance of the ego are kept at each decision (the hit one is among them), m
NEAR_M = 60.0


def ego_frame(ego, position: np.ndarray, heading: float) -> tuple[np.ndarray, float]:
    """A highway-env position and heading in the ego's radar frame: (x forward, y left) m, and heading rad."""
    c, s = np.cos(ego.heading), np.sin(ego.heading)
    d = np.asarray(position, float) - ego.position
    return np.array([c * d[0] + s * d[1], -(-s * d[0] + c * d[1])]), -(heading - ego.heading)


def points_in_box(points: np.ndarray, centre: np.ndarray, heading: float, length: float, width: float,
                  margin: float) -> int:
    """Number of points (P, 2) inside the oriented box (centre, heading, length x width) grown by ``margin`` each side."""
    c, s = np.cos(heading), np.sin(heading)
    d = points - centre[None, :]
    along, across = d @ np.array([c, s]), d @ np.array([-s, c])
    inside = (np.abs(along) <= length / 2 + margin) & (np.abs(across) <= width / 2 + margin)
    return int(inside.sum())


def _observed_points(obs: dict) -> np.ndarray:
    """The valid rows' (x, y) of a SLAM / radar observation (``points`` with ``points_mask``), (P, 2)."""
    if not isinstance(obs, dict) or "points" not in obs:
        return np.zeros((0, 2))
    pts = np.asarray(obs["points"], float)
    mask = np.asarray(obs.get("points_mask", np.ones(len(pts))), bool)
    return pts[mask, :2]


def _neighbours(env) -> dict[int, tuple[np.ndarray, float, float, float]]:
    """id -> (centre, heading, length, width) in the ego frame of every other vehicle within NEAR_M.

    Keyed by ``id``: highway-env creates an episode's vehicles at reset and keeps them all in
    ``road.vehicles`` (collided ones included), so an id names one vehicle for the whole episode.
    """
    road, ego = env.unwrapped.road, env.unwrapped.vehicle
    out = {}
    for v in road.vehicles:
        if v is ego or np.linalg.norm(v.position - ego.position) > NEAR_M:
            continue
        centre, heading = ego_frame(ego, v.position, v.heading)
        out[id(v)] = (centre, heading, float(v.LENGTH), float(v.WIDTH))
    return out


class LabelledPolicy:
    """``model`` as :func:`agents.evaluate.run_episode` drives it, with the expert's label at each of its decisions.

    A decision is every k-th ``predict`` of an episode (:class:`agents.policies.decision.HeldPolicy` decides on those);
    at each, ``decisions`` gets the env step, both actions, the observation's radar points and the neighbours.
    """

    def __init__(self, model, expert, env, k: int) -> None:
        self.model, self.expert, self.env, self.k = model, expert, env, k
        self.decisions: list[dict[str, Any]] = []
        self._t = 0

    def reset(self) -> None:
        self.decisions, self._t = [], 0
        if callable(getattr(self.model, "reset", None)):
            self.model.reset()

    def predict(self, obs, deterministic: bool = True):
        from agents.evaluate import env_action

        action, state = self.model.predict(obs, deterministic=deterministic)
        if self._t % self.k == 0:
            self.decisions.append({"step": self._t, "student": int(env_action(action)), "expert": int(self.expert.act()),
                                   "points": _observed_points(obs), "near": _neighbours(self.env)})
        self._t += 1
        return action, state


def run_labelled(env, policy: LabelledPolicy, seed: int, margin: float, window: int = 3) -> dict[str, Any]:
    """One episode (:func:`agents.evaluate.run_episode`) with the agreement of its decisions and its crash record."""
    from agents.evaluate import run_episode

    ep = run_episode(env, policy, seed)
    agree = [d["student"] == d["expert"] for d in policy.decisions]
    run: dict[str, Any] = {"seed": seed, "return": ep["return"], "steps": ep["steps"], "crashed": ep["crashed"],
                           "decisions": len(agree), "agreement": float(np.mean(agree)) if agree else None}
    if ep["crashed"]:
        run["crash"] = _crash_record(env, policy.decisions, env.unwrapped.action_type.actions, margin, window)
    return run


def _crash_record(env, decisions: list[dict], names: dict, margin: float, window: int) -> dict[str, Any]:
    """The crash seen from the student's last ``window`` decisions before it.

    The decision that counts is the first of them where the student's action differs from the expert's
    (the last one when they all agree); at that decision: both actions, the hit vehicle's position and
    its radar points in the observation. Also both action sequences over the window.
    """
    ego = env.unwrapped.vehicle
    hit = [v for v in env.unwrapped.road.vehicles if v is not ego and getattr(v, "crashed", False)]
    last = decisions[-window:]
    differ = [d for d in last if d["student"] != d["expert"]]
    chosen = differ[0] if differ else last[-1]
    rec: dict[str, Any] = {"decision_step": chosen["step"], "student": names[chosen["student"]],
                           "expert": names[chosen["expert"]], "hit_found": bool(hit),
                           "student_window": [names[d["student"]] for d in last],
                           "expert_window": [names[d["expert"]] for d in last]}
    other = min(hit, key=lambda v: np.linalg.norm(v.position - ego.position)) if hit else None
    box = chosen["near"].get(id(other)) if other is not None else None
    if box is None:
        rec.update(hazard_xy=None, hazard_points=None)
    else:
        centre, heading, length, width = box
        rec.update(hazard_xy=[round(float(x), 2) for x in centre],
                   hazard_points=points_in_box(chosen["points"], centre, heading, length, width, margin))
    rec["category"] = category(rec)
    return rec


def category(rec: dict[str, Any]) -> str:
    """``expert too`` / ``seen, student disagreed`` / ``not seen`` for a crash record (see the module docstring)."""
    if rec["student"] == rec["expert"]:
        return "expert too"
    return "seen, student disagreed" if (rec.get("hazard_points") or 0) > 0 else "not seen"


def drive_chunk(seeds: list[int], policy: str, margin: float, window: int, env_kwargs: dict | None = None,
                expert: dict | None = None) -> list[dict]:
    """Labelled episodes of ``policy`` on ``seeds`` in this process (one chunk of :func:`run_seeds`)."""
    import rhs_env  # noqa: F401
    from agents.evaluate import load_policy, make_env, resolve_env
    from agents.policies.decision import HeldPolicy
    from agents.policies.expert import HeadwayDriver

    env_id, kwargs = resolve_env(policy, None, None)
    env = make_env(env_id, {**kwargs, **(env_kwargs or {})})
    try:
        model = load_policy(policy, env, 0)
        k = model.k if isinstance(model, HeldPolicy) else 1
        labelled = LabelledPolicy(model, HeadwayDriver(env, expert), env, k)
        return [run_labelled(env, labelled, s, margin, window) for s in seeds]
    finally:
        env.close()


def run_seeds(policy: str, seeds: list[int], margin: float, window: int, workers: int,
              expert: dict | None = None) -> list[dict]:
    """Episodes on ``seeds``, in ``workers`` contiguous chunks (:func:`rhs_studies.kit.pool.map_seeds`)."""
    return map_seeds(drive_chunk, seeds, workers, policy, margin, window, None, expert)


def summarize(runs: list[dict]) -> dict[str, Any]:
    """Crash counts per category and the decision agreement with the expert (all episodes, crash episodes)."""
    crashes = [r["crash"] for r in runs if r["crashed"]]
    counts = {c: sum(1 for x in crashes if x["category"] == c) for c in CATEGORIES}
    agree = [r["agreement"] for r in runs if r["agreement"] is not None]
    agree_crash = [r["agreement"] for r in runs if r["crashed"] and r["agreement"] is not None]
    return {"episodes": len(runs), "collisions": len(crashes), "categories": counts,
            "agreement": float(np.mean(agree)) if agree else None,
            "agreement_crash_episodes": float(np.mean(agree_crash)) if agree_crash else None}


def training_steps(policy: str) -> int | None:
    """The env steps a policy was trained with (``timesteps`` of the JSON beside its zip), None if unknown."""
    from agents.algos.run_records import metadata_path

    meta = metadata_path(policy)
    return json.loads(meta.read_text()).get("timesteps") if meta.exists() else None


def fisher_p(a: dict[str, Any], b: dict[str, Any]) -> float:
    """Two-sided Fisher exact p of two summaries' collision counts (collided / not, in their episodes)."""
    from scipy.stats import fisher_exact

    table = [[a["collisions"], a["episodes"] - a["collisions"]], [b["collisions"], b["episodes"] - b["collisions"]]]
    return float(fisher_exact(table).pvalue)


def _blocks(result: dict) -> list[tuple[int, int]]:
    n = result["episodes"]
    return [(a, a + n - 1) for a in result["seed_starts"]]


def _block_text(lo: int, hi: int) -> str:
    return f"{lo}-{hi}" if hi > lo else str(lo)


def markdown(result: dict) -> str:
    """The README text: one summary row per policy, then every crash with the student's and expert's decisions."""
    blocks = _blocks(result)
    expert = result.get("expert")
    teacher = f"; the expert: the headway driver with {json.dumps(expert)}" if expert else ""
    lines = [f"Seeds {', '.join(_block_text(*b) for b in blocks)}; agreement: the share of the student's decisions "
             f"that match the expert's label, on its own states (in the episodes that crash){teacher}.", "",
             "| policy | training env steps | " + " | ".join(f"collisions, seeds {_block_text(*b)}" for b in blocks)
             + " | collisions, all | Fisher p vs first | agreement | categories (seen, student disagreed / not seen / expert too) |",
             "|---|---:|" + "---:|" * len(blocks) + "---:|---:|---|---|"]
    first = result["policies"][0]["summary"]
    for i, pol in enumerate(result["policies"]):
        s, runs = pol["summary"], pol["runs"]
        per_block = [sum(r["crashed"] for r in runs if lo <= r["seed"] <= hi) for lo, hi in blocks]
        agree = f"{100 * s['agreement']:.1f} %" if s["agreement"] is not None else "-"
        if s["agreement_crash_episodes"] is not None:
            agree += f" ({100 * s['agreement_crash_episodes']:.1f} %)"
        steps = "-" if pol["timesteps"] is None else str(pol["timesteps"])
        p = "-" if i == 0 else f"{fisher_p(first, s):.3f}"
        lines.append(f"| `{pol['policy']}` | {steps} | " + " | ".join(f"{k}/{result['episodes']}" for k in per_block)
                     + f" | {s['collisions']}/{s['episodes']} | {p} | {agree} | "
                     + " / ".join(str(v) for v in s["categories"].values()) + " |")
    lines += ["", f"Per crash, the student's last {result['window']} decisions against the expert's labels; the "
              "decision that counts is the first where they differ (else the last).", "",
              "| policy (training env steps) | seed | student, last decisions | expert | decision (env step) "
              f"| hit vehicle then (x, y m) | radar points on it (box + {result['margin_m']:g} m) | category |",
              "|---|---:|---|---|---:|---|---:|---|"]
    for pol in result["policies"]:
        name = f"{Path(pol['policy']).stem} ({pol['timesteps'] if pol['timesteps'] is not None else '?'})"
        for r in pol["runs"]:
            if not r["crashed"]:
                continue
            c = r["crash"]
            xy = "-" if c["hazard_xy"] is None else f"({c['hazard_xy'][0]:.1f}, {c['hazard_xy'][1]:.1f})"
            pts = "-" if c["hazard_points"] is None else str(c["hazard_points"])
            lines.append(f"| {name} | {r['seed']} | {', '.join(c['student_window'])} | {', '.join(c['expert_window'])} | "
                         f"{c['decision_step']} | {xy} | {pts} | {c['category']} |")
    return "\n".join(lines) + "\n"


def fingerprint() -> list[float]:
    """The DAgger student, one 2-second episode (10 steps) on seed 1000: return, steps, decisions, agreement."""
    policy = str(ROOT / DEFAULT_POLICY)
    if not Path(policy).exists():
        return []
    run = drive_chunk([1000], policy, 1.0, 3, {"duration": 2})[0]
    return [run["return"], run["steps"], run["decisions"], run["agreement"], float(run["crashed"])]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", nargs="+", default=[DEFAULT_POLICY, BUDGET_ABLATION],
                    help="policies replayed on the same seeds, the first the reference (default: %(default)s)")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(DEFAULT_SEEDS),
                    help="first seed of each block of --episodes seeds")
    ap.add_argument("--episodes", type=int, default=50, help="episodes per seed block")
    ap.add_argument("--margin-m", type=float, default=1.0, help="the hit vehicle's box grown by this each side, m")
    ap.add_argument("--window", type=int, default=3, help="the student's last decisions before a crash that are examined")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--expert", type=json.loads, default=None, metavar="JSON",
                    help='the headway driver\'s settings (agents.policies.expert.HeadwayDriverConfig), e.g. '
                         '\'{"cruise_speed_mps": 30, "margin_mps": 1}\' for the faster teacher (default: its defaults)')
    ap.add_argument("--out", default=str(ROOT / "results" / "crash_analysis.json"))
    args = ap.parse_args(argv)
    if args.episodes < 1:
        raise SystemExit(f"--episodes must be >= 1, got {args.episodes}")
    if args.workers < 1:
        raise SystemExit(f"--workers must be >= 1, got {args.workers}")
    if args.window < 1:
        raise SystemExit(f"--window must be >= 1, got {args.window}")
    if args.margin_m < 0:
        raise SystemExit(f"--margin-m must be >= 0, got {args.margin_m}")
    missing = [p for p in args.policy if not Path(p).exists()]
    if missing:
        raise SystemExit(f"policy not found: {', '.join(missing)}")
    started = time.time()
    seeds = [a + k for a in args.seeds for k in range(args.episodes)]
    policies = []
    for policy in args.policy:
        print(f"crash_analysis: {policy} on {len(seeds)} seeds", file=sys.stderr)
        runs = run_seeds(policy, seeds, args.margin_m, args.window, args.workers, args.expert)
        policies.append({"policy": policy, "timesteps": training_steps(policy), "summary": summarize(runs), "runs": runs})
    result = {"seed_starts": args.seeds, "episodes": args.episodes, "margin_m": args.margin_m, "window": args.window,
              "expert": args.expert, "policies": policies}
    out = Path(args.out)
    write_json(out, result, __file__, args, started, fingerprint, argv)
    out.with_suffix(".md").write_text(markdown(result))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
