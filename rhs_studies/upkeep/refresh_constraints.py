"""Refresh the pinned environments (``constraints/*.txt``) that the README's two commands install with.

The package's own dependency ranges (``pyproject.toml``) stay open for people who install it as a
library; the results, the fingerprints' tolerances and CI are made in *these* environments. Each
file is the ``pip freeze`` of a fresh virtual environment resolved from the project's ranges
today, exactly as the README's test command builds it (torch's CPU build first):

* ``constraints/base.txt``: ``pip install torch==2.13.0`` then ``pip install -e ".[test,docs]"``;
* ``constraints/rllib.txt``: the same with ``".[rllib,test]"`` (ray pins its own gymnasium).

    python scripts/refresh_constraints.py            # both files (a few minutes: two fresh installs)
    python scripts/refresh_constraints.py --only base

After a refresh, rerun ``python scripts/fingerprint_tolerance.py`` (the newest releases are one of
the environments a tolerance covers) and the test command.
"""

from __future__ import annotations

import argparse
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CONSTRAINTS = ROOT / "constraints"
TORCH = "torch==2.13.0"  # the local CPU build (README); never a range that admits a CUDA build
ENVIRONMENTS = {"base": ".[test,docs]", "rllib": ".[rllib,test]"}


def _extras_known(spec: str) -> str:
    """``spec`` without the extras that pyproject.toml does not define (e.g. before a docs extra exists)."""
    import tomllib

    known = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"].get("optional-dependencies", {}))
    extras = [e for e in spec[spec.index("[") + 1:spec.index("]")].split(",") if e in known]
    return f".[{','.join(extras)}]" if extras else "."


def freeze(spec: str) -> list[str]:
    """The pinned lines of a fresh venv with ``torch==2.13.0`` and ``pip install -e <spec>`` (local tags dropped)."""
    with tempfile.TemporaryDirectory(prefix="rhs-lock-") as tmp:
        venv = Path(tmp) / "venv"
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        pip = [str(venv / "bin" / "python"), "-m", "pip", "--disable-pip-version-check", "-q"]
        subprocess.run([*pip, "install", TORCH], check=True)
        subprocess.run([*pip, "install", "-e", _extras_known(spec)], cwd=ROOT, check=True)
        # --all: setuptools too (the test extra's: the wheel test builds with it); pip itself is the installer's
        out = subprocess.run([*pip, "freeze", "--all", "--exclude-editable"], check=True, capture_output=True,
                             text=True).stdout
    lines = []
    for line in out.splitlines():
        if "==" not in line or line.startswith(("-e", "pip==")):
            continue
        name, version = line.split("==", 1)
        lines.append(f"{name}=={version.split('+', 1)[0]}")
    return sorted(lines, key=str.lower)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", choices=tuple(ENVIRONMENTS), default=list(ENVIRONMENTS))
    a = ap.parse_args(argv)
    CONSTRAINTS.mkdir(exist_ok=True)
    for name in a.only:
        t0 = time.time()
        lines = freeze(ENVIRONMENTS[name])
        header = [f"# {name} environment: pip freeze of a fresh venv (python {platform.python_version()}, "
                  f"{time.strftime('%Y-%m-%d', time.gmtime())}),",
                  f"# {TORCH} then pip install -e \"{ENVIRONMENTS[name]}\". Refresh: python scripts/refresh_constraints.py"]
        (CONSTRAINTS / f"{name}.txt").write_text("\n".join(header + lines) + "\n")
        print(f"constraints/{name}.txt: {len(lines)} packages ({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
