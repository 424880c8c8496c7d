"""Pattern libraries: per-grid Tx/Rx amplitudes, stored as a hashed ``.npz``, shipped or cached.

File format (``.npz``): ``angles_deg`` (I,), ``tx`` (I, M), ``rx`` (I, M) (amplitudes
psi in [0, 1]) and ``config``: a JSON string ``{"fields": {...}, "sha256": H}`` where
``fields`` holds every input that changes the result (RHS geometry in wavelengths, so
the carrier is left out; the scan grid; the method and all its settings) and
``H = sha256(config_json(fields))``. A file whose hash does not match its fields, or
whose fields differ from the expected ones, is refused with a ``ValueError`` naming it.

Lookup order of :func:`get_library`: the libraries shipped in ``rhs_env/patterns/data``,
then the user cache (:func:`rhs_common.cache_dir.cache_subdir`: ``$RHS_SLAM_CACHE`` or
``platformdirs.user_cache_dir("rhs-slam")``, a temporary folder with one warning when neither can be
written), else the library is built (progress bar) and written to the cache.

Verification. Every file is checked when loaded (:func:`load`): a readable ``.npz`` with the four
arrays, the config hash, the format version, the arrays against the config (grid centres of the scan,
``(I, M)`` amplitudes, finite, in [0, 1]) and the config against the one asked for (elements, feeds,
grid, method, settings); a bad file raises ``ValueError`` naming it and the fix. The shipped files are
also checked byte for byte against the sha256 recorded beside them (:data:`CHECKSUMS`): a damaged one is
refused (reinstall, or delete it to build the library into the user cache), never skipped in silence.
A cached file that fails is deleted and built again, with one :class:`LibraryRebuildWarning`.

A build that :func:`estimate_build_s` puts above :data:`MAX_IMPLICIT_BUILD_S` is not started
by a lookup (``gym.make`` with a fine grid or many elements would otherwise block for minutes
to hours without having been asked to): :func:`get_library` raises a ``ValueError`` naming the
radar's fields and the estimate, unless ``max_build_s=None`` (``rhs-slam patterns``, which
builds on purpose, prints the estimate first and caches the library) or the environment
variable ``RHS_SLAM_BUILD_PATTERNS=1`` confirms it.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rhs_common.cache_dir import CACHE_ENV as _CACHE_ENV
from rhs_common.cache_dir import cache_subdir
from rhs_common.input_files import file_sha256
from rhs_common.validation import check_choice, config_json
from rhs_env.array_models import RHSConfig, ScanConfig, check_amplitudes

__all__ = [
    "BUILD_ENV", "CACHE_ENV", "CHECKSUMS", "DATA_DIR", "FORMAT_VERSION", "LibraryRebuildWarning",
    "MAX_IMPLICIT_BUILD_S", "METHODS", "PatternLibrary", "build_library", "cache_dir", "cache_path", "check_buildable",
    "estimate_build_s", "fields_hash", "file_sha256", "find_shipped", "get_library", "library_fields", "load",
    "method_settings", "rebuild_command", "write_checksums",
]

METHODS = ("fast", "sdr")
DATA_DIR = Path(__file__).resolve().parent / "data"
#: the sha256 of every shipped file, by name, with the hash of its config (written by :func:`write_checksums`)
CHECKSUMS = "checksums.json"
CACHE_ENV = _CACHE_ENV
#: set to 1 to let a lookup start a build longer than MAX_IMPLICIT_BUILD_S
BUILD_ENV = "RHS_SLAM_BUILD_PATTERNS"
#: longest build (estimated, s) a lookup starts without being asked to
MAX_IMPLICIT_BUILD_S = 180.0
FORMAT_VERSION = 1


def method_settings(method: str, **settings: Any) -> Any:
    """The validated settings dataclass of ``method`` (unknown keys raise ValueError)."""
    check_choice("method", method, METHODS)
    if method == "fast":
        from rhs_env.patterns.fast import FastSettings as cls
    else:
        from rhs_env.patterns.sdr import SDRSettings as cls  # type: ignore[assignment]
    known = set(cls.__dataclass_fields__)
    unknown = sorted(set(settings) - known)
    if unknown:
        raise ValueError(f"unknown {method} settings {unknown}; allowed: {sorted(known)}")
    return cls(**settings)


def library_fields(config: RHSConfig, scan: ScanConfig, method: str = "fast", **settings: Any) -> dict[str, Any]:
    """Every field that changes a library's content (the input of its hash)."""
    s = method_settings(method, **settings)
    rhs = config.to_dict()
    rhs.pop("carrier_hz")  # geometry is in wavelengths: the carrier does not change psi
    return {
        "format": FORMAT_VERSION,
        "rhs": rhs,
        "scan": scan.to_dict(),
        "method": method,
        "settings": s.to_dict(),
    }


