"""The studies' process pool: episodes on a list of seeds, in contiguous chunks, one single-threaded worker each.

Every study that drives episodes in parallel splits its seeds the same way (:func:`seed_chunks`: ``workers``
contiguous chunks, the last one shorter) and runs one chunk per worker process; each episode is seeded by its own
seed, so the chunking moves no number. Workers run one BLAS / OpenMP thread
(:func:`rhs_env.parallel.single_threaded_worker`, the pool's initializer), so ``workers`` is the cores used.
:func:`map_jobs` runs a list of unlike jobs (Fig. 5a's antenna x power x seed episodes) the same way.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, TypeVar

from rhs_common.validation import check_int
from rhs_env.parallel import single_threaded_worker

T = TypeVar("T")


def seed_chunks(seeds: Sequence[int], workers: int) -> list[list[int]]:
    """``seeds`` in at most ``workers`` contiguous chunks of ``ceil(len / workers)`` seeds.

    >>> seed_chunks(list(range(5)), 2)
    [[0, 1, 2], [3, 4]]
    """
    check_int("workers", workers, 1, 256)
    k = -(-len(seeds) // workers) or 1
    return [list(seeds[i : i + k]) for i in range(0, len(seeds), k)]


def _one_thread_here() -> None:
    """What a chunk run in this process sets first: one OpenMP thread unless the caller chose (as the workers)."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def map_seeds(func: Callable[..., list[T]], seeds: Sequence[int], workers: int, *args: Any) -> list[T]:
    """``func(chunk, *args)`` over :func:`seed_chunks` of ``seeds``, concatenated in seed order.

    Args:
        func: a module-level function (picklable) returning one result per seed of its chunk.
        seeds: the episode seeds.
        workers: processes (1: every chunk in this process, no pool).
        *args: passed to every call after the chunk.

    Returns:
        The results of every chunk, in the order of ``seeds``.
    """
    if workers <= 1:
        _one_thread_here()
        return list(func(list(seeds), *args))
    parts = seed_chunks(seeds, workers)
    with ProcessPoolExecutor(max_workers=len(parts), initializer=single_threaded_worker) as pool:
        done = list(pool.map(func, parts, *([a] * len(parts) for a in args)))
    return [r for part in done for r in part]


def map_jobs(func: Callable[..., T], jobs: Sequence[tuple[Any, ...]], workers: int,
             on_result: Callable[[T], None] | None = None) -> list[T]:
    """``func(*job)`` for every job over ``workers`` processes; ``on_result`` called on each result as it arrives
    (in completion order: a study saving partial results).

    Args:
        func: a module-level function (picklable).
        jobs: the argument tuples.
        workers: processes (1: in this process, in order).
        on_result: called with each result when it is done.

    Returns:
        The results in completion order (in ``jobs`` order with one worker).
    """
    out: list[T] = []

    def take(result: T) -> None:
        out.append(result)
        if on_result is not None:
            on_result(result)

    if workers <= 1:
        for job in jobs:
            take(func(*job))
        return out
    with ProcessPoolExecutor(workers, initializer=single_threaded_worker) as pool:
        for fut in as_completed([pool.submit(func, *job) for job in jobs]):
            take(fut.result())
    return out


__all__ = ["map_jobs", "map_seeds", "seed_chunks", "single_threaded_worker"]
