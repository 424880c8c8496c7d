"""The files the project loads are verified: a bad one is refused naming the file and the fix, a cached one rebuilt.

A table of user-found faults, one row each: pattern libraries (shipped, cached, given to ``--load``), the CNN
registration weights and numba's kernel cache. Every fault runs in its own process (``_run``: a time limit, a
temporary ``RHS_SLAM_CACHE`` and ``NUMBA_CACHE_DIR``) on copies of the shipped files, so the checkout and the caches
the other tests use are never touched. The ``patterns`` command's odd options and its Ctrl-C close the file.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import fuzz_settings  # noqa: F401  (loads the hypothesis profile)
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rhs_common.input_files import file_sha256
from rhs_env.array_models import RHSConfig, ScanConfig
from rhs_env.patterns import library as L
from slam.core import cnn_registration as C

ROOT = Path(__file__).resolve().parents[1]


def _run(code: str, tmp_path: Path, timeout: float = 240.0, **env: str) -> subprocess.CompletedProcess[str]:
    """``code`` in a fresh interpreter with its own caches under ``tmp_path`` (stdout, stderr captured)."""
    full = {**os.environ, "RHS_SLAM_CACHE": str(tmp_path / "cache"), "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
            "OMP_NUM_THREADS": "1", "PYTHONWARNINGS": "default", **env}
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, env=full, capture_output=True,
                          text=True, timeout=timeout)


def _data_copy(tmp_path: Path) -> Path:
    """A copy of the shipped pattern libraries with their checksums."""
    data = tmp_path / "data"
    shutil.copytree(L.DATA_DIR, data)
    return data


# ---- shipped pattern libraries: refused by name with the fix, never skipped in silence -------------------------

def _truncate(p: Path) -> None:
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])


def _random(p: Path) -> None:
    p.write_bytes(np.random.default_rng(0).bytes(p.stat().st_size))


def _times_1000(p: Path) -> None:
    with np.load(p) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["tx"] = arrays["tx"] * 1000.0
    with open(p, "wb") as f:
        np.savez(f, **arrays)


SHIPPED_FAULTS = [("truncated (BadZipFile before)", _truncate), ("random bytes (skipped in silence before)", _random),
                  ("amplitudes x 1000, valid npz", _times_1000)]


@pytest.mark.parametrize("fault", [f for _, f in SHIPPED_FAULTS], ids=[n for n, _ in SHIPPED_FAULTS])
def test_damaged_shipped_library_is_refused_naming_the_file_and_the_fix(tmp_path: Path, fault) -> None:
    data = _data_copy(tmp_path)
    target = data / "rhs_m60_grid5deg_fast.npz"
    fault(target)
    res = _run(f"""
        from rhs_env.patterns import library as L
        from rhs_env.array_models import RHSConfig, ScanConfig
        L.DATA_DIR = L.Path({str(data)!r})
        L.build_library = None  # a damaged shipped file must not start a build either
        try:
            L.get_library(RHSConfig(), ScanConfig(grid_deg=5.0))
        except ValueError as exc:
            print("REFUSED", exc)
        """, tmp_path)
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr[-2000:]
    assert res.stdout.startswith("REFUSED"), res.stdout
    assert str(target) in res.stdout and "reinstall rhs-slam" in res.stdout
    assert "rhs-slam patterns --grid-deg 5" in res.stdout


def test_shipped_libraries_load_unchanged_and_are_all_recorded() -> None:
    """Every shipped file is in checksums.json with its sha256, and loads to the arrays stored in it."""
    record = json.loads((L.DATA_DIR / L.CHECKSUMS).read_text())
    assert sorted(record) == sorted(p.name for p in L.DATA_DIR.glob("*.npz"))
    for grid in (1.0, 2.0, 5.0):
        fields = L.library_fields(RHSConfig(), ScanConfig(grid_deg=grid))
        path = L.find_shipped(fields)
        assert path is not None and record[path.name]["sha256"] == L.file_sha256(path)
        lib = L.get_library(RHSConfig(), ScanConfig(grid_deg=grid))
        with np.load(path) as z:
            np.testing.assert_array_equal(lib.tx, z["tx"])
            np.testing.assert_array_equal(lib.rx, z["rx"])


def test_deleted_shipped_library_counts_as_not_shipped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Deleting a damaged shipped file (the advice) makes the lookup build the library into the user cache."""
    data = _data_copy(tmp_path)
    (data / "rhs_m60_grid5deg_fast.npz").unlink()
    monkeypatch.setattr(L, "DATA_DIR", data)
    assert L.find_shipped(L.library_fields(RHSConfig(), ScanConfig(grid_deg=5.0))) is None
    assert L.find_shipped(L.library_fields(RHSConfig(), ScanConfig(grid_deg=2.0))) == data / "rhs_m60_grid2deg_fast.npz"