def fields_hash(fields: dict[str, Any]) -> str:
    """sha256 hex digest of the canonical JSON of ``fields``."""
    return hashlib.sha256(config_json(fields).encode()).hexdigest()


@dataclass
class PatternLibrary:
    """Optimised amplitude patterns of one radar config.

    Attributes:
        angles_deg: grid centres (I,), degrees.
        tx, rx: amplitudes psi in [0, 1], shape (I, M).
        config: the fields dict (see :func:`library_fields`).
        path: file it was loaded from / saved to, if any.
    """

    angles_deg: np.ndarray
    tx: np.ndarray
    rx: np.ndarray
    config: dict[str, Any]
    path: Path | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        self.angles_deg = np.atleast_1d(np.asarray(self.angles_deg, dtype=float))
        i = self.angles_deg.size
        m = np.shape(self.tx)[-1] if np.ndim(self.tx) == 2 else -1
        self.tx = check_amplitudes("tx", self.tx, i, m)
        self.rx = check_amplitudes("rx", self.rx, i, m)

    @property
    def hash(self) -> str:
        return fields_hash(self.config)

    def rhs_config(self, carrier_hz: float | None = None) -> RHSConfig:
        kw = dict(self.config["rhs"])
        if carrier_hz is not None:
            kw["carrier_hz"] = carrier_hz
        return RHSConfig(**kw)

    def scan_config(self) -> ScanConfig:
        return ScanConfig(**self.config["scan"])

    @classmethod
    def load(cls, path: str | os.PathLike[str], expected_config: dict[str, Any] | None = None) -> PatternLibrary:
        """Same as the module-level :func:`load`."""
        return load(path, expected_config)

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the ``.npz`` (atomically: temp file then rename)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        blob = json.dumps({"fields": self.config, "sha256": self.hash}, sort_keys=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
        try:
            np.savez(tmp, angles_deg=self.angles_deg, tx=self.tx, rx=self.rx, config=np.array(blob))
            os.replace(tmp, path)
        except BaseException:  # (Ctrl-C, a full disk: no partial file is left behind)
            tmp.unlink(missing_ok=True)
            raise
        self.path = path
        return path


class LibraryRebuildWarning(UserWarning):
    """A cached pattern library failed verification: it was deleted and is built again."""


def rebuild_command(fields: dict[str, Any], out: Path | None = None) -> str:
    """The ``rhs-slam patterns`` command line that builds the library of ``fields`` (defaults left out).

    Args:
        fields: a library's fields (:func:`library_fields`).
        out: the file to write, if any.

    Returns:
        The command, e.g. ``rhs-slam patterns --grid-deg 5``.
    """
    flags = {"elements": "--elements", "spacing_wl": "--spacing-wl", "refractive_index": "--refractive-index",
             "tx_feed": "--tx-feed", "rx_feed": "--rx-feed", "grid_deg": "--grid-deg", "sector_deg": "--sector-deg"}
    try:
        default = library_fields(RHSConfig(), ScanConfig(grid_deg=float(fields["scan"]["grid_deg"])))
        given = {**fields["rhs"], **fields["scan"]}
        base = {**default["rhs"], **default["scan"]}
        if given.get("rx_feed") == int(given.get("elements", 0)) - 1:
            given = {**given, "rx_feed": base["rx_feed"]}  # the default, -1: the last element
        parts = ["rhs-slam patterns", *(f"{flag} {given[k]:g}" for k, flag in flags.items()
                                        if k in given and (given[k] != base[k] or k == "grid_deg"))]
        if fields.get("method", "fast") != "fast":
            parts.append(f"--method {fields['method']}")
    except (KeyError, TypeError, ValueError):
        parts = ["rhs-slam patterns"]
    if out is not None:
        parts += ["--no-cache", f"--out {out}"]
    return " ".join(parts)


def _refuse(path: Path, problem: str) -> ValueError:
    """The error of an unusable library file: names it and how to get a good one."""
    return ValueError(f"pattern library {path}: {problem}; rebuild it with `rhs-slam patterns --out {path}` "
                      f"(with the radar's --elements / --grid-deg / feed options)")


def _read_fields(path: Path) -> dict[str, Any]:
    """The fields of a library file, after checking its stored hash (ValueError naming the file)."""
    if not path.is_file():
        raise _refuse(path, "no such file" if not path.exists() else "not a regular file")
    try:
        with open(path, "rb") as f, np.load(f, allow_pickle=False) as z:  # (our handle: closed on a bad zip too)
            blob = json.loads(str(z["config"]))
    except Exception as exc:  # (BadZipFile, EOFError, pickle or JSON errors: any is a bad file)
        raise _refuse(path, f"not a readable pattern library .npz ({type(exc).__name__}: {exc})") from None
    if not isinstance(blob, dict) or not isinstance(blob.get("fields"), dict) or "sha256" not in blob:
        raise _refuse(path, "config must hold 'fields' and 'sha256'")
    if fields_hash(blob["fields"]) != blob["sha256"]:
        raise _refuse(path, "config hash mismatch (file modified or corrupt)")
    if blob["fields"].get("format") != FORMAT_VERSION:
        raise _refuse(path, f"format {blob['fields'].get('format')!r}, this rhs-slam reads format {FORMAT_VERSION}")
    return blob["fields"]


def _configs(path: Path, fields: dict[str, Any]) -> tuple[RHSConfig, ScanConfig]:
    """The radar and scan configs a library's fields describe (ValueError naming the file when they are invalid)."""
    try:
        return RHSConfig(**fields["rhs"]), ScanConfig(**fields["scan"])
    except (KeyError, TypeError, ValueError) as exc:
        raise _refuse(path, f"invalid config in the file ({exc})") from None


def load(path: str | os.PathLike[str], expected_config: dict[str, Any] | None = None) -> PatternLibrary:
    """Load and verify a library file.

    Raises ``ValueError`` naming ``path`` and the fix if the file is not a readable library, if the stored hash
    does not match its config, if ``expected_config`` (a fields dict) differs from it, or if the arrays do not
    match the config (shapes, grid centres, amplitudes in [0, 1]).
    """
    path = Path(path)
    fields = _read_fields(path)
    if expected_config is not None and config_json(expected_config) != config_json(fields):
        diff = sorted(
            k for k in set(fields) | set(expected_config) if fields.get(k) != expected_config.get(k)
        )
        raise ValueError(f"pattern library {path}: config differs from the expected one in {diff}")
    config, scan = _configs(path, fields)
    try:
        with open(path, "rb") as f, np.load(f, allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k]) for k in ("angles_deg", "tx", "rx")}
    except Exception as exc:  # (a damaged member: BadZipFile, zlib.error, a bad CRC)
        raise _refuse(path, f"unreadable arrays ({type(exc).__name__}: {exc})") from None
    expect_angles = scan.angles_deg
    if arrays["angles_deg"].shape != expect_angles.shape or not np.allclose(arrays["angles_deg"], expect_angles):
        raise _refuse(path, f"angles_deg do not match its grid ({scan.slots} grids of {scan.grid_deg:g} deg)")
    try:
        lib = PatternLibrary(arrays["angles_deg"], arrays["tx"], arrays["rx"], fields, path)
    except (TypeError, ValueError) as exc:
        raise _refuse(path, str(exc)) from None
    if lib.tx.shape != (scan.slots, config.elements):
        raise _refuse(path, f"tx / rx shape {lib.tx.shape} does not match its config: ({scan.slots} grids, "
                            f"M={config.elements})")
    return lib


