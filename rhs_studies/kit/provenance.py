"""Provenance and fingerprints of everything under ``results/``: a results file cannot silently disagree with the code.

Every script that writes ``results/*.json`` imports this module (``from rhs_studies.kit.provenance import ...``;
``rhs_studies.provenance``, its path before the kit, is the same module).

**Provenance.** :func:`write_json` adds a ``"provenance"`` block to the result:
``commit`` (``git rev-parse HEAD`` when the script started; once the results file is committed,
that commit is an ancestor of the commit adding it), ``dirty`` and ``dirty_files``
(tracked files modified at start, outside ``results/``, ``docs/results/`` and ``README.md``, so a run on
uncommitted code says so), ``command`` (the script and its arguments), ``config``
(every parsed option, i.e. the full configuration of the run), the versions of
python / numpy and of every package that can move a result (``packages``), the start time (UTC) and ``wall_s`` (run time, used by
``scripts/reproduce.py`` to estimate how long a regeneration takes).

**Fingerprints.** A script whose numbers come from the code (not from timing) defines
``fingerprint() -> list[float]``: its own core (the same functions as the full run)
on a tiny, fixed config, seconds long. :func:`digest` rounds the numbers to
``SIGNIFICANT`` significant digits and hashes them. There are two records of it:

* ``results/X.json["provenance"]["fingerprint"]``: the hash computed *in the same
  process as the full run* that produced the numbers of ``results/X.json``. It is
  never rewritten without rerunning the script: it says which code made the numbers.
* ``results/fingerprints.json[NAME]``: the hash the code gives *now*, as last
  recorded (by a full run, or by ``scripts/reproduce.py --fingerprints-only``).

``tests/test_results_fresh.py`` reruns every ``fingerprint()`` and fails with
"results/X.json is stale: rerun scripts/X.py" when the code's output differs from
``fingerprints.json`` by more than the step's *tolerance*. The comparison is value by value,
not by hash: the same code gives last-digit differences on another CPU (AVX-512 against AVX2
kernels in numpy, OpenBLAS, torch), with another release of a dependency or of a conic solver,
and a closed-loop episode can turn such a difference into one flipped discrete decision. Each
entry of ``fingerprints.json`` therefore carries a ``tolerance`` measured by
``scripts/fingerprint_tolerance.py``: the spread of every value over BLAS / SIMD / thread
settings and the oldest and newest allowed dependencies, and from it

* ``rtol`` and ``atol``: value ``i`` matches when ``|now_i - recorded_i| <= atol + rtol |recorded_i|``
  (``SAFETY`` times the largest spread of the values that moved by less than ``FLIP_REL``,
  both defined in that script);
* ``may_flip``: the values that may miss that bound, those that "flipped" (moved by more
  than ``FLIP_REL``) in at least one setting: one discrete decision of a driving episode
  gone the other way moves the same few values on every machine; empty for all
  but closed-loop driving episodes).

A real change of the code's output moves many values by more than that, and still fails
(the test shows it by changing the code for two of the steps). There are then two honest ways out:

1. rerun the script (``python scripts/reproduce.py --only NAME``): new numbers, both
   records agree again;
2. when the full rerun is too long for now (another change will follow, the machine
   is busy), ``python scripts/reproduce.py --fingerprints-only --only NAME --reason
   "..."`` records the new fingerprint in ``fingerprints.json`` only. The results file
   still carries the old hash, so it is *unverified*: :func:`verification` says so,
   ``scripts/write_results_pages.py`` puts a visible warning (with the reason) in the
   block of that result on its documentation page (and in the README's headline table
   when it feeds it), and the test checks that the pages carry it.

So a stale number is either caught by the test or shown as unverified where it is shown,
never silent. Results files written before provenance existed have no fingerprint
and count as unverified in the same way.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import platform
import subprocess
import sys
import time
from collections.abc import Iterable
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "results"
FINGERPRINTS = RESULTS / "fingerprints.json"
SIGNIFICANT = 6  # significant digits kept before hashing (the hash names a run; matching uses the tolerance)
#: the rounding of the recorded values alone: a value kept to 6 digits is off by up to 5e-6 relative
ROUNDING_RTOL = 5e-6
#: paths whose modification does not make a run "dirty": they are the runs' outputs
OUTPUT_PATHS = ("results/", "README.md", "docs/results/")


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout if out.returncode == 0 else None


def git_state() -> dict[str, Any]:
    """``commit`` (HEAD or None outside git), ``dirty`` and the modified tracked files (outputs excluded)."""
    head = _git("rev-parse", "HEAD")
    status = _git("status", "--porcelain", "--untracked-files=no") or ""
    files = [line[3:] for line in status.splitlines() if line[3:] and not line[3:].startswith(OUTPUT_PATHS)]
    return {"commit": head.strip() if head else None, "dirty": bool(files), "dirty_files": files[:20]}


#: the git state when this module was first imported, i.e. when the script started: later edits
#: to the work tree (while a long run goes on) do not change what the run recorded
STATE_AT_START = git_state()


def is_ancestor(commit: str, of: str = "HEAD") -> bool | None:
    """Whether ``commit`` is an ancestor of (or equal to) ``of``; None when git cannot tell."""
    try:
        out = subprocess.run(["git", "merge-base", "--is-ancestor", commit, of], cwd=ROOT,
                             capture_output=True, timeout=30, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return {0: True, 1: False}.get(out.returncode)


def jsonable(obj: Any) -> Any:
    """JSON-safe copy of a config: Namespaces, dataclasses, paths, numpy scalars and arrays."""
    if isinstance(obj, argparse.Namespace):
        obj = vars(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        obj = dataclasses.asdict(obj)
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return _repo_relative(obj)
    if hasattr(obj, "tolist"):  # numpy scalars and arrays
        return obj.tolist()
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    return repr(obj)


def _repo_relative(path: Path) -> str:
    """A path inside the repository as relative to its root (a record names no machine's folders)."""
    resolved = path.resolve()
    return str(resolved.relative_to(ROOT)) if resolved.is_relative_to(ROOT) else str(path)


def script_name(script: str | Path) -> str:
    """``scripts/fig5a_slam_rmse.py`` -> ``fig5a_slam_rmse`` (the key in ``fingerprints.json``)."""
    return Path(script).stem


def command_line(script: str | Path, argv: list[str] | None = None) -> list[str]:
    """``python scripts/<script> <argv>`` as a user reruns it (``argv`` defaults to this process's arguments)."""
    return ["python", f"scripts/{Path(script).name}", *map(str, sys.argv[1:] if argv is None else argv)]


#: the installed distributions whose releases can move a result (``constraints/base.txt`` pins them all)
RESULT_PACKAGES = ("numpy", "scipy", "cvxpy", "clarabel", "scs", "torch", "gymnasium", "highway-env",
                   "stable-baselines3", "numba", "ray")


def package_versions(names: Iterable[str] = RESULT_PACKAGES) -> dict[str, str]:
    """``{distribution: version}`` of those of ``names`` that are installed (a results file's environment)."""
    from importlib import metadata

    out = {}
    for name in names:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return out


def provenance(script: str | Path, config: Any, started: float, argv: list[str] | None = None) -> dict[str, Any]:
    """The provenance block of a run of ``script`` that began at ``time.time() == started``."""
    import numpy as np

    args = sys.argv[1:] if argv is None else list(argv)
    return {
        **STATE_AT_START,
        "command": command_line(script, args),
        "config": jsonable(config),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "packages": package_versions(),
        "started_utc": datetime.fromtimestamp(started, timezone.utc).isoformat(timespec="seconds"),
        "wall_s": round(time.time() - started, 2),
    }


def digest(values: Iterable[float | None], significant: int = SIGNIFICANT) -> tuple[str, list[float | None]]:
    """(sha256 hex prefix, rounded values): each value kept to ``significant`` digits; NaN/inf/None -> None."""
    rounded: list[float | None] = []
    for v in values:
        v = None if v is None else float(v)
        rounded.append(None if v is None or not math.isfinite(v) else float(f"{v:.{significant - 1}e}"))
    text = json.dumps(rounded, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16], rounded


def numbers(obj: Any) -> list[float | None]:
    """Every number in a nested result (dict keys sorted; bools as 0/1; None kept): a fingerprint's values."""
    if isinstance(obj, dict):
        return [v for k in sorted(obj, key=str) for v in numbers(obj[k])]
    if isinstance(obj, (list, tuple)):
        return [v for x in obj for v in numbers(x)]
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):
        return numbers(obj.tolist())
    if obj is None or isinstance(obj, (bool, int, float)):
        return [None if obj is None else float(obj)]
    return []


