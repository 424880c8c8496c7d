"""Unwritable cache folders never stop a run: it falls back to a private temporary cache with one warning.

Run as an ordinary user, since root writes through permission bits: each case is a child process that, when the
tests run as root, becomes ``nobody`` (uid 65534) or, where ``nobody`` cannot run this interpreter (a Python under
``/root``), stays root without ``CAP_DAC_OVERRIDE`` / ``CAP_DAC_READ_SEARCH`` (then the owner's permission bits
bind it too). The read-only folders are root-owned and mode 0555, read-only for both. The workload builds a small
pattern library (user cache) and runs a compiled kernel (numba cache) -- the two things the project caches.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOBODY = 65534
PR_CAPBSET_DROP, CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH = 24, 1, 2

WORKLOAD = """
    import warnings
    warnings.simplefilter("always")
    import numpy as np
    from rhs_common import jit
    from rhs_env.array_models import RHSConfig, ScanConfig
    from rhs_env.patterns.library import get_library
    v = np.array([3.0, 2.0, 1.0])
    jit.sort_small(v)
    lib = get_library(RHSConfig(elements=8), ScanConfig(grid_deg=30.0), workers=1, progress=False)
    again = get_library(RHSConfig(elements=8), ScanConfig(grid_deg=30.0), workers=1, progress=False)
    import os
    print("ok", v.tolist(), lib.path, again.path == lib.path, os.environ.get("NUMBA_CACHE_DIR"))
