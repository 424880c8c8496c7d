"""Safe readers of the JSON and YAML documents users hand in (scene / scenario files, ``--env-kwargs``,
``--hyperparams``).

Every failure is an :class:`InputError` (a ``ValueError``) whose one-line message starts with
the name of the file (or flag) and says what is wrong, so a command can print it and exit 2:

* a path that is not a regular file (a directory, a named pipe, ``/dev/zero``, a socket): refused
  from its ``stat`` before anything is opened for reading, so a FIFO nobody writes cannot hang
  the command and a device cannot fill the memory;
* a file larger than :func:`max_input_bytes` (:data:`MAX_BYTES`, 64 MiB, unless the environment
  variable ``RHS_SLAM_MAX_INPUT_MB`` says otherwise; a YAML file: :data:`MAX_YAML_BYTES`), checked
  on its size and again on the bytes read;
* bytes that are not UTF-8 (the offset of the first bad byte); a UTF-8 byte-order mark is skipped;
* nesting deeper than :data:`MAX_DEPTH` (Python's parsers recurse: 200 000 ``[`` would be a
  ``RecursionError``; 64 levels are far more than any document here has: 3);
* integers of more than :data:`MAX_INT_DIGITS` digits (a seed is < 2**63, 19 digits; a
  400-digit integer overflows every float conversion, and past 4300 digits Python refuses
  to read it at all);
* a key given twice in one JSON object or YAML mapping (the parsers would keep the last one
  silently; YAML's merge key ``<<`` may still be overridden);
* YAML aliases (``*name``) beyond :data:`MAX_YAML_ALIASES`, a document that expands to more than
  :data:`MAX_YAML_NODES` nodes once its aliases are followed (nine aliases of nine aliases ... are
  a "billion laughs" that hangs any walk over the document), or an alias inside its own anchor;
* a document that does not parse (the parser's message with line and column).

What the values mean (numbers where numbers belong, their ranges) is checked by the reader
of each document; :func:`check_number` is the shared test for "a real number, not a string
or a boolean, finite".
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import stat
from pathlib import Path
from typing import Any

__all__ = [
    "file_sha256",
    "InputError", "MAX_BYTES", "MAX_DEPTH", "MAX_INPUT_ENV", "MAX_INT_DIGITS", "MAX_YAML_ALIASES", "MAX_YAML_BYTES",
    "MAX_YAML_NODES", "check_number", "expanded_nodes", "file_kind", "max_input_bytes", "nesting_depth", "parse_json",
    "read_json", "read_text", "read_yaml",
]

#: deepest nesting of lists / objects accepted in a document
MAX_DEPTH = 64
#: most digits of an integer literal (2**63 has 19)
MAX_INT_DIGITS = 30
#: largest document read by default, bytes (a scenario of 100 000 poses and 100 000 landmarks is ~10 MB)
MAX_BYTES = 64 * 2**20
#: the environment variable that raises (or lowers) :data:`MAX_BYTES`, in MiB
MAX_INPUT_ENV = "RHS_SLAM_MAX_INPUT_MB"
#: largest YAML document (a hyperparameter file is ~2 kB; PyYAML reads ~1 MB/s)
MAX_YAML_BYTES = 2**20
#: most aliases (``*name``) in a YAML document (the shipped hyperparameter files have 3)
MAX_YAML_ALIASES = 100
#: most nodes of a YAML document with every alias followed (the shipped ones have < 200)
MAX_YAML_NODES = 100_000

_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")


class InputError(ValueError):
    """A document that cannot be read; the message names it and fits on one line."""


def max_input_bytes() -> int:
    """The largest input document read, bytes: ``RHS_SLAM_MAX_INPUT_MB`` MiB when set, else :data:`MAX_BYTES`.

    Returns:
        The limit in bytes; ``InputError`` naming the variable when it is not a number in [1, 65536].
    """
    text = os.environ.get(MAX_INPUT_ENV, "").strip()
    if not text:
        return MAX_BYTES
    try:
        mib = float(text)
    except ValueError:
        mib = math.nan
    if not 1 <= mib <= 65536:
        raise InputError(f"{MAX_INPUT_ENV}={text!r}: must be a number of MiB in [1, 65536]")
    return int(mib * 2**20)


def file_kind(mode: int) -> str:
    """What a ``st_mode`` names, in words ("a regular file", "a named pipe (FIFO)", ...)."""
    kinds = ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a named pipe (FIFO)"),
             (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))
    return next((text for test, text in kinds if test(mode)), "not a regular file")


def _check_regular(mode: int, size: int, name: str, limit: int, hint: str) -> None:
    if not stat.S_ISREG(mode):
        raise InputError(f"{name}: cannot read it: {file_kind(mode)}, expected a regular file (save the document "
                         "to a file and pass that)")
    if size > limit:
        raise InputError(f"{name}: {size / 2**20:.1f} MiB, larger than the {limit / 2**20:g} MiB limit of "
                         f"{hint}")


def read_text(path: str | Path, name: str | None = None, limit: int | None = None) -> str:
    """The text of ``path``, strict UTF-8 (a leading byte-order mark skipped); ``InputError`` naming it otherwise.

    Args:
        path: the file; it must be a regular file (checked before it is opened: a FIFO or a device is refused).
        name: how messages name it (default: ``path``).
        limit: the largest size read, bytes (default :func:`max_input_bytes`).

    Returns:
        The decoded text.
    """
    name = name or str(path)
    hint = f"an input document (set {MAX_INPUT_ENV} to read a larger one)" if limit is None else "this document"
    limit = max_input_bytes() if limit is None else limit
    try:
        st = os.stat(path)  # never blocks, whatever the path is
        _check_regular(st.st_mode, st.st_size, name, limit, hint)
        # O_NONBLOCK: should the path have become a FIFO since the stat, the open does not wait for a writer
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(f.fileno())
            _check_regular(st.st_mode, st.st_size, name, limit, hint)
            data = f.read(limit + 1)  # a file that grows while it is read, or a size the stat under-reports
        if len(data) > limit:
            _check_regular(st.st_mode, len(data), name, limit, hint)
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


def _unique_keys(name: str):
    def pairs(items: list[tuple[str, Any]]) -> dict[str, Any]:
        obj: dict[str, Any] = {}
        for key, value in items:
            if key in obj:
                raise InputError(f"{name}: key {key!r} is given twice in one object (JSON keeps the last one "
                                 "silently); keep one")
            obj[key] = value
        return obj

    return pairs


def parse_json(text: str, name: str) -> Any:
    """A JSON document from ``text`` (``NaN`` / ``Infinity`` read as floats: the readers' range checks
    refuse them by name); ``InputError`` naming ``name`` for the failures of the module docstring."""
    _check_depth(text, name)
    try:
        return json.loads(text, parse_int=_parse_int(name), object_pairs_hook=_unique_keys(name))
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


def _yaml_loader(text: str):
    """A ``yaml.SafeLoader`` over ``text`` that counts aliases and refuses a key given twice in one mapping."""
    import yaml

    class Loader(yaml.SafeLoader):
        def __init__(self, stream: str) -> None:
            super().__init__(stream)
            self.aliases = 0
            self.explicit_keys: dict[int, list] = {}  # mapping node -> its own key nodes (before any merge)

        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                self.aliases += 1
                if self.aliases > MAX_YAML_ALIASES:
                    raise yaml.composer.ComposerError(None, None, f"more than {MAX_YAML_ALIASES} aliases (*name)",
                                                      self.peek_event().start_mark)
            return super().compose_node(parent, index)

        def compose_mapping_node(self, anchor):
            node = super().compose_mapping_node(anchor)
            self.explicit_keys[id(node)] = [k for k, _ in node.value]
            return node

        def construct_mapping(self, node, deep=False):
            if isinstance(node, yaml.MappingNode):
                seen: set = set()
                for key_node in self.explicit_keys.get(id(node), []):
                    if key_node.tag == "tag:yaml.org,2002:merge":
                        continue
                    key = self.construct_object(key_node, deep=True)
                    try:
                        duplicate = key in seen
                    except TypeError:  # an unhashable key: the base class refuses it
                        continue
                    if duplicate:
                        raise yaml.constructor.ConstructorError(
                            None, None, f"key {key!r} is given twice in one mapping (YAML keeps the last one "
                            "silently); keep one", key_node.start_mark)
                    seen.add(key)
            return super().construct_mapping(node, deep=deep)

    return Loader(text)


def expanded_nodes(node: Any, limit: int = MAX_YAML_NODES) -> int:
    """Nodes of a composed YAML graph with every alias followed (a shared node counts once per use).

    Args:
        node: a ``yaml.Node`` (the composer's output).
        limit: stop counting past this many (the answer is then ``limit + 1``).

    Returns:
        The count, at most ``limit + 1``; ``ValueError`` for an alias inside its own anchor (a cycle).
    """
    memo: dict[int, int] = {}
    active: set[int] = set()

    def count(n: Any) -> int:
        key = id(n)
        if key in memo:
            return memo[key]
        if key in active:
            raise ValueError("an alias refers to the node that contains it (a recursive document)")
        active.add(key)
        total = 1
        children = n.value if isinstance(n.value, list) else []
        for child in children:
            for c in (child if isinstance(child, tuple) else (child,)):
                total += count(c)
                if total > limit:
                    break
        active.discard(key)
        memo[key] = total = min(total, limit + 1)
        return total

    return count(node)


def read_yaml(path: str | Path, name: str | None = None) -> Any:
    """A YAML document from ``path`` (the safe loader), with the checks of :func:`parse_json`, at most
    :data:`MAX_YAML_BYTES`, aliases bounded (:data:`MAX_YAML_ALIASES`, :data:`MAX_YAML_NODES`), keys unique in
    each mapping, and integers bounded after loading; ``InputError`` naming the file otherwise.

    Args:
        path: the YAML file.
        name: how messages name it (default: ``path``).

    Returns:
        The loaded document (None for an empty one).
    """
    import yaml

    name = name or str(path)
    text = read_text(path, name, limit=min(MAX_YAML_BYTES, max_input_bytes()))
    _check_depth(text, name, _YAML_SCALARS)
    try:
        loader = _yaml_loader(text)  # its reader refuses control characters (a NUL byte) at once
    except yaml.YAMLError as exc:
        raise InputError(f"{name}: not valid YAML: {str(exc).splitlines()[0]}") from None
    try:
        node = loader.get_single_node()
        if node is not None and expanded_nodes(node) > MAX_YAML_NODES:
            raise InputError(f"{name}: its aliases (*name) expand to more than {MAX_YAML_NODES} nodes (an alias "
                             "bomb?); write the values out")
        doc = None if node is None else loader.construct_document(node)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise InputError(f"{name}: not valid YAML: {problem}{where}") from None
    except InputError:
        raise
    except (RecursionError, ValueError) as exc:  # deep block nesting; an integer past Python's digit limit; a cycle
        raise InputError(f"{name}: cannot read it: {str(exc).splitlines()[0][:120]}") from None
    finally:
        loader.dispose()
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


def file_sha256(path: str | Path) -> str:
    """sha256 hex digest of a file's bytes, read in 1 MiB chunks (the checksums of the shipped artifacts)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()
