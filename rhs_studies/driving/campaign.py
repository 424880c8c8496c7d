"""A resumable training campaign: a recipe trained on the fast SLAM env over sessions, a chunk of env steps at a
time, each chunk committed as a small checkpoint, the checkpoint kept for evaluation chosen on validation seeds.

A **recipe** (:data:`RECIPES`) fixes the algorithm (stable-baselines3 PPO), its hyperparameters, the env
(``rhs-highway-slam-fast-v0`` by default) and its kwargs, the decision interval, and the start: from scratch, or
from an imitation student's weights (imitation + RL). A **run** is a recipe and a training seed ``k``; it lives
in ``<root>/<recipe>/seed<k>/``:

* ``model.zip``: the latest policy with its optimizer state (stable-baselines3's zip: ``policy.pth`` and
  ``policy.optimizer.pth``), and ``model.json`` beside it (the record :func:`agents.evaluate.load_policy` reads);
* ``best.zip`` / ``best.json``: the checkpoint with the highest mean validation return so far;
* ``chosen.zip`` / ``chosen.json``: the checkpoint to evaluate, :func:`select_checkpoint`'s pick between ``best.zip``
  and the latest on more validation seeds (5 seeds per chunk make the best a lucky draw too);
* ``state.json``: the env steps and decisions trained, the chunks, the training wall and CPU time (the CPU
  seconds of this process: on a shared machine, steps per CPU second is the rate one free core would give), the RNG states
  (torch, numpy, Python) at the end of the last chunk, and the learning curve: per chunk, the env steps, the
  cumulative wall seconds, the training episodes' mean return / crash rate, and the validation return, collisions
  and mean speed.

One **chunk** (:func:`train_chunk`) loads the run (or creates it), restores the RNG states, makes the native vector
env (``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` through
:func:`rhs_env.vector_native.to_sb3`; with a decision interval ``k > 1`` its envs are wrapped in
:class:`agents.policies.decision.HoldAction`), resets its env ``i`` with seed ``s_c + i`` (``s_c`` from
:func:`training_seed`: the campaign's training seeds), trains ``chunk_steps`` env steps (PPO rounds them up to
whole rollouts), validates the policy on the validation seeds, and writes the files atomically. SIGINT / SIGTERM
stop at the next rollout boundary (:class:`agents.algos.resume.InterruptGuard`) and the run is saved where it stands; a
second signal exits at once, the files of the last finished chunk intact. The same chunks give the same
weights wherever they run (one process per chunk, each from the saved state): a campaign grows by sessions.

The **curves** (:func:`curves`) put the runs of a recipe on a common grid of env steps and give the mean, min and
max over the training seeds, against env steps and against the wall-clock seconds.

    python scripts/campaign.py train --recipe ppo_scratch --seeds 0 1 2 --steps 40000 --chunk 4096
    python scripts/campaign.py select --recipe ppo_scratch --seeds 0 1 2
    python scripts/campaign.py curves --recipe ppo_scratch
"""

from __future__ import annotations

import base64
import json
import os
import random
import shutil
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rhs_common.validation import check_int
from rhs_env.registration import HIGHWAY_SLAM_FAST_ID, HIGHWAY_SLAM_ID

__all__ = ["CAMPAIGN_DIR", "RECIPES", "Recipe", "chosen_policy", "curves", "exact_env_kwargs", "load_state",
           "new_model", "run_dir",
           "select_checkpoint", "train_chunk", "train_campaign", "training_seed", "validation_seeds"]

#: where the campaign's checkpoints live: ``campaign/`` of the repository (committed, small, and not in the wheel:
#: they are a study's state, not a policy the package ships)
CAMPAIGN_DIR = Path(__file__).resolve().parents[2] / "campaign"
#: the campaign's env settings: the students' five target speeds 10-30 m/s (agents/data/rl/*.json) on the default
#: radar (the fast radar ships the default radar's calibration only; the students' 5 degree scan grid would need
#: ``radar_model="fast-calibrate"``, :mod:`rhs_env.fast_radar`)
CAMPAIGN_ENV_KWARGS: dict[str, Any] = {"action": {"type": "DiscreteMetaAction", "target_speeds": [10, 15, 20, 25, 30]}}
#: the students' own settings (their radar: a 5 degree scan grid)
STUDENT_ENV_KWARGS: dict[str, Any] = {**CAMPAIGN_ENV_KWARGS, "radar": {"scan": {"grid_deg": 5}}}
POINT_SET_KWARGS = ("dict(features_extractor_class=importlib.import_module('agents.features').PointSetExtractor, "
                    "features_extractor_kwargs=dict(point_dim=64, box_dim=32), net_arch=[64, 64])")


