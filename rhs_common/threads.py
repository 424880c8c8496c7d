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
import threading
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


_INSIDE = threading.local()  # the limit of the innermost open block of this thread (``limit``), if any


@contextlib.contextmanager
def blas_threads_limit(threads: int | None) -> Iterator[None]:
    """Limit every BLAS / OpenMP pool to ``threads`` inside the block, restore the previous limits after.

    A block inside another block of the same limit (the SLAM wrapper's step around the radar wrapper's) changes
    nothing and skips threadpoolctl's query-and-set of every pool (~0.1 ms).
    """
    if threads is None or getattr(_INSIDE, "limit", None) == threads:
        yield
        return
    outer = getattr(_INSIDE, "limit", None)
    with _controller().limit(limits=threads):
        _INSIDE.limit = threads
        try:
            yield
        finally:
            _INSIDE.limit = outer
