"""Start-up on a new install: the kernel-compile progress on a cold cache, silence on a warm one, and a second process
that finds every kernel the first one compiled in the cache (counted by rhs_common.jit.compile_stats)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

from rhs_common.jit import NOTICE

ROOT = Path(__file__).resolve().parent.parent

#: two small radar kernels and the shared sort (a few seconds of compile); progress shown from the first compile on
SMALL = """
    import json, sys
    import numpy as np
    import rhs_common.jit as jit
    jit.PROGRESS_AFTER_S = 0.0
    from rhs_env.kernels import tone_spectra
    tone_spectra(np.zeros(2), np.ones(2, complex), 8, 2, 4, np.array([0.2, 0.3]))
    v = np.array([3.0, 1.0, 2.0]); jit.sort_small(v)
    print(json.dumps(jit.compile_stats()))
"""

#: the first SLAM-env step of a process (the background compile on, as for a user)
ENV_STEP = """
    import json
    import gymnasium as gym
    import rhs_env
    from rhs_common.jit import compile_stats
    env = gym.make("rhs-highway-slam-v0"); env.reset(seed=0); env.step(1)
    print(json.dumps(compile_stats()))
"""


def _run(code: str, cache: Path, **env: str) -> tuple[dict, str]:
    res = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, capture_output=True, text=True,
                         env={**os.environ, "OMP_NUM_THREADS": "1", "NUMBA_CACHE_DIR": str(cache),
                              "RHS_SLAM_QUIET": "0", **env}, timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout.strip().splitlines()[-1]), res.stderr


def test_compile_progress_on_a_cold_cache_and_silence_on_a_warm_one(tmp_path):
    """Cold: the notice, a count of the kernels compiled so far and the summary at exit; warm: nothing compiles and
    nothing is printed; RHS_SLAM_QUIET=1 on another cold cache: the kernels compile, stderr stays empty."""
    stats, err = _run(SMALL, tmp_path / "a")
    assert {"rhs_env.kernels.tone_spectra", "rhs_common.jit._sort_small"} <= set(stats["kernels"])
    assert stats["seconds"] > 0
    assert err.count(NOTICE) == 1
    assert re.search(r"rhs-slam: \d+ kernels? compiled, \d+ s so far", err)
    assert f"rhs-slam: compiled {len(stats['kernels'])} kernels in " in err
    warm, err = _run(SMALL, tmp_path / "a")
    assert warm == {"kernels": [], "seconds": 0.0}
    assert "rhs-slam" not in err
    quiet, err = _run(SMALL, tmp_path / "b", RHS_SLAM_QUIET="1")
    assert quiet["kernels"] and "rhs-slam" not in err


def test_a_second_process_finds_every_kernel_of_the_first_step_cached(tmp_path):
    """A new user's first two runs: the first SLAM-env step on an empty cache compiles its kernels (with the progress
    on stderr), a second process started right after it (its background compile may still run) compiles none."""
    first, err = _run(ENV_STEP, tmp_path)
    assert len(first["kernels"]) >= 10 and err.count(NOTICE) == 1 and re.search(r"\d+ kernels? compiled, ", err)
    second, err = _run(ENV_STEP, tmp_path)
    assert second["kernels"] == [], second
    assert NOTICE not in err


def test_the_parent_says_when_it_exits_before_its_background_compile(capsys, monkeypatch):
    """slam.gym.precompile: at exit, one line while the background compile still runs; none once it ended, none with
    RHS_SLAM_QUIET=1."""
    from slam.gym.precompile import _tell_if_running

    monkeypatch.setenv("RHS_SLAM_QUIET", "0")
    running = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    done = subprocess.Popen([sys.executable, "-c", "pass"])
    done.wait()
    try:
        _tell_if_running(running)
        assert f"background kernel compile (pid {running.pid}) goes on" in capsys.readouterr().err
        _tell_if_running(done)
        assert capsys.readouterr().err == ""
        monkeypatch.setenv("RHS_SLAM_QUIET", "1")
        _tell_if_running(running)
        assert capsys.readouterr().err == ""
    finally:
        running.kill()
        running.wait()


#: a straight-road env on a cold cache: the first steps on highway-env's code while the traffic kernels compile in
#: the background (rhs_env.traffic.warm), then the core, loaded from the cache, with nothing compiled here
TRAFFIC = """
    import json, time
    import gymnasium as gym
    import rhs_env
    from rhs_common.jit import compile_stats
    env = gym.make("rhs-highway-v0"); env.reset(seed=0)
    t0 = time.perf_counter(); env.step(1); first = time.perf_counter() - t0
    sims = [env.unwrapped.traffic_sim]
    while sims[-1] != "compiled" and time.perf_counter() - t0 < 600:
        env.step(1); time.sleep(0.2); sims.append(env.unwrapped.traffic_sim)
    env.step(1)
    from rhs_env.traffic import warm
    started = [warm.background().wait(60)] if warm.background() else []
    print(json.dumps({"first_step_s": first, "sims": sims, "background_rc": started, **compile_stats()}))
"""


def test_traffic_kernels_compile_in_the_background_while_highway_env_steps(tmp_path):
    """sim="auto" on an empty cache: the first step does not wait for the traffic core's kernels (highway-env's
    code steps it until they are cached), one background process caches them, and the env then steps with the
    core, compiling nothing itself. On a fast machine the background compile can end during the reset (which
    compiles the radar's kernels in the foreground): then the first step already uses the core."""
    out, _ = _run(TRAFFIC, tmp_path)
    assert out["background_rc"] == [0], out
    assert set(out["sims"]) <= {"highway-env", "compiled"} and out["sims"][-1] == "compiled", out["sims"]
    assert out["sims"] == sorted(out["sims"], key=lambda s: s == "compiled"), out["sims"]  # never back
    assert not [k for k in out["kernels"] if k.startswith("rhs_env.traffic")], out["kernels"]
    assert out["first_step_s"] < 5.0, out
