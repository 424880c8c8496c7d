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

import os
import subprocess
import sys
from typing import Any

from rhs_common.jit import BACKGROUND_SWITCH

__all__ = ["background", "cached", "main", "ready", "start", "workload"]

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

    if os.environ.get(BACKGROUND_SWITCH, "1") == "0" or numba_module().config.DISABLE_JIT:
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
    from rhs_common.jit import background_compile_running, compile_lock, spawn_background_compile

    if _STARTED or _foreground():
        return False
    simulate = _entry_kernels()[0]
    lock = compile_lock(simulate)
    if lock is None or background_compile_running(simulate):
        return False
    proc = spawn_background_compile("rhs_env.traffic.warm", lock)
    if proc is None:  # a cache folder we may not write: compile in the foreground
        return False
    _STARTED.append(proc)
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
    from rhs_common.jit import background_main

    return background_main(workload, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    sys.exit(main())
