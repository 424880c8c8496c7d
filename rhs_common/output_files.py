"""Where the commands write: checked before the work starts, replaced atomically when it is done.

* :func:`check_output_file` refuses, before any work, an output path that is not a regular file
  (a named pipe would block the first write until someone reads it; ``/dev/stdout`` or a device is
  not a result file), one that names an input of the same run (``--out`` equal to the scene
  overwrote it), or one whose suffix is not among the formats the writer knows
  (a figure's: the formats matplotlib writes, given by the caller), then tries that it can be written
  (:func:`rhs_common.validation.check_output_path`).
* :func:`atomic_output` / :func:`write_text_atomic` write into a temporary file beside the target
  and ``os.replace`` it onto the target at the end: a reader (or an interrupt) never sees half a
  file, and a failed or interrupted write leaves the previous file as it was and no temporary file.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from rhs_common.input_files import file_kind
from rhs_common.validation import check_output_path


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether two paths name one file: the same inode when both exist (hard links, symlinks), else the same
    resolved path."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(a).resolve() == Path(b).resolve()


def check_output_file(field: str, path: Any, inputs: Iterable[Any] = (), suffixes: Iterable[str] | None = None) -> None:
    """``ValueError`` naming ``field`` unless ``path`` can take a result file; call it before any work starts.

    Args:
        field: the flag that names the path (``--out``), for the message.
        path: the output path.
        inputs: ``(flag, path)`` pairs, or bare paths, the same run reads: the output may be none of them.
        suffixes: the allowed suffixes (lower case, with the dot); None: any.
    """
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise TypeError(f"{field} must be a path, got {path!r} ({type(path).__name__})")
    p = Path(path)
    with contextlib.suppress(OSError):
        mode = os.stat(p).st_mode
        kind = file_kind(mode)
        if kind not in ("a regular file", "a directory"):  # a directory: check_output_path says so
            raise ValueError(f"{field}: {p} is {kind}, expected a regular file path (results are written to files)")
    for given in inputs:
        flag, other = given if isinstance(given, tuple) else ("the input", given)
        if other is not None and str(other) and same_file(p, other):
            raise ValueError(f"{field}: {p} is also {flag} of this run (one file cannot be both); choose another "
                             "path")
    if suffixes is not None:
        allowed = sorted(set(suffixes))
        if p.suffix.lower() not in allowed:
            got = f"suffix {p.suffix!r}" if p.suffix else "no suffix"
            raise ValueError(f"{field}: {p} has {got}; the format is taken from the suffix, one of "
                             f"{', '.join(allowed)}")
    check_output_path(field, p)


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path beside ``path`` (same folder, same suffix) to write; on leaving the block it replaces
    ``path`` (``os.replace``: atomic on one file system). On an exception, ``KeyboardInterrupt`` included,
    the temporary file is removed and ``path`` is left as it was.

    Args:
        path: the file to write (a symbolic link: the file it points to); its folder is created.

    Returns:
        The context manager; it yields the temporary path.
    """
    target = Path(os.path.realpath(path))
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = _new_temporary(target)
    try:
        yield tmp
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def _new_temporary(target: Path) -> Path:
    """A new empty file ``.<stem>.<random>.tmp<suffix>`` beside ``target`` (mode 0666 less the umask, as the
    writers' own files would have)."""
    for _ in range(100):
        tmp = target.with_name(f".{target.stem}.{secrets.token_hex(4)}.tmp{target.suffix}")
        try:
            os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        except FileExistsError:
            continue
        return tmp
    raise FileExistsError(f"no free temporary name beside {target}")


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` through :func:`atomic_output`, flushed to disk before the rename."""
    with atomic_output(path) as tmp, open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
