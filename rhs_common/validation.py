"""Configuration validation and building: one mechanism for every config dataclass.

Every config of the project is a frozen dataclass whose ``__post_init__`` calls
:func:`check_types` (each field against its type hint: a wrong type raises
``TypeError``) and then the range checks below (a wrong value raises
``ValueError`` naming the field and the allowed range). :func:`build` turns a
nested mapping (what ``gym.make(..., radar={...})`` receives) into such a
config, recursively by the type hints, and prefixes every error with the field
path: ``radar.detection.pfa must be in (0.0, 0.5], got 2``.

Fields that moved when a config was regrouped stay accepted in mappings: the
class attribute ``MOVED_FIELDS`` (old name -> new dotted path, e.g.
``{"cfar_pfa": "detection.pfa"}``) makes :func:`build` move each old key to its
new place with a ``DeprecationWarning`` that names the new path
(``radar.cfar_pfa is now radar.detection.pfa``); the same field given both ways
is a ``ValueError``. :func:`flat_dict` is the inverse (the old flat dict of a config).

Why a small builder of our own rather than pydantic's dataclasses or cattrs:
both would do the recursion and the type checks, but the range checks and their
messages (the allowed interval in the message) live in our ``__post_init__``
anyway, the configs must stay plain frozen dataclasses that pickle into
subprocess vector envs, and ~100 lines here cost less than a dependency whose
error format (pydantic's multi-line reports, cattrs' exception groups) we would
have to translate back into one line that names the field.

Examples:
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Inner:
    ...     pfa: float = 1e-6
    ...     def __post_init__(self):
    ...         check_types(self)
    ...         check_range("pfa", self.pfa, 0.0, 0.5, low_open=True)
    >>> @dataclass(frozen=True)
    ... class Outer:
    ...     detection: Inner = Inner()
    ...     def __post_init__(self):
    ...         check_types(self)
    >>> build(Outer, {"detection": {"pfa": 1e-3}}).detection.pfa
    0.001
    >>> build(Outer, {"detection": {"pfa": 2}}, "radar")
    Traceback (most recent call last):
    ...
    ValueError: radar.detection.pfa must be in (0.0, 0.5], got 2.0
    >>> build(Outer, {"detection": {"pfa": "2"}}, "radar")
    Traceback (most recent call last):
    ...
    TypeError: radar.detection.pfa must be a number, got '2' (str)
    >>> Outer.MOVED_FIELDS = {"cfar_pfa": "detection.pfa"}  # a field of before the grouping
    >>> import warnings
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     build(Outer, {"cfar_pfa": 1e-3}, "radar").detection.pfa
    0.001
    >>> str(caught[0].message)
    'radar.cfar_pfa is now radar.detection.pfa'
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
import sys
import types
import typing
import warnings
from collections.abc import Mapping
from typing import Any, TypeVar

import numpy as np

__all__ = [
    "DEFAULT_MEMORY_LIMIT_BYTES", "MEMORY_LIMIT_ENV", "apply_moved_fields", "build", "check_bool", "check_choice",
    "check_int", "check_memory", "check_output_path", "check_range", "check_types", "config_json", "flat_dict",
    "format_bytes", "memory_limit_bytes", "unknown_fields_message",
]

T = TypeVar("T")


# --------------------------------------------------------------------------- scalar checks
def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _is_int(value: Any) -> bool:
    return isinstance(value, (numbers.Integral, np.integer)) and not isinstance(value, (bool, np.bool_))


def _shown(value: Any) -> str:
    """``repr(value)``, an integer of more than 30 digits by its size (Python refuses to write one past 4300 digits)."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 100:
        return f"an integer of about {int(value.bit_length() * math.log10(2)) + 1} digits"
    return repr(value)


