"""Pattern libraries: per-grid Tx/Rx amplitudes, stored as a hashed ``.npz``, shipped or cached.

File format (``.npz``): ``angles_deg`` (I,), ``tx`` (I, M), ``rx`` (I, M) (amplitudes
psi in [0, 1]) and ``config``: a JSON string ``{"fields": {...}, "sha256": H}`` where
``fields`` holds every input that changes the result (RHS geometry in wavelengths, so
the carrier is left out; the scan grid; the method and all its settings) and
``H = sha256(config_json(fields))``. A file whose hash does not match its fields, or
whose fields differ from the expected ones, is refused with a ``ValueError`` naming it.

Lookup order of :func:`get_library`: the libraries shipped in ``rhs_env/patterns/data``,
then the user cache (``platformdirs.user_cache_dir("rhs-slam")`` or ``$RHS_SLAM_CACHE``),
else the library is built (progress bar) and written to the cache.

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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rhs_common.validation import check_choice, config_json
from rhs_env.array_models import RHSConfig, ScanConfig, check_amplitudes

METHODS = ("fast", "sdr")
DATA_DIR = Path(__file__).resolve().parent / "data"
CACHE_ENV = "RHS_SLAM_CACHE"
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
        np.savez(tmp, angles_deg=self.angles_deg, tx=self.tx, rx=self.rx, config=np.array(blob))
        os.replace(tmp, path)
        self.path = path
        return path


def _read_fields(path: Path) -> dict[str, Any]:
    """The fields of a library file, after checking its stored hash (ValueError naming the file)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            blob = json.loads(str(z["config"]))
    except (OSError, KeyError, ValueError) as exc:
        raise ValueError(f"pattern library {path}: unreadable or missing 'config' ({exc})") from None
    if not isinstance(blob, dict) or "fields" not in blob or "sha256" not in blob:
        raise ValueError(f"pattern library {path}: config must hold 'fields' and 'sha256'")
    if fields_hash(blob["fields"]) != blob["sha256"]:
        raise ValueError(f"pattern library {path}: config hash mismatch (file modified or corrupt)")
    return blob["fields"]


def load(path: str | os.PathLike[str], expected_config: dict[str, Any] | None = None) -> PatternLibrary:
    """Load and verify a library file.

    Raises ``ValueError`` naming ``path`` if the stored hash does not match its config,
    if ``expected_config`` (a fields dict) differs from it, or if the arrays are malformed.
    """
    path = Path(path)
    fields = _read_fields(path)
    if expected_config is not None and config_json(expected_config) != config_json(fields):
        diff = sorted(
            k for k in set(fields) | set(expected_config) if fields.get(k) != expected_config.get(k)
        )
        raise ValueError(f"pattern library {path}: config differs from the expected one in {diff}")
    with np.load(path, allow_pickle=False) as z:
        try:
            lib = PatternLibrary(z["angles_deg"], z["tx"], z["rx"], fields, path)
        except (KeyError, ValueError) as exc:
            raise ValueError(f"pattern library {path}: {exc}") from None
    m = fields["rhs"]["elements"]
    expect_angles = ScanConfig(**fields["scan"]).angles_deg
    if lib.tx.shape[1] != m or not np.allclose(lib.angles_deg, expect_angles):
        raise ValueError(f"pattern library {path}: arrays do not match its config (M={m}, grids)")
    return lib


def cache_dir() -> Path:
    """``$RHS_SLAM_CACHE`` or ``platformdirs.user_cache_dir("rhs-slam")``, joined with ``patterns``."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env) / "patterns"
    import platformdirs

    return Path(platformdirs.user_cache_dir("rhs-slam")) / "patterns"


def cache_path(fields: dict[str, Any]) -> Path:
    return cache_dir() / f"patterns_{fields_hash(fields)[:20]}.npz"


def find_shipped(fields: dict[str, Any]) -> Path | None:
    """The shipped file in ``DATA_DIR`` whose config equals ``fields`` (files with bad hashes are skipped)."""
    want = config_json(fields)
    for p in sorted(DATA_DIR.glob("*.npz")):
        try:
            if config_json(_read_fields(p)) == want:
                return p
        except ValueError:
            continue
    return None


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

    A cached file that fails verification raises ``ValueError`` naming it (delete it to rebuild).
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
    path = cache_path(fields)
    if path.exists():
        return load(path, fields)
    estimate = estimate_build_s(config, scan, method, workers)
    if max_build_s is not None and estimate > max_build_s and os.environ.get(BUILD_ENV) != "1":
        raise ValueError(
            f"radar.rhs.elements={config.elements} with radar.scan.grid_deg={scan.grid_deg:g}: the RHS pattern "
            f"library of this radar ({scan.slots} grids) is not built yet, and building it takes about "
            f"{_duration(estimate)} (estimated for 2 cores); build it once with `rhs-slam patterns --elements "
            f"{config.elements} --grid-deg {scan.grid_deg:g}` (cached for every later run), or set {BUILD_ENV}=1 to "
            f"build it here, or choose fewer elements / a coarser grid")
    lib = build_library(config, scan, method, workers=workers, progress=progress, **settings)
    lib.save(path)
    return lib
