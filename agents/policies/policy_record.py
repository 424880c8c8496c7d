"""A policy zip's record: the env id, env kwargs, decision interval and shield it was trained with.

The record is what ``rhs-slam evaluate`` / ``demo`` drive a policy with; without it they would build the
default env (other target speeds, no shield, no decision interval) and the policy would drive an env it was
not trained for. It is kept twice:

* as the JSON side-car beside the zip (``model.zip`` -> ``model.json``), as before, and
* inside the zip itself, as the member :data:`RECORD_MEMBER` (stable-baselines3 reads only its own
  members, so the zip loads as before), written by :func:`save_model` and :func:`embed_record`.

:func:`read_record` looks for the side-car beside the path given, then beside the file a symbolic link
points to, then inside the zip; a zip with none of them is a ``ValueError`` naming the missing side-car.
Zips are written atomically (a temporary file beside the target, then ``os.replace``): an interrupt
leaves the previous file whole.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from pathlib import Path
from typing import Any

__all__ = ["RECORD_MEMBER", "embed_record", "embedded_record", "read_record", "save_model", "sidecar_candidates",
           "sidecar_path", "write_bytes_atomic"]

#: the member of a policy zip that holds its record
RECORD_MEMBER = "rhs_slam_record.json"


def sidecar_path(policy: str | Path) -> Path:
    """The JSON written beside a policy zip (``model.zip`` -> ``model.json``)."""
    return Path(policy).with_suffix(".json")


def write_bytes_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file beside it (:func:`rhs_common.output_files.atomic_output`),
    flushed to disk, then renamed onto it: an interrupt leaves the previous file whole.

    Args:
        path: the target.
        data: the bytes to write.

    Returns:
        The target path.
    """
    from rhs_common.output_files import atomic_output

    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    return Path(path)


def _with_record(data: bytes, record: dict[str, Any]) -> bytes:
    """The zip ``data`` with :data:`RECORD_MEMBER` set to ``record`` (an older copy of it dropped)."""
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as src, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            if info.filename != RECORD_MEMBER:
                dst.writestr(info, src.read(info.filename))
        dst.writestr(RECORD_MEMBER, json.dumps(record, indent=2))
    return out.getvalue()


def save_model(model: Any, path: str | Path, record: dict[str, Any] | None = None) -> Path:
    """``model.save`` to ``path`` atomically, with ``record`` inside the zip when given.

    Args:
        model: a stable-baselines3 model.
        path: the zip to write.
        record: the run record to carry (None: the zip as stable-baselines3 writes it).

    Returns:
        The path written.
    """
    buf = io.BytesIO()
    model.save(buf)
    data = buf.getvalue()
    return write_bytes_atomic(path, _with_record(data, record) if record is not None else data)


def embed_record(path: str | Path, record: dict[str, Any]) -> None:
    """Put ``record`` inside the existing zip ``path`` (rewritten atomically; the rest of it unchanged)."""
    path = Path(path)
    write_bytes_atomic(path, _with_record(path.read_bytes(), record))


def embedded_record(path: str | Path) -> dict[str, Any] | None:
    """The record inside the zip ``path``, or None (no such member, or not a zip)."""
    try:
        with zipfile.ZipFile(path) as z:
            if RECORD_MEMBER not in z.namelist():
                return None
            value = json.loads(z.read(RECORD_MEMBER).decode("utf-8"))
    except (OSError, zipfile.BadZipFile, UnicodeDecodeError):
        return None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: its {RECORD_MEMBER} is not valid JSON ({exc})") from None
    return value if isinstance(value, dict) else None


def sidecar_candidates(policy: str | Path) -> list[Path]:
    """Where a policy's side-car may be: beside the path given, then beside the file a symbolic link names."""
    given = sidecar_path(policy)
    resolved = sidecar_path(Path(policy).resolve())
    return [given] if resolved == given.resolve() else [given, resolved]


def read_record(policy: str | Path, required: bool = True) -> dict[str, Any]:
    """The record of the policy zip (or RLlib checkpoint folder) ``policy``.

    Args:
        policy: the zip (or folder).
        required: without any record, raise (True) or return ``{}`` (False).

    Returns:
        The record: the side-car JSON (beside ``policy``, else beside the file it links to), else the one inside
        the zip.

    Raises:
        ValueError: a side-car that is not a JSON object, or (``required``) no record at all, naming the
            side-car that is missing and what to do.
    """
    from rhs_common.input_files import read_json

    for path in sidecar_candidates(policy):
        if path.is_file():
            meta = read_json(path)
            if not isinstance(meta, dict):
                raise ValueError(f"{path}: a policy record must be a JSON object, got {type(meta).__name__}")
            return meta
    inside = embedded_record(policy) if Path(policy).is_file() else None
    if inside is not None:
        return inside
    if not required:
        return {}
    raise ValueError(
        f"{policy}: no record of the env it was trained on: {sidecar_path(policy)} is missing and the zip carries "
        f"none ({RECORD_MEMBER}); without it the policy would drive the default env (other target speeds, no "
        f"shield, no decision interval). Put the {sidecar_path(policy).name} that came with the zip beside it")
