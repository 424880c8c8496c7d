"""Single-threaded BLAS / OpenMP inside env steps, scoped to the step (threadpoolctl).

An env step does many small matrix products (radar OMP, SLAM): BLAS threads buy
nothing there and, with another busy process on the machine (a second
``SubprocVecEnv`` worker), they fight it and halve the step rate. The wrappers
therefore run their work inside :func:`blas_threads_limit` with ``threads=1`` by
default; the limits of the user's process are restored on exit, so nothing
outside the step changes. ``threads=None`` leaves the thread pools alone (a
single-env user who wants BLAS threads opts in with ``blas_threads=None``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np
from threadpoolctl import ThreadpoolController

__all__ = ["blas_threads_limit", "check_blas_threads"]

_CONTROLLER: ThreadpoolController | None = None


def _controller() -> ThreadpoolController:
    """The process's thread-pool controller, built once (a fresh scan of the loaded libraries costs ~1 ms)."""
    global _CONTROLLER
    if _CONTROLLER is None:
        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER


def check_blas_threads(value: int | None) -> int | None:
    """``None`` (leave the thread pools alone) or an integer in [1, 1024] (a numpy integer too, returned as an int);
    ValueError naming ``blas_threads`` otherwise."""
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not 1 <= value <= 1024:
        raise ValueError(f"blas_threads must be None or an int in [1, 1024], got {value!r}")
    return int(value)


@contextlib.contextmanager
def blas_threads_limit(threads: int | None) -> Iterator[None]:
    """Limit every BLAS / OpenMP pool to ``threads`` inside the block, restore the previous limits after."""
    if threads is None:
        yield
        return
    with _controller().limit(limits=threads):
        yield
