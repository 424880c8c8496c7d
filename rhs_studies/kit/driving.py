"""The driving studies' shared parts: the RL study's arms (the trained policies every driving comparison drives),
their starts and labels, one policy's episodes on a list of seeds, the scripted references, and the RL targets.

* :data:`ARMS`: each trained arm's recipe (algorithm, hyperparameters, budget, start), :data:`LABELS` the table
  label of every row, :data:`STARTS` the rows the arms start from, :data:`SHIPPED_DIR` where the arms' zips are;
* :func:`run_policy`: a policy's episodes on seeds over the kit's pool (:func:`rhs_studies.kit.pool.map_seeds`);
  :func:`drive_arm`: a shipped arm on its saved env, behind its saved shield or another;
* :func:`evaluate_rows`: learned policies on their envs and the scripted references (always SLOWER, IDM + MOBIL,
  the headway expert, the lookahead teacher) on the ground-truth env;
* :func:`targets`: the fine-tune's targets (return >= 1.08x IDM + MOBIL, collisions <= 2 per 100, speed >= 24 m/s,
  a paired gain over its start >= +3 with its interval above 0, more than its DAgger control);
* :func:`rl_fingerprint`: the starts and shipped arms on one short episode (the RL studies' fingerprint).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

from agents.evaluate import DAGGER_CRUISE30_CLOSE_POLICY, resolve_env
from agents.policies.decision import SLOWER
from rhs_studies.kit.pool import map_seeds
from rhs_studies.kit.runner import option
from rhs_studies.kit.seeds import consecutive, first
from rhs_studies.kit.tables import paired

ROOT = Path(__file__).resolve().parents[2]
ENV_ID = "rhs-highway-slam-v0"
STUDENT = ROOT / "agents" / "data" / "dagger_rhs_highway_slam.zip"
#: the shield student (the 30 m/s DAgger student behind the radar shield, shipped until the RL fine-tune of it
#: replaced it): the start of the shield arms
SHIPPED_START = DAGGER_CRUISE30_CLOSE_POLICY
#: the rows the arms start from
STARTS = {"student": STUDENT, "shipped": SHIPPED_START}
#: where the trained arms are kept (the actor zips and their training records)
SHIPPED_DIR = ROOT / "agents" / "data" / "rl"
HYPERPARAMS = ROOT / "agents" / "hyperparams"

#: the DAgger / PPO students of the policies table (rhs_studies.driving.train_policy trains them)
DATA = ROOT / "agents" / "data"
SLAM_ID, TRUTH_ID, DENSE_ID = "rhs-highway-slam-v0", "rhs-highway-v0", "rhs-dense-v0"
ALGOS = ("dagger", "ppo")
#: highway-env's Kinematics observation with the followers in view: 8 vehicles, behind as well as ahead (the
#: default sees the 4 nearest vehicles ahead only, not the followers the expert checks before a lane change)
KINEMATICS_ALL_AROUND = {"observation": {"type": "Kinematics", "vehicles_count": 8, "see_behind": True}}
#: name -> (env id, radar kwargs merged over --slam-env-kwargs; None: a ground-truth env, no radar[, env kwargs])
TARGETS: dict[str, tuple] = {
    "slam": (SLAM_ID, {}),
    "truth": (TRUTH_ID, None),
    "truth_all_around": (TRUTH_ID, None, KINEMATICS_ALL_AROUND),
    # the antenna study, does the antenna matter for driving: the same student on the RHS and on a phased array,
    # and both on the dense roadside
    "slam_rhs": (SLAM_ID, {"antenna": "rhs"}),
    "slam_phased": (SLAM_ID, {"antenna": "phased"}),
    "dense": (DENSE_ID, {}),
    "dense_phased": (DENSE_ID, {"antenna": "phased"}),
}
SHIPPED = ("slam", "truth")
#: the radar / SLAM envs train on a 5-degree beam grid (18 beams per sweep, ~2x faster than the 1-degree default)
SLAM_ENV_KWARGS = {"radar": {"scan": {"grid_deg": 5}}}
#: every policy's env (``--env-kwargs``): highway-env's DiscreteMetaAction with target speeds down to 10 m/s
#: instead of [20, 25, 30]. With them the expert can slow behind a slower leader instead of crashing into it
#: (results/ablations.json, 200 seeds: 2 collisions against 5) and its students learn that.
FINE_SPEEDS = {"action": {"type": "DiscreteMetaAction", "target_speeds": [10, 15, 20, 25, 30]}}
ANTENNA_STUDY = ("slam_rhs", "slam_phased", "dense", "dense_phased")


def target_path(algo: str, name: str, data_dir: Path = DATA) -> Path:
    """Where the ``name`` policy trained by ``algo`` goes: ``<algo>_rhs_highway_<name>.zip``, the antenna
    study's other policies in ``antenna/``."""
    sub = "" if name in SHIPPED else ("truth/" if name.startswith("truth") else "antenna/")
    return Path(data_dir) / f"{sub}{algo}_rhs_highway_{name}.zip"


