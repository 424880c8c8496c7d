"""The threads a training run uses: torch's in the learner, one per worker process.

:func:`limit_threads` sets torch's intra-op threads here and ``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS`` = 1 for the
workers (unless set already); :func:`update_threads_for` chooses the threads of an on-policy update, when the
workers wait.
"""

from __future__ import annotations

import os

__all__ = ["limit_threads", "update_threads_for"]


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
