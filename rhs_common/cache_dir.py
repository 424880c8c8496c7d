"""The project's cache folder: one place that chooses it, and a temporary one when it cannot be written.

What is cached: pattern libraries built for a radar no shipped library covers (:mod:`rhs_env.patterns.library`,
``patterns/``) and numba's compiled kernels on a read-only install (:mod:`rhs_common.jit`, ``numba/``).

Where (:func:`cache_root`): ``$RHS_SLAM_CACHE`` when set, else ``platformdirs.user_cache_dir("rhs-slam")``
(``$XDG_CACHE_HOME/rhs-slam`` or ``~/.cache/rhs-slam`` on Linux). A folder that cannot be created or written
(``HOME`` unset or read-only, ``XDG_CACHE_HOME`` read-only, ``RHS_SLAM_CACHE`` a regular file or read-only) does
not stop a run: the cache moves to a private folder under the system temporary directory
(``rhs-slam-cache-<uid>``, mode 0700, refused when another user owns it), with one warning
(:class:`CacheFallbackWarning`) that names the folder, the reason and the variable to set. The fallback is
exported in ``RHS_SLAM_CACHE``, so the worker processes of the run use it without warning again. Only when the
temporary directory cannot be written either does :func:`cache_root` raise an ``OSError`` naming the variable.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path

__all__ = ["CACHE_ENV", "CacheFallbackWarning", "cache_root", "cache_subdir", "fallback_root", "unusable_reason"]

#: the variable that chooses the cache folder
CACHE_ENV = "RHS_SLAM_CACHE"


class CacheFallbackWarning(UserWarning):
    """The cache folder could not be written: a temporary one is used for this run."""


_WARNED: set[str] = set()


def unusable_reason(path: Path) -> str | None:
    """Why ``path`` cannot serve as a cache folder (created when missing), or None when it can.

    Args:
        path: the folder.

    Returns:
        A short reason (``"not a directory"``, ``"not writable"``, the OS error), or None.
    """
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        return "it exists and is not a directory"
    except OSError as exc:
        return exc.strerror or str(exc)
    if not path.is_dir():
        return "it is not a directory"
    try:  # os.access says yes to root on a read-only mount: write a probe file
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        return exc.strerror or str(exc)
    return None


def _default_root() -> tuple[Path | None, str]:
    """platformdirs' user cache folder and the variables that choose it (None when there is no home to find)."""
    import platformdirs

    try:
        path = Path(platformdirs.user_cache_dir("rhs-slam"))
    except (KeyError, OSError, RuntimeError) as exc:  # no HOME and no passwd entry
        return None, f"XDG_CACHE_HOME / HOME ({exc})"
    if not path.is_absolute() or path.parts[0].startswith("~"):  # no HOME and no passwd entry: "~" left as is
        return None, "XDG_CACHE_HOME / HOME"
    return path, "XDG_CACHE_HOME / HOME"


def _private_temp() -> Path:
    """``<tmp>/rhs-slam-cache-<uid>``: created 0700, kept only when this user owns it (else a fresh mkdtemp)."""
    uid = os.geteuid() if hasattr(os, "geteuid") else 0
    path = Path(tempfile.gettempdir()) / f"rhs-slam-cache-{uid}"
    try:
        path.mkdir(mode=0o700, exist_ok=True)
        st = path.lstat()
        if path.is_symlink() or not path.is_dir() or (hasattr(os, "geteuid") and st.st_uid != uid):
            raise PermissionError(f"{path} is not this user's")
        if st.st_mode & 0o077:
            path.chmod(0o700)
        if unusable_reason(path) is None:
            return path
    except OSError:
        pass
    return Path(tempfile.mkdtemp(prefix="rhs-slam-cache-"))


def fallback_root(what: str, reason: str, variable: str) -> Path:
    """The temporary cache folder, after one warning (per ``what``) that ``what`` could not be used.

    Args:
        what: the folder that failed, as the warning names it (``RHS_SLAM_CACHE=/x``).
        reason: why it failed.
        variable: the variable the user should set to a writable folder.

    Returns:
        The private temporary folder.

    Raises:
        OSError: when no temporary folder can be written either (names ``variable``).
    """
    try:
        path = _private_temp()
    except OSError as exc:
        raise OSError(f"no writable cache folder: {what} ({reason}) and the temporary directory "
                      f"{tempfile.gettempdir()} ({exc.strerror or exc}); set {variable} to a writable folder") from None
    if what not in _WARNED:
        _WARNED.add(what)
        warnings.warn(f"rhs-slam: cannot use the cache folder {what} ({reason}); using the temporary folder {path} "
                      f"for this run (rebuilt after a reboot); set {variable} to a writable folder to keep the cache",
                      CacheFallbackWarning, stacklevel=3)
    return path


def cache_root() -> Path:
    """The writable cache folder: ``$RHS_SLAM_CACHE``, the user cache, or the temporary fallback (module docstring).

    Returns:
        An existing folder this process can write.
    """
    env = os.environ.get(CACHE_ENV)
    if env:
        path = Path(env).expanduser()
        what, variable = f"{CACHE_ENV}={env}", CACHE_ENV
        reason = unusable_reason(path)
    else:
        found, variables = _default_root()
        variable = f"{CACHE_ENV} (or {variables})"
        if found is None:
            what, reason = "the user cache folder", "no home folder"
        else:
            path, what = found, str(found)
            reason = unusable_reason(path)
    if reason is None:
        return path
    path = fallback_root(what, reason, variable)
    os.environ[CACHE_ENV] = str(path)  # worker processes inherit it and do not warn again
    return path


def cache_subdir(name: str) -> Path:
    """``cache_root() / name``, created (a sub-folder that cannot be made falls back like the root).

    Args:
        name: the sub-folder (``patterns``, ``numba``).

    Returns:
        An existing folder this process can write.
    """
    path = cache_root() / name
    reason = unusable_reason(path)
    if reason is None:
        return path
    path = fallback_root(str(path), reason, CACHE_ENV) / name
    path.mkdir(parents=True, exist_ok=True)
    return path
