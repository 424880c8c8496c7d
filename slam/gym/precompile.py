"""Compile the kernels a SLAM env reaches last in a second process while the env compiles the first (a cold start on two cores).

On an empty kernel cache the first step of a SLAM env compiles every kernel in call order: the radar's
(synthesis, detection, the OMP) first, then the SLAM's (:mod:`slam.core.kernels`: the Doppler fits, the
ICP, the association, the proposal and the landmark update), one after the other on one core. The SLAM's
kernels do not depend on the radar's, so :func:`start` (called by the SLAM env's constructor) runs
:func:`workload` in a background process when their cache is cold, in three parts:

1. a :class:`slam.core.pipeline.SlamPipeline` on synthetic clouds (static roadside points seen by the four
   radars, with their Doppler, from a car at 25 m/s), through the same code paths, so the same signatures
   compile and land in the on-disk cache, which the env's process then loads instead of compiling (first: they
   need none of the radar's kernels, which the env is compiling meanwhile);
2. the OMP's joint refinement's stages and row bookkeeping (:meth:`rhs_env.radar.RadarSystem.warm_refinement`),
   by when the env has cached the Taylor atoms they call;
3. the points (:meth:`rhs_env.radar.RadarSystem.warm_points`) and the one-call OMP
   (:meth:`rhs_env.radar.RadarSystem.warm_one_call_omp`): until the one-call
   OMP is in the cache the env's scans run its body in Python on the compiled stages
   (:data:`rhs_env.kernels.omp_doppler_tiered`, the same bits), so the env's first step does not wait for the
   6-8 s numba spends linking the OMP's whole tree again. The env compiles the points itself (~3 s, reached
   after the OMP): with the points before the SLAM's kernels, the background reached those after the env did,
   which then compiled them itself (docs/results/speed.md, cold start).

One background process per cache at a time: a lock file (:data:`rhs_common.jit.COMPILE_LOCK`, holding the
background process' pid) beside the one-call OMP's cache index, stale after
:data:`rhs_common.jit.LOCK_STALE_S` or once that process is gone; nothing runs with ``NUMBA_DISABLE_JIT=1``,
with a warm cache, or with ``RHS_SLAM_BACKGROUND_COMPILE=0``. The background process prints nothing and needs
nothing from its parent: if the parent reaches a kernel first, it compiles it itself, as before. When the parent
exits first, it says so in one stderr line (not with ``RHS_SLAM_QUIET=1``).

    python -m slam.gym.precompile     # the workload in this process (what the background process runs)
"""

from __future__ import annotations

import os
import subprocess
import sys
from typing import Any

import numpy as np

from rhs_common.jit import BACKGROUND_SWITCH

__all__ = ["main", "start", "synthetic_cloud", "workload"]



def _probes() -> tuple[Any, Any]:
    """The kernels :func:`workload` compiles last, each of its kernel module: the one-call OMP (whose cache folder
    holds the lock) and the RBPF's landmark update."""
    from rhs_env.kernels import omp_doppler
    from slam.core.kernels import landmark_update

    return omp_doppler, landmark_update


def start() -> bool:
    """Start :func:`workload` in a background process if the kernels' cache is cold; True if it started."""
    if os.environ.get(BACKGROUND_SWITCH, "1") == "0":
        return False
    from rhs_common.jit import background_compile_running, cache_index, compile_lock, numba_module, spawn_background_compile

    if numba_module().config.DISABLE_JIT:
        return False
    omp, last = _probes()
    omp_index, last_index, lock = cache_index(omp), cache_index(last), compile_lock(omp)
    if omp_index is None or last_index is None or lock is None or (omp_index.exists() and last_index.exists()):
        return False
    if background_compile_running(omp):
        return False
    proc = spawn_background_compile("slam.gym.precompile", lock)
    if proc is None:  # a cache folder we may not write: nothing to share through it
        return False
    import atexit

    atexit.register(_tell_if_running, proc)
    return True


def _tell_if_running(proc: subprocess.Popen) -> None:
    """At exit: one stderr line when the background compile still runs (it goes on, and caches the kernels it
    compiles for the next runs), unless ``RHS_SLAM_QUIET=1``."""
    from rhs_common.jit import QUIET_ENV

    poll = getattr(proc, "poll", None)  # an atexit hook must never raise (tests stand the process in)
    if callable(poll) and poll() is None and os.environ.get(QUIET_ENV, "0") in ("", "0"):
        print(f"rhs-slam: the background kernel compile (pid {proc.pid}) goes on and caches the last kernels for the "
              f"next runs (a run started meanwhile runs the OMP's Python body on its compiled stages until then)",
              file=sys.stderr, flush=True)


def synthetic_cloud(pose: np.ndarray, velocity: np.ndarray, landmarks: np.ndarray, sensors: np.ndarray,
                    rng: np.random.Generator) -> np.ndarray:
    """Rows ``x, y, vr, amplitude, range std, angle std, radar`` (N, 7) of the static ``landmarks`` (world, m) seen
    from ``pose`` (x, y, heading) at ``velocity`` (vehicle frame, m/s) by the radar ``sensors`` (4, 2) nearest each."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = landmarks - pose[:2]
    p = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])  # vehicle frame
    p = p[np.hypot(p[:, 0], p[:, 1]) < 90.0]
    radar = np.argmin(np.linalg.norm(p[:, None, :] - sensors[None], axis=2), axis=1)
    los = p - sensors[radar]
    u = los / np.linalg.norm(los, axis=1, keepdims=True)
    vr = -(u @ velocity) + rng.normal(0, 0.02, len(p))
    xy = p + rng.normal(0, 0.03, p.shape)
    n = len(p)
    return np.column_stack([xy, vr, np.full(n, 20.0), np.full(n, 0.05), np.full(n, 0.002), radar.astype(float)])


def workload(cycles: int = 8) -> None:
    """The SLAM env's pipeline (default configs, the four radars' mounts) on ``cycles`` synthetic clouds, the OMP's
    refinement stages, then the points and the one-call OMP (:class:`rhs_env.radar.RadarSystem`'s ``warm_*``)."""
    from rhs_env.radar_config import RadarConfig
    from slam.core.pipeline import SlamPipeline
    from slam.core.rbpf import SlamConfig
    from slam.core.registration import DEFAULT_REGISTRATION, make_registration

    rng = np.random.default_rng(0)
    sensors = RadarConfig().mounting.mounts()[0]
    xs = np.arange(-100.0, 400.0, 9.0)
    landmarks = np.concatenate([np.column_stack([xs, np.full(xs.size, 11.0)]),
                                np.column_stack([xs + 4.0, np.full(xs.size, -9.0)])])
    pipeline = SlamPipeline(make_registration(DEFAULT_REGISTRATION), SlamConfig(), np.random.default_rng(0),
                            sensor_xy=sensors)
    dt, speed = 0.2, 25.0
    for k in range(cycles):
        pose = np.array([speed * dt * k, 0.0, 0.0])
        pipeline.step(synthetic_cloud(pose, np.array([speed, 0.0]), landmarks, sensors, rng), dt)
    from rhs_env.radar import RadarSystem  # (~1 s of imports: after the SLAM's kernels)

    radar = RadarSystem(RadarConfig(), np.random.default_rng(0))
    radar.warm_refinement()
    radar.warm_points()
    radar.warm_one_call_omp()


def main(argv: list[str] | None = None) -> int:
    from rhs_common.jit import background_main

    return background_main(workload, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    sys.exit(main())