class Arm(NamedTuple):
    """One training run of the study: ``rhs-slam train --algo ALGO`` with the hyperparameters ``spec``."""

    algo: str
    #: ``NAME.yml`` of agents/hyperparams, or ``NAME.yml:key=value;...`` (see :func:`hyperparams_file`)
    spec: str
    #: starts from the shipped DAgger student (``--init-policy``)
    from_student: bool
    #: env steps; None: the study's ``--timesteps``
    timesteps: int | None = None
    #: the row it starts from (a key of :data:`STARTS`), whose env kwargs it trains on; its paired differences are
    #: against that row
    start: str = "student"


HORIZON = "finetune.yml:gamma=0.95;reward_shaping={ttc_s: 3.0, weight: 0.5}"
#: a longer budget for the best fine-tune setting and its DAgger control (same env steps each)
LONG_STEPS = 80000
#: the exploring fine-tune under the shield: the warm-up recipe without the anchor, entropy 0.02, learning rate 3e-4
SHIELD_EXPLORE = "finetune_warmup.yml:anchor_coef=0;ent_coef=0.02;learning_rate=3.0e-4"
#: PPO from scratch under the shield with PPO's usual settings (the first study's ``scratch`` arm)
SCRATCH_EXPLORE = "finetune_shielded.yml:learning_rate=5.0e-4;clip_range=0.2;ent_coef=0.01"
ARMS: dict[str, Arm] = {
    "finetune": Arm("finetune", "finetune.yml", True),
    "finetune_no_anchor": Arm("finetune", "finetune.yml:anchor_coef=0", True),
    "finetune_horizon": Arm("finetune", HORIZON, True),
    "dagger_continue": Arm("dagger", "dagger_continue.yml", True),
    "scratch": Arm("finetune", "finetune.yml:learning_rate=5.0e-4;clip_range=0.2;ent_coef=0.01;"
                               "reward_shaping={ttc_s: 3.0, weight: 0.5}", False),
    "finetune_horizon_80k": Arm("finetune", HORIZON, True, LONG_STEPS),
    "dagger_continue_80k": Arm("dagger", "dagger_continue.yml", True, LONG_STEPS),
    "dagger_lookahead": Arm("dagger", "dagger_lookahead.yml", True, 48000),
    "shield_finetune": Arm("finetune", "finetune_shielded.yml", True, 20000, "shipped"),
    "shield_warmup": Arm("finetune", "finetune_warmup.yml", True, 60000, "shipped"),
    "shield_explore": Arm("finetune", SHIELD_EXPLORE, True, 40000, "shipped"),
    "shield_flank_explore": Arm("finetune", SHIELD_EXPLORE, True, 40000, "shipped"),
    "shield_dagger": Arm("dagger", "dagger_shielded.yml", True, 40000, "shipped"),
    "shield_scratch": Arm("finetune", "finetune_shielded.yml", False, 60000, "shipped"),
    "shield_scratch_explore": Arm("finetune", SCRATCH_EXPLORE, False, 60000, "shipped"),
    "shield_scratch_cost": Arm("finetune", SCRATCH_EXPLORE + ";reward_shaping={ttc_s: 3.0, weight: 0.5, shield_cost: 0.5}",
                               False, 60000, "shipped"),
}
LABELS = {
    "student": "DAgger student (start of the arms above the shield's)",
    "finetune": "PPO fine-tune, privileged critic, decaying anchor",
    "finetune_no_anchor": "PPO fine-tune without the anchor (control)",
    "finetune_horizon": "PPO fine-tune, gamma 0.95 and time-to-collision shaping",
    "finetune_horizon_80k": f"PPO fine-tune, gamma 0.95 and time-to-collision shaping, {LONG_STEPS // 1000}k env steps",
    "dagger_continue": "DAgger continuation (control)",
    "dagger_continue_80k": f"DAgger continuation, {LONG_STEPS // 1000}k env steps (control; shipped before the shield student)",
    "scratch": "PPO from scratch, privileged critic",
    "dagger_lookahead": "DAgger from the lookahead teacher, 48k env steps",
    "slower": "always SLOWER (scripted)",
    "idm": "IDM + MOBIL (highway-env, scripted)",
    "headway": "HeadwayDriver at 1 Hz, IDLE between (the expert)",
    "lookahead": "LookaheadDriver at 1 Hz, IDLE between (the rollout teacher)",
    "shipped": "Shield student: 30 m/s DAgger student behind the radar shield (start of the shield arms; shipped before "
               "the RL fine-tune)",
    "shield_finetune": "PPO fine-tune under the shield, gamma 0.95 and time-to-collision shaping, 20k env steps",
    "shield_warmup": "PPO fine-tune under the shield with a critic warm-up, 60k env steps",
    "shield_explore": "PPO fine-tune under the shield, critic warm-up, no anchor, entropy 0.02, 40k env steps",
    "shield_flank_explore": "PPO fine-tune trained under the shield with its flank rule, warm-up, no anchor, entropy 0.02, "
                            "40k env steps",
    "shield_dagger": "DAgger continuation under the shield, 40k env steps (control of the shield fine-tunes)",
    "shield_scratch": "PPO from scratch under the shield, 60k env steps",
    "shield_scratch_explore": "PPO from scratch under the shield, learning rate 5e-4, clip 0.2, entropy 0.01, 60k env steps",
    "shield_scratch_cost": "PPO from scratch under the shield, as above, each shield intervention costing 0.5, 60k env "
                           "steps",
}
#: the fine-tune's targets: return vs IDM + MOBIL, collisions per episode, mean speed, paired gain over the student
TARGET_VS_IDM, TARGET_COLLISIONS, TARGET_SPEED_MPS, TARGET_GAIN = 1.08, 0.02, 24.0, 3.0