# ---- library files: the schema ---------------------------------------------------------------------------------

def _small(tmp_path: Path) -> tuple[Path, dict]:
    cfg, scan = RHSConfig(elements=8), ScanConfig(grid_deg=30.0)
    fields = L.library_fields(cfg, scan)
    lib = L.PatternLibrary(scan.angles_deg, np.full((3, 8), 0.5), np.full((3, 8), 0.25), fields)
    return lib.save(tmp_path / "lib.npz"), fields


def _rewrite(path: Path, **arrays: np.ndarray) -> None:
    with np.load(path) as z:
        old = {k: z[k] for k in z.files}
    with open(path, "wb") as f:
        np.savez(f, **{**old, **arrays})


SCHEMA_FAULTS = [
    ("amplitudes x 1000", {"tx": np.full((3, 8), 500.0)}, "amplitudes must lie in [0, 1]"),
    ("NaN amplitudes", {"rx": np.where(np.eye(3, 8) > 0, np.nan, 0.5)}, "amplitudes must lie in [0, 1]"),
    ("rows of another grid", {"tx": np.full((4, 8), 0.5), "rx": np.full((4, 8), 0.5)}, "shape"),
    ("columns of another radar", {"tx": np.full((3, 9), 0.5), "rx": np.full((3, 9), 0.5)}, "shape"),
    ("angles of another grid", {"angles_deg": np.array([-20.0, 0.0, 20.0])}, "angles_deg do not match"),
    ("angles missing a grid", {"angles_deg": np.array([-30.0, 0.0])}, "angles_deg do not match"),
]


@pytest.mark.parametrize(("arrays", "fragment"), [(a, f) for _, a, f in SCHEMA_FAULTS],
                         ids=[n for n, _, _ in SCHEMA_FAULTS])
def test_library_arrays_must_match_their_config(tmp_path: Path, arrays: dict, fragment: str) -> None:
    path, fields = _small(tmp_path)
    _rewrite(path, **arrays)
    with pytest.raises(ValueError, match="rebuild it with `rhs-slam patterns") as exc:
        L.load(path, fields)
    assert str(path) in str(exc.value) and fragment in str(exc.value)


def test_library_of_other_feeds_is_refused(tmp_path: Path) -> None:
    path, _ = _small(tmp_path)
    other = L.library_fields(RHSConfig(elements=8, tx_feed=1), ScanConfig(grid_deg=30.0))
    with pytest.raises(ValueError, match=r"differs from the expected one in \['rhs'\]"):
        L.load(path, other)


# ---- the user cache: a bad file is rebuilt with one warning ----------------------------------------------------

