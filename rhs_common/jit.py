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
(:func:`rhs_common.cache_dir.cache_subdir`: ``$RHS_SLAM_CACHE/numba`` or
``platformdirs.user_cache_dir("rhs-slam")/numba``, a private temporary folder with one warning when
that cannot be written) before numba is imported; a ``NUMBA_CACHE_DIR`` that cannot be written
falls back the same way. numba checks only a kernel's own file before it loads its cache entry, while a
kernel's machine code holds its callees' (in the other modules of a kernel package such as
:mod:`rhs_env.kernels`): an entry of a package's kernel is therefore stamped with every module of the package
(:func:`_package_stamp`), so an edit of any of them compiles the package's kernels again, as an edit of one file did.

Bad cache files. A truncated or overwritten ``.nbi`` / ``.nbc`` file of a kernel is removed and the
kernel compiled again (one :class:`KernelCacheWarning` per process), and a cache folder that turns
out unwritable leaves the kernels compiled in memory (:func:`_checked_cache`).

Progress. The first compile of a kernel in a process prints one line to stderr
(:data:`NOTICE`), once per process: a new install compiles every kernel once
(seconds; the measured cost is on the speed page, ``docs/results/speed.md``). Once compiling has taken more than
:data:`PROGRESS_AFTER_S`, a count of the kernels compiled so far follows (in place on a terminal), and a summary
at exit; nothing when every kernel loads from the cache, nothing at all with ``RHS_SLAM_QUIET=1``
(:data:`QUIET_ENV`). :func:`compile_stats` names the kernels compiled in this process.

Vector envs. Worker processes started on an empty cache would each compile every kernel
(seconds of CPU per worker); :func:`warm_cache` runs a workload once in the parent first, so the
workers only load (``agents.algos.vec_env.make_vec_env`` does it before its subprocess workers start).

