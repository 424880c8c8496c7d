"""The vector envs a training run steps: :func:`make_vec_env` and what its worker processes need.

``n_envs`` copies of an env id, each in a ``Monitor`` that logs ``crashed``, with the decision interval and the
caller's wrappers, in ``SubprocVecEnv`` workers (:class:`rhs_env.vector.SubprocVecEnv`) when ``n_envs`` > 1. The
workers resolve the rhs ids (:func:`worker_env_id`), start from a forkserver that has the env modules imported
(:data:`FORKSERVER_PRELOAD`) and ignores SIGINT (:func:`start_forkserver_ignoring_sigint`), and load the radar and
SLAM kernels that :func:`warm_kernels` compiled once in the parent.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

__all__ = [
    "EnvFactory", "FORKSERVER_PRELOAD", "WARM_STEPS", "make_vec_env", "start_forkserver_ignoring_sigint",
    "warm_kernels", "worker_env_id",
]


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
    native_workers: int | None = None,
):
    """``n_envs`` copies of ``env_id`` (``Monitor`` logging ``crashed``), in subprocesses when n_envs > 1.

    ``native_workers`` (None: SB3's ``SubprocVecEnv``, one worker per env) takes the project's native vector env
    instead (:class:`rhs_env.vector_native.RhsVectorEnv` through :func:`rhs_env.vector_native.to_sb3`, the same
    envs and seeds): its ``n_envs`` envs in this process (1) or in that many worker processes, contiguous groups
    of envs each (:mod:`rhs_env.vector_workers`; started from the same preloaded forkserver). Fewer processes than
    envs: 8 envs on 2 cores step in 2 processes, and the policy's forward pass takes all 8 observations at once.

    ``decision_interval`` > 1 wraps each ``Monitor`` in :class:`agents.policies.decision.HoldAction`
    (the monitor still counts env steps and per-step rewards), which repeats the action
    or, with ``decision_mode="pulse"``, fills the steps after it with IDLE. ``wrapper`` (a picklable
    callable, env -> env) wraps each ``Monitor`` first, e.g.
    :class:`agents.algos.imitation.ExpertActionInfo`. The monitor of env ``i`` writes
    ``monitor_dir/<i><monitor_suffix>.monitor.csv`` (a resumed run: a new file beside the earlier ones).
    The subprocess workers ignore SIGINT (:class:`EnvFactory`, :func:`start_forkserver_ignoring_sigint`): a
    Ctrl-C in a terminal signals the whole process group, and the run's own handler stops them cleanly.
    The envs are built as stable-baselines3's ``make_vec_env`` builds them (same seeds). The workers run in
    :class:`rhs_env.vector.SubprocVecEnv` (stable-baselines3's, fault-safe): a worker's exception (a bad env kwarg,
    a bad action) is raised in this process with its type and message, naming the worker, and a killed worker is a
    :class:`rhs_env.vector.WorkerError`, never a ``ConnectionResetError`` or a wait.
    """
    from stable_baselines3.common.vec_env import DummyVecEnv

    from agents.policies.decision import HoldAction, check_decision_interval, fill_action
    from rhs_env.vector import SubprocVecEnv  # SB3's, with the workers' errors raised here and dead workers named

    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    k = check_decision_interval(decision_interval)
    if native_workers is not None:
        from rhs_env.vector_workers import check_workers

        check_workers(native_workers, n_envs)
    in_workers = subprocess and n_envs > 1 and (native_workers is None or native_workers > 1)
    if in_workers:
        _preload_forkserver()
        warm_kernels(env_id, env_kwargs or {})
        start_forkserver_ignoring_sigint()
    wrap = _compose(wrapper, partial(HoldAction, k=k, fill=fill_action(decision_mode)) if k > 1 else None)
    factories = [EnvFactory(worker_env_id(env_id), rank, seed, dict(env_kwargs or {}),
                            os.path.join(monitor_dir, f"{rank}{monitor_suffix}") if monitor_dir else None,
                            wrap, ignore_sigint=in_workers) for rank in range(n_envs)]
    if native_workers is not None:
        import multiprocessing

        from rhs_env.vector_native import RhsVectorEnv, to_sb3

        workers = native_workers if in_workers else 1
        context = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
        venv = to_sb3(RhsVectorEnv(factories, autoreset_mode="SameStep", workers=workers, context=context))
    else:
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