@dataclass(frozen=True)
class Recipe:
    """One training recipe of the campaign (frozen: a run's recipe is its name's).

    Attributes:
        name: the recipe's name (its folder).
        env_id: the training env (the fast SLAM env).
        eval_env_id: the exact env the policy is judged on (its record's ``env_id``).
        env_kwargs: both envs' kwargs.
        n_envs: envs of the native vector env.
        decision_interval: env steps per decision (``k``); ``decision_mode`` ``"hold"`` or ``"pulse"`` (IDLE between).
        hyperparams: stable-baselines3 PPO's arguments (``policy_kwargs`` as the zoo-style string).
        init_policy: a student zip (a PPO policy) whose weights start the run (imitation + RL), or None (scratch).
        deterministic: validation drives the greedy policy (True) or samples it.
        reward_shaping: the training reward's shaping (:class:`agents.algos.shaping.ShapingConfig` as a dict: a
            time-to-collision penalty, a crash penalty), or None for highway-env's reward. Only the training envs
            are shaped: validation, selection and every evaluation keep highway-env's reward; the training
            episodes' returns of the learning curve are the shaped ones.
    """

    name: str
    env_id: str = HIGHWAY_SLAM_FAST_ID
    eval_env_id: str = HIGHWAY_SLAM_ID
    env_kwargs: Mapping[str, Any] = field(default_factory=lambda: dict(CAMPAIGN_ENV_KWARGS))
    n_envs: int = 2
    decision_interval: int = 5
    decision_mode: str = "pulse"
    hyperparams: Mapping[str, Any] = field(default_factory=dict)
    init_policy: str | None = None
    deterministic: bool = True
    reward_shaping: Mapping[str, Any] | None = None

    def __post_init__(self) -> None:
        from agents.policies.decision import check_decision_interval, check_decision_mode

        if not self.name or "/" in self.name:
            raise ValueError(f"recipe.name must be a non-empty folder name, got {self.name!r}")
        check_int("recipe.n_envs", self.n_envs, 1, 64)
        check_decision_interval(self.decision_interval)
        check_decision_mode(self.decision_mode)
        unknown = set(self.hyperparams) - set(PPO_DEFAULTS)
        if unknown:
            raise ValueError(f"recipe.hyperparams: unknown {sorted(unknown)}; allowed {sorted(PPO_DEFAULTS)}")
        if self.reward_shaping is not None:
            self.shaping_config()  # a wrong value raises here, naming recipe.reward_shaping's field

    def shaping_config(self) -> Any:
        """The training reward's :class:`agents.algos.shaping.ShapingConfig`, None without shaping."""
        if self.reward_shaping is None:
            return None
        from agents.algos.shaping import ShapingConfig
        from rhs_common.validation import build

        return build(ShapingConfig, dict(self.reward_shaping), "recipe.reward_shaping")

    def ppo_args(self) -> dict[str, Any]:
        """PPO's keyword arguments: :data:`PPO_DEFAULTS` under the recipe's, ``policy_kwargs`` evaluated."""
        from agents.algos.hyperparams import resolve_policy_kwargs

        args = {**PPO_DEFAULTS, **self.hyperparams}
        args["policy_kwargs"] = resolve_policy_kwargs(args["policy_kwargs"])
        return args

    def eval_env_kwargs(self) -> dict[str, Any]:
        """The kwargs of the exact env the policy is judged on: :attr:`env_kwargs` without ``radar_model`` (a fast
        radar setting such as ``"fast-calibrate"`` would turn the exact id's radar into the fast one)."""
        return exact_env_kwargs(self.env_kwargs)

    def record(self) -> dict[str, Any]:
        """The recipe as JSON."""
        return {**asdict(self), "env_kwargs": dict(self.env_kwargs), "hyperparams": dict(self.hyperparams),
                "reward_shaping": None if self.reward_shaping is None else dict(self.reward_shaping)}


#: PPO's settings for the campaign (those of the shipped PPO-from-scratch arm, agents/data/rl/scratch.json, without
#: its fine-tuning extras): 1 Hz decisions (5 env steps, IDLE pulses between), gamma 0.8 over decisions
PPO_DEFAULTS: dict[str, Any] = {"n_steps": 64, "batch_size": 64, "n_epochs": 5, "learning_rate": 5.0e-4,
                                "gamma": 0.8, "gae_lambda": 0.9, "clip_range": 0.2, "ent_coef": 0.01,
                                "policy_kwargs": POINT_SET_KWARGS}