def check_range(
    field: str,
    value: Any,
    low: float | None = None,
    high: float | None = None,
    *,
    low_open: bool = False,
    high_open: bool = False,
) -> None:
    """``TypeError`` unless ``value`` is a real number; ``ValueError`` unless finite and ``low <= value <= high``."""
    lo_br = "(" if low_open else "["
    hi_br = ")" if high_open else "]"
    allowed = f"{lo_br}{'-inf' if low is None else low}, {'inf' if high is None else high}{hi_br}"
    if not _is_real(value):
        raise TypeError(f"{field} must be a number in {allowed}, got {value!r} ({type(value).__name__})")
    try:
        v = float(value)
    except OverflowError:  # an int past 1.8e308 (10**400)
        v = math.inf
    if not math.isfinite(v):  # NaN and +-inf: every bound keeps the work finite
        raise ValueError(f"{field} must be a finite number in {allowed}, got {_shown(value)}")
    bad = (low is not None and (v <= low if low_open else v < low)) or (
        high is not None and (v >= high if high_open else v > high)
    )
    if bad:
        raise ValueError(f"{field} must be in {allowed}, got {_shown(value)}")


def check_int(field: str, value: Any, low: int | None = None, high: int | None = None) -> None:
    """``TypeError`` unless ``value`` is an integer (not a bool); ``ValueError`` unless in ``[low, high]``."""
    if not _is_int(value):
        raise TypeError(f"{field} must be an integer, got {value!r} ({type(value).__name__})")
    check_range(field, int(value), low, high)


