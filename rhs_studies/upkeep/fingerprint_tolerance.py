"""Measure how far each results fingerprint moves when nothing but the machine changes, and record its tolerance.

The same code gives slightly different numbers on another CPU or with another release of a
dependency: numpy dispatches its sin / cos / exp loops to AVX-512 or AVX2, OpenBLAS picks a kernel
per CPU, torch its own, the conic solvers behind cvxpy iterate to a tolerance, and a driving
episode can turn such a last-digit difference into one flipped discrete decision. A fingerprint
compared by hash therefore fails on a fresh machine although the code is the same.

This script reruns every fingerprint in subprocesses under settings that change exactly those
things, and compares each value with the one recorded in ``results/fingerprints.json``
(which was computed on the machine that ran the full study):

==================  =====================================================================
``native``          this machine, as the tests run it (single-threaded BLAS)
``threads-2``       two OpenMP / MKL / torch threads
``openblas-*``      OpenBLAS forced to its Sandybridge (AVX) and SkylakeX (AVX-512) kernels
``numpy-avx2``      numpy's SIMD dispatch capped below AVX-512 (``NPY_DISABLE_CPU_FEATURES``)
``torch-avx2``      torch's kernels capped at AVX2 (``ATEN_CPU_CAPABILITY``), MKL in AVX2 mode
``avx2-machine``    all of the above at once and numba's code for Haswell (``NUMBA_CPU_NAME``): what an
                    AVX2-only CPU computes (this and ``numpy-avx2`` compile the kernels in a cache of their own)
``--python L=PY``   another environment named ``L``, e.g. one resolved to the oldest allowed
                    dependencies (``uv pip install --resolution lowest-direct -e .``)
==================  =====================================================================

For a step with recorded values ``r_i``, a setting's values ``v_i`` move by the relative amount
``d_i = |v_i - r_i| / max(|r_i|, s)``, where ``s = SCALE_FRACTION * median |r|`` keeps values that
are numerically zero (a sidelobe null of 1e-10) from counting as large relative moves. A value
with ``d_i > FLIP_REL`` has *flipped* (a discrete decision went the other way: an action count,
a collision); the others are round-off. The recorded tolerance is

    rtol = max(SAFETY * max_i d_i (non-flipped values, every setting), ROUNDING_RTOL)
    atol = rtol * s
    may_flip = the indices i that flipped in at least one setting

so a value matches when ``|now - recorded| <= atol + rtol |recorded|``, and at most
only the values in ``may_flip`` may miss it (a closed-loop episode flips the same few values, those
after its one decision that went the other way; a real change of the code moves others). The
measured spread is written beside the tolerance.

Machines accumulate: each step keeps every machine's own measurement under ``machines`` (named by its CPU,
:func:`machine`; measuring again on a machine replaces that machine's), and its tolerance is derived from
all of them (the larger rtol and atol, the union of may_flip, each machine's spread under its name), so a
tolerance measured on one CPU keeps holding there after it is measured on another (``--fresh`` starts over).

    python scripts/fingerprint_tolerance.py                         # measure every step, print, record
    python scripts/fingerprint_tolerance.py --only fig5b fig5c --dry-run
    python scripts/fingerprint_tolerance.py --python oldest-deps=/path/to/oldest-venv/bin/python
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from rhs_studies.kit.episodes import study_env
from rhs_studies.kit.provenance import FINGERPRINTS, ROOT, ROUNDING_RTOL, STATE_AT_START, load_fingerprints, script_name

SAFETY = 4.0  # tolerance = SAFETY x the largest measured round-off spread
FLIP_REL = 0.02  # a value that moved by more than 2 % under a machine-only change flipped a discrete decision
SCALE_FRACTION = 1e-3  # values below 1e-3 x the step's median magnitude count on the absolute scale

_AVX512_OFF = "X86_V4 AVX512_ICL AVX512_SPR"
SETTINGS: dict[str, dict[str, str]] = {
    "native": {},
    "threads-2": {"OMP_NUM_THREADS": "2", "MKL_NUM_THREADS": "2", "OPENBLAS_NUM_THREADS": "2", "RHS_TORCH_THREADS": "2"},
    "openblas-sandybridge": {"OPENBLAS_CORETYPE": "Sandybridge"},
    "openblas-skylakex": {"OPENBLAS_CORETYPE": "SkylakeX"},
    "numpy-avx2": {"NPY_DISABLE_CPU_FEATURES": _AVX512_OFF},
    "torch-avx2": {"ATEN_CPU_CAPABILITY": "avx2", "MKL_CBWR": "AVX2"},
    "avx2-machine": {"OPENBLAS_CORETYPE": "Haswell", "NPY_DISABLE_CPU_FEATURES": _AVX512_OFF,
                     "ATEN_CPU_CAPABILITY": "avx2", "MKL_CBWR": "AVX2", "NUMBA_CPU_NAME": "haswell"},
}
#: settings whose kernels are compiled in a numba cache of their own, as on another machine: a cache compiled with
#: numpy's full dispatch and loaded under ``NPY_DISABLE_CPU_FEATURES`` crashed in the traffic core (AMD EPYC with
#: AVX-512, numba 0.68.1, numpy 2.4.6), which a machine without AVX-512 never meets (it compiles its own)
OWN_NUMBA_CACHE = frozenset({"numpy-avx2", "avx2-machine"})


def _steps(only: list[str] | None):
    from rhs_studies.upkeep import reproduce

    return [s for s in reproduce.STEPS if not s.no_fingerprint and (not only or s.name in only)]


def worker(names: list[str]) -> None:
    """Print ``{step: values}`` as JSON on the last line (run in a subprocess under one setting)."""
    from rhs_studies.kit.provenance import compute_fingerprint, package_versions
    from rhs_studies.upkeep import reproduce

    if os.environ.get("RHS_TORCH_THREADS"):
        import torch

        torch.set_num_threads(int(os.environ["RHS_TORCH_THREADS"]))
    out: dict = {"_packages": package_versions()}
    for s in _steps(names):
        out[s.name] = compute_fingerprint(reproduce.fingerprint_fn(s))["values"]
        print(f"  {s.name}: {len(out[s.name])} values", file=sys.stderr, flush=True)
    print(json.dumps(out))


def run_setting(label: str, env: dict[str, str], names: list[str], python: str) -> dict[str, Any]:
    """The fingerprints of ``names`` computed by ``python`` in a fresh process with ``env`` added."""
    t0 = time.time()
    with tempfile.TemporaryDirectory(prefix=f"rhs-fingerprint-{label}-") as cache:
        own = {"NUMBA_CACHE_DIR": cache} if label in OWN_NUMBA_CACHE else {}
        full = study_env({**env, **own}, blas_single_thread=False)  # one OpenMP thread, as the tests run
        proc = subprocess.run([python, "-m", "rhs_studies.upkeep.fingerprint_tolerance", "--worker", *names], cwd=ROOT,
                              env=full, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"setting {label} failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
    print(f"{label:22s} {time.time() - t0:6.1f} s", flush=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def relative_moves(recorded: list, now: list) -> tuple[np.ndarray, float]:
    """``d_i`` (module docstring) of each value and the step's scale ``s``; a None against a number moves by inf."""
    mags = [abs(v) for v in recorded if v is not None and v != 0]
    scale = SCALE_FRACTION * float(np.median(mags)) if mags else 1.0
    d = []
    for a, b in zip(recorded, now):
        if a is None or b is None:
            d.append(0.0 if a is b else np.inf)
        else:
            d.append(abs(b - a) / max(abs(a), scale))
    return np.asarray(d, dtype=float), scale