def cache_dir() -> Path:
    """The ``patterns`` folder of the project's cache (:func:`rhs_common.cache_dir.cache_subdir`, writable)."""
    return cache_subdir("patterns")


def cache_path(fields: dict[str, Any]) -> Path:
    return cache_dir() / f"patterns_{fields_hash(fields)[:20]}.npz"


def write_checksums(directory: Path) -> Path:
    """Record every library of ``directory`` in its :data:`CHECKSUMS` file (file sha256 and config hash).

    Args:
        directory: a folder of library files (``DATA_DIR`` for the shipped ones).

    Returns:
        The checksums file written.
    """
    entries = {}
    for p in sorted(directory.glob("*.npz")):
        entries[p.name] = {"sha256": file_sha256(p), "config_sha256": fields_hash(_read_fields(p))}
    out = directory / CHECKSUMS
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(entries, indent=1, sort_keys=True) + "\n")
    os.replace(tmp, out)
    return out


def _shipped_checksums(directory: Path) -> dict[str, dict[str, str]]:
    """The :data:`CHECKSUMS` record of ``directory`` (ValueError naming it when damaged)."""
    record = directory / CHECKSUMS
    try:
        entries = json.loads(record.read_text())
        if not isinstance(entries, dict) or not all(
                isinstance(e, dict) and isinstance(e.get("sha256"), str) and isinstance(e.get("config_sha256"), str)
                for e in entries.values()):
            raise ValueError("not a map of file name to sha256 and config_sha256")
    except FileNotFoundError:
        return {}
    except (OSError, ValueError) as exc:
        raise ValueError(f"the record of the shipped pattern libraries {record} is damaged ({exc}); reinstall "
                         f"rhs-slam") from None
    return entries


