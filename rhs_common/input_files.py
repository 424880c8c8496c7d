"""Safe readers of the JSON and YAML documents users hand in (scene / scenario files, ``--env-kwargs``,
``--hyperparams``).

Every failure is an :class:`InputError` (a ``ValueError``) whose one-line message starts with
the name of the file (or flag) and says what is wrong, so a command can print it and exit 2:

* bytes that are not UTF-8 (the offset of the first bad byte); a UTF-8 byte-order mark is skipped;
* nesting deeper than :data:`MAX_DEPTH` (Python's parsers recurse: 200 000 ``[`` would be a
  ``RecursionError``; 64 levels are far more than any document here has: 3);
* integers of more than :data:`MAX_INT_DIGITS` digits (a seed is < 2**63, 19 digits; a
  400-digit integer overflows every float conversion, and past 4300 digits Python refuses
  to read it at all);
* a document that does not parse (the parser's message with line and column).

What the values mean (numbers where numbers belong, their ranges) is checked by the reader
of each document; :func:`check_number` is the shared test for "a real number, not a string
or a boolean, finite".
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

__all__ = [
    "InputError", "MAX_BYTES", "MAX_DEPTH", "MAX_INT_DIGITS", "check_number", "nesting_depth", "parse_json",
    "read_json", "read_text", "read_yaml",
]

#: deepest nesting of lists / objects accepted in a document
MAX_DEPTH = 64
#: most digits of an integer literal (2**63 has 19)
MAX_INT_DIGITS = 30
#: largest document read, bytes (a scenario of 100 000 poses is ~5 MB)
MAX_BYTES = 256 * 1024 * 1024

_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")


class InputError(ValueError):
    """A document that cannot be read; the message names it and fits on one line."""


def read_text(path: str | Path, name: str | None = None) -> str:
    """The text of ``path``, strict UTF-8 (a leading byte-order mark skipped); ``InputError`` naming it otherwise."""
    name = name or str(path)
    try:
        p = Path(path)
        if p.is_dir():
            raise InputError(f"{name}: cannot read it: is a directory, expected a file")
        if p.exists() and p.stat().st_size > MAX_BYTES:
            raise InputError(f"{name}: larger than {MAX_BYTES // 2**20} MiB")
        data = p.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{name}: cannot read it: no such file") from None
    except OSError as exc:
        raise InputError(f"{name}: cannot read it: {exc.strerror or exc}") from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"{name}: not UTF-8 text (byte {exc.start} is {data[exc.start:exc.start + 1]!r}); "
                         "save it as UTF-8") from None


def nesting_depth(text: str, strings: re.Pattern[str] = _STRING) -> int:
    """The deepest nesting of ``[`` / ``{`` in JSON (or YAML flow) text, brackets inside strings ignored."""
    brackets = _NOT_BRACKET.sub("", strings.sub("", text))
    depth = deepest = 0
    for ch in brackets:
        if ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        else:
            depth -= 1
    return deepest


def _check_depth(text: str, name: str, strings: re.Pattern[str] = _STRING) -> None:
    depth = nesting_depth(text, strings)
    if depth > MAX_DEPTH:
        raise InputError(f"{name}: nested {depth} levels deep, at most {MAX_DEPTH}")


def _parse_int(name: str):
    def parse(literal: str) -> int:
        digits = len(literal.lstrip("-"))
        if digits > MAX_INT_DIGITS:
            raise InputError(f"{name}: an integer of {digits} digits ({literal[:12]}...), at most {MAX_INT_DIGITS} "
                             "digits")
        return int(literal)

    return parse


def parse_json(text: str, name: str) -> Any:
    """A JSON document from ``text`` (``NaN`` / ``Infinity`` read as floats: the readers' range checks
    refuse them by name); ``InputError`` naming ``name`` for the failures of the module docstring."""
    _check_depth(text, name)
    try:
        return json.loads(text, parse_int=_parse_int(name))
    except InputError:
        raise
    except json.JSONDecodeError as exc:
        raise InputError(f"{name}: not valid JSON: {exc.msg} (line {exc.lineno}, column {exc.colno})") from None
    except RecursionError:  # a depth the pre-scan missed
        raise InputError(f"{name}: nested too deep, at most {MAX_DEPTH} levels") from None


def read_json(path: str | Path, name: str | None = None) -> Any:
    """:func:`parse_json` of the file ``path`` (read by :func:`read_text`)."""
    name = name or str(path)
    return parse_json(read_text(path, name), name)


_YAML_SCALARS = re.compile(r"\"(?:[^\"\\]|\\.)*\"|'(?:[^']|'')*'|#[^\n]*")


def read_yaml(path: str | Path, name: str | None = None) -> Any:
    """A YAML document from ``path`` (``yaml.safe_load``), with the checks of :func:`parse_json` and
    integers bounded after loading; ``InputError`` naming the file otherwise."""
    import yaml

    name = name or str(path)
    text = read_text(path, name)
    _check_depth(text, name, _YAML_SCALARS)
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise InputError(f"{name}: not valid YAML: {problem}{where}") from None
    except (RecursionError, ValueError) as exc:  # deep block nesting; an integer past Python's digit limit
        raise InputError(f"{name}: cannot read it: {str(exc).splitlines()[0][:120]}") from None
    _check_tree(doc, name, "", 0)
    return doc


def _check_tree(node: Any, name: str, path: str, depth: int) -> None:
    """Depth and integer size of a loaded document (YAML block nesting has no brackets to count)."""
    if depth > MAX_DEPTH:
        raise InputError(f"{name}: nested deeper than {MAX_DEPTH} levels")
    if isinstance(node, dict):
        for k, v in node.items():
            _check_tree(v, name, f"{path}.{k}" if path else str(k), depth + 1)
    elif isinstance(node, list):
        for i, v in enumerate(node):
            _check_tree(v, name, f"{path}[{i}]", depth + 1)
    elif isinstance(node, int) and not isinstance(node, bool) and len(str(abs(node))) > MAX_INT_DIGITS:
        raise InputError(f"{name}: {path or 'the document'} is an integer of {len(str(abs(node)))} digits, "
                         f"at most {MAX_INT_DIGITS}")


def check_number(field: str, value: Any, low: float | None = None, high: float | None = None) -> float:
    """``value`` as a float: a real number (not a string, not a boolean), finite, in ``[low, high]``.

    ``TypeError`` / ``ValueError`` naming ``field`` otherwise.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{field} must be a number, got {value!r} ({type(value).__name__})")
    try:
        v = float(value)
    except OverflowError:
        raise ValueError(f"{field} is too large, got an integer of {len(str(abs(int(value))))} digits") from None
    if not math.isfinite(v) or (low is not None and v < low) or (high is not None and v > high):
        bounds = f" in [{'-inf' if low is None else f'{low:g}'}, {'inf' if high is None else f'{high:g}'}]"
        raise ValueError(f"{field} must be a finite number{bounds}, got {value!r}")
    return v
