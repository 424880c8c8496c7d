"""Train driving agents with stable-baselines3 (``rhs-slam train``).

PPO or DQN with the hyperparameters of ``agents/hyperparams/<algo>.yml`` for the
env id (rl-baselines3-zoo style: ``policy``, ``n_envs``, ``n_timesteps``,
``env_kwargs``, ``policy_kwargs``, ``lin_<value>`` learning-rate schedules, and
the algorithm's own arguments; plus ``decision_interval``, default 1: env steps
per agent decision, see :mod:`agents.policies.decision`), ``SubprocVecEnv`` over ``n_envs`` envs each
wrapped in a ``Monitor`` that logs ``crashed`` (``DIR/monitor/*.monitor.csv``;
TensorBoard also gets ``rollout/crash_rate``), TensorBoard logs, an
``EvalCallback`` on a separate env, periodic checkpoints and a progress bar.

Writes into ``DIR``:

* ``model.zip``: the final policy, and ``model.json`` beside it: the env id and
  ``env_kwargs`` it was trained on (``rhs-slam evaluate`` / ``demo`` default to
  them) and its ``decision_interval`` (evaluation holds each action that long),
  with the settings and timings of the run;
* ``best_model.zip`` / ``best_model.json``: the best policy of the periodic evaluations;
* ``checkpoints/``, ``tb/`` (TensorBoard), ``eval/evaluations.npz``, ``monitor/``;
* ``train.json``: the same summary as ``model.json``.

Subprocess workers look the env up by name, so the rhs ids are passed to
stable-baselines3 as ``"rhs_env:<id>"`` (gymnasium imports ``rhs_env``, which
registers them, in each worker).
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import signal
import sys
import time
import warnings
from pathlib import Path
from typing import Any

# re-exported: the names users of agents.train know (the parts of agents.run_setup that train reads)
from agents.algos.hyperparams import (  # noqa: F401
    ALGOS,
    HYPERPARAMS_DIR,
    META_KEYS,
    RunSettings,
    eval_policy_kwargs,
    load_hyperparams,
    policy_kwargs_by_name,
    resolve_policy_kwargs,
    run_settings,
)
from agents.algos.run_checks import check_env_kwargs, check_train_args, parse_env_kwargs
from agents.algos.run_records import metadata_path, run_summary, tensorboard_available, write_summary
from agents.algos.threads import limit_threads, update_threads_for
from agents.algos.vec_env import FORKSERVER_PRELOAD, make_vec_env, worker_env_id  # noqa: F401

__all__ = [
    "ALGOS", "BACKENDS", "HYPERPARAMS_DIR", "RUN_DIRS", "RUN_FILES", "configure", "load_hyperparams", "metadata_path",
    "policy_kwargs_by_name", "run", "train", "train_rllib_backend", "update_threads_for", "worker_env_id",
]


def _train_dagger(algo: str, env_id: str, timesteps: int | None, out: str | Path, seed: int, n_envs: int | None,
                  hyperparams: str | Path | None, env_kwargs: dict | None, progress: bool, torch_threads: int | None,
                  resume: bool, init_policy: str | Path | None) -> dict[str, Any]:
    """:func:`train`'s DAgger branch (:func:`agents.algos.imitation.train_dagger`); the flags it does not take are errors."""
    from agents.algos.imitation import train_dagger

    if algo != "dagger":
        raise ValueError(f"--init-policy continues a DAgger student; for {algo} use --resume")
    return train_dagger(env_id, timesteps, out, seed=seed, n_envs=n_envs, hyperparams=hyperparams,
                        env_kwargs=env_kwargs, progress=progress, torch_threads=torch_threads, init_policy=init_policy,
                        resume=resume)