"""


def _become_nobody() -> None:
    os.setgroups([])
    os.setgid(NOBODY)
    os.setuid(NOBODY)


def _drop_dac() -> None:
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH):
        if libc.prctl(PR_CAPBSET_DROP, cap, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP)")


@pytest.fixture(scope="module")
def ordinary() -> tuple[Callable[[], None] | None, str]:
    """How a child becomes an ordinary user: (preexec_fn, name); skips where no way works."""
    if not hasattr(os, "geteuid"):
        pytest.skip("POSIX permissions")
    if os.geteuid() != 0:
        return None, "user"
    for how, name in ((_become_nobody, "nobody"), (_drop_dac, "root without DAC override")):
        try:
            probe = subprocess.run([sys.executable, "-c", "import numpy, numba, rhs_env.patterns.library"], cwd=ROOT,
                                   preexec_fn=how, capture_output=True, timeout=120)
        except (OSError, subprocess.SubprocessError):
            continue
        if probe.returncode == 0:
            return how, name
    pytest.skip("cannot run a child as an ordinary user here")


@pytest.fixture
def base() -> Iterator[Path]:
    """A folder every user can enter (tmp_path's parents are 0700), removed afterwards."""
    path = Path(tempfile.mkdtemp(prefix="rhs-slam-cache-test-"))
    path.chmod(0o755)
    (path / "tmp").mkdir(mode=0o777)
    (path / "tmp").chmod(0o1777)
    (path / "ro").mkdir()
    (path / "ro").chmod(0o555)  # read-only for its owner (root) and everyone else
    (path / "file").write_text("not a folder")
    (path / "file").chmod(0o644)
    yield path
    (path / "ro").chmod(0o755)
    shutil.rmtree(path, ignore_errors=True)


CASES = {
    # name: (environment changes, the variable the warning must name); None removes the variable
    "HOME unset": ({"HOME": None}, "RHS_SLAM_CACHE"),
    "HOME read-only": ({"HOME": "{ro}"}, "RHS_SLAM_CACHE (or XDG_CACHE_HOME / HOME)"),
    "XDG_CACHE_HOME read-only": ({"XDG_CACHE_HOME": "{ro}"}, "RHS_SLAM_CACHE (or XDG_CACHE_HOME / HOME)"),
    "RHS_SLAM_CACHE a regular file": ({"RHS_SLAM_CACHE": "{file}"}, "set RHS_SLAM_CACHE to a writable folder"),
    "RHS_SLAM_CACHE read-only": ({"RHS_SLAM_CACHE": "{ro}"}, "set RHS_SLAM_CACHE to a writable folder"),
    "RHS_SLAM_CACHE below a file": ({"RHS_SLAM_CACHE": "{file}/cache"}, "set RHS_SLAM_CACHE to a writable folder"),
    "NUMBA_CACHE_DIR read-only": ({"NUMBA_CACHE_DIR": "{ro}/numba", "RHS_SLAM_CACHE": "{tmp}/ok"},
                                  "set NUMBA_CACHE_DIR to a writable folder"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_unwritable_cache_folder_falls_back_with_one_warning(case: str, ordinary, base: Path) -> None:
    how, who = ordinary
    changes, variable = CASES[case]
    if case == "HOME unset" and who != "nobody":
        pytest.skip("the passwd home of this user is writable by it: nothing falls back")
    env = {k: v for k, v in os.environ.items() if k not in ("RHS_SLAM_CACHE", "NUMBA_CACHE_DIR", "XDG_CACHE_HOME")}
    env.update({"HOME": str(base / "ro"), "TMPDIR": str(base / "tmp"), "OMP_NUM_THREADS": "1",
                "PYTHONDONTWRITEBYTECODE": "1"})
    if who != "nobody":  # root owns the checkout: keep numba's cache out of it (in-tree __pycache__)
        env["NUMBA_CACHE_DIR"] = str(base / "tmp" / "numba")
    for key, value in changes.items():
        if value is None:
            env.pop(key, None)
        else:
            env[key] = value.format(ro=base / "ro", file=base / "file", tmp=base / "tmp")
    res = subprocess.run([sys.executable, "-c", textwrap.dedent(WORKLOAD)], cwd=ROOT, env=env, preexec_fn=how,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and "Traceback" not in res.stderr, (who, res.stderr[-3000:])
    assert res.stdout.startswith("ok [1.0, 2.0, 3.0]") and " True " in res.stdout, res.stdout
    warnings = [ln for ln in res.stderr.splitlines() if "Warning:" in ln]
    assert len(warnings) == 1, (who, res.stderr[-3000:])
    assert "CacheFallbackWarning" in warnings[0] and variable in warnings[0], warnings
    assert str(base / "tmp" / "rhs-slam-cache-") in res.stdout  # the library (or kernel) went to the private folder
    private = next((base / "tmp").glob("rhs-slam-cache-*"))
    assert private.stat().st_mode & 0o777 == 0o700


def test_private_temporary_folder_of_another_user_is_not_used(tmp_path: Path, monkeypatch) -> None:
    """A ``rhs-slam-cache-<uid>`` folder someone else made (or a symlink) is never the fallback."""
    from rhs_common import cache_dir

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    uid = os.geteuid()
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / f"rhs-slam-cache-{uid}").symlink_to(tmp_path / "elsewhere")
    path = cache_dir._private_temp()
    assert path.parent == tmp_path and path.name != f"rhs-slam-cache-{uid}" and not path.is_symlink()


def test_no_fallback_without_need(tmp_path: Path, monkeypatch, recwarn) -> None:
    from rhs_common import cache_dir

    monkeypatch.setenv("RHS_SLAM_CACHE", str(tmp_path / "c"))
    assert cache_dir.cache_subdir("patterns") == tmp_path / "c" / "patterns"
    assert not [w for w in recwarn if issubclass(w.category, cache_dir.CacheFallbackWarning)]


def test_no_home_and_no_passwd_entry_falls_back(tmp_path: Path, monkeypatch) -> None:
    """A container user with no HOME and no passwd entry: ``~`` stays unexpanded, and the cache must not become a
    folder named ``~`` in the working directory."""
    import pwd

    from rhs_common import cache_dir

    for var in ("RHS_SLAM_CACHE", "HOME", "XDG_CACHE_HOME"):
        monkeypatch.setenv(var, "x")  # (recorded, so the fallback's export is undone after the test)
        monkeypatch.delenv(var)
    monkeypatch.setattr(pwd, "getpwuid", lambda uid: (_ for _ in ()).throw(KeyError(uid)))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(cache_dir, "_WARNED", set())
    monkeypatch.chdir(tmp_path)
    with pytest.warns(cache_dir.CacheFallbackWarning, match="no home folder.*set RHS_SLAM_CACHE"):
        root = cache_dir.cache_root()
    assert root.parent == tmp_path and root.name.startswith("rhs-slam-cache-")
    assert not (tmp_path / "~").exists()
    assert os.environ["RHS_SLAM_CACHE"] == str(root)
