"""The pinned environments (``constraints/*.txt``) agree with the package's open ranges and the README.

The package's dependency ranges stay open for library users; the README's two commands install
through the constraints files, so CI and the results run on the versions the results were made
with (``scripts/refresh_constraints.py`` refreshes them).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import tomllib
from packaging.requirements import Requirement
from packaging.version import Version

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def pins(name: str) -> dict[str, Version]:
    """``{normalised distribution name: pinned version}`` of ``constraints/<name>.txt``."""
    out = {}
    for line in (ROOT / "constraints" / f"{name}.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        req = Requirement(line)
        (spec,) = req.specifier
        assert spec.operator == "==", f"constraints/{name}.txt: {line!r} is not an exact pin"
        out[_norm(req.name)] = Version(spec.version)
    return out


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


@pytest.mark.parametrize(("lock", "extras"), [("base", ("test",)), ("rllib", ("rllib", "test"))])
def test_every_dependency_is_pinned_inside_the_packages_range(lock, extras):
    pinned = pins(lock)
    reqs = [Requirement(r) for r in PYPROJECT["project"]["dependencies"]]
    for extra in extras:
        reqs += [Requirement(r) for r in PYPROJECT["project"]["optional-dependencies"][extra]]
    for req in reqs:
        name = _norm(req.name)
        assert name in pinned, f"constraints/{lock}.txt does not pin {req.name}: python scripts/refresh_constraints.py"
        assert req.specifier.contains(pinned[name], prereleases=True), (
            f"constraints/{lock}.txt pins {req.name}=={pinned[name]}, outside pyproject's {req.specifier}")
    assert pinned["torch"] == Version("2.13.0"), "torch must stay the local CPU build the README installs first"


def test_the_package_ranges_stay_open():
    """Library users get lower bounds (and a cap only where an upstream break is known), never exact pins."""
    for r in PYPROJECT["project"]["dependencies"]:
        assert all(s.operator in (">=", "<", "!=") for s in Requirement(r).specifier), r


def test_readme_commands_install_through_the_constraints():
    readme = (ROOT / "README.md").read_text()
    for marker in ("<!-- main-command -->", "<!-- test-command -->"):
        block = readme.split(marker, 1)[1].split("```", 2)[1]
        installs = [c for c in re.split(r"&&", block) if "pip install" in c]
        assert installs, marker
        for cmd in installs:
            assert re.search(r"-c constraints/(base|rllib)\.txt", cmd), f"{marker}: {cmd.strip()!r} installs without a constraints file"