@pytest.mark.parametrize("content", [b"garbage", b"PK\x03\x04" + b"\0" * 64, b""], ids=["text", "zip header", "empty"])
def test_garbage_in_the_cache_is_rebuilt_with_one_warning(tmp_path: Path, content: bytes) -> None:
    res = _run(f"""
        import warnings
        from rhs_env.patterns import library as L
        from rhs_env.array_models import RHSConfig, ScanConfig
        cfg, scan = RHSConfig(elements=8), ScanConfig(grid_deg=30.0)
        path = L.cache_path(L.library_fields(cfg, scan))
        path.write_bytes({content!r})
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            lib = L.get_library(cfg, scan, workers=1, progress=False)
            again = L.get_library(cfg, scan, workers=1, progress=False)
        print(sum(issubclass(w.category, L.LibraryRebuildWarning) for w in caught), lib.path == path,
              L.load(path).tx.shape, str(path) in str(caught[0].message))
        """, tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.split() == ["1", "True", "(3,", "8)", "True"], res.stdout


# ---- rhs-slam patterns --load ----------------------------------------------------------------------------------

@pytest.mark.parametrize("fault", ["truncated", "random", "missing", "directory"])
def test_patterns_load_of_a_bad_file_is_one_clean_line(tmp_path: Path, fault: str) -> None:
    path = tmp_path / "lib.npz"
    if fault == "directory":
        path.mkdir()
    elif fault != "missing":
        shutil.copy(L.DATA_DIR / "rhs_m60_grid5deg_fast.npz", path)
        (_truncate if fault == "truncated" else _random)(path)
    res = _run(f"from rhs_slam.cli import main; raise SystemExit(main(['patterns', '--load', {str(path)!r}]))",
               tmp_path, timeout=120)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr[-2000:]
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and str(path) in lines[0] and "rhs-slam patterns --out" in lines[0], lines


# ---- CNN registration weights ----------------------------------------------------------------------------------

def _weights_copy(tmp_path: Path) -> Path:
    out = tmp_path / "w" / "registration_cnn.pt"
    out.parent.mkdir()
    shutil.copy(C.DEFAULT_WEIGHTS, out)
    shutil.copy(C.weights_record(C.DEFAULT_WEIGHTS), C.weights_record(out))
    return out


def _other_grid(path: Path) -> None:
    """Weights whose tensors are the shipped ones but whose meta claims a 32-cell grid map."""
    import torch

    blob = torch.load(path, weights_only=True)
    blob["meta"]["grid"] = {"cells": 32, "cell_m": 1.5}
    torch.save(blob, path)
    C.weights_record(path).unlink()


WEIGHT_FAULTS = [
    ("truncated, shipped", "shipped", lambda p: _truncate(p), "sha256 differs"),
    ("random, shipped", "shipped", lambda p: _random(p), "sha256 differs"),
    ("record deleted, shipped", "shipped", lambda p: C.weights_record(p).unlink(), "record"),
    ("truncated, no record", "user", lambda p: (_truncate(p), C.weights_record(p).unlink()), "not a readable"),
    ("random, no record", "user", lambda p: (_random(p), C.weights_record(p).unlink()), "not a readable"),
    ("meta of another grid", "user", _other_grid, "do not fit the network of its grid"),
    ("a pickle that runs code", "user", lambda p: (p.write_bytes(
        b"cos\nsystem\n(S'echo PWNED'\ntR."), C.weights_record(p).unlink()), "not a readable"),
]


@pytest.mark.parametrize(("which", "fault", "fragment"), [(w, f, m) for _, w, f, m in WEIGHT_FAULTS],
                         ids=[n for n, *_ in WEIGHT_FAULTS])
def test_bad_cnn_weights_are_refused_naming_the_file_and_how_to_regenerate(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str], which: str, fault,
        fragment: str) -> None:
    """(In this process: reading weights neither hangs nor crashes, and ``weights_only`` runs no code.)"""
    path = _weights_copy(tmp_path)
    fault(path)
    if which == "shipped":
        monkeypatch.setattr(C, "DEFAULT_WEIGHTS", path)
    with pytest.raises(ValueError) as exc:
        C.CNNRegistration() if which == "shipped" else C.CNNRegistration(path)
    message = str(exc.value)
    assert str(path) in message and fragment in message and "scripts/train_registration.py" in message, message
    assert "PWNED" not in capfd.readouterr().out


