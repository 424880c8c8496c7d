"""Short, measured ablations of what limits learning to drive.

Each named variant trains PPO or a DAgger student (stable-baselines3 backend,
``agents/hyperparams/ppo.yml`` or ``dagger.yml`` with the variant's overrides) for
``--timesteps`` env steps on its env and training env kwargs, then evaluates the
final policy **greedily on the default reward** (whatever reward the variant
trained on) on the same seeds as ``scripts/evaluate_policies.py`` (``--eval-seed``,
``--eval-seed + 1``, ...), next to scripted drivers on the same seeds (``ref_*``).
Records are merged into ``--out`` (default ``results/ablations.json``, under
``records``) under ``variant/seed/timesteps``, each with the commit and command
line that made it; the file carries the provenance of its latest run. ``--fresh``
starts a new table (what ``scripts/reproduce.py --only ablations`` does).

    OMP_NUM_THREADS=1 nice -n 10 python scripts/ablate_policy.py base_truth no_norm_truth --timesteps 15000

Variants (``VARIANTS``):

* PPO: reward terms and normalisation (highway-env's ``collision_reward``,
  ``high_speed_reward``, ``normalize_reward``), discount, entropy bonus, the
  decision interval (``hold5_*``: the action held for 5 env steps,
  :mod:`agents.policies.decision`; evaluation still scores every env step), and the
  observation (ground-truth Kinematics on ``rhs-highway-v0`` vs radar point cloud
  + SLAM on ``rhs-highway-slam-v0`` with the 5-degree grid; ``grid_*``: the
  ego-centred occupancy grid encoder instead of the point-set one);
* DAgger (``dagger_*``): the shipped recipe on the same budget, without class
  weights (``p0``: plain maximum likelihood), with meta-actions held instead of
  pulsed between decisions (``hold``), deciding at 5 Hz (``5hz``), and with the
  states between decisions labelled too (``between``: 5x the samples, same env steps).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

from rhs_studies.kit.driving import FINE_SPEEDS  # target speeds down to 10 m/s (highway-env's default: 20, 25, 30)
from rhs_studies.kit.provenance import STATE_AT_START, write_json
from rhs_studies.kit.seeds import first

ROOT = Path(__file__).resolve().parents[2]

TRUTH, SLAM = "rhs-highway-v0", "rhs-highway-slam-v0"
FIVE_DEG = {"radar": {"scan": {"grid_deg": 5}}}
#: the default reward of the envs (highway-env's), restored for evaluation
DEFAULT_REWARD = {"collision_reward": -1, "high_speed_reward": 0.4, "right_lane_reward": 0.1,
                  "reward_speed_range": [20, 30], "normalize_reward": True}  # fmt: skip
NO_NORM = {"normalize_reward": False}
SPEED = {"normalize_reward": False, "high_speed_reward": 1.0, "right_lane_reward": 0.0, "collision_reward": -5}
HOLD5 = {"decision_interval": 5, "gamma": 0.8}
#: name -> (env id, training env kwargs, hyperparameter overrides): PPO (agents/hyperparams/ppo.yml)
VARIANTS: dict[str, tuple[str, dict, dict]] = {
    "base_truth": (TRUTH, {}, {}),
    "no_norm_truth": (TRUTH, NO_NORM, {}),
    "speed_truth": (TRUTH, SPEED, {}),
    "gamma99_truth": (TRUTH, {}, {"gamma": 0.99}),
    "ent01_truth": (TRUTH, {}, {"ent_coef": 0.01}),
    "no_norm_ent01_truth": (TRUTH, NO_NORM, {"ent_coef": 0.01}),
    "base_slam": (SLAM, FIVE_DEG, {}),
    "no_norm_slam": (SLAM, {**FIVE_DEG, **NO_NORM}, {}),
    "grid_slam": (SLAM, FIVE_DEG, {"policy_kwargs": {"features_extractor_class": "grid", "net_arch": [64, 64]}}),
    "grid_no_norm_slam": (SLAM, {**FIVE_DEG, **NO_NORM},
                          {"policy_kwargs": {"features_extractor_class": "grid", "net_arch": [64, 64]}}),
    # a decision every 5 env steps (1 Hz, highway-env's own rate; agents.policies.decision.HoldAction), with
    # highway-env's 1 Hz discount 0.8; --timesteps stays the env-step budget (timesteps / 5 decisions)
    "hold5_truth": (TRUTH, {}, HOLD5),
    "hold5_slam": (SLAM, FIVE_DEG, HOLD5),
}
#: name -> (env id, training env kwargs, overrides): DAgger students (agents/hyperparams/dagger.yml)
DAGGER_VARIANTS: dict[str, tuple[str, dict, dict]] = {
    "dagger_truth": (TRUTH, {}, {}),
    "dagger_p0_truth": (TRUTH, {}, {"class_weight_power": 0.0}),
    "dagger_hold_truth": (TRUTH, {}, {"decision_mode": "hold"}),
    "dagger_5hz_truth": (TRUTH, {}, {"decision_interval": 1}),
    "dagger_between_truth": (TRUTH, {}, {"label_between": True}),
    "dagger_slam": (SLAM, FIVE_DEG, {}),
    "dagger_between_slam": (SLAM, FIVE_DEG, {"label_between": True}),
}
#: what ``scripts/reproduce.py --only ablations`` runs (``--fresh``, default budget and seeds)
REPRODUCE = ("ref_slower", "ref_idm", "ref_headway", "ref_headway_fine_speeds", "base_truth", "speed_truth", "grid_slam",
             "dagger_truth", "dagger_p0_truth", "dagger_hold_truth", "dagger_between_truth")


def run_variant(name: str, timesteps: int, seed: int, episodes: int, eval_seed: int, n_envs: int | None) -> dict:
    """Train the variant, evaluate it on the default reward; returns its record."""
    from agents.algos.train import HYPERPARAMS_DIR, train
    from agents.evaluate import evaluate, summarize

    algo = "dagger" if name in DAGGER_VARIANTS else "ppo"
    env_id, env_kwargs, overrides = (DAGGER_VARIANTS if algo == "dagger" else VARIANTS)[name]
    table = yaml.safe_load((HYPERPARAMS_DIR / f"{algo}.yml").read_text())
    entry = {**table[env_id], **overrides}
    with tempfile.TemporaryDirectory() as tmp:
        hp_path = Path(tmp) / f"{algo}.yml"
        hp_path.write_text(yaml.safe_dump({env_id: entry}))
        out = ROOT / "runs" / "ablations" / f"{name}_s{seed}"
        t0 = time.perf_counter()
        s = train(algo, env_id, timesteps, out, seed=seed, n_envs=n_envs, hyperparams=hp_path, env_kwargs=env_kwargs,
                  eval_freq=0, checkpoint_freq=0, progress=False)  # fmt: skip
        train_wall = time.perf_counter() - t0
    eval_kwargs = {**env_kwargs, **DEFAULT_REWARD}
    t0 = time.perf_counter()
    ev = evaluate(out / "model.zip", env_id, episodes, eval_seed, eval_kwargs, progress=False)
    eval_wall = time.perf_counter() - t0
    runs = [{k: r[k] for k in ("seed", "return", "steps", "crashed", "mean_speed")} for r in ev["runs"]]
    actions = _action_histogram(out / "model.zip", env_id, eval_kwargs, eval_seed)
    return {
        "algo": algo,
        "env_id": env_id,
        "train_env_kwargs": env_kwargs,
        "eval_env_kwargs": eval_kwargs,
        "hyperparams": entry,
        "timesteps": s["timesteps"],
        "decision_interval": s.get("decision_interval", 1),
        "decisions": s.get("decisions", s["timesteps"]),
        "seed": seed,
        "train_wall_s": round(train_wall, 1),
        "train_recent_episodes": s.get("recent_episodes"),
        "dagger_iterations": s.get("iterations"),
        "eval": {k: v for k, v in summarize(ev["runs"]).items() if k in ("episodes", "return", "collision_rate",
                                                                         "mean_speed_mps", "episode_length")},  # fmt: skip
        "eval_seeds": ev["seeds"],
        "eval_wall_s": round(eval_wall, 1),
        "greedy_action_histogram_first_episode": actions,
        "runs": runs,
    }


def _action_histogram(policy: Path, env_id: str, kwargs: dict, seed: int) -> dict[str, int]:
    """How often each meta-action is chosen greedily in the first evaluation episode
    (:func:`agents.evaluate.run_episode` driving the policy, its choices counted)."""
    import gymnasium as gym
    import numpy as np

    import rhs_env  # noqa: F401
    from agents.evaluate import load_policy, run_episode

    env = gym.make(env_id, **kwargs)
    model = load_policy(policy, env)  # a HeldPolicy for a decision_interval > 1
    base: Any = env.unwrapped  # highway-env's AbstractEnv (untyped)
    names = base.action_type.actions
    counts: dict[str, int] = {}

    class Counted:
        """The policy, counting its actions."""

        def reset(self) -> None:
            if callable(getattr(model, "reset", None)):
                model.reset()

        def predict(self, obs, deterministic: bool = True):
            a, state = model.predict(obs, deterministic=deterministic)
            name = names[int(np.asarray(a))]
            counts[name] = counts.get(name, 0) + 1
            return a, state

    run_episode(env, Counted(), seed)
    env.close()
    return counts


#: scripted references on the same seeds (no training): name -> (policy, env kwargs over the default reward,
#: episodes: None for --episodes)
REFERENCES: dict[str, tuple[str, dict, int | None]] = {
    "ref_slower": ("constant:4", {}, None),
    "ref_idm": ("idm", {}, None),
    # the DAgger expert as it taught (every 5 steps, IDLE between), and with target speeds down to 10 m/s: whether
    # the 20 m/s floor of the meta-actions is what its collisions (which bound its students') come from; a few
    # percent, so 200 seeds whatever --episodes says
    "ref_headway": ("headway:5", {}, 200),
    "ref_headway_fine_speeds": ("headway:5", FINE_SPEEDS, 200),
}


def run_reference(name: str, episodes: int, eval_seed: int) -> dict:
    from agents.evaluate import evaluate, summarize

    policy, kwargs, _ = REFERENCES[name]
    eval_kwargs = {**kwargs, **DEFAULT_REWARD}
    ev = evaluate(policy, TRUTH, episodes, eval_seed, eval_kwargs, progress=False)
    return {
        "env_id": TRUTH,
        "policy": policy,
        "eval_env_kwargs": eval_kwargs,
        "eval": {k: v for k, v in summarize(ev["runs"]).items() if k in ("episodes", "return", "collision_rate",
                                                                         "mean_speed_mps", "episode_length")},  # fmt: skip
        "eval_seeds": ev["seeds"],
        "greedy_action_histogram_first_episode": {},
        "runs": [{k: r[k] for k in ("seed", "return", "steps", "crashed", "mean_speed")} for r in ev["runs"]],
    }


def records(data: dict) -> dict:
    """The records of an ablations file (``records``; a file of before the provenance block was the table itself)."""
    if "records" in data:
        return dict(data["records"])
    return {k: v for k, v in data.items() if k != "provenance"}


def _merge(out: Path, key: str, rec: dict, args: argparse.Namespace, started: float, argv: list[str] | None) -> None:
    """Add ``rec`` under ``key`` to the records at ``out`` and rewrite it with this run's provenance
    (locked: variants may run in parallel processes)."""
    import fcntl

    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        table = records(json.loads(out.read_text())) if out.exists() else {}
        table[key] = rec
        write_json(out, {"records": table}, __file__, args, started, argv=argv)


def _scripted(r: dict) -> str:
    """A scripted reference's policy, with the env kwargs it adds to the default reward (if any)."""
    extra = {k: v for k, v in r.get("eval_env_kwargs", {}).items() if k not in DEFAULT_REWARD}
    return r["policy"] + (f" on {json.dumps(extra)}" if extra else "")