def _train_finetune(env_id: str, timesteps: int | None, out: str | Path, seed: int, n_envs: int | None,
                    hyperparams: str | Path | None, env_kwargs: dict | None, progress: bool, torch_threads: int | None,
                    resume: bool, init_policy: str | Path | None, checkpoint_freq: int) -> dict[str, Any]:
    """:func:`train`'s fine-tuning branch (:func:`agents.algos.finetune.train_finetune`); ``--resume`` is an error."""
    from agents.algos.finetune import train_finetune

    if resume:
        raise ValueError("--resume is not supported for --algo finetune; start the run again")
    return train_finetune(env_id, timesteps, out, init_policy=init_policy, seed=seed, n_envs=n_envs,
                          hyperparams=hyperparams, env_kwargs=env_kwargs, progress=progress,
                          torch_threads=torch_threads, checkpoint_freq=checkpoint_freq)


def train(
    algo: str,
    env_id: str,
    timesteps: int | None,
    out: str | Path,
    seed: int = 0,
    n_envs: int | None = None,
    hyperparams: str | Path | None = None,
    env_kwargs: dict | None = None,
    eval_freq: int = 2000,
    eval_episodes: int = 3,
    checkpoint_freq: int = 5000,
    progress: bool = True,
    torch_threads: int | None = 1,
    resume: bool = False,
    init_policy: str | Path | None = None,
    update_threads: int | str | None = None,
    force: bool | None = None,
    command: list[str] | None = None,
    native_workers: int | None = None,
) -> dict[str, Any]:
    """Train ``algo`` on ``env_id`` for ``timesteps`` steps; returns the summary written to ``out/train.json``.

    ``timesteps=None`` takes ``n_timesteps`` from the YAML. ``env_kwargs`` are
    merged over the YAML's. ``eval_freq`` / ``checkpoint_freq`` count env steps over all envs (0 disables).
    With a ``decision_interval`` k in the YAML the agent acts every k env steps (:class:`agents.policies.decision.HoldAction`):
    ``timesteps`` stays the env-step budget, i.e. ``ceil(timesteps / k)`` decisions. ``resume`` continues from the checkpoint with the
    most steps in ``out/checkpoints`` (see :mod:`agents.algos.resume`; SIGTERM / SIGINT
    stop a run there, ``summary["interrupted"]`` is then True; DAgger: from the last finished round,
    :func:`agents.algos.imitation.load_round_state`). ``torch_threads``: torch's intra-op threads here (1: the envs need
    the other cores); workers get ``OMP_NUM_THREADS=1`` unless set. ``init_policy``: the student zip DAgger continues
    (:func:`agents.algos.imitation.train_dagger`) or ``"finetune"`` tunes (:func:`agents.algos.finetune.train_finetune`).
    ``update_threads``: PPO's torch threads during its gradient updates, while the subprocess workers wait
    (None: ``torch_threads`` throughout; ``"auto"``: those workers' cores too; see
    :func:`agents.algos.threads.update_threads_for`, and why it is not the default). ``summary["timing"]`` splits the
    wall time: ``setup_s`` (vector env, kernel warm-up, model), ``learn_s``, the first rollout and the steady rate
    from the second rollout on (:class:`agents.algos.callbacks.PhaseTimer`). ``native_workers``: the training envs
    in the project's native vector env with that many worker processes instead of one ``SubprocVecEnv`` worker per
    env (:func:`agents.algos.vec_env.make_vec_env`).

    PPO / DQN: SIGINT / SIGTERM are caught for the whole run (:class:`agents.algos.resume.InterruptGuard`): the first
    stops at the next rollout boundary with a checkpoint (the subprocess workers ignore SIGINT, so a Ctrl-C in a
    terminal stops them cleanly too), a second exits at once with 128 + its number, leaving the checkpoints saved
    so far. ``force``: without ``resume``, a run already in ``out`` is refused (False, the CLI's default) or
    deleted first (True); None, the library's default, writes over it as before. With ``resume``, a checkpoint
    trained on another env id, env kwargs or decision interval, or one with more env steps than ``timesteps``,
    is refused unless ``force`` is True. ``command``: the command line the interrupt message tells to rerun with
    ``--resume``. Resumed runs write new monitor and evaluation files beside the earlier ones
    (``monitor/<i>.resume<n>.monitor.csv``, ``eval/evaluations.resume<n>.npz``) and TensorBoard events into the
    same run folder: nothing written before is replaced.
    """
    if force and (algo in ("dagger", "finetune") or init_policy is not None):
        raise ValueError("--force is for --algo ppo / dqn (dagger and finetune start over in OUT as before)")
    if algo == "finetune":
        return _train_finetune(env_id, timesteps, out, seed, n_envs, hyperparams, env_kwargs, progress, torch_threads,
                               resume, init_policy, checkpoint_freq)
    if algo == "dagger" or init_policy is not None:
        return _train_dagger(algo, env_id, timesteps, out, seed, n_envs, hyperparams, env_kwargs, progress,
                             torch_threads, resume, init_policy)
    from agents.algos.resume import InterruptGuard

    with InterruptGuard() as guard:
        return _train_sb3(algo, env_id, timesteps, Path(out), seed, n_envs, hyperparams, env_kwargs, eval_freq,
                          eval_episodes, checkpoint_freq, progress, torch_threads, resume, update_threads, force,
                          command, guard, native_workers)


