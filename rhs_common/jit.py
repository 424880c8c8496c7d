"""Compiled kernels: numba's ``njit`` with an on-disk cache that works on any install.

The radar's and the SLAM's inner loops (:mod:`rhs_env.kernels`, :mod:`slam.core.kernels`)
run on arrays of 30-300 rows, where numpy pays more in interpreter overhead than in
arithmetic; compiled with numba they compute the same equations in the same order
(the numpy code stays the reference, ``kernels="numpy"`` in the radar and SLAM
configs selects it).

Cache. Every kernel is compiled with ``cache=True``: the machine code is written
once per machine (and numba / numpy / CPU) and loaded by later processes, so
subprocess vector envs, async workers and RLlib env runners load it instead of
compiling again. Where numba keeps it: ``NUMBA_CACHE_DIR`` when the user sets it;
else next to the source (``__pycache__``) when the package directory is writable;
else (a read-only install: a system site-packages, a container layer) this module
points ``NUMBA_CACHE_DIR`` at the user cache directory
(``platformdirs.user_cache_dir("rhs-slam")/numba``) before numba is imported.

Notice. The first compile of a kernel in a process prints one line to stderr
(:data:`NOTICE`), once per process: a new install compiles every kernel once
(seconds, see :mod:`rhs_env.kernels` for the measured cost).

Vector envs. Worker processes started on an empty cache would each compile every kernel
(seconds of CPU per worker); :func:`warm_cache` runs a workload once in the parent first, so the
workers only load (``agents.run_setup.make_vec_env`` does it before its subprocess workers start).

``NUMBA_DISABLE_JIT=1`` runs the kernels as the plain Python functions they are
(the tests use it to cover their source).
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

__all__ = ["KERNELS", "NOTICE", "njit", "numba_module", "sort_small", "warm_cache", "watch_compiles"]

#: the kernel implementations a config may choose: compiled (default) or the numpy reference
KERNELS = ("numba", "numpy")
NOTICE = "rhs-slam: compiling the radar / SLAM kernels (first run on this machine, cached afterwards) ..."
_PACKAGE_ROOT = Path(__file__).resolve().parent.parent


def _project_kernel(ev: Any) -> str:
    """``module.name`` of the function a numba compile event is for when it is one of the project's kernels, else ""."""
    func = getattr((ev.data or {}).get("dispatcher"), "py_func", None)
    module = getattr(func, "__module__", "") or ""
    if func is None or module.split(".")[0] not in ("rhs_env", "slam", "rhs_common"):
        return ""
    return f"{module}.{func.__qualname__}"


@contextlib.contextmanager
def watch_compiles() -> Iterator[set[str]]:
    """The set of the project's kernels (``module.name``) numba compiles inside the ``with`` block."""
    numba_module()
    from numba.core import event

    names: set[str] = set()

    class _Collect(event.Listener):
        def on_start(self, ev: Any) -> None:
            if name := _project_kernel(ev):
                names.add(name)

        def on_end(self, ev: Any) -> None:
            pass

    with event.install_listener("numba:compile", _Collect()):
        yield names


def numba_module() -> Any:
    """numba itself, imported as the kernels import it: after the cache directory is chosen, with the compile notice
    registered (for code that extends numba or reads its config, e.g. :mod:`rhs_common.native`)."""
    return _numba()


def _writable(path: Path) -> bool:
    """Whether numba can write its cache next to the sources under ``path`` (``__pycache__`` there, or the folder)."""
    cache = path / "__pycache__"
    return os.access(cache if cache.is_dir() else path, os.W_OK)