def find_shipped(fields: dict[str, Any]) -> Path | None:
    """The shipped file in ``DATA_DIR`` whose config equals ``fields``, verified byte for byte; None when none is.

    Only files recorded in :data:`CHECKSUMS` count; a recorded file that was deleted counts as not shipped (the
    library is then built into the user cache). Raises ``ValueError`` naming the file and the fix when its bytes
    differ from the recorded sha256 (truncated, replaced, edited).
    """
    want = fields_hash(fields)
    for name, entry in sorted(_shipped_checksums(DATA_DIR).items()):
        if entry["config_sha256"] != want:
            continue
        path = DATA_DIR / name
        if not path.exists():
            return None
        try:
            ok = path.is_file() and file_sha256(path) == entry["sha256"]
        except OSError:
            ok = False
        if not ok:
            raise ValueError(
                f"the shipped pattern library {path} is damaged (its sha256 differs from the one in "
                f"{DATA_DIR / CHECKSUMS}); reinstall rhs-slam (in a source checkout: `git checkout -- {path}`), or "
                f"delete the file and run `{rebuild_command(fields)}` to build the library into the user cache")
        return path
    return None


def _grids_without_sidelobes(config: RHSConfig, scan: ScanConfig, oversample: float) -> list[float]:
    """The grid centres (deg) whose main lobe covers every visible direction (an empty sidelobe set D)."""
    from rhs_env.patterns.metrics import sidelobe_directions

    return [float(a) for a in scan.angles_deg if sidelobe_directions(config, float(a), oversample).size == 0]


def check_buildable(config: RHSConfig, scan: ScanConfig, oversample: float = 4.0) -> None:
    """Refuse a radar too small to have sidelobes: every grid needs directions outside its main lobe.

    The main lobe of an M-element line spans ``|s - s_i| <= 1 / (M d)`` in ``s = sin(theta)``; with few elements it
    covers the whole visible region ``[-1, 1]`` and there is nothing to optimise (the P1 objective has no sidelobe
    set). Raises ``ValueError`` naming ``elements`` and the smallest count that has a sidelobe set on every grid.
    """
    empty = _grids_without_sidelobes(config, scan, oversample)
    if not empty:
        return
    smallest = config.elements + 1
    while smallest < 4096 and _grids_without_sidelobes(
            RHSConfig(elements=smallest, spacing_wl=config.spacing_wl, refractive_index=config.refractive_index),
            scan, oversample):
        smallest += 1
    raise ValueError(
        f"elements={config.elements} with spacing_wl={config.spacing_wl:g}: the main lobe (half-width 1/(M d) = "
        f"{config.mainlobe_halfwidth:.3g} in sin(theta)) covers every direction of the grid at {empty[0]:g} deg, "
        f"so there are no sidelobes to suppress and no pattern to optimise; a library of {scan.grid_deg:g}-degree "
        f"grids needs elements in [{smallest}, 4096]")


