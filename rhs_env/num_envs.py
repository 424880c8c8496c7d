"""How many envs a vector env may hold, checked where gymnasium reads it.

:func:`check_num_envs` is the bound (an int in [1, :data:`MAX_ENVS`], numpy integers too) and
:class:`SpecKwargs` the registered specs' kwargs dict that applies it when ``gym.make_vec`` reads
``num_envs``. Both live below :mod:`rhs_env.registration` (which registers the ids with
:class:`SpecKwargs`) and :mod:`rhs_env.vector` (which re-exports them), so neither imports the other.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["MAX_ENVS", "SpecKwargs", "check_num_envs"]

#: most envs of one vector env (the CLI's ``--n-envs`` bound)
MAX_ENVS = 256


def check_num_envs(num_envs: Any) -> int:
    """``num_envs`` as an int in [1, :data:`MAX_ENVS`] (numpy integers too); ``ValueError`` naming it otherwise."""
    if isinstance(num_envs, (bool, np.bool_)) or not isinstance(num_envs, (int, np.integer)) \
            or not 1 <= num_envs <= MAX_ENVS:
        raise ValueError(f"num_envs must be an integer in [1, {MAX_ENVS}], got {num_envs!r}")
    return int(num_envs)


class SpecKwargs(dict):
    """The kwargs dict of the project's registered specs: a plain dict whose ``pop("num_envs", n)`` checks ``n``.

    gymnasium's ``make_vec`` deep-copies the spec (the class is kept) and calls
    ``spec_kwargs.pop("num_envs", num_envs)`` before it builds any env, so ``gym.make_vec(id, num_envs=0)``
    (any mode) is :func:`check_num_envs`'s ``ValueError``. A ``num_envs`` set in the dict itself is left to gymnasium.

    >>> SpecKwargs().pop("num_envs", 0)
    Traceback (most recent call last):
    ...
    ValueError: num_envs must be an integer in [1, 256], got 0
    >>> SpecKwargs(a=1).pop("a")
    1
    """

    def pop(self, key: Any, *default: Any) -> Any:
        """``dict.pop``; ``pop("num_envs", n)`` with no ``num_envs`` in the dict checks ``n`` first."""
        if key == "num_envs" and default and key not in self:
            check_num_envs(default[0])
        return super().pop(key, *default)