def test_missing_weights_name_the_training_script(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nowhere.pt.*scripts/train_registration.py"):
        C.CNNRegistration(tmp_path / "nowhere.pt")


def test_shipped_weights_match_their_record_and_load_as_before() -> None:
    import torch

    record = json.loads(C.weights_record(C.DEFAULT_WEIGHTS).read_text())
    assert record["sha256"] == file_sha256(C.DEFAULT_WEIGHTS)
    reg = C.CNNRegistration()
    blob = torch.load(C.DEFAULT_WEIGHTS, weights_only=True)
    for k, v in reg.net.state_dict().items():
        assert torch.equal(v, blob["state_dict"][k].float()), k


def test_trained_weights_get_a_record_and_self_consistent_other_grid_is_refused(tmp_path: Path) -> None:
    """train_cnn writes the record beside the file; weights trained for a 32-cell map are refused for the 64-cell
    map the SLAM uses, accepted for their own."""
    grid = C.GridMapConfig(cells=32, cell_m=1.0)
    x = np.random.default_rng(0).random((8, 2, 32, 32)).astype(np.float32)
    y = np.random.default_rng(1).normal(size=(8, 3))
    out = tmp_path / "w32.pt"
    C.train_cnn(x, y, grid, C.CNNTrainConfig(epochs=1, batch_size=8), out=out, progress=False)
    assert json.loads(C.weights_record(out).read_text())["grid"] == {"cells": 32, "cell_m": 1.0}
    assert C.CNNRegistration(out).grid == grid
    with pytest.raises(ValueError, match="trained for grid"):
        C.CNNRegistration(out, grid=C.GridMapConfig())
    out.write_bytes(out.read_bytes() + b"x")  # edited after training: the record says so
    with pytest.raises(ValueError, match="sha256 differs"):
        C.CNNRegistration(out)


# ---- numba's kernel cache --------------------------------------------------------------------------------------

KERNEL = """
    import numpy as np
    from rhs_common import jit
    v = np.array([3.0, 1.0, 2.0])
    jit.sort_small(v)
    print(v.tolist())
"""


def _index_and_data(numba_dir: Path) -> tuple[Path, Path]:
    index = next(numba_dir.rglob("jit._sort_small-*.nbi"))
    return index, next(index.parent.glob(index.name[: -len(".nbi")] + ".*.nbc"))


NUMBA_FAULTS = ["truncated index", "random index", "truncated data", "random data", "empty data"]


@pytest.fixture(scope="module")
def warm_numba(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A numba cache holding the compiled kernel (made once, copied by each fault)."""
    tmp = tmp_path_factory.mktemp("warm")
    first = _run(KERNEL, tmp)
    assert first.returncode == 0 and first.stdout.strip() == "[1.0, 2.0, 3.0]", first.stderr[-2000:]
    return tmp / "numba"


@pytest.mark.parametrize("fault", NUMBA_FAULTS)
def test_bad_numba_cache_file_is_recompiled_with_one_warning(tmp_path: Path, warm_numba: Path, fault: str) -> None:
    shutil.copytree(warm_numba, tmp_path / "numba")
    index, data = _index_and_data(tmp_path / "numba")
    target = index if "index" in fault else data
    if fault.startswith("truncated"):
        _truncate(target)
    elif fault.startswith("random"):
        _random(target)
    else:
        target.write_bytes(b"")
    second = _run(KERNEL, tmp_path)
    assert second.returncode == 0 and second.stdout.strip() == "[1.0, 2.0, 3.0]", second.stderr[-2000:]
    assert second.stderr.count("KernelCacheWarning") == 1 and "compiling again" in second.stderr, second.stderr
    assert str(index.parent) in second.stderr and "Traceback" not in second.stderr
    third = _run(KERNEL, tmp_path)  # the entry written again is good: silent
    assert third.returncode == 0 and "KernelCacheWarning" not in third.stderr, third.stderr


# ---- rhs-slam patterns: odd options --------------------------------------------------------------------------

PATTERN_OPTIONS = [
    ("same feed on both ends", ["--tx-feed", "0", "--rx-feed", "0"], "tx_feed and rx_feed must be different"),
    ("same feed, negative index", ["--elements", "8", "--tx-feed", "7", "--rx-feed", "-1"],
     "tx_feed and rx_feed must be different"),
    ("SDR on 4096 elements", ["--elements", "4096", "--method", "sdr"], "TiB"),
    ("2 elements", ["--elements", "2", "--grid-deg", "10"], "elements in [5, 4096]"),
    ("4 elements on a grid centred at 0", ["--elements", "4", "--grid-deg", "10"], "elements in [5, 4096]"),
]


@pytest.mark.parametrize(("argv", "fragment"), [(a, f) for _, a, f in PATTERN_OPTIONS],
                         ids=[n for n, *_ in PATTERN_OPTIONS])
def test_patterns_refuses_an_unbuildable_radar_up_front(tmp_path: Path, argv: list[str], fragment: str) -> None:
    t0 = time.monotonic()
    res = _run(f"from rhs_slam.cli import main; raise SystemExit(main(['patterns', '--quiet', *{argv!r}]))",
               tmp_path, timeout=120)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr[-2000:]
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and fragment in lines[0], lines
    assert time.monotonic() - t0 < 60  # refused before any grid is built
    assert not list((tmp_path / "cache").rglob("*.npz"))


def test_sdr_memory_estimate_names_the_limit() -> None:
    from rhs_env.patterns import sdr

    small = sdr.estimate_memory_bytes(RHSConfig(elements=24), ScanConfig(grid_deg=10.0))
    assert 100 * 2**20 < small < 200 * 2**20  # measured: ~94 MiB for one M = 24 grid
    big = sdr.estimate_memory_bytes(RHSConfig(elements=4096), ScanConfig(grid_deg=1.0))
    assert big > 2**40  # the lifted problem of 4096 elements: terabytes
    with pytest.raises(ValueError, match=r"method sdr with elements=4096.*limit of .*of this machine's"):
        sdr.check_memory(RHSConfig(elements=4096), ScanConfig(grid_deg=1.0))
    sdr.check_memory(RHSConfig(elements=24), ScanConfig(grid_deg=10.0))


def test_patterns_builds_the_smallest_radar_with_sidelobes(tmp_path: Path) -> None:
    """5 elements on 10-degree grids (the smallest count the message offers) builds."""
    res = _run("from rhs_slam.cli import main; raise SystemExit(main(['patterns', '--quiet', '--elements', '5', "
               "'--grid-deg', '10', '--workers', '1']))", tmp_path, timeout=200)
    assert res.returncode == 0 and "9 grids" in res.stdout, res.stderr[-2000:]


@pytest.mark.parametrize("target", ["parent", "group"], ids=["kill -INT", "Ctrl-C in a terminal"])
def test_patterns_build_stops_on_the_first_sigint(tmp_path: Path, target: str) -> None:
    """A 0.25-degree build (minutes) exits on one SIGINT -- to the command alone or, as a terminal's Ctrl-C, to its
    workers too -- with one line, workers stopped, no file written."""
    out = tmp_path / "lib.npz"
    env = {**os.environ, "RHS_SLAM_CACHE": str(tmp_path / "cache"), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-c", "from rhs_slam.cli import main; raise SystemExit(main())", "patterns", "--grid-deg",
         "0.25", "--no-cache", "--workers", "2", "--quiet", "--out", str(out)],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # (a background job ignores SIGINT)
    try:
        time.sleep(10.0)  # imports, then the worker pool runs its first grids
        assert proc.poll() is None, proc.communicate()
        if target == "parent":
            proc.send_signal(signal.SIGINT)  # to the parent only, as `kill -INT` does
        else:
            os.killpg(proc.pid, signal.SIGINT)  # to the whole process group, as a terminal does
        t0 = time.monotonic()
        _, err = proc.communicate(timeout=30)
        waited = time.monotonic() - t0
    finally:  # the workers too: they hold the pipes open
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
    assert proc.returncode == 128 + signal.SIGINT and waited < 20, (proc.returncode, waited, err[-2000:])
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "interrupted" in lines[0] and "nothing was written" in lines[0], lines
    assert not out.exists() and not list(tmp_path.glob(".lib.npz*"))


# ---- the rule behind the table: any damage to a library file is refused or harmless ---------------------------

def _damage(original: bytes, cut: int | None, flips: list[tuple[int, int]]) -> bytes:
    data = bytearray(original if cut is None else original[: cut % max(1, len(original))])
    for pos, value in flips:
        if data:
            data[pos % len(data)] ^= value
    return bytes(data)


def test_any_damage_to_a_library_file_is_refused_naming_it_or_leaves_its_arrays(tmp_path: Path) -> None:
    """Truncated at any byte or with bytes flipped anywhere, a library either loads to its own arrays (a flip in a
    byte nothing reads) or is a ValueError naming the file; a shipped copy is refused by its sha256 either way."""
    source = L.DATA_DIR / "rhs_m60_grid5deg_fast.npz"
    original = source.read_bytes()
    fields = L.library_fields(RHSConfig(), ScanConfig(grid_deg=5.0))
    good = L.load(source, fields)
    data = _data_copy(tmp_path)
    target = data / source.name

    @given(cut=st.none() | st.integers(0, len(original) - 1),
           flips=st.lists(st.tuples(st.integers(0, len(original) - 1), st.integers(1, 255)), max_size=3))
    def check(cut: int | None, flips: list[tuple[int, int]]) -> None:
        damaged = _damage(original, cut, flips)
        if damaged == original:
            return
        target.write_bytes(damaged)
        try:
            lib = L.load(target, fields)
        except ValueError as exc:
            assert str(target) in str(exc)
        else:
            np.testing.assert_array_equal(lib.tx, good.tx)
            np.testing.assert_array_equal(lib.rx, good.rx)
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(L, "DATA_DIR", data)
            with pytest.raises(ValueError, match="shipped pattern library .* is damaged"):
                L.find_shipped(fields)

    check()