def compute_fingerprint(fn) -> dict[str, Any]:
    """Run a script's ``fingerprint()`` and return ``{hash, values, seconds}``.

    It runs with single-threaded BLAS / OpenMP whatever the caller's setting: a threaded
    reduction sums in another order, and a SLAM episode turns that round-off into a
    different trajectory, so the same code would give two fingerprints.
    """
    from rhs_common.threads import blas_threads_limit

    t0 = time.perf_counter()
    with blas_threads_limit(1):
        h, values = digest(fn())
    return {"hash": h, "values": values, "seconds": round(time.perf_counter() - t0, 2)}


def values_outside(recorded: list[float | None], now: list[float | None],
                   tolerance: dict[str, Any] | None) -> list[tuple[int, float | None, float | None]]:
    """The values of ``now`` that miss ``recorded`` by more than ``atol + rtol |recorded|``: (index, recorded, now).

    ``None`` (a NaN or inf in the fingerprint) matches only ``None``. Without a measured
    ``tolerance`` only the rounding of the recorded digits is allowed (``ROUNDING_RTOL``).
    """
    tol = tolerance or {}
    rtol = max(float(tol.get("rtol", 0.0)), ROUNDING_RTOL)
    atol = float(tol.get("atol", 0.0))
    out = []
    for i, (a, b) in enumerate(zip(recorded, now)):
        if a is None or b is None:
            if a is not b:
                out.append((i, a, b))
        elif not abs(b - a) <= atol + rtol * abs(a):
            out.append((i, a, b))
    return out


