"""Deprecated location: the checks live in :mod:`rhs_common.validation` (kept one release for old imports)."""

from rhs_common.validation import (
    build,
    check_bool,
    check_choice,
    check_int,
    check_range,
    check_types,
)

__all__ = ["build", "check_bool", "check_choice", "check_int", "check_range", "check_types"]