#: the shield arms the targets judge, in order of preference (the first evaluated; chosen on the validation seeds
#: 4000-4049, where shield_explore led: +3.2 +- 2.5 paired against the shield student, 0 / 50 collisions, before and
#: after the flank rule; shield_flank_explore +1.7 +- 2.6 with 1 / 50) and their DAgger control
SHIELD_ARMS = ("shield_explore", "shield_warmup", "shield_finetune")
SHIELD_CONTROL = "shield_dagger"


def start_of(row: str) -> str:
    """The row ``row`` is compared with: its arm's start, else the DAgger student."""
    return ARMS[row].start if row in ARMS else "student"




def drive_seeds(seeds: list[int], policy: str, env_id: str, env_kwargs: dict, deterministic: bool = True,
                shield: dict | None = None) -> list[dict]:
    """``policy``'s episodes on the contiguous ``seeds`` in this process (:func:`agents.evaluate.evaluate`'s runs)."""
    from agents.evaluate import evaluate

    s = evaluate(policy, env_id, len(seeds), seeds[0], env_kwargs, progress=False, deterministic=deterministic,
                 shield=shield)
    return s["runs"]


def run_policy(policy: str, env_id: str, env_kwargs: dict, seeds: list[int], workers: int,
               deterministic: bool = True, shield: dict | None = None) -> list[dict]:
    """Episodes on ``seeds`` (contiguous), split over ``workers`` processes; greedy actions, or (``deterministic``
    False) sampled, seeded by each episode's seed; ``shield`` (a :class:`agents.policies.shield.ShieldConfig` as a dict) in
    place of the shield saved beside the policy (None: as its record says)."""
    return map_seeds(drive_seeds, seeds, workers, policy, env_id, env_kwargs, deterministic, shield)


def arm_policies(rows: tuple[str, ...], ship_dir: Path = SHIPPED_DIR) -> dict[str, Path]:
    """The policy file of each row: a start's, else the arm's zip in ``ship_dir``."""
    return {row: STARTS[row] if row in STARTS else ship_dir / f"{row}.zip" for row in rows}