#: the campaign's recipes
RECIPES: dict[str, Recipe] = {
    "ppo_scratch": Recipe("ppo_scratch"),
    # the DAgger student (its radar: the fast radar calibrates its 5 degree grid once, into the user cache)
    "ppo_student": Recipe("ppo_student", init_policy="agents/data/dagger_rhs_highway_slam.zip",
                          env_kwargs={**STUDENT_ENV_KWARGS, "radar_model": "fast-calibrate"},
                          hyperparams={"ent_coef": 0.0, "learning_rate": 1.0e-4}),
    # the same start, trained on a reward that prices the crash (agents.algos.shaping: the break-even crash hazard
    # of a speed gain falls from ~4.6 % to ~0.13 % per decision) and looks further ahead (gamma 0.95: 20 decisions)
    "ppo_student_safe": Recipe("ppo_student_safe", init_policy="agents/data/dagger_rhs_highway_slam.zip",
                               env_kwargs={**STUDENT_ENV_KWARGS, "radar_model": "fast-calibrate"},
                               hyperparams={"ent_coef": 0.0, "learning_rate": 1.0e-4, "gamma": 0.95},
                               reward_shaping={"ttc_s": 3.0, "weight": 0.5, "crash_penalty": 500.0}),
}
def exact_env_kwargs(kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """``kwargs`` for an exact id: without ``radar_model`` (the fast radar's setting; on an exact id it would select
    the fast radar)."""
    return {k: v for k, v in kwargs.items() if k != "radar_model"}


#: first seed of the campaign's training envs: run k, chunk c resets env i with FIRST + k * PER_RUN + c * n_envs + i
TRAINING_SEED_FIRST, TRAINING_SEED_PER_RUN = 1_000_000, 1_000_000


def training_seed(run_seed: int, chunk: int, n_envs: int) -> int:
    """The reset seed of chunk ``chunk`` of run ``run_seed`` (its env ``i`` gets this + ``i``): in the ledger's
    ``campaign_training`` set, disjoint between runs (:data:`TRAINING_SEED_PER_RUN` seeds each)."""
    check_int("seed", run_seed, 0, 90)
    seed = TRAINING_SEED_FIRST + run_seed * TRAINING_SEED_PER_RUN + chunk * n_envs
    if chunk * n_envs + n_envs > TRAINING_SEED_PER_RUN:
        raise ValueError(f"chunk {chunk} of run {run_seed} runs past its {TRAINING_SEED_PER_RUN} training seeds")
    return seed


def validation_seeds(episodes: int) -> list[int]:
    """The first ``episodes`` seeds of the ledger's ``campaign_validation`` set (the checkpoints are chosen on them)."""
    from rhs_studies.kit.seeds import seed_set

    seeds = seed_set("campaign_validation").seeds
    check_int("validation_episodes", episodes, 1, len(seeds))
    return seeds[:episodes]


def run_dir(root: str | Path, recipe: str, seed: int) -> Path:
    """``<root>/<recipe>/seed<seed>``."""
    return Path(root) / recipe / f"seed{seed}"


def load_state(folder: str | Path) -> dict[str, Any] | None:
    """A run's ``state.json`` (None when the run has not started)."""
    path = Path(folder) / "state.json"
    return json.loads(path.read_text()) if path.exists() else None


# ----------------------------------------------------------------------------------------------- RNG state
def _rng_state() -> dict[str, Any]:
    """torch's, numpy's global and Python's RNG states, JSON-ready."""
    import torch

    kind, keys, pos, has_gauss, cached = np.random.get_state()  # noqa: NPY002  (SB3 seeds the legacy state)
    py = random.getstate()
    return {"torch": base64.b64encode(torch.get_rng_state().numpy().tobytes()).decode(),
            "numpy": [kind, np.asarray(keys).tolist(), int(pos), int(has_gauss), float(cached)],
            "python": [py[0], list(py[1]), py[2]]}


def _set_rng_state(state: Mapping[str, Any]) -> None:
    """Restore :func:`_rng_state`'s states."""
    import torch

    torch.set_rng_state(torch.from_numpy(np.frombuffer(base64.b64decode(state["torch"]), dtype=np.uint8).copy()))
    kind, keys, pos, has_gauss, cached = state["numpy"]
    np.random.set_state((kind, np.asarray(keys, dtype=np.uint32), pos, has_gauss, cached))  # noqa: NPY002
    py = state["python"]
    random.setstate((py[0], tuple(py[1]), py[2]))


# ----------------------------------------------------------------------------------------------- envs and model
def make_train_env(recipe: Recipe) -> Any:
    """The stable-baselines3 ``VecEnv`` of ``recipe``: the native vector env (``SAME_STEP`` autoreset) through
    :func:`rhs_env.vector_native.to_sb3`, under a ``VecMonitor`` (episode returns and lengths, ``crashed``)."""
    import gymnasium as gym
    from stable_baselines3.common.vec_env import VecMonitor

    import rhs_env  # noqa: F401
    from rhs_env.vector_native import RhsVectorEnv, to_sb3

    kwargs = dict(recipe.env_kwargs)
    shaping = recipe.shaping_config()
    vec: Any
    if recipe.decision_interval == 1 and shaping is None:
        vec = gym.make_vec(recipe.env_id, num_envs=recipe.n_envs, vectorization_mode="vector_entry_point",
                           autoreset_mode="SameStep", **kwargs)
    else:  # the entry point builds plain envs; the shaping and the held action wrap each one (same envs, seeds)
        from agents.algos.shaping import RewardShaping
        from agents.policies.decision import HoldAction, fill_action

        def make_one() -> gym.Env:
            env: gym.Env = gym.make(recipe.env_id, **kwargs)
            if shaping is not None:
                env = RewardShaping(env, shaping)
            if recipe.decision_interval > 1:
                env = HoldAction(env, recipe.decision_interval, fill_action(recipe.decision_mode))
            return env
        vec = RhsVectorEnv([make_one] * recipe.n_envs, autoreset_mode="SameStep")
    return VecMonitor(to_sb3(vec), info_keywords=("crashed",))


def new_model(recipe: Recipe, venv: Any, seed: int) -> Any:
    """A PPO model for ``recipe`` (``init_policy``: its weights loaded from the student's zip)."""
    from stable_baselines3 import PPO

    model = PPO("MultiInputPolicy", venv, seed=seed, verbose=0, device="cpu", **recipe.ppo_args())
    if recipe.init_policy is not None:
        student = PPO.load(recipe.init_policy, device="cpu")
        model.policy.load_state_dict(student.policy.state_dict())
    return model


def _load_model(path: Path, venv: Any) -> Any:
    from stable_baselines3 import PPO

    return PPO.load(path, env=venv, device="cpu")


# ----------------------------------------------------------------------------------------------- one chunk
def _validate(model: Any, recipe: Recipe, seeds: list[int]) -> dict[str, Any]:
    """Mean return, collisions and mean speed of ``model`` on the fast env over ``seeds`` (one episode each)."""
    import gymnasium as gym

    from agents.evaluate import run_episode
    from agents.policies.decision import held

    env = gym.make(recipe.env_id, **dict(recipe.env_kwargs))
    try:
        policy = held(model, recipe.decision_interval, recipe.decision_mode)
        runs = [run_episode(env, policy, s, deterministic=recipe.deterministic) for s in seeds]
    finally:
        env.close()
    speeds = [r["mean_speed"] for r in runs if r["mean_speed"] is not None]
    return {"episodes": len(runs), "return": float(np.mean([r["return"] for r in runs])),
            "returns": [round(float(r["return"]), 4) for r in runs],
            "collisions": int(sum(bool(r["crashed"]) for r in runs)),
            "mean_speed": float(np.mean(speeds)) if speeds else None}


def _episodes_of(venv: Any) -> dict[str, Any]:
    """The training episodes the ``VecMonitor`` finished in this chunk (mean return, crash rate, count)."""
    infos = list(getattr(venv, "_campaign_episodes", []))
    if not infos:
        return {"episodes": 0, "return": None, "crash_rate": None}
    return {"episodes": len(infos), "return": float(np.mean([e["r"] for e in infos])),
            "crash_rate": float(np.mean([bool(e.get("crashed", False)) for e in infos]))}


def _episode_logger() -> Any:
    """A callback that keeps each finished training episode's ``info["episode"]`` on the env (for the curve)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class EpisodeLog(BaseCallback):
        def _on_training_start(self) -> None:
            self.training_env._campaign_episodes = []  # type: ignore[attr-defined]

        def _on_step(self) -> bool:
            for info in self.locals.get("infos", []):
                if "episode" in info:
                    self.training_env._campaign_episodes.append(  # type: ignore[attr-defined]
                        {**info["episode"], "crashed": bool(info.get("crashed", False))})
            return True
    return EpisodeLog()


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _save_zip(model: Any, path: Path) -> None:
    tmp = path.with_name(path.stem + ".tmp.zip")
    model.save(tmp)
    os.replace(tmp, path)


def _policy_record(recipe: Recipe, seed: int, state: Mapping[str, Any], model_path: Path) -> dict[str, Any]:
    """The record beside a campaign zip (what :func:`agents.evaluate.load_policy` / ``resolve_env`` read)."""
    return {"algo": "ppo", "env_id": recipe.eval_env_id, "train_env_id": recipe.env_id,
            "env_kwargs": recipe.eval_env_kwargs(), "train_env_kwargs": dict(recipe.env_kwargs),
            "policy": "MultiInputPolicy",
            "decision_interval": recipe.decision_interval, "decision_mode": recipe.decision_mode,
            "recipe": recipe.name, "seed": seed, "timesteps": int(state["env_steps"]),
            "train_wall_s": round(float(state["train_wall_s"]), 1), "commit": state.get("commit"),
            "model": model_path.name}  # beside this record: the run folder moves with the repo


def train_chunk(recipe: Recipe, root: str | Path, seed: int, chunk_steps: int, validation_episodes: int = 5,
                guard: Any = None) -> dict[str, Any]:
    """Train run ``(recipe, seed)`` in ``root`` for ``chunk_steps`` more env steps, validate it, save it.

    Args:
        recipe: the recipe.
        root: the campaign folder (the run is ``root/<recipe>/seed<seed>``).
        seed: the training seed (the model's seed, and the env seeds through :func:`training_seed`).
        chunk_steps: env steps to add (rounded up by PPO to whole rollouts of ``n_steps x n_envs`` decisions).
        validation_episodes: validation seeds driven after the chunk (:func:`validation_seeds`).
        guard: an :class:`agents.algos.resume.InterruptGuard` (None: one of its own for the chunk).

    Returns:
        The run's new state (``state.json``); ``state["interrupted"]`` True when a signal cut the chunk short.
    """
    from agents.algos.resume import InterruptGuard, StopOnSignal
    from rhs_studies.kit.provenance import git_state

    check_int("chunk_steps", chunk_steps, 1, 10**9)
    folder = run_dir(root, recipe.name, seed)
    folder.mkdir(parents=True, exist_ok=True)
    state = load_state(folder) or {"recipe": recipe.record(), "seed": seed, "env_steps": 0, "decisions": 0,
                                   "chunks": 0, "train_wall_s": 0.0, "curve": [], "best": None, "rng": None}
    if state["recipe"]["name"] != recipe.name or state["seed"] != seed:
        raise ValueError(f"{folder}/state.json is run {state['recipe']['name']} seed {state['seed']}, not "
                         f"{recipe.name} seed {seed}")
    t0, before = time.perf_counter(), int(state["env_steps"])
    venv = make_train_env(recipe)
    own = guard is None
    guard = InterruptGuard("campaign") if own else guard
    try:
        if own:
            guard.__enter__()
        model = _load_model(folder / "model.zip", venv) if state["chunks"] else new_model(recipe, venv, seed)
        if state["rng"] is not None:
            _set_rng_state(state["rng"])
        venv.seed(training_seed(seed, state["chunks"], recipe.n_envs))
        stopper = StopOnSignal(guard)
        decisions = -(-chunk_steps // recipe.decision_interval)
        t_learn, cpu_learn = time.perf_counter(), time.process_time()
        model.learn(total_timesteps=decisions, callback=[_episode_logger(), stopper], reset_num_timesteps=False)
        learn_s, learn_cpu_s = time.perf_counter() - t_learn, time.process_time() - cpu_learn
        training = _episodes_of(venv)
    finally:
        venv.close()
        if own:
            guard.__exit__()
    if stopper.stopped and int(model.num_timesteps) == state["decisions"]:  # nothing trained: the run stays as it was
        return {**state, "interrupted": True}
    state["rng"] = _rng_state()
    state["decisions"] = int(model.num_timesteps)
    state["env_steps"] = state["decisions"] * recipe.decision_interval
    state["chunks"] += 1
    state["train_wall_s"] += learn_s
    state["train_cpu_s"] = state.get("train_cpu_s", 0.0) + learn_cpu_s
    state["commit"] = git_state()["commit"]
    validation = _validate(model, recipe, validation_seeds(validation_episodes))
    state["curve"].append({"chunk": state["chunks"], "env_steps": state["env_steps"],
                           "train_wall_s": round(state["train_wall_s"], 2), "chunk_wall_s": round(time.perf_counter()
                                                                                                    - t0, 2),
                           "steps_per_s": round((state["env_steps"] - before) / max(learn_s, 1e-9), 2),
                           "steps_per_cpu_s": round((state["env_steps"] - before) / max(learn_cpu_s, 1e-9), 2),
                           "training": training,
                           "validation": validation, "commit": state["commit"]})
    _save_zip(model, folder / "model.zip")
    _write_atomic(folder / "model.json", json.dumps(_policy_record(recipe, seed, state, folder / "model.zip"),
                                                    indent=1))
    if state["best"] is None or validation["return"] > state["best"]["validation_return"]:
        shutil.copyfile(folder / "model.zip", folder / "best.tmp.zip")
        os.replace(folder / "best.tmp.zip", folder / "best.zip")
        state["best"] = {"env_steps": state["env_steps"], "chunk": state["chunks"],
                         "validation_return": validation["return"], "validation_collisions": validation["collisions"]}
        _write_atomic(folder / "best.json", json.dumps(_policy_record(recipe, seed, state, folder / "best.zip"),
                                                       indent=1))
    state["interrupted"] = bool(stopper.stopped)
    _write_atomic(folder / "state.json", json.dumps(state, indent=1))
    return state


def train_campaign(recipe: Recipe, root: str | Path, seeds: list[int], total_steps: int, chunk_steps: int,
                   validation_episodes: int = 5, deadline: float | None = None,
                   log: Any = print) -> dict[int, dict[str, Any]]:
    """Round-robin chunks over ``seeds`` until each run has ``total_steps`` env steps or ``deadline``
    (``time.time()``) would pass (a chunk starts only when the previous chunk's wall time still fits).

    Returns:
        Each seed's state after its last chunk of this call.
    """
    from agents.algos.resume import InterruptGuard

    states = {s: load_state(run_dir(root, recipe.name, s)) or {"env_steps": 0} for s in seeds}
    last_chunk_s = 0.0
    with InterruptGuard("campaign") as guard:
        while guard.requested is None:
            todo = [s for s in seeds if states[s]["env_steps"] < total_steps]
            if not todo:
                break
            seed = min(todo, key=lambda s: (states[s]["env_steps"], s))
            if deadline is not None and time.time() + last_chunk_s > deadline:
                log(f"campaign: deadline: stopping before seed {seed}'s next chunk")
                break
            t = time.time()
            states[seed] = train_chunk(recipe, root, seed, min(chunk_steps, total_steps - states[seed]["env_steps"]),
                                       validation_episodes, guard)
            last_chunk_s = time.time() - t
            v = states[seed]["curve"][-1]
            log(f"campaign: {recipe.name} seed {seed}: {states[seed]['env_steps']} env steps, "
                f"validation return {v['validation']['return']:.2f} ({v['validation']['collisions']} collisions), "
                f"{v['steps_per_s']:.1f} steps/s, chunk {last_chunk_s:.0f} s")
    return states


# ----------------------------------------------------------------------------------------------- selection
#: validation seeds :func:`select_checkpoint` drives each candidate on (the chunks' own validation: the first 5)
SELECT_EPISODES = 50


def select_checkpoint(recipe: Recipe, root: str | Path, seed: int, episodes: int = SELECT_EPISODES) -> dict[str, Any]:
    """Choose run ``(recipe, seed)``'s checkpoint for evaluation on ``episodes`` validation seeds.

    ``best.zip`` won its chunk's validation on 5 seeds: over many chunks the maximum of a noisy score favours luck
    (the winner's curse). The selection drives the candidates, ``best.zip`` and the latest ``model.zip`` (one
    candidate when they are the same chunk), on the first ``episodes`` validation seeds of the ledger and keeps the
    one of highest mean return (fewer collisions break a tie) as ``chosen.zip`` / ``chosen.json``. The record says
    at which env steps the run stood (``selected_at_env_steps``): a chunk trained after it makes it stale
    (:func:`chosen_policy` refuses it).

    Returns:
        The selection: per candidate its env steps and validation (return, collisions, mean speed), the winner.
    """
    from stable_baselines3 import PPO

    folder = run_dir(root, recipe.name, seed)
    state = load_state(folder)
    if state is None or state["best"] is None:
        raise FileNotFoundError(f"{folder}: no trained run to select from (scripts/campaign.py train first)")
    candidates = {"best": int(state["best"]["env_steps"]), "final": int(state["env_steps"])}
    if candidates["best"] == candidates["final"]:
        del candidates["final"]
    seeds = validation_seeds(episodes)
    scores = {}
    for name, steps in candidates.items():
        model = PPO.load(folder / ("best.zip" if name == "best" else "model.zip"), device="cpu")
        scores[name] = {"env_steps": steps, **_validate(model, recipe, seeds)}
    winner = max(scores, key=lambda k: (scores[k]["return"], -scores[k]["collisions"]))
    zip_name = "best" if winner == "best" else "model"
    shutil.copyfile(folder / f"{zip_name}.zip", folder / "chosen.tmp.zip")
    os.replace(folder / "chosen.tmp.zip", folder / "chosen.zip")
    selection = {"episodes": episodes, "seeds": [seeds[0], seeds[-1]], "candidates": scores, "chosen": winner,
                 "selected_at_env_steps": int(state["env_steps"])}
    record = json.loads((folder / f"{zip_name}.json").read_text())
    record.update(model="chosen.zip", selection=selection)
    _write_atomic(folder / "chosen.json", json.dumps(record, indent=1))
    return selection


def chosen_policy(root: str | Path, recipe: str, seed: int) -> Path:
    """The zip of run ``(recipe, seed)`` to evaluate: ``chosen.zip`` (:func:`select_checkpoint`) when the selection
    is current, ``best.zip`` when the run was never selected; ValueError when a chunk was trained after the
    selection (select again), FileNotFoundError when the run has no checkpoint."""
    folder = run_dir(root, recipe, seed)
    sel, state = _selection(folder), load_state(folder)
    if sel is not None and state is not None:
        at = sel["selected_at_env_steps"]
        if at != state["env_steps"]:
            raise ValueError(f"{folder}: the selection was made at {at} env steps, the run has {state['env_steps']}: "
                             f"run scripts/campaign.py select --recipe {recipe} --seeds {seed} again")
        return folder / "chosen.zip"
    if not (folder / "best.zip").exists():
        raise FileNotFoundError(f"{folder / 'best.zip'} not found (train the run first: scripts/campaign.py train)")
    return folder / "best.zip"


# ----------------------------------------------------------------------------------------------- curves
def curves(root: str | Path, recipe: str, seeds: list[int], points: int = 20) -> dict[str, Any]:
    """The learning curves of ``recipe``'s runs ``seeds`` in ``root``: per run, validation return / collisions
    and training return against env steps and wall seconds; over runs, on a common grid of env steps (linear
    interpolation, inside the range every run reached) and of wall seconds, the mean, min and max."""
    runs = {}
    for s in seeds:
        state = load_state(run_dir(root, recipe, s))
        if state is None or not state["curve"]:
            continue
        c = state["curve"]
        runs[s] = {"env_steps": [p["env_steps"] for p in c], "train_wall_s": [p["train_wall_s"] for p in c],
                   "validation_return": [p["validation"]["return"] for p in c],
                   "validation_collisions": [p["validation"]["collisions"] for p in c],
                   "validation_episodes": c[-1]["validation"]["episodes"],
                   "training_return": [p["training"]["return"] for p in c],
                   "training_crash_rate": [p["training"]["crash_rate"] for p in c],
                   "steps_per_s": [p["steps_per_s"] for p in c], "best": state["best"],
                   "selection": _current_selection(root, recipe, s, state)}
    return {"recipe": recipe, "runs": {str(s): r for s, r in runs.items()},
            "by_env_steps": _spread(runs, "env_steps", points), "by_wall_s": _spread(runs, "train_wall_s", points)}


def _current_selection(root: str | Path, recipe: str, seed: int, state: Mapping[str, Any]) -> dict[str, Any] | None:
    """The run's :func:`select_checkpoint` result when it is current (None: never selected, or trained on since)."""
    sel = _selection(run_dir(root, recipe, seed))
    return sel if sel is not None and sel["selected_at_env_steps"] == state["env_steps"] else None


def _selection(folder: Path) -> dict[str, Any] | None:
    """The selection recorded in ``folder/chosen.json`` (None when the run was never selected)."""
    path = folder / "chosen.json"
    return json.loads(path.read_text())["selection"] if path.exists() else None


def _spread(runs: Mapping[int, Mapping[str, Any]], axis: str, points: int) -> dict[str, Any] | None:
    """Mean / min / max over ``runs`` of the validation return on a grid of ``axis`` common to all of them."""
    if not runs:
        return None
    lo = max(r[axis][0] for r in runs.values())
    hi = min(r[axis][-1] for r in runs.values())
    grid = np.linspace(lo, hi, points) if hi > lo else np.asarray([hi])
    ys = np.asarray([np.interp(grid, r[axis], r["validation_return"]) for r in runs.values()])
    return {axis: grid.round(2).tolist(), "mean": ys.mean(axis=0).round(3).tolist(),
            "min": ys.min(axis=0).round(3).tolist(), "max": ys.max(axis=0).round(3).tolist(), "runs": len(runs)}


# ----------------------------------------------------------------------------------------------- command line
def _deadline(text: str | None) -> float | None:
    """``HH:MM`` (UTC, today; tomorrow when already past) as ``time.time()``; None stays None."""
    if not text:
        return None
    from datetime import datetime, timedelta, timezone

    try:
        hh, mm = (int(x) for x in text.split(":"))
        now = datetime.now(timezone.utc)
        when = now.replace(hour=hh, minute=mm, second=0, microsecond=0)
    except ValueError:
        raise ValueError(f"--until must be HH:MM (UTC), got {text!r}") from None
    return (when + timedelta(days=1 if when < now else 0)).timestamp()


def main(argv: list[str] | None = None) -> int:
    """``campaign.py train`` (chunks until ``--steps`` per seed or ``--until``) / ``campaign.py select`` (the
    checkpoint to evaluate, on ``--select-episodes`` validation seeds) / ``campaign.py curves``."""
    import argparse

    from rhs_studies.kit.provenance import write_json

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("command", choices=("train", "select", "curves"))
    ap.add_argument("--recipe", choices=sorted(RECIPES), default="ppo_scratch")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="training seeds")
    ap.add_argument("--steps", type=int, default=2_000_000, help="env steps per run (the campaign's target)")
    ap.add_argument("--chunk", type=int, default=4096, help="env steps per chunk (one checkpoint each)")
    ap.add_argument("--validation-episodes", type=int, default=5, help="train: validation seeds after each chunk")
    ap.add_argument("--select-episodes", type=int, default=SELECT_EPISODES,
                    help="select: validation seeds each candidate checkpoint is driven on")
    ap.add_argument("--until", default=None, help="HH:MM UTC: start no chunk that would end after it")
    ap.add_argument("--root", type=Path, default=CAMPAIGN_DIR)
    ap.add_argument("--out", type=Path, default=None, help="the JSON (curves: default results/campaign_<recipe>.json; "
                    "select: results/campaign_select_<recipe>.json)")
    args = ap.parse_args(argv)
    recipe = RECIPES[args.recipe]
    started = time.time()
    if args.command == "train":
        check_int("--steps", args.steps, 1, 10**9)
        states = train_campaign(recipe, args.root, list(args.seeds), args.steps, args.chunk, args.validation_episodes,
                                _deadline(args.until), log=lambda s: print(s, flush=True))
        print(json.dumps({s: st.get("env_steps") for s, st in states.items()}))
        return 0
    results = Path(__file__).resolve().parents[2] / "results"
    if args.command == "select":
        chosen = {}
        for seed in args.seeds:
            sel = chosen[str(seed)] = select_checkpoint(recipe, args.root, seed, args.select_episodes)
            print(f"campaign: {recipe.name} seed {seed}: chose {sel['chosen']} ("
                  + ", ".join(f"{k} at {c['env_steps']} env steps: {c['return']:.2f}, {c['collisions']} collisions"
                              for k, c in sel["candidates"].items()) + ")", flush=True)
        out = args.out or results / f"campaign_select_{recipe.name}.json"
        write_json(out, {"recipe": recipe.name, "runs": chosen}, "scripts/campaign.py", vars(args), started, argv=argv)
        print(f"wrote {out}")
        return 0
    result = curves(args.root, recipe.name, list(args.seeds))
    out = args.out or results / f"campaign_{recipe.name}.json"
    write_json(out, {"recipe": recipe.record(), **result}, "scripts/campaign.py", vars(args), started,
               argv=argv)
    print(f"wrote {out}")
    return 0