def _train_sb3(algo: str, env_id: str, timesteps: int | None, out: Path, seed: int, n_envs: int | None,
               hyperparams: str | Path | None, env_kwargs: dict | None, eval_freq: int, eval_episodes: int,
               checkpoint_freq: int, progress: bool, torch_threads: int | None, resume: bool,
               update_threads: int | str | None, force: bool | None, command: list[str] | None,
               guard: Any, native_workers: int | None = None) -> dict[str, Any]:
    """:func:`train` for PPO / DQN, under the run's :class:`agents.algos.resume.InterruptGuard` ``guard``."""
    import torch

    from agents.algos.callbacks import UpdateThreads
    from agents.algos.run_records import run_record

    t_setup = time.perf_counter()
    run = run_settings(algo, env_id, timesteps, n_envs, hyperparams, env_kwargs)
    check_train_args(run.timesteps, run.n_envs, seed, eval_freq, eval_episodes, checkpoint_freq)
    found = _check_start(algo, env_id, run, out, resume, force)
    out.mkdir(parents=True, exist_ok=True)
    limit_threads(torch_threads)
    updating = update_threads_for(torch_threads, run.n_envs, update_threads) if algo == "ppo" else None
    if run.n_envs > 1:
        check_env_kwargs(env_id, run.env_kwargs)
    k = run.decision_interval
    suffix = _resume_suffix(out) if found is not None else ""
    record = run_record(algo, env_id, run, seed)
    venv = make_vec_env(env_id, run.n_envs, seed, run.env_kwargs, monitor_dir=out / "monitor", decision_interval=k,
                        decision_mode=run.decision_mode, monitor_suffix=suffix, native_workers=native_workers)
    decisions = -(-run.timesteps // k)
    eval_env = None
    try:
        model = _new_or_resumed_model(algo, run, venv, seed, out, found is not None)
        done = int(model.num_timesteps)
        callbacks, eval_cb, eval_env = _callbacks(algo, env_id, run, seed, out, eval_freq, eval_episodes,
                                                  checkpoint_freq, max(0, decisions - done) if progress else None,
                                                  record, suffix)
        if updating is not None:
            callbacks.append(UpdateThreads(torch.get_num_threads(), updating))
        t0, wall, stopper, timer = _learn(algo, model, callbacks, decisions - done, done == 0, out, guard, record)
    finally:
        venv.close()
        if eval_env is not None:
            eval_env.close()
    summary = _summary(algo, env_id, run, seed, model, eval_cb, out, wall, done, stopper.stopped)
    summary["timing"] = {"update_threads": updating, "setup_s": round(t0 - t_setup, 3), "learn_s": round(wall, 3),
                         "learn_start_s": round(timer.started - t0, 3) if timer.rollouts else None,
                         **timer.phases(run.decision_interval)}
    if stopper.stopped:
        summary["signal"] = signal.Signals(guard.requested or signal.SIGTERM).name
        summary["checkpoint"] = str(stopper.checkpoint)
        print(f"rhs-slam train: interrupted at {model.num_timesteps} steps, saved {summary['checkpoint']}; "
              f"resume with: {_resume_hint(command)}", file=sys.stderr)
    else:
        write_summary(out, summary)
    return summary


def _resume_hint(command: list[str] | None) -> str:
    """``command`` with ``--resume`` (and without ``--force``), or a sentence saying to rerun it so."""
    if not command:
        return "the same command with --resume"
    args = [a for a in command if a != "--force"]
    return shlex.join(args if "--resume" in args else [*args, "--resume"])


def _resume_suffix(out: Path) -> str:
    """``.resume<n>``, the first ``n`` no monitor or evaluation file of ``out`` uses yet."""
    n = 1
    while list((out / "monitor").glob(f"*.resume{n}.monitor.csv")) or (out / "eval" / f"evaluations.resume{n}.npz").exists():
        n += 1
    return f".resume{n}"


def _learn(algo: str, model: Any, callbacks: list, remaining: int, fresh: bool, out: Path, guard: Any,
           record: dict[str, Any]) -> tuple[float, float, Any, Any]:
    """``model.learn`` over the ``remaining`` decisions with ``callbacks``, a stop once ``guard`` has a signal and a
    :class:`agents.algos.callbacks.PhaseTimer`; saves ``out/model.zip`` (or, stopped, a checkpoint carrying ``record``,
    its path in ``stopper.checkpoint``). Returns the start (perf_counter), the wall seconds, the stopper and the
    timer."""
    from stable_baselines3.common.callbacks import CallbackList

    from agents.algos.callbacks import PhaseTimer
    from agents.algos.resume import StopOnSignal, save_checkpoint
    from agents.policies.policy_record import embed_record, save_model

    stopper, timer = StopOnSignal(guard), PhaseTimer()
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        # the eval env is a DummyVecEnv, the training env a SubprocVecEnv: same envs, on purpose
        warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
        if guard.requested is not None:  # a signal during the setup: nothing to learn, save where it stands
            stopper.stopped = True
        elif remaining > 0:
            model.learn(total_timesteps=remaining, callback=CallbackList([*callbacks, stopper, timer]),
                        tb_log_name=algo, reset_num_timesteps=fresh)
    wall = max(time.perf_counter() - t0, 1e-9)
    if stopper.stopped:
        stopper.checkpoint = save_checkpoint(model, out, algo, record)
        if (out / "best_model.zip").exists():
            embed_record(out / "best_model.zip", {**record, "model": str(out / "best_model.zip")})
    else:
        save_model(model, out / "model.zip")
    return t0, wall, stopper, timer


#: what a run leaves in its ``--out`` (:func:`train` refuses to start over onto them without ``force``)
RUN_FILES = ("model.zip", "model.json", "best_model.zip", "best_model.json", "train.json")
RUN_DIRS = ("checkpoints", "monitor", "eval", "tb")


def _check_start(algo: str, env_id: str, run: RunSettings, out: Path, resume: bool,
                 force: bool | None) -> tuple[Path, int] | None:
    """Before any work: the checkpoint to resume from (``ValueError`` naming ``--resume`` without one, or for one
    another run made, see :func:`_check_resumable`), or, for a new run, ``out`` free of an earlier run
    (:func:`_check_fresh_out`); say so when PPO will train more steps than asked (it collects whole rollouts of
    ``n_steps * n_envs``)."""
    from agents.algos.resume import checkpoints, usable_checkpoint

    found = None
    if resume:
        found = usable_checkpoint(out, algo)
        if found is None:
            damaged = [str(p) for p, _ in checkpoints(out, algo)]
            raise ValueError(f"--resume: no {'whole ' if damaged else ''}checkpoint {algo}_<steps>_steps.zip in "
                             f"{out / 'checkpoints'} to continue from; run without --resume to start a new run"
                             + (" (with --force to replace this one)" if damaged else ""))
        _check_resumable(found, env_id, run, force)
    else:
        _check_fresh_out(algo, out, force)
    if algo == "ppo":
        rollout = int(run.hp.get("n_steps", 2048)) * run.n_envs  # stable-baselines3's default n_steps: 2048
        decisions = -(-run.timesteps // run.decision_interval)
        rounded = -(-decisions // rollout) * rollout * run.decision_interval
        if rounded != run.timesteps:
            print(f"rhs-slam train: PPO collects whole rollouts of n_steps x n_envs = {rollout} decisions: "
                  f"--timesteps {run.timesteps} is rounded up to {rounded} env steps", file=sys.stderr)
    return found


def _check_resumable(found: tuple[Path, int], env_id: str, run: RunSettings, force: bool | None) -> None:
    """``ValueError`` unless ``force``: the checkpoint ``found`` was trained on another env id, env kwargs or
    decision interval / mode than ``run`` (its record inside the zip says), or has more env steps than ``run``'s
    budget."""
    from agents.policies.policy_record import embedded_record

    path, decisions = found
    saved = embedded_record(path) or {}
    steps = decisions * int(saved.get("decision_interval", run.decision_interval))
    now = {"env_id": env_id.split(":", 1)[-1], "env_kwargs": run.env_kwargs,
           "decision_interval": run.decision_interval, "decision_mode": run.decision_mode}
    changed = [f"{key} {saved[key]!r} -> {value!r}" for key, value in now.items()
               if key in saved and saved[key] != value]
    if force:
        for problem in changed:
            print(f"rhs-slam train: warning: --force: resuming {path} with {problem}", file=sys.stderr)
        return
    hint = "or pass --force to resume anyway"
    if changed:
        raise ValueError(f"--resume: {path} was trained with other settings ({'; '.join(changed)}): run the same "
                         f"--env, --env-kwargs and --hyperparams as the interrupted run, {hint}")
    if steps > run.timesteps:
        raise ValueError(f"--resume: {path} has trained {steps} env steps already, more than --timesteps "
                         f"{run.timesteps}: give --timesteps of at least {steps}, {hint} (the checkpoint becomes "
                         "the final model)")


def _check_fresh_out(algo: str, out: Path, force: bool | None) -> None:
    """``out`` holds an earlier run (:data:`RUN_FILES`, :data:`RUN_DIRS`): ``ValueError`` naming ``--out``
    (``force`` False), its files deleted (True), or left to be written over (None)."""
    from agents.algos.resume import latest_checkpoint

    found = [out / n for n in RUN_FILES if (out / n).is_file()]
    found += [out / n for n in RUN_DIRS if (out / n).is_dir() and any((out / n).iterdir())]
    if not found or force is None:
        return
    if force:
        for path in found:
            shutil.rmtree(path) if path.is_dir() else path.unlink()
        print(f"rhs-slam train: --force: deleted the earlier run in {out} ({', '.join(p.name for p in found)})",
              file=sys.stderr)
        return
    last = latest_checkpoint(out, algo)
    what = ("a finished run (model.zip)" if (out / "model.zip").exists()
            else f"an interrupted run (checkpoint at {last[1]} steps)" if last else "the files of an earlier run")
    raise ValueError(f"--out {out} already holds {what}: continue it with --resume, choose another --out, or pass "
                     "--force to delete it and start over")


def _new_or_resumed_model(algo: str, run: RunSettings, venv: Any, seed: int, out: Path, resume: bool) -> Any:
    """A fresh ``algo`` model on ``venv``, or (``resume``) the newest whole checkpoint in ``out/checkpoints``
    (:func:`agents.algos.resume.load_latest`: a damaged one is passed over with a warning)."""
    from stable_baselines3 import DQN, PPO

    from agents.algos.resume import load_latest

    cls = {"ppo": PPO, "dqn": DQN}[algo]
    tb = str(out / "tb") if tensorboard_available() else None
    if tb is None:
        print("rhs-slam train: tensorboard is not installed; no TensorBoard logs", file=sys.stderr)
    if not resume:
        return cls(run.policy, venv, seed=seed, verbose=0, tensorboard_log=tb, device="cpu", **run.hp)
    schedules = {k: v for k, v in run.hp.items() if k in ("learning_rate", "clip_range")}
    model, path = load_latest(cls, out, algo, venv, custom_objects=schedules, tensorboard_log=tb)
    print(f"rhs-slam train: resuming from {path} ({model.num_timesteps} steps)", file=sys.stderr)
    return model


def _callbacks(algo: str, env_id: str, run: RunSettings, seed: int, out: Path, eval_freq: int,
               eval_episodes: int, checkpoint_freq: int, progress_total: int | None, record: dict[str, Any],
               suffix: str = ""):
    """Crash-rate logging, evaluation (its env returned to be closed; a resumed run, ``suffix``, logs into a new
    ``eval/evaluations<suffix>.npz`` and keeps the best mean return so far), checkpoints carrying ``record``,
    progress bar."""
    from stable_baselines3.common.callbacks import EvalCallback

    from agents.algos.callbacks import AtomicCheckpoint, CrashRateCallback, TqdmCallback, best_eval_return

    callbacks: list = [CrashRateCallback()]
    eval_cb = eval_env = None
    if eval_freq and eval_freq > 0:
        k = run.decision_interval
        eval_env = make_vec_env(env_id, 1, seed + 10_000, run.env_kwargs, subprocess=False, decision_interval=k,
                                decision_mode=run.decision_mode)
        eval_cb = EvalCallback(eval_env, n_eval_episodes=eval_episodes,
                               eval_freq=max(1, eval_freq // (run.n_envs * k)),
                               best_model_save_path=str(out), log_path=str(out / "eval"), deterministic=True, verbose=0)
        if suffix:
            eval_cb.log_path = str(out / "eval" / f"evaluations{suffix}")
            eval_cb.best_mean_reward = best_eval_return(out / "eval")
        callbacks.append(eval_cb)
    if checkpoint_freq and checkpoint_freq > 0:
        callbacks.append(AtomicCheckpoint(max(1, checkpoint_freq // (run.n_envs * run.decision_interval)), out, algo,
                                          record))
    if progress_total is not None:
        callbacks.append(TqdmCallback(progress_total))
    return callbacks, eval_cb, eval_env


def _summary(algo: str, env_id: str, run: RunSettings, seed: int, model, eval_cb, out: Path, wall: float,
             done: int, interrupted: bool) -> dict[str, Any]:
    recent = list(model.ep_info_buffer)
    best = float(eval_cb.best_mean_reward) if eval_cb is not None and eval_cb.n_calls else None
    return run_summary(
        algo, env_id, run, seed, int(model.num_timesteps), wall, out,
        recent_episodes={
            "count": len(recent),
            "mean_return": sum(e["r"] for e in recent) / len(recent) if recent else None,
            "mean_length": sum(e["l"] for e in recent) / len(recent) if recent else None,
            "crash_rate": sum(float(e.get("crashed", 0)) for e in recent) / len(recent) if recent else None,
        },
        best_eval_mean_return=None if best is None or best == float("-inf") else best,
        resumed_from_steps=done * run.decision_interval,
        interrupted=interrupted,
    )


BACKENDS = ("sb3", "rllib")


def train_rllib_backend(
    env_id: str,
    timesteps: int | None,
    out: str | Path,
    seed: int = 0,
    hyperparams: str | Path | None = None,
    env_kwargs: dict | None = None,
    num_env_runners: int | None = None,
    address: str | None = None,
    eval_freq: int = 0,
    eval_episodes: int = 3,
    checkpoint_freq: int = 5000,
    progress: bool = True,
    algo: str = "ppo",
    init_policy: str | Path | None = None,
) -> dict[str, Any]:
    """PPO (``algo="ppo"``) or the fine-tuning stage (``"finetune"``, :mod:`agents.algos.finetune`) with Ray RLlib
    (:mod:`agents.algos.rllib`) from the same YAML entry as the SB3 backend (``agents/hyperparams/<algo>.yml``).

    ``num_env_runners`` defaults to the YAML's ``n_envs`` (one Ray actor per env);
    the train batch stays ``n_steps * n_envs`` decisions whatever the number of runners. ``decision_interval`` /
    ``decision_mode`` wrap every runner's env as the SB3 backend does (:class:`agents.policies.decision.HoldAction`).
    ``init_policy`` (finetune): the student zip to start from; ``env_kwargs`` are merged over its own.
    """
    from agents.algos.rllib import require_ray, train_rllib
    from agents.policies.decision import check_decision_interval, check_decision_mode

    if algo not in ("ppo", "finetune"):
        raise ValueError(f"the rllib backend trains ppo or finetune, got --algo {algo}")
    if init_policy is not None and algo != "finetune":
        raise ValueError("--init-policy on the rllib backend is for --algo finetune")
    if num_env_runners is not None and int(num_env_runners) < 0:
        raise ValueError(f"num_env_runners must be >= 0, got {num_env_runners}")
    if init_policy is not None:
        from agents.algos.imitation import continued_env_kwargs

        if not Path(init_policy).exists():
            raise FileNotFoundError(f"--init-policy: no such student zip: {init_policy}")
        env_kwargs = continued_env_kwargs(env_id, env_kwargs, init_policy)
    hp = load_hyperparams(algo, env_id, hyperparams)
    policy = str(hp.pop("policy"))
    hp["policy_kwargs"] = policy_kwargs_by_name(hp.get("policy_kwargs") or {})
    mode = check_decision_mode(hp.pop("decision_mode", "hold"))
    k = check_decision_interval(hp.pop("decision_interval", 1))
    require_ray()
    yaml_steps = hp.pop("n_timesteps", None)
    timesteps = int(timesteps if timesteps is not None else (yaml_steps or 0))
    if timesteps < 1:
        raise ValueError(f"timesteps must be >= 1, got {timesteps}")
    n_envs = int(hp.pop("n_envs", 1))
    env_kwargs = {**(hp.pop("env_kwargs", None) or {}), **(env_kwargs or {})}
    runners = n_envs if num_env_runners is None else int(num_env_runners)
    bare_id = env_id.split(":", 1)[-1]
    check_env_kwargs(bare_id, env_kwargs)
    return train_rllib(bare_id, timesteps, out, hp, env_kwargs, n_envs, runners, address=address, seed=seed,
                       eval_freq=eval_freq, eval_episodes=eval_episodes, checkpoint_freq=checkpoint_freq,
                       progress=progress, decision_interval=k, decision_mode=mode, algo=algo,
                       init_policy=init_policy, policy=policy)  # fmt: skip


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--backend", choices=BACKENDS, default="sb3",
        help="sb3: stable-baselines3 on this machine; rllib: Ray RLlib, --algo ppo or finetune (pip install -e "
        "'.[rllib]')",
    )  # fmt: skip
    parser.add_argument("--algo", choices=ALGOS, default="ppo")
    parser.add_argument("--env", default="rhs-highway-slam-v0", help="env id (default: rhs-highway-slam-v0)")
    parser.add_argument("--timesteps", type=int, default=None, help="env steps (default: n_timesteps of the YAML)")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--n-envs", type=int, default=None, help="subprocess envs (default: from the YAML)")
    parser.add_argument("--hyperparams", default=None, help="zoo-style YAML (default: agents/hyperparams/ALGO.yml)")
    parser.add_argument("--env-kwargs", default=None,
                        help="JSON dict passed to gym.make (merged over the YAML's; with --init-policy, over the "
                        "env kwargs the policy was trained on)")
    parser.add_argument("--eval-freq", type=int, default=2000, help="env steps between evaluations (0: none)")
    parser.add_argument("--eval-episodes", type=int, default=3)
    parser.add_argument("--checkpoint-freq", type=int, default=5000, help="env steps between checkpoints (0: none)")
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument(
        "--num-env-runners", type=int, default=None,
        help="rllib: Ray actors sampling the env (default: n_envs of the YAML; 0: sample in the driver)",
    )  # fmt: skip
    parser.add_argument(
        "--address", default=None,
        help="rllib: join an existing Ray cluster ('auto', 'HOST:6379' or 'ray://HOST:10001'; default: a local one)",
    )  # fmt: skip
    parser.add_argument("--init-policy", default=None,
                        help="dagger: continue from this student zip (first_beta / iterations of the YAML); "
                        "finetune: the student to fine-tune with PPO (omit it for PPO from scratch with the "
                        "privileged critic)")
    parser.add_argument("--resume", action="store_true",
                        help="continue from the latest checkpoint in OUT/checkpoints (after SIGTERM / SIGINT / a crash); "
                        "dagger: from the state the last finished round left in OUT")
    parser.add_argument("--force", action="store_true",
                        help="ppo / dqn: without --resume, delete a run already in OUT and start over; with --resume, "
                        "continue a checkpoint on other env kwargs or with fewer --timesteps than it has")


def run(args: argparse.Namespace) -> int:
    from rhs_common.validation import check_output_path

    try:
        check_output_path("--out", args.out, directory=True)
        env_kwargs = parse_env_kwargs(args.env_kwargs)
        if args.backend == "rllib":
            if args.algo not in ("ppo", "finetune"):
                raise ValueError(f"the rllib backend trains ppo or finetune, got --algo {args.algo}")
            if args.n_envs is not None:
                raise ValueError("--n-envs is for the sb3 backend; the rllib backend takes --num-env-runners")
            if args.resume or args.force:
                raise ValueError("--resume / --force are for the sb3 backend (the rllib backend saves "
                                 "OUT/checkpoints/step_N)")
            summary = train_rllib_backend(
                args.env, args.timesteps, args.out, seed=args.seed, hyperparams=args.hyperparams,
                env_kwargs=env_kwargs, num_env_runners=args.num_env_runners, address=args.address,
                eval_freq=args.eval_freq, eval_episodes=args.eval_episodes, checkpoint_freq=args.checkpoint_freq,
                progress=not args.no_progress, algo=args.algo, init_policy=args.init_policy,
            )  # fmt: skip
            print(json.dumps({k: v for k, v in summary.items() if k != "iterations"}, indent=2))
            return 0
        if args.num_env_runners is not None or args.address is not None:
            raise ValueError("--num-env-runners / --address need --backend rllib")
        summary = train(
            args.algo,
            args.env,
            args.timesteps,
            args.out,
            seed=args.seed,
            n_envs=args.n_envs,
            hyperparams=args.hyperparams,
            env_kwargs=env_kwargs,
            eval_freq=args.eval_freq,
            eval_episodes=args.eval_episodes,
            checkpoint_freq=args.checkpoint_freq,
            progress=not args.no_progress,
            resume=args.resume,
            init_policy=args.init_policy,
            force=bool(args.force),
            command=["rhs-slam", *sys.argv[1:]] if sys.argv[1:2] == ["train"] else None,
        )
    except (ValueError, TypeError, FileNotFoundError, json.JSONDecodeError) as exc:
        print(f"rhs-slam train: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(summary, indent=2))
    if summary.get("interrupted"):  # 128 + the signal: the run is not finished
        return 128 + int(signal.Signals[summary.get("signal", "SIGTERM")])
    return 0
