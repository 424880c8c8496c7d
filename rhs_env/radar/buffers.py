"""Persistent work arrays of a radar stage: the large temporaries of a scan, allocated once and re-used."""

from __future__ import annotations

import numpy as np

__all__ = ["WorkBuffers"]


class WorkBuffers:
    """Named work arrays re-used across scans (no fresh allocation, so no page faults, per scan).

    Examples:
        >>> import numpy as np
        >>> buf = WorkBuffers()
        >>> a = buf.get("x", (2, 3), np.float32)
        >>> a is buf.get("x", (2, 3), np.float32), a is buf.get("x", (3, 2), np.float32)
        (True, False)
    """

    def __init__(self) -> None:
        self._arrays: dict[str, np.ndarray] = {}

    def get(self, name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
        """The array ``name`` of this shape and dtype (its contents are the last user's), allocated when it changes."""
        buf = self._arrays.get(name)
        if buf is None or buf.shape != shape or buf.dtype != dtype:
            buf = self._arrays[name] = np.empty(shape, dtype)
        return buf
