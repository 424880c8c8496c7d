"""``rhs-slam train`` survives SIGTERM: it stops at a rollout boundary, saves a checkpoint,
and ``--resume`` finishes at the same step count as an uninterrupted run."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
N_STEPS = 16  # PPO rollout length (one env)
TOTAL = 72  # not a multiple of N_STEPS: SB3 rounds up to whole rollouts (80)
YAML = f"""
rhs-highway-v0:
  policy: MlpPolicy
  n_envs: 1
  n_timesteps: {TOTAL}
  n_steps: {N_STEPS}
  batch_size: 16
  n_epochs: 1
  learning_rate: lin_3.0e-4
  policy_kwargs:
    net_arch: [16]
"""
ENV_KWARGS = {"vehicles_count": 2, "lanes_count": 2, "duration": 2}


def _command(out: Path, hp: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "rhs_slam", "train", "--algo", "ppo", "--env", "rhs-highway-v0",
            "--out", str(out), "--hyperparams", str(hp), "--env-kwargs", json.dumps(ENV_KWARGS),
            "--eval-freq", "0", "--checkpoint-freq", str(N_STEPS), "--no-progress", *extra]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg",
            "SDL_VIDEODRIVER": "dummy"}


def test_sigterm_then_resume_reaches_the_uninterrupted_step_count(tmp_path):
    from agents.algos.resume import latest_checkpoint

    hp = tmp_path / "ppo.yml"
    hp.write_text(YAML)
    out = tmp_path / "run"
    proc = subprocess.Popen(_command(out, hp), cwd=ROOT, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        deadline = time.monotonic() + 240
        while latest_checkpoint(out, "ppo") is None:  # the first periodic checkpoint: training is under way
            assert proc.poll() is None, proc.communicate()[1][-2000:]
            assert time.monotonic() < deadline, "no checkpoint within 240 s"
            time.sleep(0.2)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, err[-2000:]
    assert "interrupted at" in err and "Traceback" not in err
    path, steps = latest_checkpoint(out, "ppo")
    assert steps % N_STEPS == 0 and 0 < steps < TOTAL  # a whole number of rollouts, before the end
    assert not (out / "model.zip").exists()

    done = subprocess.run(_command(out, hp, "--resume"), cwd=ROOT, env=_env(), capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"resuming from {path}" in done.stderr
    summary = json.loads((out / "train.json").read_text())
    assert summary["resumed_from_steps"] == steps
    assert summary["timesteps"] == math.ceil(TOTAL / N_STEPS) * N_STEPS  # what an uninterrupted run reaches
    assert (out / "model.zip").exists()


def test_latest_checkpoint_picks_the_most_steps(tmp_path):
    from agents.algos.resume import latest_checkpoint

    assert latest_checkpoint(tmp_path, "ppo") is None
    folder = tmp_path / "checkpoints"
    folder.mkdir()
    for name in ("ppo_32_steps.zip", "ppo_128_steps.zip", "ppo_64_steps.zip", "dqn_999_steps.zip", "ppo_x_steps.zip"):
        (folder / name).write_text("")
    assert latest_checkpoint(tmp_path, "ppo") == (folder / "ppo_128_steps.zip", 128)
    assert latest_checkpoint(tmp_path, "dqn") == (folder / "dqn_999_steps.zip", 999)


@pytest.mark.parametrize("out", ["/proc/rhs-slam-test/run", "FILE"])
def test_train_refuses_an_unwritable_out_before_any_work(tmp_path, capsys, out):
    from rhs_slam.cli import main

    if out == "FILE":
        out = str(tmp_path / "a_file")
        Path(out).write_text("")
    code = main(["train", "--env", "rhs-highway-v0", "--out", out, "--timesteps", "8"])
    err = capsys.readouterr().err
    assert code == 2 and "--out" in err and len(err.strip().splitlines()) == 1