def _configure_cache() -> None:
    """Point ``NUMBA_CACHE_DIR`` at the user cache directory when the package directory is read-only."""
    if os.environ.get("NUMBA_CACHE_DIR") or _writable(_PACKAGE_ROOT / "rhs_env"):
        return
    import platformdirs

    path = Path(platformdirs.user_cache_dir("rhs-slam")) / "numba"
    path.mkdir(parents=True, exist_ok=True)
    os.environ["NUMBA_CACHE_DIR"] = str(path)
    if "numba" in sys.modules:  # imported before us: its config is read, tell it too
        from numba.core import config

        config.CACHE_DIR = str(path)  # type: ignore[attr-defined]


_NUMBA: Any = None


def _numba() -> Any:
    """numba, imported on first use (after the cache directory is chosen, with the compile notice registered)."""
    global _NUMBA
    if _NUMBA is None:
        _configure_cache()
        import numba
        from numba.core import event

        class _CompileNotice(event.Listener):
            """Prints :data:`NOTICE` once per process when one of the project's kernels starts compiling."""

            announced = False

            def on_start(self, ev: Any) -> None:
                if not _CompileNotice.announced and _project_kernel(ev):
                    _CompileNotice.announced = True
                    print(NOTICE, file=sys.stderr, flush=True)

            def on_end(self, ev: Any) -> None:
                pass

        event.register("numba:compile", _CompileNotice())
        _NUMBA = numba
    return _NUMBA


def njit(func: Callable | None = None, **options: Any) -> Any:
    """``numba.njit`` with the project's defaults: ``cache=True``, ``error_model="numpy"`` (x / 0 -> inf, as numpy)."""
    options = {"cache": True, "error_model": "numpy", **options}
    if func is None:
        return lambda f: _numba().njit(**options)(f)
    return _numba().njit(**options)(func)


def _sort_small(v: np.ndarray) -> None:
    """Sort the short 1-D array v ascending, in place (insertion sort: ``x_q`` moves left past every larger value).

    For the tens of values of an ICP gate (:mod:`slam.core.kernels`) and any other short window a kernel ranks (the
    OS-CFAR of :mod:`rhs_env.kernels` needs no sort: it counts): ~160 ns for 16 values, 8x faster than
    ``np.partition`` inside numba (which allocates and dispatches).
    """
    for q in range(1, v.size):
        x = v[q]
        p = q - 1
        while p >= 0 and v[p] > x:
            v[p + 1] = v[p]
            p -= 1
        v[p + 1] = x


if TYPE_CHECKING:
    sort_small = _sort_small


def __getattr__(name: str) -> Any:
    """``sort_small``: :func:`_sort_small` compiled (one cached dispatcher for both kernel modules), made on first
    access so that importing this module does not import numba."""
    if name == "sort_small":
        compiled = globals()["sort_small"] = njit(_sort_small)
        return compiled
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def warm_cache(run: Callable[[], Any], probe: Any, key: str = "") -> bool:
    """Run ``run`` (a workload calling the kernels) unless this cache was warmed for ``key`` already; True if it ran.

    ``probe``: one of the project's kernels; the cache it writes to holds a marker file named by a
    digest of ``key``, numba's version and the sources of the kernel modules (any edit re-warms), written
    after ``run`` returns. Without numba's cache (``NUMBA_DISABLE_JIT=1``) nothing runs.
    """
    import hashlib

    numba = _numba()
    if numba.config.DISABLE_JIT:
        return False
    try:
        folder = Path(probe._cache._cache_file._index_path).parent
    except AttributeError:  # no on-disk cache (not a cached dispatcher)
        return False
    digest = hashlib.sha256(f"{key}|{numba.__version__}".encode())
    for module in ("rhs_env/kernels.py", "slam/core/kernels.py", "rhs_common/jit.py", "rhs_common/native.py"):
        source = _PACKAGE_ROOT / module
        if source.is_file():
            digest.update(source.read_bytes())
    marker = folder / f"rhs-slam-warm-{digest.hexdigest()[:16]}"
    if marker.exists():
        return False
    run()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        marker.touch()
    except OSError:  # a cache folder we may not write: the next parent warms again
        pass
    return True
