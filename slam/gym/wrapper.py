"""Deprecated: the former name of :mod:`slam.gym.wrappers` (renamed like ``rhs_env.wrappers``), kept so that old
imports still work.

``from slam.gym.wrapper import SlamObservation`` gives the same object as ``from slam.gym.wrappers import
SlamObservation``, with a ``DeprecationWarning`` that names the new module.
"""

from __future__ import annotations

import warnings
from typing import Any

from slam.gym import wrappers as _wrappers

__all__ = list(_wrappers.__all__)


def __getattr__(name: str) -> Any:
    value = getattr(_wrappers, name)
    warnings.warn(f"slam.gym.wrapper is now slam.gym.wrappers: import {name} from there", DeprecationWarning,
                  stacklevel=2)
    return value