def drive_arm(arm: str, seeds: list[int], workers: int, ship_dir: Path = SHIPPED_DIR, deterministic: bool = True,
              shield: dict[str, Any] | None = None) -> list[dict]:
    """The arm's zip in ``ship_dir`` on ``seeds``, on its saved env; greedy or sampled actions, behind ``shield``
    (None: the shield its record keeps; :func:`run_policy`)."""
    path = str(ship_dir / f"{arm}.zip")
    env_id, kwargs = resolve_env(path)
    return run_policy(path, env_id, kwargs, seeds, workers, deterministic, shield)


def targets(rows: dict[str, dict[str, Any]], runs: dict[str, list[dict]], arm: str = "finetune",
            control: str | None = "dagger_continue") -> dict[str, Any]:
    """The fine-tune's targets against IDM + MOBIL, its start (:func:`start_of`) and the DAgger continuation
    ``control`` (None: none): :data:`TARGET_VS_IDM` and the other ``TARGET_`` constants."""
    if arm not in rows:
        return {}
    s = rows[arm]
    gain = paired(runs[arm], runs[start_of(arm)])
    out: dict[str, Any] = {
        "arm": arm, "control": control,
        "return_vs_idm": s["return"]["mean"] / rows["idm"]["return"]["mean"],
        "collision_rate": s["collision_rate"],
        "mean_speed_mps": s["mean_speed_mps"]["mean"],
        "gain_over_student": gain,
    }
    if control in runs:
        out["gain_over_control"] = paired(runs[arm], runs[control])
    out["met"] = {
        "return_vs_idm": out["return_vs_idm"] >= TARGET_VS_IDM,
        "collisions": s["collision_rate"] <= TARGET_COLLISIONS,
        "mean_speed": out["mean_speed_mps"] >= TARGET_SPEED_MPS,
        "gain_over_student": gain["mean"] >= TARGET_GAIN and gain["low"] > 0,
        "beats_control": ("gain_over_control" in out and out["gain_over_control"]["low"] > 0),
    }
    return out


#: the scripted references: name -> (policy, whether it drives with the students' action set). Always SLOWER and
#: IDM with highway-env's own action set, as the driving targets were set; the teachers with the students' target
#: speeds, as they taught them
SCRIPTED: dict[str, tuple[str, bool]] = {"slower": (f"constant:{SLOWER}", False), "idm": ("idm", False),
                                         "headway": ("headway:5", True), "lookahead": ("lookahead:5", True)}


def scripted_kwargs(name: str) -> dict[str, Any]:
    """The env kwargs of the scripted reference ``name`` on ``rhs-highway-v0`` (:data:`SCRIPTED`)."""
    if not SCRIPTED[name][1]:
        return {}
    _, student_kwargs = resolve_env(str(STUDENT))
    return {"action": student_kwargs.get("action")} if "action" in student_kwargs else {}


