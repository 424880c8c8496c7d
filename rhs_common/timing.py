"""Wall-time per named stage, for the benchmark's stage tables.

Examples:
    >>> timer = StageTimer()
    >>> with timer("predict"):
    ...     _ = sum(range(10))
    >>> sorted(timer.times)
    ['predict']
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["StageTimer"]


class StageTimer:
    """Accumulates ``time.perf_counter`` seconds per stage name in :attr:`times`."""

    def __init__(self) -> None:
        self.times: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.times[stage] = self.times.get(stage, 0.0) + time.perf_counter() - t0

    def reset(self) -> None:
        self.times = {}
