"""The traffic core's kernels compiled in a background process on a cold cache, highway-env's code meanwhile.

The compiled core's 32 kernels (:mod:`rhs_env.traffic.core`, :mod:`rhs_env.traffic.npmath`) take about 11 s of CPU
to compile on an empty cache, at the first step of the first env: before the radar's and the SLAM's kernels, on
the first step's critical path. With the default ``sim="auto"`` an env does not wait for them: its first
:meth:`CompiledTraffic.supports <rhs_env.traffic.engine.CompiledTraffic.supports>` call starts :func:`workload` in a
background process (:func:`start`) and, until that process has cached the kernels (:func:`ready`), the env steps
its traffic with highway-env's own code, which the core is aligned with (``results/traffic_alignment.md``); from
the step after, the kernels load from the cache and the core steps the scene (packed from the up-to-date vehicle
objects). ``sim="compiled"`` compiles them in the foreground, as does ``RHS_SLAM_BACKGROUND_COMPILE=0`` (then
``sim="auto"`` too), ``NUMBA_DISABLE_JIT=1`` (the kernels run as Python) and a cache that cannot be written.

One background process per cache at a time: the lock file :data:`rhs_common.jit.COMPILE_LOCK` beside
:func:`rhs_env.traffic.core.simulate`'s cache index (:func:`rhs_common.jit.background_compile_running`).

    python -m rhs_env.traffic.warm     # the workload in this process (what the background process runs)
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

__all__ = ["background", "cached", "main", "ready", "start", "workload"]

_ENV_SWITCH = "RHS_SLAM_BACKGROUND_COMPILE"
#: this process' background compile (started once per process)
_STARTED: list[subprocess.Popen] = []


def _entry_kernels() -> tuple[Any, Any]:
    from rhs_env.traffic import core

    return core.simulate, core.reward_terms


def _compiled_here() -> bool:
    """Whether both entry kernels hold a compiled signature in this process (compiled or loaded)."""
    return all(getattr(k, "signatures", None) for k in _entry_kernels())


def cached() -> bool:
    """Whether both entry kernels (:func:`~rhs_env.traffic.core.simulate`, :func:`~rhs_env.traffic.core.reward_terms`)
    have an on-disk cache index (their callees are cached before them)."""
    from rhs_common.jit import cache_index

    indexes = [cache_index(k) for k in _entry_kernels()]
    return all(i is not None and i.exists() for i in indexes)


def _foreground() -> bool:
    """The kernels compile in the foreground here: background compiles off, no JIT, or no cache to share through."""
    from rhs_common.jit import cache_index, numba_module

    if os.environ.get(_ENV_SWITCH, "1") == "0" or numba_module().config.DISABLE_JIT:
        return True
    return cache_index(_entry_kernels()[0]) is None


def ready() -> bool:
    """Whether an env with ``sim="auto"`` steps its traffic with the core now: the kernels are compiled here, or cached
    and no background compile still writes them, or they compile in the foreground (:func:`_foreground`). Starts
    the background compile (:func:`start`) when they are neither."""
    if _compiled_here() or _foreground():
        return True
    from rhs_common.jit import background_compile_running

    if background_compile_running(_entry_kernels()[0]):
        return False
    if cached():
        return True
    return not start()


def background() -> subprocess.Popen | None:
    """The background compile this process started (:func:`start`), or None if it started none."""
    return _STARTED[0] if _STARTED else None


def start() -> bool:
    """Start :func:`workload` in a background process (once per process, one per cache); True if it started."""
    from rhs_common.jit import background_compile_running, compile_lock

    if _STARTED or _foreground():
        return False
    simulate = _entry_kernels()[0]
    lock = compile_lock(simulate)
    if lock is None or background_compile_running(simulate):
        return False
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        lock.write_text(str(os.getpid()))
    except OSError:  # a cache folder we may not write: compile in the foreground
        return False
    env = {**os.environ, _ENV_SWITCH: "0", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "rhs_env.traffic.warm", "--lock", str(lock)], env=env,
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    _STARTED.append(proc)
    with contextlib.suppress(OSError):
        lock.write_text(str(proc.pid))  # the lock now lives as long as the background process
    return True


def workload() -> None:
    """A small highway scene stepped by the core with every meta-action, then its reward: the kernels the envs call,
    with their signatures, compiled and cached."""
    from rhs_env.traffic.alignment import make_scene

    env = make_scene("highway", "compiled", vehicles_count=5)
    env.reset(seed=0)
    for action in range(int(env.action_space.n)):
        env.step(action)
    env.close()


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lock", help="the lock file to remove when done")
    a = ap.parse_args(argv)
    try:
        workload()
    finally:
        if a.lock:
            Path(a.lock).unlink(missing_ok=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