Tiers. A kernel that strings ten compiled stages together (the OMP) costs seconds more to compile than
its stages (numba links every callee's code into the caller's module and optimises the whole tree
again). :class:`Tiered` runs such a kernel's own source in the interpreter on its compiled stages
(:func:`python_body`: the same stages, in the same order, on the same arrays) while a background
process compiles it (:func:`background_compile_running`: a lock file beside the kernel's cache), and the
compiled kernel from then on.

``NUMBA_DISABLE_JIT=1`` runs the kernels as the plain Python functions they are
(the tests use it to cover their source).
"""

from __future__ import annotations

import contextlib
import functools
import os
import subprocess
import sys
import time
import types
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "BACKGROUND_SWITCH", "COMPILE_LOCK", "KERNELS", "LOCK_STALE_S", "NOTICE", "QUIET_ENV", "KernelCacheWarning",
    "KernelTable", "Tiered", "background_compile_running", "background_main", "cache_index", "compile_lock",
    "compile_stats", "discard_cache_entry", "njit", "numba_module", "numpy_dispatch_stamp", "python_body", "sort_small",
    "spawn_background_compile", "warm_cache", "watch_compiles",
]

#: the kernel implementations a config may choose: compiled (default) or the numpy reference
KERNELS = ("numba", "numpy")
NOTICE = "rhs-slam: compiling the radar / SLAM kernels (first run on this machine, cached afterwards) ..."
_PACKAGE_ROOT = Path(__file__).resolve().parent.parent
#: the lock file a background compile keeps beside the cache index of the kernel it compiles last
COMPILE_LOCK = "rhs-slam-background-compile.lock"
#: a lock file older than this (s) belongs to a background compile that died: another may start
LOCK_STALE_S = 300.0
#: the environment variable that turns the background compiles off (``0``): their kernels then compile in the
#: foreground; the background process itself runs with it at ``0`` (it starts no other)
BACKGROUND_SWITCH = "RHS_SLAM_BACKGROUND_COMPILE"


def _project_kernel(ev: Any) -> str:
    """``module.name`` of the function a numba compile event is for when it is one of the project's kernels, else "".

    The module is the one users import the kernel from: the package when it re-exports the kernel of one of its
    modules (``rhs_env.kernels.tone_spectra``, defined in ``rhs_env.kernels.synthesis``).
    """
    dispatcher = (ev.data or {}).get("dispatcher")
    func = getattr(dispatcher, "py_func", None)
    module = getattr(func, "__module__", "") or ""
    if func is None or module.split(".")[0] not in ("rhs_env", "slam", "rhs_common"):
        return ""
    package = sys.modules.get(module.rpartition(".")[0])
    if package is not None and getattr(package, func.__name__, None) is dispatcher:
        module = package.__name__
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
    """Point ``NUMBA_CACHE_DIR`` at the project's cache folder (:func:`rhs_common.cache_dir.cache_subdir`) when the
    package directory is read-only, or at the temporary fallback when the user's ``NUMBA_CACHE_DIR`` is unwritable."""
    from rhs_common.cache_dir import cache_subdir, fallback_root, unusable_reason

    user = os.environ.get("NUMBA_CACHE_DIR")
    try:
        if user:
            reason = unusable_reason(Path(user))
            if reason is None:
                return
            path = fallback_root(f"NUMBA_CACHE_DIR={user}", reason, "NUMBA_CACHE_DIR") / "numba"
            path.mkdir(parents=True, exist_ok=True)
        elif _writable(_PACKAGE_ROOT / "rhs_env" / "kernels"):
            return
        else:
            path = cache_subdir("numba")
    except OSError as exc:  # no folder at all can be written: the kernels compile in memory (_jit)
        _warn_cache_once(f"rhs-slam: {exc}; the kernels are compiled on every run", stacklevel=3)
        return
    os.environ["NUMBA_CACHE_DIR"] = str(path)
    if "numba" in sys.modules:  # imported before us: its config is read, tell it too
        from numba.core import config

        config.CACHE_DIR = str(path)  # type: ignore[attr-defined]


_NUMBA: Any = None


#: ``RHS_SLAM_QUIET=1``: no compile notice, progress or summary on stderr
QUIET_ENV = "RHS_SLAM_QUIET"
#: the first progress report comes once the kernels compiled in this process have taken this long (s)
PROGRESS_AFTER_S = 1.0
#: without a terminal (a log file), one progress line at most every this many seconds
PROGRESS_EVERY_S = 5.0


class _Progress:
    """What this process compiled of the project's kernels: names, compile seconds, and what stderr was told."""

    def __init__(self) -> None:
        self.kernels: list[str] = []
        self.seconds = 0.0
        self.depth = 0
        self.started = 0.0
        self.announced = False
        self.reported = False
        self.last_line = 0.0
        self.live = False  # a progress line on a terminal waits for its end

    def quiet(self) -> bool:
        return os.environ.get(QUIET_ENV, "0") not in ("", "0")

    def write(self, text: str, end: str = "\n") -> None:
        if self.live:
            text = "\r\x1b[K" + text
        sys.stderr.write(text + end)
        sys.stderr.flush()
        self.live = end == ""

    def start(self, name: str) -> None:
        if self.depth == 0:
            self.started = time.perf_counter()
        self.depth += 1
        if not self.announced and not self.quiet():
            self.announced = True
            self.write(NOTICE)
            import atexit

            atexit.register(self.summary)

    def end(self, name: str) -> None:
        self.kernels.append(name)
        self.depth -= 1
        if self.depth:
            return
        self.seconds += time.perf_counter() - self.started
        if self.quiet() or self.seconds < PROGRESS_AFTER_S:
            return
        stage = {"slam": "SLAM", "rhs_env": "radar"}.get(name.split(".")[0], "shared")
        n = len(self.kernels)
        line = (f"rhs-slam: {n} kernel{'s' * (n != 1)} compiled, {self.seconds:.0f} s so far (a {stage} kernel: "
                f"{name.rsplit('.', 1)[-1]}) ...")
        tty = sys.stderr.isatty()
        now = time.monotonic()
        if tty or now - self.last_line >= PROGRESS_EVERY_S:
            self.last_line = now
            self.reported = True
            self.write(line, end="" if tty else "\n")

    def summary(self) -> None:
        """At exit: how many kernels compiled in how long, and where they are cached (after a progress report)."""
        if self.reported and not self.quiet():
            folder = os.environ.get("NUMBA_CACHE_DIR") or "__pycache__ beside the package's sources"
            n = len(self.kernels)
            self.write(f"rhs-slam: compiled {n} kernel{'s' * (n != 1)} in {self.seconds:.1f} s; cached in {folder}, "
                       f"the next runs load them")


_PROGRESS = _Progress()


def compile_stats() -> dict[str, Any]:
    """The project's kernels numba compiled in this process so far (nothing when every kernel came from the cache).

    Returns:
        ``{"kernels": [module.name, ...] (in the order their compiles ended, callees before their callers),
        "seconds": compile wall seconds (outermost compiles only)}``.

    Examples:
        >>> from rhs_common.jit import compile_stats
        >>> sorted(compile_stats())
        ['kernels', 'seconds']
    """
    return {"kernels": list(_PROGRESS.kernels), "seconds": _PROGRESS.seconds}


def _progress_listener() -> Any:
    """The numba compile-event listener that feeds :data:`_PROGRESS` (registered once, by :func:`_numba`).

    The first compile of one of the project's kernels in a process prints :data:`NOTICE`; once compiling has taken
    :data:`PROGRESS_AFTER_S`, a count follows (rewritten in place on a terminal, a line every
    :data:`PROGRESS_EVERY_S` in a log) and one summary line at exit. Nothing when every kernel loads from the cache,
    nothing at all with ``RHS_SLAM_QUIET=1``.
    """
    from numba.core import event

    class _CompileProgress(event.Listener):
        def on_start(self, ev: Any) -> None:
            if name := _project_kernel(ev):
                _PROGRESS.start(name)

        def on_end(self, ev: Any) -> None:
            if name := _project_kernel(ev):
                _PROGRESS.end(name)

    return _CompileProgress()


def _numba() -> Any:
    """numba, imported on first use (after the cache directory is chosen, with the compile progress registered)."""
    global _NUMBA
    if _NUMBA is None:
        _configure_cache()
        import numba
        from numba.core import event

        event.register("numba:compile", _progress_listener())
        _NUMBA = numba
    return _NUMBA


class KernelCacheWarning(UserWarning):
    """A numba cache entry was unreadable (removed, the kernel compiled again) or the cache could not be written."""


_CACHE_WARNED = False


def _warn_cache_once(message: str, stacklevel: int = 4) -> None:
    """One :class:`KernelCacheWarning` per process (a cache with every entry bad says it once)."""
    global _CACHE_WARNED
    if not _CACHE_WARNED:
        _CACHE_WARNED = True
        import warnings

        warnings.warn(message, KernelCacheWarning, stacklevel=stacklevel)


def discard_cache_entry(cache: Any) -> list[Path]:
    """Delete the on-disk cache files of one kernel (its index ``.nbi`` and data ``.nbc`` files); the paths deleted.

    Args:
        cache: the kernel's numba cache (``dispatcher._cache``).

    Returns:
        The files removed.
    """
    import glob

    index = Path(cache._cache_file._index_path)
    removed = []
    for name in [index, *index.parent.glob(glob.escape(index.name[: -len(".nbi")]) + ".*.nbc")]:
        try:
            name.unlink()
            removed.append(name)
        except FileNotFoundError:
            pass
        except OSError as exc:  # read-only cache: numba compiles in memory and fails to save (warned)
            _warn_cache_once(f"rhs-slam: cannot remove the bad numba cache file {name} ({exc.strerror}); delete "
                             f"{index.parent} or set NUMBA_CACHE_DIR to a writable folder")
    return removed


_CHECKED_CACHE: Any = None


def _checked_cache() -> type:
    """numba's ``FunctionCache`` that treats an unreadable entry as missing and an unwritable cache as no cache.

    A truncated or overwritten ``.nbi`` / ``.nbc`` file (``UnpicklingError``, ``EOFError``, an LLVM error while
    linking it) is deleted (:func:`discard_cache_entry`) and the kernel compiled again, which writes a good entry;
    a cache folder that cannot be written leaves the kernel compiled in memory. Each with one warning per process.
    """
    global _CHECKED_CACHE
    if _CHECKED_CACHE is None:
        from numba.core.caching import FunctionCache

        class CheckedCache(FunctionCache):
            def __init__(self, py_func: Callable) -> None:
                super().__init__(py_func)
                package = _package_stamp(py_func)
                if package:
                    self._cache_file._source_stamp = (self._cache_file._source_stamp, package)
                dispatch = numpy_dispatch_stamp()
                if dispatch:
                    self._cache_file._source_stamp = (self._cache_file._source_stamp, dispatch)

            def load_overload(self, sig: Any, target_context: Any) -> Any:
                try:
                    return super().load_overload(sig, target_context)
                except Exception as exc:  # (any failure to read an entry: compile instead)
                    index = Path(self._cache_file._index_path)
                    discard_cache_entry(self)
                    _warn_cache_once(
                        f"rhs-slam: the numba cache of {self._py_func.__module__}.{self._py_func.__qualname__} in "
                        f"{index.parent} was unreadable ({type(exc).__name__}: {exc}); removed it, compiling again")
                    return None

            def save_overload(self, sig: Any, data: Any) -> None:
                try:
                    super().save_overload(sig, data)
                except Exception as exc:  # (an unwritable or vanished cache folder: run uncached)
                    _warn_cache_once(f"rhs-slam: cannot write the numba cache in {self._cache_path} ({exc}); the "
                                     f"kernels run compiled but are compiled again next run; set NUMBA_CACHE_DIR to a "
                                     f"writable folder")

        _CHECKED_CACHE = CheckedCache
    return _CHECKED_CACHE


@functools.cache
def numpy_dispatch_stamp() -> tuple[str, ...]:
    """numpy's SIMD dispatch in this process, when it goes past AVX2: the AVX-512 targets it uses, e.g.
    ``("AVX512_SKX", ...)``; () without AVX-512 (or under ``NPY_DISABLE_CPU_FEATURES`` capping it).

    Part of every kernel's cache stamp: the compiled traffic calls numpy's own AVX-512 SVML functions by address
    where numpy dispatches to them (:mod:`rhs_env.traffic.npmath`), and numba's cache key holds the CPU but not
    numpy's dispatch, so a kernel compiled with it and loaded by a process that capped it called a null
    address (a segmentation fault). With the stamp such a process compiles its own. Computed once per process
    (the dispatch is fixed at numpy's import), not once per kernel.
    """
    import importlib

    try:
        umath = importlib.import_module("numpy._core._multiarray_umath")
    except ImportError:  # numpy < 2
        return ()
    features = getattr(umath, "__cpu_features__", {})
    return tuple(sorted(k for k, on in features.items() if on and k.startswith("AVX512")))


def _package_stamp(py_func: Callable) -> tuple:
    """``(name, mtime, size)`` of every module of the kernel package ``py_func`` is defined in (a package named
    ``kernels``, as :mod:`rhs_env.kernels`); () for a kernel in a plain module (its own file's stamp suffices)."""
    code = getattr(py_func, "__code__", None)
    folder = Path(code.co_filename).parent if code is not None else None
    if folder is None or folder.name != "kernels" or not (folder / "__init__.py").is_file():
        return ()
    stamp = []
    for source in sorted(folder.glob("*.py")):
        st = source.stat()
        stamp.append((source.name, st.st_mtime, st.st_size))
    return tuple(stamp)


def _jit(func: Callable, options: dict[str, Any]) -> Any:
    """``numba.njit(**options)(func)`` with ``cache=True`` served by :func:`_checked_cache`."""
    options = dict(options)
    cache = options.pop("cache")
    dispatcher = _numba().njit(cache=False, **options)(func)
    if cache and hasattr(dispatcher, "enable_caching"):  # (NUMBA_DISABLE_JIT=1 returns the function itself)
        try:
            dispatcher._cache = _checked_cache()(dispatcher.py_func)
        except RuntimeError as exc:  # numba found no folder to cache in: compile in memory
            _warn_cache_once(f"rhs-slam: no writable numba cache folder ({exc}); the kernels are compiled on every "
                             f"run; set NUMBA_CACHE_DIR to a writable folder", stacklevel=4)
    return dispatcher


def njit(func: Callable | None = None, **options: Any) -> Any:
    """``numba.njit`` with the project's defaults: ``cache=True``, ``error_model="numpy"`` (x / 0 -> inf, as numpy).

    The cache recovers from bad files by itself (:func:`_checked_cache`).
    """
    options = {"cache": True, "error_model": "numpy", **options}
    if func is None:
        return lambda f: _jit(f, options)
    return _jit(func, options)


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


class KernelTable:
    """The stages of one module, each written twice: compiled (``"numba"``) and the numpy reference (``"numpy"``).

    The choice between the two is made here, once per config, not at every call site: a module registers each
    stage's two functions with :meth:`stage` and its object keeps ``table.choose(config.kernels)``, whose
    attributes are the chosen functions (``impl.statistic(self, spec)``). A compiled function that cannot take an
    input (a dtype or layout its kernel does not cover) calls the numpy one itself; the numpy functions never import
    numba, so ``kernels="numpy"`` runs without it.

    Examples:
        >>> from rhs_common.jit import KernelTable
        >>> table = KernelTable("demo")
        >>> @table.stage("double", "numpy")
        ... def _double_numpy(v):
        ...     return 2 * v
        >>> @table.stage("double", "numba")
        ... def _double_numba(v):
        ...     return v + v
        >>> table.choose("numba").double(3), table.choose("numpy").double(3)
        (6, 6)
        >>> table.choose("fortran")
        Traceback (most recent call last):
        ...
        ValueError: kernels: expected one of 'numba', 'numpy', got 'fortran'
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self.stages: dict[str, dict[str, Callable]] = {}
        self._chosen: dict[str, types.SimpleNamespace] = {}

    def stage(self, name: str, kernels: str) -> Callable[[Callable], Callable]:
        """Decorator: the function is stage ``name``'s implementation for ``kernels`` ("numba" or "numpy")."""
        _check_kernels(kernels)

        def register(func: Callable) -> Callable:
            self.stages.setdefault(name, {})[kernels] = func
            self._chosen.clear()
            return func

        return register

    def choose(self, kernels: str) -> Any:
        """The chosen implementations, one attribute per stage (and ``kernels``, the choice).

        Raises:
            ValueError: ``kernels`` is not one of :data:`KERNELS`, or a stage lacks one of its two implementations.
        """
        chosen = self._chosen.get(kernels)
        if chosen is None:
            _check_kernels(kernels)
            missing = sorted(f"{stage} ({k})" for stage, impls in self.stages.items() for k in KERNELS if k not in impls)
            if missing:
                raise ValueError(f"{self.name}: stages without an implementation: {', '.join(missing)}")
            chosen = types.SimpleNamespace(kernels=kernels, **{s: impls[kernels] for s, impls in self.stages.items()})
            self._chosen[kernels] = chosen
        return chosen


def _check_kernels(kernels: str) -> None:
    """ValueError unless ``kernels`` is one of :data:`KERNELS`."""
    if kernels not in KERNELS:
        raise ValueError(f"kernels: expected one of {', '.join(map(repr, KERNELS))}, got {kernels!r}")


def warm_cache(run: Callable[[], Any], probe: Any, key: str = "") -> bool:
    """Run ``run`` (a workload calling the kernels) unless this cache was warmed for ``key`` already; True if it ran.

    ``probe``: one of the project's kernels; the cache it writes to holds a marker file named by a
    digest of ``key``, numba's version and the sources of the kernel modules (any edit re-warms), written
    after ``run`` returns. Without numba's cache (``NUMBA_DISABLE_JIT=1``) nothing runs.
    """
    import hashlib

    numba = _numba()
    index = cache_index(probe)
    if numba.config.DISABLE_JIT or index is None:  # no on-disk cache
        return False
    folder = index.parent
    digest = hashlib.sha256(f"{key}|{numba.__version__}".encode())
    sources = [*sorted((_PACKAGE_ROOT / "rhs_env" / "kernels").glob("*.py")),
               *(_PACKAGE_ROOT / module for module in ("slam/core/kernels.py", "rhs_common/jit.py", "rhs_common/native.py"))]
    for source in sources:
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


def cache_index(kernel: Any) -> Path | None:
    """The on-disk cache index of a compiled kernel (written once a first signature is compiled); None without one."""
    try:
        return Path(kernel._cache._cache_file._index_path)
    except AttributeError:  # not a cached dispatcher (NUMBA_DISABLE_JIT=1, a plain function)
        return None


def compile_lock(kernel: Any) -> Path | None:
    """The background compile's lock file beside ``kernel``'s cache index (:data:`COMPILE_LOCK`); None without a cache."""
    index = cache_index(kernel)
    return None if index is None else index.parent / COMPILE_LOCK


def background_compile_running(kernel: Any) -> bool:
    """Whether a background compile holds :func:`compile_lock` of ``kernel`` (written by
    :func:`slam.gym.precompile.start`): the file exists, is younger than :data:`LOCK_STALE_S` and names a live process."""
    lock = compile_lock(kernel)
    if lock is None:
        return False
    try:
        pid = lock.read_text().strip()
        age = time.time() - lock.stat().st_mtime
    except OSError:
        return False
    if age > LOCK_STALE_S:
        return False
    if pid.isdigit() and sys.platform != "win32":  # (os.kill(pid, 0) on Windows is a Ctrl-C)
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            return False
        except PermissionError:  # alive, another user's
            pass
    return True


def spawn_background_compile(module: str, lock: Path) -> subprocess.Popen | None:
    """Start ``python -m module --lock LOCK`` as a detached, single-threaded background compile holding ``lock``
    (:data:`COMPILE_LOCK`: written with this pid first, then the child's, so it lives as long as the child);
    None when the lock's folder cannot be written (nothing to share the kernels through: compile in the
    foreground). The module's ``main`` is :func:`background_main`."""
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        lock.write_text(str(os.getpid()))
    except OSError:
        return None
    env = {**os.environ, BACKGROUND_SWITCH: "0", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", module, "--lock", str(lock)], env=env, stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    with contextlib.suppress(OSError):
        lock.write_text(str(proc.pid))
    return proc


def background_main(workload: Callable[[], None], description: str, argv: list[str] | None = None) -> int:
    """The command line of a background compile (:func:`spawn_background_compile`): runs ``workload`` (the calls
    whose kernels it compiles and caches), then removes the ``--lock`` file, also when the workload failed."""
    import argparse

    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--lock", help="the lock file to remove when done")
    a = ap.parse_args(argv)
    try:
        workload()
    finally:
        if a.lock:
            Path(a.lock).unlink(missing_ok=True)
    return 0


def python_body(kernel: Any, *python_callees: str) -> Callable:
    """``kernel``'s own source run by the interpreter; the kernels it calls stay compiled, except ``python_callees``
    (names of module-level kernels it calls), which run as Python bodies too.

    Every floating-point operation of the callees runs in their compiled code; the body itself copies,
    selects and loops, so it computes the same bits as the compiled kernel (tested for the OMP). A plain
    function (``NUMBA_DISABLE_JIT=1``) is returned as it is.

    Examples:
        >>> import numpy as np
        >>> from rhs_common.jit import njit, python_body
        >>> double = njit(lambda v: 2.0 * v, cache=False)
        >>> def total(v):
        ...     return double(v).sum()
        >>> body = python_body(njit(total, cache=False))
        >>> body.__code__ is total.__code__  # total's own statements, run by the interpreter
        True
        >>> float(body(np.arange(3.0)))
        6.0
    """
    func = getattr(kernel, "py_func", kernel)
    if func is kernel and not python_callees:
        return func
    scope = dict(func.__globals__)
    for name in python_callees:
        scope[name] = getattr(scope[name], "py_func", scope[name])
    return types.FunctionType(func.__code__, scope, func.__name__, func.__defaults__, func.__closure__)


class Tiered:
    """A compiled kernel that, while a background process compiles it, runs as its :func:`python_body`.

    ``mode``: ``"auto"`` (default) calls the compiled kernel once it is compiled in this process, or its
    cache index exists (the call loads it), or no background compile is running
    (:func:`background_compile_running`: then this process compiles it, as any kernel); else the Python body
    with ``python_callees`` as Python too. ``"compiled"`` and ``"python"`` force one tier (the background
    compile uses both). Once compiled, the check is one attribute read.
    """

    def __init__(self, kernel: Any, *python_callees: str) -> None:
        self.kernel = kernel
        self.python_callees = python_callees
        self.mode = "auto"
        self._compiled = False
        self._body: Callable | None = None

    def __call__(self, *args: Any) -> Any:
        if self.use_compiled():
            return self.kernel(*args)
        if self._body is None:
            self._body = python_body(self.kernel, *self.python_callees)
        return self._body(*args)

    def wait_for_background(self, timeout_s: float = LOCK_STALE_S, poll_s: float = 0.1) -> bool:
        """Block while a background compile of this kernel runs (at most ``timeout_s``); True if one was running (the
        calls so far may have run the Python body: the next one runs the compiled kernel, loaded or compiled here)."""
        if self._compiled or self.mode != "auto" or not background_compile_running(self.kernel):
            return False
        deadline = time.monotonic() + timeout_s
        while background_compile_running(self.kernel) and time.monotonic() < deadline:
            time.sleep(poll_s)
        return True

    def use_compiled(self) -> bool:
        """Whether the next call runs the compiled kernel (see the class docstring)."""
        if self.mode != "auto":
            return self.mode == "compiled"
        if self._compiled:
            return True
        index = cache_index(self.kernel)
        ready = (index is None or bool(self.kernel.signatures) or index.exists()
                 or not background_compile_running(self.kernel))
        self._compiled = ready
        return ready