def markdown(table: dict) -> str:
    """The README table of every record: greedy evaluation on the default reward, mean +- 95 % t-interval."""
    from rhs_common.stats import t_quantile

    def ci(s: dict) -> str:
        half = t_quantile(s.get("n", 0)) * s["sem"] if s.get("n", 0) > 1 else float("nan")
        return f"{s['mean']:.1f} ± {half:.1f}"

    rows = ["| record | algorithm | env | training env kwargs / scripted policy | hyperparameters changed | env steps | "
            "decisions every | gamma | return | collisions | speed (m/s) | commit |",
            "|---|---|---|---|---|---:|---:|---:|---:|---:|---:|---|"]
    for key, r in records(table).items():
        variant = {**VARIANTS, **DAGGER_VARIANTS}.get(key.split("/", 1)[0])
        changed = json.dumps(variant[2]) if variant and variant[2] else "-"
        e = r["eval"]
        trained = "timesteps" in r
        hp = r.get("hyperparams", {})
        gamma = hp.get("gamma", "-") if r.get("algo", "ppo") == "ppo" else "-"
        interval = f"{r.get('decision_interval', 1)} ({hp.get('decision_mode', 'hold')})" if trained else "-"
        rows.append(f"| `{key}` | {r.get('algo', 'ppo') if trained else 'scripted'} | `{r['env_id']}` "
                    f"| {json.dumps(r.get('train_env_kwargs', {})) if trained else _scripted(r)} | {changed} "
                    f"| {r.get('timesteps', '-')} | {interval} | {gamma} "
                    f"| {ci(e['return'])} | {e['collision_rate']:.2f} ({len(r['runs'])} ep.) | {ci(e['mean_speed_mps'])} "
                    f"| {str(r.get('commit', ''))[:10]} |")  # fmt: skip
    return ("Greedy evaluation on the default reward, seeds from 1000 (the `policies` seeds); mean ± 95 % t-interval "
            "over episodes. References: scripted drivers on the same seeds.\n\n" + "\n".join(rows) + "\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    known = [*VARIANTS, *DAGGER_VARIANTS, *REFERENCES]
    ap.add_argument("variants", nargs="*", metavar="VARIANT",
                    help=f"of: {', '.join(known)} (default: {' '.join(REPRODUCE)})")
    ap.add_argument("--timesteps", type=int, default=15000)
    ap.add_argument("--seed", type=int, default=first("training"), help="training seed")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--eval-seed", type=int, default=first("policies_table"))
    ap.add_argument("--n-envs", type=int, default=None)
    ap.add_argument("--out", default=str(ROOT / "results" / "ablations.json"))
    ap.add_argument("--fresh", action="store_true", help="start a new table (drop the records already in --out)")
    ap.add_argument("--report-only", action="store_true", help="rewrite the .md beside --out from its records")
    args = ap.parse_args(argv)
    if args.report_only:
        out = Path(args.out)
        out.with_suffix(".md").write_text(markdown(json.loads(out.read_text())))
        return 0
    unknown = [v for v in args.variants if v not in known]
    if unknown:
        ap.error(f"unknown variants {unknown}; choose from {', '.join(known)}")
    args.variants = args.variants or list(REPRODUCE)
    started = time.time()
    if args.fresh and Path(args.out).exists():
        Path(args.out).unlink()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    command = " ".join([Path(sys.argv[0]).name, *(argv if argv is not None else sys.argv[1:])])
    state = STATE_AT_START  # the code this process runs (the worktree may move on during a long run)
    commit = f"{state['commit'] or 'unknown'}{'-dirty' if state['dirty'] else ''}"
    for name in args.variants:
        if name in REFERENCES:
            episodes = REFERENCES[name][2] or args.episodes
            rec, key = run_reference(name, episodes, args.eval_seed), f"{name}/{episodes}"
        else:
            rec = run_variant(name, args.timesteps, args.seed, args.episodes, args.eval_seed, args.n_envs)
            key = f"{name}/seed{args.seed}/{args.timesteps}"
        rec.update(commit=commit, command=command)
        _merge(Path(args.out), key, rec, args, started, argv)
        e = rec["eval"]
        print(f"{name}: return {e['return']['mean']:.1f}, collisions {e['collision_rate']:.2f}, speed "
              f"{e['mean_speed_mps']['mean']:.1f} m/s, actions {rec['greedy_action_histogram_first_episode']}",
              file=sys.stderr)  # fmt: skip
    out = Path(args.out)
    out.with_suffix(".md").write_text(markdown(json.loads(out.read_text())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