def evaluate_rows(policies: dict[str, Path], seeds: list[int], workers: int,
                  skip: tuple[str, ...] = ()) -> dict[str, list[dict]]:
    """Every learned policy on the SLAM env and the scripted references on the ground-truth env, same seeds
    (the rows named in ``skip`` left out)."""
    scripted = {k: (SCRIPTED[k][0], scripted_kwargs(k)) for k in SCRIPTED if k not in skip}
    runs: dict[str, list[dict]] = {}
    for key, path in {k: v for k, v in policies.items() if k not in skip}.items():
        env_id, kwargs = resolve_env(str(path))
        t0 = time.perf_counter()
        runs[key] = run_policy(str(path), env_id, kwargs, seeds, workers)
        print(f"rl_finetune: {key}: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    for key, (policy, kwargs) in scripted.items():
        runs[key] = run_policy(policy, "rhs-highway-v0", kwargs, seeds, workers)
    return runs


def drive_row(name: str, seeds: list[int], workers: int, ship_dir: Path = SHIPPED_DIR, deterministic: bool = True,
              shield_changes: Mapping[str, Any] | None = None, episode_s: float | None = None) -> list[dict]:
    """One row of a comparison on ``seeds``: a scripted reference (:data:`SCRIPTED`) on ``rhs-highway-v0``, else a
    start or a shipped arm (:func:`arm_policies`) on its saved env, greedy or sampled, behind the shield its record
    keeps with ``shield_changes`` (None: as saved); ``episode_s``: the episode's duration (None: the env's).

    Args:
        name: a key of :data:`SCRIPTED`, :data:`STARTS` or :data:`ARMS`.
        seeds: contiguous episode seeds.
        workers: processes.
        ship_dir: where the arms' zips are.
        deterministic: greedy actions (False: sampled, seeded by the episode's seed).
        shield_changes: fields of the saved shield changed.
        episode_s: the env's ``duration``.

    Returns:
        The episodes, in seed order.
    """
    short = {} if episode_s is None else {"duration": episode_s}
    if name in SCRIPTED:
        return run_policy(SCRIPTED[name][0], "rhs-highway-v0", {**scripted_kwargs(name), **short}, seeds, workers)
    path = str(arm_policies((name,), ship_dir)[name])
    env_id, kwargs = resolve_env(path)
    shield = None
    if shield_changes:
        from agents.evaluate import policy_metadata

        shield = {**policy_metadata(path)["shield"], **shield_changes}
    return run_policy(path, env_id, {**kwargs, **short}, seeds, workers, deterministic, shield)


SLIM_KEYS = ("seed", "return", "steps", "crashed", "mean_speed", "position_rmse_m")


def rl_fingerprint() -> list[float]:
    """The starts and each shipped arm, one 2-second episode (10 steps) on seed 3000 (the other zips beside the
    arms are not this study's)."""
    out: list[float] = []
    for path in [*STARTS.values(), *sorted(p for p in SHIPPED_DIR.glob("*.zip") if p.stem in ARMS)]:
        env_id, kwargs = resolve_env(str(path))
        run = run_policy(str(path), env_id, {**kwargs, "duration": 2}, [3000], 1)[0]
        out += [float(run[k]) for k in SLIM_KEYS[1:] if isinstance(run.get(k), (int, float))]
    return out



@dataclass(frozen=True)
class DriveOptions:
    """The options every driving study shares: workers and folders."""

    workers: int = option(2)
    ship_dir: Path = option(SHIPPED_DIR, "the RL study's shipped arms")
    out_dir: Path = option(ROOT / "results")


@dataclass(frozen=True)
class FreshSeeds(DriveOptions):
    """The options of a study on fresh seeds (:mod:`rhs_studies.driving.rl_confirm`,
    :mod:`rhs_studies.driving.rl_lane_rule_trial`): :class:`DriveOptions` and its validation and test seeds;
    ``ValueError`` when a set has fewer than two episodes or the sets overlap."""

    validation_seed: int = option(first("rl_confirm_validation"), "first validation seed (the choice)")
    validation_episodes: int = option(100)
    seed: int = option(first("rl_confirm_test"), "first test seed")
    episodes: int = option(100, "test episodes")

    def __post_init__(self) -> None:
        if self.episodes < 2 or self.validation_episodes < 2:
            raise ValueError("--episodes and --validation-episodes must be >= 2 (intervals need two episodes)")
        val, test = self.seed_sets()
        if set(val) & set(test):
            raise ValueError(f"the validation seeds {val[0]}-{val[-1]} overlap the test seeds {test[0]}-{test[-1]}")

    def seed_sets(self) -> tuple[list[int], list[int]]:
        """The validation and the test seeds."""
        return consecutive(self.validation_seed, self.validation_episodes), consecutive(self.seed, self.episodes)


def check_zips(ship_dir: Path, arms: list[str]) -> None:
    """``ValueError`` when an arm of ``arms`` has no zip in ``ship_dir``."""
    missing = [a for a in arms if not (Path(ship_dir) / f"{a}.zip").exists()]
    if missing:
        raise ValueError(f"no shipped zip for {missing} in {ship_dir}: run scripts/rl_finetune.py first")


__all__ = ["ALGOS", "ANTENNA_STUDY", "ARMS", "Arm", "DATA", "DENSE_ID", "DriveOptions", "ENV_ID", "FINE_SPEEDS",
           "FreshSeeds", "HYPERPARAMS", "KINEMATICS_ALL_AROUND", "LABELS", "SCRIPTED", "SHIELD_ARMS",
           "SHIELD_CONTROL", "SHIPPED", "SHIPPED_DIR", "SHIPPED_START", "SLAM_ENV_KWARGS", "SLAM_ID", "SLIM_KEYS",
           "STARTS", "STUDENT", "TARGETS", "TARGET_COLLISIONS", "TARGET_GAIN", "TARGET_SPEED_MPS", "TARGET_VS_IDM",
           "TRUTH_ID", "arm_policies", "check_zips", "drive_arm", "drive_row", "drive_seeds", "evaluate_rows",
           "rl_fingerprint", "run_policy", "scripted_kwargs", "start_of", "target_path", "targets"]