def fingerprint_matches(entry: dict[str, Any], now: list[float | None]) -> tuple[bool, str]:
    """(matches, why not): ``now`` against the recorded ``entry`` of ``fingerprints.json``, within its tolerance."""
    recorded = entry["values"]
    if len(recorded) != len(now):
        return False, f"{len(recorded)} values recorded, {len(now)} now"
    tol = entry.get("tolerance") or {}
    outside = values_outside(recorded, now, tol)
    may_flip = set(tol.get("may_flip", ()))
    unexpected = [o for o in outside if o[0] not in may_flip]
    bound = f"rtol {tol.get('rtol', 0):.1e} / atol {tol.get('atol', 0):.1e}"
    if not unexpected:
        return True, f"{len(outside)} of {len(now)} values outside {bound}, all among the {len(may_flip)} that may flip"
    return False, (f"{len(unexpected)} of {len(now)} values outside {bound} that never flipped on another machine; "
                   f"first (index, recorded, now): {unexpected[:5]}")


def load_fingerprints(path: Path = FINGERPRINTS) -> dict[str, Any]:
    return json.loads(path.read_text()) if path.exists() else {}


def record_fingerprint(name: str, fp: dict[str, Any], results: list[str], note: str,
                       path: Path = FINGERPRINTS) -> None:
    """Store ``fp`` as the current fingerprint of script ``name`` in ``fingerprints.json``."""
    data = load_fingerprints(path)
    tolerance = data.get(name, {}).get("tolerance")  # measured for the step, not for one run: kept
    data[name] = {**fp, "results": sorted(results), "note": note, **STATE_AT_START}
    if tolerance is not None:
        data[name]["tolerance"] = tolerance
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(dict(sorted(data.items())), indent=1) + "\n")