def check_bool(field: str, value: Any) -> None:
    """``TypeError`` unless ``value`` is ``True`` or ``False`` (not 0 / 1 or a string)."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{field} must be True or False, got {value!r} ({type(value).__name__})")


def check_choice(field: str, value: Any, choices: tuple[str, ...]) -> None:
    """``TypeError`` unless ``value`` is a string, ``ValueError`` unless it is one of ``choices``."""
    if not isinstance(value, str):
        raise TypeError(f"{field} must be one of {', '.join(map(repr, choices))}, got {value!r} ({type(value).__name__})")
    if value not in choices:
        raise ValueError(f"{field} must be one of {', '.join(map(repr, choices))}, got {value!r}")


# --------------------------------------------------------------------------- memory
#: environment variable that overrides :data:`DEFAULT_MEMORY_LIMIT_BYTES` (bytes, or with a K / M / G / T suffix)
MEMORY_LIMIT_ENV = "RHS_SLAM_MEMORY_LIMIT"
#: the largest allocation a config may ask for before it is refused (8 GiB; the defaults need a few MB)
DEFAULT_MEMORY_LIMIT_BYTES = 8 * 2**30
_SUFFIXES = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}


def format_bytes(nbytes: float) -> str:
    """``nbytes`` in the largest binary unit that keeps it >= 1: ``format_bytes(3 * 2**30) == '3.00 GiB'``."""
    for unit, size in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if nbytes >= size:
            return f"{nbytes / size:.2f} {unit}"
    return f"{nbytes:.0f} B"


def memory_limit_bytes() -> int:
    """The allocation limit of :func:`check_memory`: ``$RHS_SLAM_MEMORY_LIMIT`` if set, else 8 GiB.

    The variable holds a number of bytes, optionally with a binary suffix (``32G``, ``512M``,
    ``1.5T``; a trailing ``B`` / ``iB`` is allowed). Anything else is a ``ValueError`` naming it.
    """
    import os

    text = os.environ.get(MEMORY_LIMIT_ENV, "").strip()
    if not text:
        return DEFAULT_MEMORY_LIMIT_BYTES
    t = text.upper().removesuffix("IB").removesuffix("B")
    unit = t[-1:] if t[-1:] in _SUFFIXES else ""
    try:
        value = float(t[: len(t) - len(unit)])
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"{MEMORY_LIMIT_ENV} must be a positive number of bytes (e.g. 17179869184 or 16G), "
                         f"got {text!r}")
    return int(value * _SUFFIXES[unit])


def check_memory(what: str, nbytes: float, limit: int | None = None) -> None:
    """``ValueError`` when an allocation of ``nbytes`` (``what``: the fields and their product) exceeds the limit.

    Called by the configs at construction, so a setting that would exhaust memory is refused
    before any array is made, naming the fields and the bytes; ``limit`` defaults to
    :func:`memory_limit_bytes` (``$RHS_SLAM_MEMORY_LIMIT``, 8 GiB).

    >>> check_memory("n_particles x max_landmarks = 100 x 256 slots", 1.7e6)
    >>> check_memory("n_particles x max_landmarks = 100000 x 5000 slots", 3.25e10, limit=2**33)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: n_particles x max_landmarks = 100000 x 5000 slots needs 30.27 GiB (3.25e+10 bytes), above ... 8.00 GiB; ...
    """
    cap = memory_limit_bytes() if limit is None else limit
    if nbytes > cap:
        raise ValueError(f"{what} needs {format_bytes(nbytes)} ({nbytes:.3g} bytes), above the memory limit of "
                         f"{format_bytes(cap)}; lower them, or raise the limit with the environment variable "
                         f"{MEMORY_LIMIT_ENV} (bytes, e.g. 64G)")


# --------------------------------------------------------------------------- type hints
_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    """Resolved type hints of a dataclass (cached); names the module cannot resolve (a class
    defined in a function or a doctest) are looked up among the classes of the fields' defaults."""
    if cls not in _HINTS:
        try:
            _HINTS[cls] = typing.get_type_hints(cls)
        except NameError:
            local: dict[str, Any] = {}
            for f in dataclasses.fields(cls):
                default = f.default if f.default is not dataclasses.MISSING else (
                    f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
                local[type(default).__name__] = type(default)
            _HINTS[cls] = typing.get_type_hints(cls, localns=local)
    return _HINTS[cls]


def _union_args(hint: Any) -> tuple[Any, ...] | None:
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return typing.get_args(hint)
    return None


def _type_error(field: str, value: Any, hint: Any) -> str | None:
    """Why ``value`` does not fit ``hint`` (None when it does). Unknown hints accept anything."""
    args = _union_args(hint)
    if args is not None:
        reasons = [_type_error(field, value, a) for a in args]
        return None if any(r is None for r in reasons) else next(r for r in reasons if r)
    if hint is type(None):
        return None if value is None else f"{field} must be None"
    origin = typing.get_origin(hint)
    if hint is float:
        return None if _is_real(value) else f"{field} must be a number"
    if hint is int:
        return None if _is_int(value) else f"{field} must be an integer"
    if hint is bool:
        return None if isinstance(value, (bool, np.bool_)) else f"{field} must be True or False"
    if hint is str:
        return None if isinstance(value, str) else f"{field} must be a string"
    if origin is typing.Literal:
        return None if isinstance(value, str) or value in typing.get_args(hint) else f"{field} must be a string"
    if origin is tuple or hint is tuple:
        return None if isinstance(value, tuple) else f"{field} must be a tuple"
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return None if isinstance(value, hint) else f"{field} must be a {hint.__name__} or a dict of its fields"
    return None


def check_types(config: Any) -> None:
    """``TypeError`` naming the first field of a config dataclass whose value does not fit its type hint.

    An integer or a numpy number given for a ``float`` field is stored as a Python float, a
    numpy integer for an ``int`` field as a Python int, so equal configs compare and hash
    equal and serialise (``grid_deg=5``, ``5.0`` and ``np.float32(5.0)`` name the same pattern library).
    """
    hints = _hints(type(config))
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        hint = hints.get(f.name, Any)
        reason = _type_error(f.name, value, hint)
        if reason:
            raise TypeError(f"{reason}, got {value!r} ({type(value).__name__})")
        if hint is float and not isinstance(value, float):  # an int or a numpy scalar: the Python float
            try:
                object.__setattr__(config, f.name, float(value))
            except OverflowError:  # an int past 1.8e308
                raise ValueError(f"{f.name} must be a finite number, got {_shown(value)}") from None
        elif hint is int and isinstance(value, np.integer):
            object.__setattr__(config, f.name, int(value))


# --------------------------------------------------------------------------- building
def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def _nested_class(hint: Any) -> type | None:
    """The dataclass a field holds (``X`` or ``X | None``), else None."""
    for h in _union_args(hint) or (hint,):
        if dataclasses.is_dataclass(h) and isinstance(h, type):
            return h
    return None


def _optional(hint: Any) -> bool:
    """The hint admits None (``X | None``)."""
    return type(None) in (_union_args(hint) or ())


def _value(hint: Any, value: Any, path: str) -> Any:
    nested = _nested_class(hint)
    if nested is not None and isinstance(value, Mapping):
        return build(nested, value, path)
    if isinstance(value, list) and (typing.get_origin(hint) is tuple or hint is tuple):
        return tuple(value)
    return value


def unknown_fields_message(cls: type, unknown: list[str], path: str) -> str:
    """``ValueError`` text for keys that are not fields of ``cls``."""
    known = sorted(f.name for f in dataclasses.fields(cls) if f.init)
    where = path or cls.__name__
    return f"{where} has unknown field(s) {', '.join(map(repr, unknown))}; allowed: {', '.join(known)}"


#: packages whose frames a moved-field warning skips: it names the caller of ``gym.make`` / the config
_INTERNAL_PACKAGES = ("rhs_common", "rhs_env", "slam", "agents", "rhs_slam", "gymnasium")


def _caller_stacklevel() -> int:
    """``stacklevel`` of the first frame outside this project's packages (and gymnasium), for ``warnings.warn``."""
    frame = sys._getframe(1)
    level = 1
    while frame is not None and frame.f_globals.get("__name__", "").split(".")[0] in _INTERNAL_PACKAGES:
        frame = frame.f_back  # type: ignore[assignment]
        level += 1
    return level


def _moved_path(cls: type, key: str, value: Any) -> str | None:
    """The new path of a key of ``cls.MOVED_FIELDS`` given in a mapping, None when it is taken as it is.

    A moved name that is no longer a field always moves. A name that is a field
    again, now a nested config (``detection``, once a string, now a group whose
    ``mode`` the string became), moves only when its value is not that config or
    a mapping of its fields.
    """
    moved: Mapping[str, str] = getattr(cls, "MOVED_FIELDS", {})
    if key not in moved:
        return None
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    if key not in names:
        return moved[key]
    group = _nested_class(_hints(cls).get(key, Any))
    if group is not None and not isinstance(value, (Mapping, group)) and moved[key].startswith(key + "."):
        return moved[key]
    return None


def _place(tree: dict[str, Any], old: str, new: str, value: Any, path: str) -> None:
    """Put ``value`` at the dotted path ``new`` of ``tree`` (copying the mappings on the way); ValueError on a conflict."""
    old_p, new_p = _join(path, old), _join(path, new)
    *parents, leaf = new.split(".")
    node = tree
    for i, part in enumerate(parents):
        sub = node.get(part)
        if sub is not None and not isinstance(sub, Mapping):
            given = _join(path, ".".join(parents[: i + 1]))
            raise ValueError(f"{old_p} (now {new_p}) conflicts with {given} given as a whole; give {new_p} once")
        node[part] = dict(sub or {})
        node = node[part]
    if leaf in node:
        raise ValueError(f"{old_p} and {new_p} both given ({old_p} is now {new_p}); give it once")
    node[leaf] = value


def apply_moved_fields(cls: type, value: Mapping[str, Any], path: str = "") -> dict[str, Any]:
    """``value`` with the keys of ``cls.MOVED_FIELDS`` (old flat names) moved to their new nested paths.

    Each moved key emits a ``DeprecationWarning`` naming the new path
    (``radar.cfar_pfa is now radar.detection.pfa``); the same field given both
    ways (``{"cfar_pfa": 1e-5, "detection": {"pfa": 1e-4}}``) is a ``ValueError``.
    The input is not modified.
    """
    out = dict(value)
    moves = []
    for key, v in value.items():
        new = _moved_path(cls, str(key), v)
        if new is not None:
            moves.append((str(key), new, out.pop(key)))
    for old, new, v in moves:
        warnings.warn(f"{_join(path, old)} is now {_join(path, new)}", DeprecationWarning,
                      stacklevel=_caller_stacklevel())
        _place(out, old, new, v, path)
    return out


def flat_dict(config: Any) -> dict[str, Any]:
    """``asdict(config)`` with the fields of ``MOVED_FIELDS`` back under their old flat names.

    The inverse of :func:`apply_moved_fields`: the dict the config had before its
    fields were grouped (a stable identity for keys or seeds derived from it). A
    field of a group that has no old name (added after the grouping) appears
    under its dotted path, except where the class attribute ``ADDED_FIELDS``
    (dotted path -> the value that behaves as before the field existed) holds its
    value: then it is left out, so the identity of a config that does what it
    did before is the identity it had.
    """
    tree = dataclasses.asdict(config)
    added: Mapping[str, Any] = getattr(type(config), "ADDED_FIELDS", {})
    moved: Mapping[str, str] = getattr(type(config), "MOVED_FIELDS", {})
    by_new = {new: old for old, new in moved.items()}
    groups = {new.split(".")[0] for new in moved.values()}
    out = {k: v for k, v in tree.items() if k not in groups and not (k in added and v == added[k])}

    def walk(node: dict[str, Any], prefix: str) -> None:
        for k, v in node.items():
            p = _join(prefix, k)
            if p in by_new:
                out[by_new[p]] = v
            elif isinstance(v, dict) and any(n.startswith(p + ".") for n in by_new):
                walk(v, p)
            elif not (p in added and v == added[p]):
                out[p] = v

    walk({g: tree[g] for g in groups if g in tree}, "")
    return out


def build(cls: type[T], value: Any = None, path: str = "") -> T:
    """A ``cls`` from None (defaults), an instance (kept) or a mapping of its fields (recursive).

    Nested config fields accept mappings too, and None for "the group's default" (unless the
    field itself may be None). Errors name the field path:
    unknown keys and out-of-range values raise ``ValueError``, wrong types
    ``TypeError``. Old flat names listed in ``cls.MOVED_FIELDS`` (a class
    attribute, old name -> new dotted path) are moved to their new place with a
    ``DeprecationWarning`` (:func:`apply_moved_fields`).
    """
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if not isinstance(value, Mapping):
        raise TypeError(f"{path or cls.__name__} must be a {cls.__name__} or a dict of its fields, "
                        f"got {type(value).__name__}")
    if getattr(cls, "MOVED_FIELDS", None):
        value = apply_moved_fields(cls, value, path)
    names = {f.name for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    unknown = sorted(str(k) for k in value if k not in names)
    if unknown:
        raise ValueError(unknown_fields_message(cls, unknown, path))
    hints = _hints(cls)
    # None for a nested group that cannot be None means "the default" (``radar={"waveform": None}``)
    kwargs = {k: _value(hints.get(k, Any), v, _join(path, k)) for k, v in value.items()
              if not (v is None and _nested_class(hints.get(k, Any)) is not None and not _optional(hints.get(k, Any)))}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as err:
        if not path or str(err).startswith(path):
            raise
        raise type(err)(_join(path, str(err))) from None


# --------------------------------------------------------------------------- output paths
def check_output_path(field: str, path: Any, directory: bool = False) -> None:
    """``ValueError`` naming ``field`` unless ``path`` can be written; call it before any work starts.

    Tried, not guessed (permissions lie for root and on read-only mounts): the
    missing parent directories are created (the writer would create them anyway);
    a file path is opened for appending, or created and removed again; a
    directory (``directory=True``) is created. An existing directory where a
    file is expected, or the reverse, is refused.
    """
    import os
    from pathlib import Path

    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise TypeError(f"{field} must be a path, got {path!r} ({type(path).__name__})")
    p = Path(path)
    try:
        if directory:
            if p.exists() and not p.is_dir():
                raise ValueError(f"{field}: {p} exists and is not a directory")
            p.mkdir(parents=True, exist_ok=True)
            probe = p / f".rhs-slam-write-test-{os.getpid()}"
            probe.touch()
            probe.unlink()
            return
        if p.is_dir():
            raise ValueError(f"{field}: {p} is a directory, expected a file path")
        if p.exists() and not p.is_file():  # a FIFO would block the open below, a device would take the output
            raise ValueError(f"{field}: {p} is not a regular file (a named pipe, device or socket); give a file path")
        p.parent.mkdir(parents=True, exist_ok=True)
        if p.exists():
            with p.open("a"):
                pass
        else:
            p.touch()
            p.unlink()
    except OSError as exc:
        raise ValueError(f"{field}: cannot write {p}: {exc.strerror or exc}") from None


def config_json(*parts: dict[str, Any]) -> str:
    """Canonical JSON of merged config dicts (sorted keys), the input of config hashes.

    A numpy scalar is written as the Python number of the same value (``np.float32(5.0)`` as ``5.0``).
    """
    merged: dict[str, Any] = {}
    for p in parts:
        merged.update(p)
    return json.dumps(merged, sort_keys=True, separators=(",", ":"), default=_json_number)


def _json_number(value: Any) -> Any:
    """``json.dumps``'s fallback: numpy scalars as Python numbers, anything else refused as json does."""
    item = getattr(value, "item", None)
    if item is not None and getattr(value, "shape", None) == ():
        return item()
    raise TypeError(f"Object of type {type(value).__name__} is not JSON serializable")
