"""Field checks shared by the configuration dataclasses.

Every check raises ``ValueError`` that names the field and the allowed range,
so a wrong ``gym.make(..., **kwargs)`` value fails at construction.
"""

from __future__ import annotations

import math
from typing import Any


def check_range(
    field: str,
    value: Any,
    low: float | None = None,
    high: float | None = None,
    *,
    low_open: bool = False,
    high_open: bool = False,
) -> None:
    """Raise ``ValueError`` unless ``low <= value <= high`` (open ends where asked)."""
    lo_br = "(" if low_open else "["
    hi_br = ")" if high_open else "]"
    allowed = f"{lo_br}{'-inf' if low is None else low}, {'inf' if high is None else high}{hi_br}"
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{field} must be a number in {allowed}, got {value!r}") from None
    if math.isnan(v):
        raise ValueError(f"{field} must be a number in {allowed}, got NaN")
    bad = (
        (low is not None and (v <= low if low_open else v < low))
        or (high is not None and (v >= high if high_open else v > high))
    )
    if bad:
        raise ValueError(f"{field} must be in {allowed}, got {value!r}")


def check_int(field: str, value: Any, low: int | None = None, high: int | None = None) -> None:
    """Raise ``ValueError`` unless ``value`` is an integer in ``[low, high]``."""
    if isinstance(value, bool) or not isinstance(value, (int,)) and not (
        hasattr(value, "__index__")
    ):
        raise ValueError(f"{field} must be an integer, got {value!r}")
    check_range(field, int(value), low, high)


def check_bool(field: str, value: Any) -> None:
    """Raise ``ValueError`` unless ``value`` is ``True`` or ``False`` (not 0 / 1 or a string)."""
    if not isinstance(value, bool):
        raise ValueError(f"{field} must be True or False, got {value!r}")  # noqa: TRY004 (config errors are ValueError)


def check_choice(field: str, value: Any, choices: tuple[str, ...]) -> None:
    """Raise ``ValueError`` unless ``value`` is one of ``choices``."""
    if value not in choices:
        raise ValueError(f"{field} must be one of {', '.join(map(repr, choices))}, got {value!r}")