def same_code_elsewhere(recorded: dict[str, Any], fp: dict[str, Any]) -> bool:
    """Whether a new run's fingerprint ``fp`` differs from the ``recorded`` entry of ``fingerprints.json`` only as
    another machine's would: another hash, every value within the entry's measured tolerance (the bound
    ``tests/test_results_fresh.py`` applies, from ``scripts/fingerprint_tolerance.py``).

    Then the recorded fingerprint stays the code's, and the results already made with it stay verified: a hash of
    rounded digits alone would call them stale on every CPU whose BLAS rounds the last digit otherwise.

    >>> entry = {"hash": "a", "values": [1.0, 2.0], "tolerance": {"rtol": 1e-4, "atol": 0.0}}
    >>> same_code_elsewhere(entry, {"hash": "b", "values": [1.00002, 2.0]})
    True
    >>> same_code_elsewhere(entry, {"hash": "c", "values": [1.001, 2.0]})
    False
    >>> same_code_elsewhere({"hash": "a", "values": [1.0]}, {"hash": "b", "values": [1.00002]})  # no tolerance
    False
    """
    if not recorded or not recorded.get("tolerance") or recorded.get("hash") == fp["hash"]:
        return False
    return fingerprint_matches(recorded, fp["values"])[0]


def record_results(name: str, results: list[str], path: Path = FINGERPRINTS) -> None:
    """Set the results files listed under script ``name``'s fingerprint in ``fingerprints.json`` (the rest kept)."""
    data = load_fingerprints(path)
    data[name] = {**data[name], "results": sorted(results)}
    path.write_text(json.dumps(dict(sorted(data.items())), indent=1) + "\n")


def _in_results(path: Path) -> bool:
    try:
        Path(path).resolve().relative_to(RESULTS.resolve())
    except ValueError:
        return False
    return True


def write_json(path: str | Path, result: dict[str, Any], script: str | Path, config: Any, started: float,
               fingerprint_fn=None, argv: list[str] | None = None) -> dict[str, Any]:
    """Write ``result`` + provenance to ``path``; with ``fingerprint_fn``, also its fingerprint.

    The fingerprint is computed here, in the process of the full run, so the hash in the
    file names the code that produced its numbers. When ``path`` lies in the repository's
    ``results/``, ``fingerprints.json`` is updated too (runs into other folders, e.g.
    tests, leave the repository's records alone). Returns the provenance block.
    """
    path = Path(path)
    prov = provenance(script, config, started, argv)
    if fingerprint_fn is not None:
        fp = compute_fingerprint(fingerprint_fn)
        name = script_name(script)
        prov["fingerprint"] = {"name": name, "hash": fp["hash"], "seconds": fp["seconds"]}
        if _in_results(path):
            recorded = load_fingerprints(FINGERPRINTS).get(name, {})
            known = recorded.get("results", [])
            if same_code_elsewhere(recorded, fp):  # this machine's last digits: the recorded fingerprint stands
                prov["fingerprint"].update(hash=recorded["hash"], this_run_hash=fp["hash"])
                record_results(name, sorted({*known, path.name}), FINGERPRINTS)
            else:
                record_fingerprint(name, fp, sorted({*known, path.name}), "full run", FINGERPRINTS)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({**result, "provenance": prov}, indent=1, default=jsonable) + "\n")
    return prov


def verification(result_file: str | Path, fingerprints: dict[str, Any] | None = None) -> tuple[bool, str]:
    """(verified, why): verified when ``result_file`` carries the fingerprint the code gives now.

    "Now" is ``fingerprints.json`` (``tests/test_results_fresh.py`` checks that it matches
    the code). Files of scripts without a fingerprint (timings) are verified by provenance alone.
    """
    path = Path(result_file)
    fps = load_fingerprints() if fingerprints is None else fingerprints
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return False, f"{path.name} cannot be read"
    prov = data.get("provenance") if isinstance(data, dict) else None
    if not prov:
        return False, f"{path.name} was written before results recorded their provenance"
    fp = prov.get("fingerprint")
    if fp is None:
        return True, "no fingerprint (timings): provenance only"
    current = fps.get(fp["name"])
    if current is None:
        return False, f"no current fingerprint of scripts/{fp['name']}.py in fingerprints.json"
    if current["hash"] != fp["hash"]:
        return False, (f"the code's output changed after this run ({current.get('note', '')}, "
                       f"commit {str(current.get('commit'))[:10]})")
    return True, "fingerprint matches the code"