def build_library(
    config: RHSConfig,
    scan: ScanConfig,
    method: str = "fast",
    workers: int = 2,
    progress: bool = True,
    **settings: Any,
) -> PatternLibrary:
    """Optimise every grid with ``method`` (``fast`` | ``sdr``) and return the library (not saved)."""
    from tqdm.auto import tqdm

    fields = library_fields(config, scan, method, **settings)
    s = method_settings(method, **settings)
    check_buildable(config, scan, s.oversample)
    if method == "sdr":
        from rhs_env.patterns.sdr import check_memory

        check_memory(config, scan, s, workers)
    with tqdm(total=scan.slots, desc=f"patterns ({method}, M={config.elements}, {scan.grid_deg:g} deg)",
              disable=not progress, unit="grid") as bar:
        if method == "fast":
            from rhs_env.patterns.fast import build_fast

            tx, rx, _ = build_fast(config, scan, s, workers=workers, progress=bar)
        else:
            from rhs_env.patterns.sdr import build_sdr

            tx, rx, _ = build_sdr(config, scan, s, workers=workers, progress=bar)
    return PatternLibrary(scan.angles_deg, np.clip(tx, 0.0, 1.0), np.clip(rx, 0.0, 1.0), fields)


def estimate_build_s(config: RHSConfig, scan: ScanConfig, method: str = "fast", workers: int = 2) -> float:
    """Rough wall time (s) of :func:`build_library` with the ``fast`` method on a 2-core machine.

    ``6 + I * 0.3 s * (M / 60)^1.1 * max(1, 1 deg / dtheta)^0.75 * 2 / workers`` for I grids of
    dtheta degrees and M elements, fitted to builds measured on the project's 2-core machine
    (M = 24..960 at 10 deg: 6.5..55 s; M = 60 at 1 deg: 26 s, at 0.25 deg: about 5 min); the
    ``sdr`` method is taken as 10 times slower. A guide for refusing hours, not a benchmark.
    """
    per_grid = 0.3 * (config.elements / 60) ** 1.1 * max(1.0, 1.0 / scan.grid_deg) ** 0.75
    seconds = 6.0 + scan.slots * per_grid * 2.0 / max(1, workers)
    return seconds * (10.0 if method == "sdr" else 1.0)


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min" if seconds < 7200 else \
        f"{seconds / 3600:.1f} h"


def get_library(
    config: RHSConfig | None = None,
    scan: ScanConfig | None = None,
    method: str = "fast",
    workers: int = 2,
    progress: bool = True,
    max_build_s: float | None = MAX_IMPLICIT_BUILD_S,
    **settings: Any,
) -> PatternLibrary:
    """The library of (config, scan, method, settings): shipped, cached, or built once and cached.

    A shipped file that fails verification raises ``ValueError`` naming it and the fix; a cached one is deleted and
    built again (one :class:`LibraryRebuildWarning`).
    A build estimated (:func:`estimate_build_s`) above ``max_build_s`` seconds raises ``ValueError``
    naming ``radar.rhs.elements`` and ``radar.scan.grid_deg`` with the estimate, unless
    ``max_build_s`` is None or ``$RHS_SLAM_BUILD_PATTERNS`` is 1.
    """
    config = config or RHSConfig()
    scan = scan or ScanConfig()
    fields = library_fields(config, scan, method, **settings)
    shipped = find_shipped(fields)
    if shipped is not None:
        return load(shipped, fields)
    try:
        path: Path | None = cache_path(fields)
    except OSError as exc:  # no folder can be written, not even a temporary one: build, keep it in memory
        path = None
        warnings.warn(f"rhs-slam: {exc}; the pattern library is built for this run only", LibraryRebuildWarning,
                      stacklevel=2)
    if path is not None and (path.exists() or path.is_symlink()):
        try:
            return load(path, fields)
        except ValueError as exc:
            path.unlink(missing_ok=True)
            warnings.warn(f"rhs-slam: the cached pattern library {path} failed verification ({exc}); deleted it, "
                          f"building the library again", LibraryRebuildWarning, stacklevel=2)
    estimate = estimate_build_s(config, scan, method, workers)
    if max_build_s is not None and estimate > max_build_s and os.environ.get(BUILD_ENV) != "1":
        raise ValueError(
            f"radar.rhs.elements={config.elements} with radar.scan.grid_deg={scan.grid_deg:g}: the RHS pattern "
            f"library of this radar ({scan.slots} grids) is not built yet, and building it takes about "
            f"{_duration(estimate)} (estimated for 2 cores); build it once with `rhs-slam patterns --elements "
            f"{config.elements} --grid-deg {scan.grid_deg:g}` (cached for every later run), or set {BUILD_ENV}=1 to "
            f"build it here, or choose fewer elements / a coarser grid")
    lib = build_library(config, scan, method, workers=workers, progress=progress, **settings)
    if path is not None:
        lib.save(path)
    return lib
