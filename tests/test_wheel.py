"""The wheel works outside the checkout: it holds every file of the packages, and installed it runs.

The wheel is built offline (``pip wheel --no-deps --no-build-isolation --no-index``, with this environment's
setuptools) from a copy of the checkout's files, not in place: a ``build/`` folder left by an earlier build could
otherwise slip deleted modules into it, and the checkout stays untouched. It is installed (``--no-deps
--force-reinstall``) into a fresh virtual environment in a temporary folder; that environment reads the
dependencies from this one's site-packages as plain paths (a ``.pth`` file), so no ``.pth`` hook of this
environment runs there, the checkout's editable install included. From a temporary working folder the
installed ``rhs-slam demo`` drives a short episode (2 s, 10 steps) with the shipped policy and every registered
``rhs-*`` id is made, reset and stepped once, each module imported from the new environment's site-packages.
About a minute on a quiet 2-core machine, most of it the cold compile of the kernels in the new location (in the
foreground: ``RHS_SLAM_BACKGROUND_COMPILE=0``, so no process outlives the test).
"""

from __future__ import annotations

import json
import os
import site
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: the packages the wheel ships (pyproject.toml's [tool.setuptools.packages.find])
PACKAGES = ("rhs_common", "rhs_env", "slam", "agents", "rhs_slam", "rhs_studies")
#: the project files a build reads besides the packages
BUILD_FILES = ("pyproject.toml", "README.md", "MANIFEST.in", "LICENSE")
#: the episode the installed demo drives: 2 s at 5 decisions per second
SHORT_DEMO = {"duration": 2}


def package_files() -> list[str]:
    """Paths (relative to the checkout) of the packages' files: git's tracked and untracked-not-ignored files that
    exist, or, outside a git checkout, every file but caches."""
    try:
        out = subprocess.run(["git", "ls-files", "-z", "-co", "--exclude-standard", "--", *PACKAGES], cwd=ROOT,
                             capture_output=True, check=True, timeout=60).stdout.decode()
        names = [n for n in out.split("\0") if n]
    except (OSError, subprocess.CalledProcessError):
        names = [str(p.relative_to(ROOT)) for pkg in PACKAGES for p in (ROOT / pkg).rglob("*")
                 if p.is_file() and "__pycache__" not in p.parts and p.suffix not in (".pyc", ".nbi", ".nbc")]
    return sorted(n for n in names if (ROOT / n).is_file())


def build_wheel(src: Path, dist: Path) -> Path:
    """Copy the packages' files and the build files into ``src``, build the wheel into ``dist`` and return it."""
    for name in [*package_files(), *BUILD_FILES]:
        if (ROOT / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            (src / name).write_bytes((ROOT / name).read_bytes())
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q", "-w", str(dist),
         str(src)], capture_output=True, text=True, timeout=300, env={**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1"})
    assert proc.returncode == 0, f"pip wheel failed:\n{proc.stdout}\n{proc.stderr}"
    (wheel,) = dist.glob("rhs_slam-*.whl")
    return wheel


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("wheel")
    return build_wheel(tmp / "src", tmp / "dist")


def test_the_wheel_holds_every_file_of_the_packages(wheel):
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
    missing = [n for n in package_files() if n not in names]
    assert not missing, f"{len(missing)} files of the packages are not in the wheel (pyproject.toml package-data): {missing}"
    data = [n for n in package_files() if not n.endswith(".py")]
    assert any(n.startswith("agents/data/rl/") for n in data), "the shipped policies live in agents/data/rl/"
    assert {"agents/data/shipped.zip", "agents/data/shipped.json"} <= names, "the shipped policy, under its role name"
    for pkg in PACKAGES:
        assert f"{pkg}/py.typed" in names, f"{pkg} ships no py.typed marker"
    tops = {n.split("/", 1)[0] for n in names}
    assert tops - set(PACKAGES) == {wheel.name.split("-py")[0] + ".dist-info"}, f"unexpected top-level entries: {tops}"


def _venv(path: Path, wheel: Path) -> tuple[Path, Path]:
    """A fresh virtual environment at ``path`` with ``wheel`` installed and this environment's site-packages as
    plain paths; returns (its python, its site-packages)."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(path)], check=True, timeout=120)
    python = path / "bin" / "python"
    purelib = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                  capture_output=True, text=True, check=True, timeout=60).stdout.strip())
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--force-reinstall", "--no-index",
         "-q", str(wheel)], capture_output=True, text=True, timeout=300,
        env={**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1"})
    assert proc.returncode == 0, f"pip install of the wheel failed:\n{proc.stdout}\n{proc.stderr}"
    # after the install: pip never sees (nor uninstalls) this environment's copy of rhs-slam
    (purelib / "_rhs_wheel_test_deps.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    return python, purelib


def _run(cmd: list[str], cwd: Path, timeout: float = 400) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    # no background compile (slam.gym.precompile): it would outlive the test in a detached process
    env.update(MPLBACKEND="Agg", SDL_VIDEODRIVER="dummy", OMP_NUM_THREADS="1", PYTHONNOUSERSITE="1",
               RHS_SLAM_BACKGROUND_COMPILE="0")
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}"
    return proc.stdout


#: run by the installed python: where each package comes from, the installed version, every rhs-* id made and stepped
MAKE_EVERY_ID = """
import importlib, json, sys, importlib.metadata as md
import gymnasium as gym
files = {p: importlib.import_module(p).__file__ for p in sys.argv[1:]}
ids = sorted(i for i in gym.registry if i.startswith("rhs-"))
for env_id in ids:
    env = gym.make(env_id)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    env.close()
print(json.dumps({"files": files, "ids": ids, "version": md.version("rhs-slam")}))
"""


def test_the_installed_wheel_runs_the_demo_and_every_env(wheel, tmp_path):
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids this checkout defines)

    python, purelib = _venv(tmp_path / "venv", wheel)
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    out = cwd / "demo"
    _run([str(python.parent / "rhs-slam"), "demo", "--env-kwargs", json.dumps(SHORT_DEMO), "--out", str(out)], cwd)
    summary = json.loads((out / "demo.json").read_text())
    assert Path(summary["policy"]).is_relative_to(purelib), f"the demo's policy is not the installed one: {summary['policy']}"
    assert Path(summary["policy"]).name == "shipped.zip", summary["policy"]
    assert summary["env_id"] == "rhs-highway-slam-v0" and summary["steps"] == 10, summary
    assert (out / "trajectory_map.png").stat().st_size > 0

    report = json.loads(_run([str(python), "-c", MAKE_EVERY_ID, *PACKAGES], cwd).strip().splitlines()[-1])
    for pkg, file in report["files"].items():
        assert Path(file).is_relative_to(purelib), f"{pkg} came from {file}, not from the installed wheel in {purelib}"
    assert report["ids"] == sorted(i for i in gym.registry if i.startswith("rhs-")), report["ids"]
    assert report["version"] == wheel.name.split("-")[1], report["version"]