def tolerance(recorded: list, runs: dict[str, list]) -> dict:
    """The step's tolerance and measured spread from its values under every setting (module docstring)."""
    round_off, may_flip, spread = [0.0], set(), {}
    scale = 1.0
    for label, now in runs.items():
        if len(now) != len(recorded):
            raise RuntimeError(f"{label}: {len(now)} values, {len(recorded)} recorded: the code changed, rerun the step")
        d, scale = relative_moves(recorded, now)
        flipped = d > FLIP_REL
        may_flip |= set(np.flatnonzero(flipped).tolist())
        round_off.append(float(d[~flipped].max()) if (~flipped).any() else 0.0)
        spread[label] = {"max_rel": float(f"{round_off[-1]:.3g}"), "flipped": int(flipped.sum())}
    rtol = max(SAFETY * max(round_off), ROUNDING_RTOL)
    return {"rtol": float(f"{rtol:.3g}"), "atol": float(f"{rtol * scale:.3g}"), "may_flip": sorted(may_flip),
            "spread": spread, "safety": SAFETY, "flip_rel": FLIP_REL,
            "measured": {"commit": STATE_AT_START["commit"], "dirty": STATE_AT_START["dirty"], "machine": machine(),
                         "utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}}


def machine() -> str:
    """This machine's CPU model and widest SIMD level (``AMD EPYC avx512``), the label of its measurements."""
    model, flags = "unknown CPU", ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and model == "unknown CPU":
                model = value.strip()
            elif key.strip() == "flags" and not flags:
                flags = value
    except OSError:
        import platform

        model = platform.processor() or model
    level = "avx512" if "avx512f" in flags.split() else "avx2" if "avx2" in flags.split() else ""
    return f"{model} {level}".strip()


#: the keys of one machine's measurement kept under ``machines`` (the combined tolerance is derived from them)
_PER_MACHINE = ("rtol", "atol", "may_flip", "spread", "environments", "measured")
#: the name of a measurement recorded before machines were named
EARLIER_MACHINE = "first machine (unnamed)"


def merged(old: dict | None, new: dict) -> dict:
    """``new``'s measurement added to the machines an earlier tolerance ``old`` was measured on.

    ``machines`` keeps each machine's own measurement (a new one on the same machine replaces it); the tolerance
    itself is derived from all of them: the largest rtol and atol, the union of may_flip, every spread under
    ``"<machine>: <setting>"``."""
    machines = dict((old or {}).get("machines", {}))
    if old and not machines:  # recorded before machines were named: one machine, whatever it was
        machines[old.get("measured", {}).get("machine", EARLIER_MACHINE)] = {k: old[k] for k in _PER_MACHINE if k in old}
    tag = new["measured"]["machine"]
    machines[tag] = {k: new[k] for k in _PER_MACHINE if k in new}
    if len(machines) == 1:
        return {**new, "machines": machines}
    per = machines.values()
    return {**new, "rtol": max(m["rtol"] for m in per), "atol": max(m["atol"] for m in per),
            "may_flip": sorted(set().union(*(m.get("may_flip", []) for m in per))),
            "spread": {f"{name}: {k}": v for name, m in machines.items() for k, v in m.get("spread", {}).items()},
            "environments": {f"{name}: {k}": v for name, m in machines.items() for k, v in m.get("environments", {}).items()},
            "machines": machines}


def distinct_environments(environments: dict[str, dict[str, str]]) -> dict[str, dict[str, str]]:
    """The package versions of each setting, keeping one label per distinct set (settings differ by env vars)."""
    out: dict[str, dict[str, str]] = {}
    for label, packages in environments.items():
        if packages not in out.values():
            out[label] = packages
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", help="these steps only (names as in scripts/reproduce.py --list)")
    ap.add_argument("--python", nargs="*", default=[], metavar="LABEL=PYTHON",
                    help="other environments' interpreters to include, each named by a label")
    ap.add_argument("--settings", nargs="+", choices=tuple(SETTINGS), default=list(SETTINGS))
    ap.add_argument("--dry-run", action="store_true", help="print the spread and tolerance, record nothing")
    ap.add_argument("--fresh", action="store_true", help="replace the recorded tolerance (default: merge with it when it "
                                                         "was measured on another machine)")
    ap.add_argument("--worker", nargs="*", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker is not None:
        worker(a.worker)
        return 0
    steps = _steps(a.only)
    if not steps:
        print(f"fingerprint_tolerance: error: no fingerprinted step among {a.only}", file=sys.stderr)
        return 2
    names = [s.name for s in steps]
    runs: dict[str, dict[str, Any]] = {}
    for label in a.settings:
        runs[label] = run_setting(label, SETTINGS[label], names, sys.executable)
    for item in a.python:
        label, _, py = item.rpartition("=")
        label = label or Path(py).parent.parent.name
        runs[label] = run_setting(label, {}, names, py)
    environments = {label: r.pop("_packages") for label, r in runs.items()}
    fps = load_fingerprints()
    print(f"\n{'step':28s} {'n':>4s} {'max round-off':>14s} {'flipped':>8s} {'rtol':>9s} {'atol':>9s} {'may_flip':>8s}")
    for s in steps:
        key = script_name(s.script)
        tol = tolerance(fps[key]["values"], {label: r[s.name] for label, r in runs.items()})
        tol["environments"] = distinct_environments(environments)
        worst = max(v["max_rel"] for v in tol["spread"].values())
        flipped = max(v["flipped"] for v in tol["spread"].values())
        print(f"{s.name:28s} {len(fps[key]['values']):4d} {worst:14.2e} {flipped:8d} {tol['rtol']:9.2e} "
              f"{tol['atol']:9.2e} {len(tol['may_flip']):8d}")
        fps[key]["tolerance"] = tol if a.fresh else merged(fps[key].get("tolerance"), tol)
    if not a.dry_run:
        FINGERPRINTS.write_text(json.dumps(dict(sorted(fps.items())), indent=1) + "\n")
        print(f"recorded in {FINGERPRINTS.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
