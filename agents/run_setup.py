"""What a training run is built from, shared by :mod:`agents.train` (PPO / DQN) and :mod:`agents.imitation` (DAgger).

* hyperparameters: ``agents/hyperparams/<algo>.yml`` entries per env id
  (rl-baselines3-zoo style; :func:`load_hyperparams`, :func:`run_settings`);
* vector envs: :func:`make_vec_env` (``SubprocVecEnv`` workers that import the
  rhs ids, ``Monitor`` logging ``crashed``, the decision interval and extra wrappers);
* the run's thread limits (:func:`limit_threads`), argument checks
  (:func:`check_train_args`) and summary files (:func:`write_summary`).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

__all__ = [
    "ALGOS", "EnvFactory", "FORKSERVER_PRELOAD", "HP_NUMBERS", "HP_SCHEDULES", "HYPERPARAMS_DIR", "META_KEYS",
    "RunSettings", "WARM_STEPS", "check_env_kwargs", "check_hyperparams", "check_train_args", "eval_policy_kwargs",
    "limit_threads", "load_hyperparams", "make_vec_env", "metadata_path", "parse_env_kwargs", "policy_kwargs_by_name",
    "resolve_policy_kwargs", "run_record", "run_settings", "run_summary", "shield_setting",
    "start_forkserver_ignoring_sigint", "tensorboard_available", "update_threads_for", "warm_kernels", "worker_env_id",
    "write_summary",
]

ALGOS = ("ppo", "dqn", "dagger", "finetune")
HYPERPARAMS_DIR = Path(__file__).parent / "hyperparams"
#: keys of a hyperparameter entry that are not arguments of the algorithm class
META_KEYS = ("policy", "n_envs", "n_timesteps", "env_kwargs", "decision_interval", "decision_mode")


def load_hyperparams(algo: str, env_id: str, path: str | Path | None = None) -> dict[str, Any]:
    """Hyperparameters for ``env_id`` from a zoo-style YAML file (default: the shipped one for ``algo``)."""
    from rhs_common.input_files import read_yaml
    from rhs_env.registration import check_env_id

    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    check_env_id(env_id)
    path = Path(path) if path else HYPERPARAMS_DIR / f"{algo}.yml"
    if not path.exists():
        raise ValueError(f"hyperparameter file not found: {path}")
    table = read_yaml(path) or {}
    if not isinstance(table, dict):
        raise ValueError(f"{path}: must map env ids to hyperparameter entries, got a {type(table).__name__}")  # noqa: TRY004
    key = env_id.split(":", 1)[-1]
    if key not in table:
        raise ValueError(f"{path} has no hyperparameters for env {key!r} (has: {', '.join(map(str, table))})")
    if not isinstance(table[key], dict):
        raise ValueError(f"{path}: entry {key!r} must be a mapping of hyperparameters, got {table[key]!r}")  # noqa: TRY004
    hp = dict(table[key])
    if "policy" not in hp:
        raise ValueError(f"{path}: entry {key!r} has no 'policy'")
    check_hyperparams(hp, f"{path}: {key}")
    if isinstance(hp.get("policy_kwargs"), str):  # refused here, naming the file, before anything else reads it
        eval_policy_kwargs(hp["policy_kwargs"], f"{path}: {key}.policy_kwargs")
    return hp


#: the numeric hyperparameters (stable-baselines3's PPO / DQN, DAgger's, this project's): integer or not,
#: and the allowed range; a string or a boolean there would fail deep inside the algorithm
HP_NUMBERS: dict[str, tuple[bool, float, float]] = {
    "n_timesteps": (True, 1, 10**9), "n_envs": (True, 1, 256), "n_steps": (True, 1, 10**6),
    "batch_size": (True, 1, 10**6), "n_epochs": (True, 1, 10_000), "gamma": (False, 0.0, 1.0),
    "gae_lambda": (False, 0.0, 1.0), "ent_coef": (False, 0.0, 1.0), "vf_coef": (False, 0.0, 100.0),
    "max_grad_norm": (False, 0.0, 1e6), "buffer_size": (True, 1, 10**9), "learning_starts": (True, 0, 10**9),
    "gradient_steps": (True, -1, 10**6), "target_update_interval": (True, 1, 10**9),
    "exploration_fraction": (False, 0.0, 1.0), "exploration_initial_eps": (False, 0.0, 1.0),
    "exploration_final_eps": (False, 0.0, 1.0), "tau": (False, 0.0, 1.0), "decision_interval": (True, 1, 10_000),
    "iterations": (True, 1, 10_000), "beta_decay": (False, 0.0, 1.0), "epochs": (True, 1, 100_000),
    "class_weight_power": (False, 0.0, 100.0), "anchor_coef": (False, 0.0, 1e3), "anchor_fraction": (False, 0.0, 1.0),
    "anchor_epochs": (True, 0, 100), "prior_steps": (True, 1, 10**7), "critic_warmup_fraction": (False, 0.0, 1.0),
}
#: numbers that may also be written ``lin_<number>`` (a linear schedule down to 0)
HP_SCHEDULES = {"learning_rate": 1.0, "clip_range": 100.0}


def check_hyperparams(hp: dict[str, Any], where: str) -> None:
    """``TypeError`` / ``ValueError`` naming ``where.key`` for a numeric hyperparameter of the wrong type or range."""
    from rhs_common.validation import check_int, check_range

    for key, (integer, low, high) in HP_NUMBERS.items():
        if key in hp and integer:
            check_int(f"{where}.{key}", hp[key], int(low), int(high))
        elif key in hp:
            check_range(f"{where}.{key}", hp[key], low, high)
    for key, high in HP_SCHEDULES.items():
        value = hp.get(key)
        if isinstance(value, str) and value.startswith("lin_"):
            try:
                value = float(value[4:])
            except ValueError:
                raise ValueError(f"{where}.{key} must be a number or 'lin_<number>', got {hp[key]!r}") from None
        if key in hp:
            if isinstance(value, str):
                raise TypeError(f"{where}.{key} must be a number or 'lin_<number>', got {value!r}")
            check_range(f"{where}.{key}", value, 0.0, high, low_open=True)


def parse_env_kwargs(text: str | None) -> dict[str, Any] | None:
    """``--env-kwargs`` JSON -> dict (``None`` when not given); ``ValueError`` naming ``--env-kwargs``."""
    from rhs_common.input_files import parse_json

    if text is None:
        return None
    value = parse_json(text, "--env-kwargs")
    if not isinstance(value, dict):
        raise ValueError(f"--env-kwargs must be a JSON object, got {type(value).__name__}")  # noqa: TRY004
    return value


def metadata_path(policy: str | Path) -> Path:
    """The JSON written beside a policy zip (``model.zip`` -> ``model.json``)."""
    return Path(policy).with_suffix(".json")


def _linear_schedule(initial: float):
    def schedule(progress_remaining: float) -> float:
        return progress_remaining * initial

    return schedule


def _resolve_schedules(hp: dict[str, Any]) -> dict[str, Any]:
    """zoo-style ``"lin_5e-4"`` values -> linear schedules from that value to 0."""
    out = dict(hp)
    for key in ("learning_rate", "clip_range"):
        value = out.get(key)
        if isinstance(value, str):
            if not value.startswith("lin_"):
                raise ValueError(f"{key} must be a number or 'lin_<number>', got {value!r}")
            out[key] = _linear_schedule(float(value[4:]))
    return out


def eval_policy_kwargs(text: str, where: str = "policy_kwargs") -> dict[str, Any]:
    """A zoo-style ``policy_kwargs`` string -> dict, parsed without running it
    (:func:`agents.policy_kwargs.parse_policy_kwargs`: literals, ``dict(...)`` and a fixed set of names such as
    ``nn.ReLU`` or ``importlib.import_module('agents.features').PointSetExtractor``; ``ValueError`` naming
    ``where`` for anything else)."""
    from agents.policy_kwargs import parse_policy_kwargs

    return parse_policy_kwargs(text, where)


def resolve_policy_kwargs(kwargs: dict[str, Any] | str) -> dict[str, Any]:
    from agents.features import FEATURE_EXTRACTORS

    if isinstance(kwargs, str):
        kwargs = eval_policy_kwargs(kwargs)
    kwargs = dict(kwargs or {})
    name = kwargs.get("features_extractor_class")
    if isinstance(name, str):
        if name not in FEATURE_EXTRACTORS:
            raise ValueError(f"features_extractor_class must be one of {list(FEATURE_EXTRACTORS)}, got {name!r}")
        kwargs["features_extractor_class"] = FEATURE_EXTRACTORS[name]
    return kwargs


def policy_kwargs_by_name(kwargs: dict[str, Any] | str) -> dict[str, Any]:
    """``policy_kwargs`` with the extractor by its registered name (``"point_set"``), as the RLlib backend takes it.

    The shipped YAML writes it as rl-baselines3-zoo's Python expression naming the class.
    """
    from agents.features import FEATURE_EXTRACTORS

    kwargs = dict(eval_policy_kwargs(kwargs) if isinstance(kwargs, str) else (kwargs or {}))
    cls = kwargs.get("features_extractor_class")
    if cls is not None and not isinstance(cls, str):
        names = [name for name, c in FEATURE_EXTRACTORS.items() if c is cls]
        if not names:
            raise ValueError(f"features_extractor_class must be one of {list(FEATURE_EXTRACTORS)}, got {cls!r}")
        kwargs["features_extractor_class"] = names[0]
    return kwargs


def check_train_args(timesteps: int, n_envs: int, seed: int, eval_freq: int, eval_episodes: int,
                     checkpoint_freq: int) -> None:
    """Bounds that keep a training run finite (``ValueError`` / ``TypeError`` naming the argument)."""
    from rhs_common.validation import check_int

    check_int("timesteps", timesteps, 1, 10**9)
    check_int("n_envs", n_envs, 1, 256)
    check_int("seed", seed, 0, 2**32 - 1)  # numpy's legacy seeding inside stable-baselines3
    check_int("eval_freq", eval_freq, 0, 10**9)
    check_int("eval_episodes", eval_episodes, 1, 10_000)
    check_int("checkpoint_freq", checkpoint_freq, 0, 10**9)


def worker_env_id(env_id: str) -> str:
    """``env_id`` as a fresh worker process can resolve it: the rhs ids get the ``rhs_env:`` prefix."""
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids in this process)

    if ":" in env_id:
        return env_id
    spec = gym.registry.get(env_id)
    entry = spec.entry_point if spec is not None else None
    if isinstance(entry, str) and entry.startswith(("rhs_env.", "slam.")):  # the ids rhs_env registers
        return f"rhs_env:{env_id}"
    return env_id


#: imported once by the forkserver, so each worker forked from it starts with them loaded
#: (highway-env alone imports matplotlib and pygame: seconds per worker otherwise)
FORKSERVER_PRELOAD = ("rhs_env", "rhs_env.envs", "rhs_env.registration", "rhs_env.wrappers", "slam.gym.envs",
                      "slam.gym.wrappers", "slam.gym.metrics_info")


def _preload_forkserver() -> None:
    """Ask the forkserver (SB3's default start method on Linux) to import the env modules once.

    No effect when the forkserver is already running or another start method is used;
    the server only imports, it starts no threads, so forking from it stays safe.
    """
    import multiprocessing

    if "forkserver" in multiprocessing.get_all_start_methods():
        multiprocessing.set_forkserver_preload(["__main__", *FORKSERVER_PRELOAD])


def shield_setting(env_id: str, hp: dict[str, Any], env_kwargs: dict[str, Any]) -> dict[str, Any] | None:
    """The run's radar shield (the YAML entry ``hp``'s ``shield``) as its full record (None: none), validated: a wrong
    field names ``shield.<field>``, and an env without radar points (one built with ``env_kwargs``) is refused."""
    from agents.shield import check_shield_env, shield_record

    shield = shield_record(hp.get("shield"))
    if shield is None:
        return None
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids)

    env = gym.make(env_id, **env_kwargs)
    try:
        check_shield_env(env.observation_space)
    finally:
        env.close()
    return shield


def make_vec_env(
    env_id: str,
    n_envs: int,
    seed: int,
    env_kwargs: dict | None = None,
    subprocess: bool = True,
    monitor_dir: str | Path | None = None,
    decision_interval: int = 1,
    wrapper: Callable[[Any], Any] | None = None,
    decision_mode: str = "hold",
    monitor_suffix: str = "",
):
    """``n_envs`` copies of ``env_id`` (``Monitor`` logging ``crashed``), in subprocesses when n_envs > 1.

    ``decision_interval`` > 1 wraps each ``Monitor`` in :class:`agents.decision.HoldAction`
    (the monitor still counts env steps and per-step rewards), which repeats the action
    or, with ``decision_mode="pulse"``, fills the steps after it with IDLE. ``wrapper`` (a picklable
    callable, env -> env) wraps each ``Monitor`` first, e.g.
    :class:`agents.imitation.ExpertActionInfo`. The monitor of env ``i`` writes
    ``monitor_dir/<i><monitor_suffix>.monitor.csv`` (a resumed run: a new file beside the earlier ones).
    The subprocess workers ignore SIGINT (:class:`EnvFactory`, :func:`start_forkserver_ignoring_sigint`): a
    Ctrl-C in a terminal signals the whole process group, and the run's own handler stops them cleanly.
    The envs are built as stable-baselines3's ``make_vec_env`` builds them (same seeds). The workers run in
    :class:`rhs_env.vector.SubprocVecEnv` (stable-baselines3's, fault-safe): a worker's exception (a bad env kwarg,
    a bad action) is raised in this process with its type and message, naming the worker, and a killed worker is a
    :class:`rhs_env.vector.WorkerError`, never a ``ConnectionResetError`` or a wait.
    """
    from stable_baselines3.common.vec_env import DummyVecEnv

    from agents.decision import HoldAction, check_decision_interval, fill_action
    from rhs_env.vector import SubprocVecEnv  # SB3's, with the workers' errors raised here and dead workers named

    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    k = check_decision_interval(decision_interval)
    in_workers = subprocess and n_envs > 1
    if in_workers:
        _preload_forkserver()
        warm_kernels(env_id, env_kwargs or {})
        start_forkserver_ignoring_sigint()
    wrap = _compose(wrapper, partial(HoldAction, k=k, fill=fill_action(decision_mode)) if k > 1 else None)
    factories = [EnvFactory(worker_env_id(env_id), rank, seed, dict(env_kwargs or {}),
                            os.path.join(monitor_dir, f"{rank}{monitor_suffix}") if monitor_dir else None,
                            wrap, ignore_sigint=in_workers) for rank in range(n_envs)]
    venv = SubprocVecEnv(factories) if in_workers else DummyVecEnv(factories)  # type: ignore[arg-type]
    venv.seed(seed)  # the seeds of the first reset, as stable-baselines3's make_vec_env sets them
    return venv


@dataclass(frozen=True)
class EnvFactory:
    """Builds env ``rank`` of a vector env in its worker, as stable-baselines3's ``make_vec_env`` does
    (``render_mode="rgb_array"`` where the env takes it, the action space seeded ``seed + rank``, a ``Monitor``
    logging ``crashed`` into ``monitor_file``, then ``wrapper``); ``ignore_sigint``: first set SIGINT to be
    ignored in this (worker) process."""

    env_id: str
    rank: int
    seed: int
    env_kwargs: dict[str, Any]
    monitor_file: str | None = None
    wrapper: Callable[[Any], Any] | None = None
    ignore_sigint: bool = False

    def __call__(self) -> Any:
        import gymnasium as gym
        from stable_baselines3.common.monitor import Monitor

        if self.ignore_sigint:
            import signal

            signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            env = gym.make(self.env_id, **{"render_mode": "rgb_array", **self.env_kwargs})
        except TypeError:
            env = gym.make(self.env_id, **self.env_kwargs)
        env.action_space.seed(self.seed + self.rank)
        if self.monitor_file is not None:
            os.makedirs(os.path.dirname(self.monitor_file), exist_ok=True)
        env = Monitor(env, filename=self.monitor_file, info_keywords=("crashed",))
        return self.wrapper(env) if self.wrapper is not None else env


def start_forkserver_ignoring_sigint() -> None:
    """Start multiprocessing's forkserver (where it is used and not running yet) with SIGINT ignored.

    The forkserver hands its own SIGINT setting to every worker it forks, so the workers ignore a Ctrl-C from
    their first instruction on (:class:`EnvFactory` sets it too, for a forkserver started elsewhere).
    """
    import multiprocessing
    import signal
    import threading

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return
    if threading.current_thread() is not threading.main_thread():
        return
    from multiprocessing import forkserver

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)  # inherited by the server process it spawns
    try:
        forkserver.ensure_running()
    finally:
        signal.signal(signal.SIGINT, previous)


#: env steps of :func:`warm_kernels`' workload: past the first scans, until the SLAM matches landmarks
WARM_STEPS = 12


def warm_kernels(env_id: str, env_kwargs: dict[str, Any], steps: int = WARM_STEPS) -> bool:
    """Compile (or load) the radar / SLAM kernels here, before vector-env workers start; True if it ran.

    On an empty kernel cache each worker would compile every kernel itself; this steps one env of
    ``env_id`` (with ``env_kwargs``) ``steps`` times in this process, once per cache and config
    (:func:`rhs_common.jit.warm_cache`), so the workers load the cache. Where the SLAM env's background compile
    was still compiling the one-call OMP (:data:`rhs_env.kernels.omp_doppler_tiered`), it waits for that and steps
    once more, so the workers start on it. The base highway env has no kernels.
    """
    import gymnasium as gym

    import rhs_env  # noqa: F401
    from rhs_common.jit import warm_cache
    from rhs_env.kernels import lstsq, omp_doppler_tiered
    from rhs_env.registration import HIGHWAY_ID

    bare = env_id.split(":", 1)[-1]
    if bare == HIGHWAY_ID:
        return False

    def run() -> None:
        env = gym.make(bare, **env_kwargs)

        def step(n: int) -> None:
            _, _, term, trunc, _ = env.step(env.action_space.sample())
            if term or trunc:
                env.reset(seed=n + 1)

        try:
            env.reset(seed=0)
            env.action_space.seed(0)
            for n in range(steps):
                step(n)
            if omp_doppler_tiered.wait_for_background():
                step(steps)  # one step more, on the one-call OMP the background compile cached
        finally:
            env.close()

    return warm_cache(run, lstsq, key=f"{bare}|{sorted(env_kwargs.items())!r}")


def _compose(*wrappers: Callable[[Any], Any] | None) -> Callable[[Any], Any] | None:
    """The wrappers applied in order (the first innermost); None when there are none."""
    chain = [w for w in wrappers if w is not None]
    if not chain:
        return None
    if len(chain) == 1:
        return chain[0]
    return partial(_apply_all, chain)


def _apply_all(chain: list[Callable[[Any], Any]], env: Any) -> Any:
    for wrap in chain:
        env = wrap(env)
    return env


def check_env_kwargs(env_id: str, env_kwargs: dict[str, Any]) -> None:
    """Build and close one env here, so bad ``env_kwargs`` raise a readable error before workers start."""
    import gymnasium as gym

    import rhs_env  # noqa: F401

    try:
        env = gym.make(env_id.split(":", 1)[-1] if env_id.startswith("rhs_env:") else env_id, **env_kwargs)
    except TypeError as exc:
        raise ValueError(f"bad env_kwargs for {env_id}: {exc}") from None
    env.close()


def tensorboard_available() -> bool:
    try:
        import tensorboard  # noqa: F401
    except ImportError:
        return False
    return True


def limit_threads(torch_threads: int | None) -> None:
    """torch's intra-op threads in this process; worker processes get ``OMP_NUM_THREADS=1`` unless set already."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("MKL_NUM_THREADS", "1")
    if torch_threads:
        import torch

        torch.set_num_threads(int(torch_threads))


def update_threads_for(torch_threads: int | None, n_envs: int, update_threads: int | str | None = None) -> int | None:
    """torch's threads during an on-policy update, or None: the learner keeps ``torch_threads`` throughout.

    ``update_threads``: None (the default: no switch), an int in [1, 1024], or ``"auto"``: the cores that the
    ``n_envs`` subprocess workers and the learner's ``torch_threads`` use while collecting (they wait during the
    update), at most the cores this process may run on (None where ``torch_threads`` is None or ``n_envs`` is 1).
    Not the default: on a machine that other jobs keep busy, torch's threads wait for each other at every
    operation (2 cores at load ~3: the SLAM env's PPO update 0.68-0.74 -> 12-32 s per rollout with 2 threads (two runs); quiet,
    0.70 -> 0.47 s).
    """
    from rhs_common.validation import check_int

    if update_threads is None:
        return None
    if update_threads == "auto":
        if not torch_threads or n_envs < 2:
            return None
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        return max(int(torch_threads), min(cores, n_envs + int(torch_threads)))
    if isinstance(update_threads, str):  # a wrong word: a value error, as for the other settings
        raise ValueError(  # noqa: TRY004
            f"update_threads must be None, 'auto' or an int in [1, 1024], got {update_threads!r}")
    check_int("update_threads", update_threads, 1, 1024)
    return int(update_threads)


@dataclass(frozen=True)
class RunSettings:
    """What a training run uses, from the YAML merged with the caller's arguments."""

    policy: str
    timesteps: int
    n_envs: int
    env_kwargs: dict[str, Any]
    hp: dict[str, Any]  # constructor kwargs of the algorithm (schedules and policy_kwargs resolved)
    hp_record: dict[str, Any]  # the YAML as written, for the summary
    decision_interval: int = 1  # env steps per agent decision (agents.decision.HoldAction)
    decision_mode: str = "hold"  # between decisions: the action repeated, or IDLE after it ("pulse")


def run_settings(algo: str, env_id: str, timesteps: int | None, n_envs: int | None,
                  hyperparams: str | Path | None, env_kwargs: dict | None) -> RunSettings:
    from agents.decision import check_decision_interval, check_decision_mode

    hp = load_hyperparams(algo, env_id, hyperparams)
    policy = hp.pop("policy")
    k = check_decision_interval(hp.pop("decision_interval", 1))
    mode = check_decision_mode(hp.pop("decision_mode", "hold"))
    yaml_steps = hp.pop("n_timesteps", None)
    steps = int(timesteps if timesteps is not None else (yaml_steps or 0))
    if steps < 1:
        raise ValueError(f"timesteps must be >= 1, got {steps}")
    yaml_envs = hp.pop("n_envs", 1)
    envs = int(n_envs if n_envs is not None else yaml_envs)
    if envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {envs}")
    kwargs = {**(hp.pop("env_kwargs", None) or {}), **(env_kwargs or {})}
    hp["policy_kwargs"] = resolve_policy_kwargs(hp.get("policy_kwargs", {}))
    record = {k: v for k, v in load_hyperparams(algo, env_id, hyperparams).items() if k not in META_KEYS}
    return RunSettings(policy, steps, envs, kwargs, _resolve_schedules(hp), record, k, mode)


def run_summary(algo: str, env_id: str, run: RunSettings, seed: int, decisions: int, wall: float, out: Path,
                timed_decisions: int | None = None, **extra: Any) -> dict[str, Any]:
    """The record of a finished run that every trainer writes (``extra`` appended: the algorithm's own fields).

    ``timesteps`` counts env steps, ``decisions x decision_interval`` (an episode cut short by a crash
    takes fewer); ``steps_per_s`` is timesteps over the wall time ``wall`` (s), or, where ``wall`` covers
    only ``timed_decisions`` of them (a resumed run whose earlier parts were not timed), those over ``wall``.
    """
    wall = max(wall, 1e-9)
    timed = decisions if timed_decisions is None else timed_decisions
    return {
        "algo": algo,
        "env_id": env_id.split(":", 1)[-1],
        "env_kwargs": run.env_kwargs,
        "policy": run.policy,
        "timesteps": int(decisions) * run.decision_interval,
        "decision_interval": run.decision_interval,
        "decision_mode": run.decision_mode,
        "decisions": int(decisions),
        "n_envs": run.n_envs,
        "seed": seed,
        "wall_time_s": round(wall, 1),
        "steps_per_s": round(int(timed) * run.decision_interval / wall, 2),
        "hyperparams": run.hp_record,
        "model": str(out / "model.zip"),
        **extra,
    }


def run_record(algo: str, env_id: str, run: RunSettings, seed: int) -> dict[str, Any]:
    """What a checkpoint of a run carries inside its zip: the env and settings to drive and to resume it with."""
    return {"algo": algo, "env_id": env_id.split(":", 1)[-1], "env_kwargs": run.env_kwargs, "policy": run.policy,
            "decision_interval": run.decision_interval, "decision_mode": run.decision_mode, "n_envs": run.n_envs,
            "seed": seed, "planned_timesteps": run.timesteps, "hyperparams": run.hp_record}


def write_summary(out: Path, summary: dict[str, Any]) -> None:
    """``out/train.json`` and the record of ``model.zip`` (and ``best_model.zip``): the JSON beside each zip and
    a copy inside it (:mod:`agents.policy_record`), all written atomically."""
    from agents.policy_record import embed_record, write_bytes_atomic

    text = json.dumps(summary, indent=2)
    write_bytes_atomic(out / "train.json", text.encode())
    for name in ("model.zip", "best_model.zip"):
        if name == "model.zip" or (out / name).exists():
            record = summary if name == "model.zip" else {**summary, "model": str(out / name)}
            if (out / name).exists():
                embed_record(out / name, record)
            write_bytes_atomic(metadata_path(out / name), json.dumps(record, indent=2).encode())
