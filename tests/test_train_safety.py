"""``rhs-slam train`` loses nothing to an interrupt and refuses what would go wrong silently.

* Ctrl-C in a terminal signals the whole process group: the subprocess workers ignore it, the run saves a
  checkpoint atomically, closes its envs and says how to resume (exit 130); a second Ctrl-C exits at once,
  leaving whole checkpoints; ``--resume`` then finishes, also after two interrupts.
* ``--resume`` writes new monitor / evaluation files beside the earlier ones and TensorBoard events into new
  files: nothing logged before changes.
* ``--resume`` passes over a damaged latest checkpoint (a warning names it), refuses other env kwargs or a
  smaller budget without ``--force``; ``--out`` onto a finished run is refused without ``--resume`` / ``--force``.
* a hyperparameter file with a duplicate key or a YAML alias bomb is refused.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from agents.algos.resume import checkpoint_problem, checkpoints, latest_checkpoint

ROOT = Path(__file__).resolve().parents[1]
ENV_KWARGS = {"vehicles_count": 2, "lanes_count": 2, "duration": 2}


def _yaml(n_envs: int, n_steps: int, total: int) -> str:
    return (f"rhs-highway-v0:\n  policy: MlpPolicy\n  n_envs: {n_envs}\n  n_timesteps: {total}\n"
            f"  n_steps: {n_steps}\n  batch_size: 16\n  n_epochs: 1\n  learning_rate: lin_3.0e-4\n"
            "  policy_kwargs:\n    net_arch: [16]\n")


def _args(out: Path, hp: Path, *extra: str, checkpoint_freq: int = 16, eval_freq: int = 0) -> list[str]:
    return ["train", "--algo", "ppo", "--env", "rhs-highway-v0", "--out", str(out), "--hyperparams", str(hp),
            "--env-kwargs", json.dumps(ENV_KWARGS), "--eval-freq", str(eval_freq), "--eval-episodes", "1",
            "--checkpoint-freq", str(checkpoint_freq), "--no-progress", *extra]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg",
            "SDL_VIDEODRIVER": "dummy"}


def _start(args: list[str]) -> subprocess.Popen:
    """``python -m rhs_slam ARGS`` in a session of its own: its process group is the run and its workers."""
    return subprocess.Popen([sys.executable, "-m", "rhs_slam", *args], cwd=ROOT, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


def _wait_for_checkpoint(proc: subprocess.Popen, out: Path, more_than: int = -1, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while (latest_checkpoint(out, "ppo") or (None, -1))[1] <= more_than:
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        assert time.monotonic() < deadline, f"no checkpoint within {timeout} s"
        time.sleep(0.1)


def _ctrl_c(proc: subprocess.Popen, times: int = 1, gap: float = 0.3) -> tuple[str, str]:
    """SIGINT to the whole process group (what a terminal's Ctrl-C does), ``times`` times."""
    try:
        for k in range(times):
            if k:
                time.sleep(gap)
            os.killpg(proc.pid, signal.SIGINT)
        return proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()


def _digests(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _assert_clean_interrupt(proc: subprocess.Popen, err: str) -> None:
    assert proc.returncode == 130, err[-3000:]
    assert "Traceback" not in err and "KeyboardInterrupt" not in err and "EOFError" not in err, err[-3000:]


def test_ctrl_c_to_the_process_group_twice_then_resume_loses_nothing(tmp_path):
    """Subprocess workers: Ctrl-C, resume, Ctrl-C, resume to the end; the earlier logs never change."""
    from stable_baselines3 import PPO

    from agents.policies.policy_record import embedded_record

    hp = tmp_path / "ppo.yml"
    hp.write_text(_yaml(n_envs=2, n_steps=16, total=100_000))
    out = tmp_path / "run"
    first = _start(_args(out, hp))
    _wait_for_checkpoint(first, out)
    _, err = _ctrl_c(first)
    _assert_clean_interrupt(first, err)
    assert "interrupted at" in err and "resume with: rhs-slam train" in err and "--resume" in err
    path, steps = latest_checkpoint(out, "ppo")
    assert checkpoint_problem(path) is None and steps % 32 == 0
    assert PPO.load(path, device="cpu").num_timesteps == steps
    assert embedded_record(path)["env_kwargs"] == ENV_KWARGS
    logs_before = _digests(out / "monitor")
    assert sorted(logs_before) == ["0.monitor.csv", "1.monitor.csv"]

    second = _start(_args(out, hp, "--resume"))
    _wait_for_checkpoint(second, out, more_than=steps)
    _, err = _ctrl_c(second)
    _assert_clean_interrupt(second, err)
    assert f"resuming from {path}" in err
    _, steps2 = latest_checkpoint(out, "ppo")
    assert steps2 > steps
    logs_mid = _digests(out / "monitor")
    assert {k: logs_mid[k] for k in logs_before} == logs_before  # the first part's episodes are still there
    assert {"0.resume1.monitor.csv", "1.resume1.monitor.csv"} <= set(logs_mid)
    tb_before = _digests(out / "tb")

    from rhs_slam.cli import main

    assert main(_args(out, hp, "--resume", "--timesteps", str(steps2 + 64))) == 0  # here: one interpreter less
    summary = json.loads((out / "train.json").read_text())
    assert summary["resumed_from_steps"] == steps2 and summary["timesteps"] >= steps2 + 64
    logs_after = _digests(out / "monitor")
    assert {k: logs_after[k] for k in logs_mid} == logs_mid
    assert {"0.resume2.monitor.csv", "1.resume2.monitor.csv"} <= set(logs_after)
    tb_after = _digests(out / "tb")
    assert {k: tb_after[k] for k in tb_before} == tb_before and len(tb_after) > len(tb_before)


def test_a_second_ctrl_c_exits_at_once_and_keeps_the_checkpoints(tmp_path):
    """Long rollouts (the first Ctrl-C waits for the rollout's end): the second one exits within a second."""
    hp = tmp_path / "ppo.yml"
    hp.write_text(_yaml(n_envs=2, n_steps=4096, total=100_000))
    out = tmp_path / "run"
    proc = _start(_args(out, hp, checkpoint_freq=32))
    _wait_for_checkpoint(proc, out)
    t0 = time.monotonic()
    _, err = _ctrl_c(proc, times=2)
    assert time.monotonic() - t0 < 20
    _assert_clean_interrupt(proc, err)
    assert "SIGINT again: exiting now" in err
    assert checkpoints(out, "ppo") and all(checkpoint_problem(p) is None for p, _ in checkpoints(out, "ppo"))

    from rhs_slam.cli import main

    steps = latest_checkpoint(out, "ppo")[1]
    resumed = _args(out, hp, "--resume", "--timesteps", str(steps), "--n-envs", "1")  # one env: no workers to start
    assert main(resumed) == 0  # nothing left to learn: the checkpoint becomes the model
    assert json.loads((out / "train.json").read_text())["timesteps"] == steps


def _finished_run(tmp_path: Path, eval_freq: int = 0) -> tuple[Path, Path]:
    """A finished 1-env run of 64 steps with checkpoints at 16, 32, 48 and 64 (in this process)."""
    from rhs_slam.cli import main

    hp = tmp_path / "ppo.yml"
    hp.write_text(_yaml(n_envs=1, n_steps=16, total=64))
    out = tmp_path / "run"
    assert main(_args(out, hp, eval_freq=eval_freq)) == 0
    assert [s for _, s in checkpoints(out, "ppo")] == [64, 48, 32, 16]
    return out, hp


def test_resume_falls_back_over_a_truncated_checkpoint_and_appends_the_logs(tmp_path, capsys):
    from rhs_slam.cli import main

    out, hp = _finished_run(tmp_path, eval_freq=16)
    bad = out / "checkpoints" / "ppo_64_steps.zip"
    bad.write_bytes(bad.read_bytes()[:1000])
    before = {k: v for k, v in _digests(out).items() if k.startswith(("monitor/", "eval/", "tb/"))}
    assert "eval/evaluations.npz" in before
    capsys.readouterr()
    assert main(_args(out, hp, "--resume", "--timesteps", "80", eval_freq=16)) == 0
    err = capsys.readouterr().err
    assert f"checkpoint {bad} is damaged" in err and "falling back" in err
    assert f"resuming from {out / 'checkpoints' / 'ppo_48_steps.zip'}" in err
    after = _digests(out)
    assert {k: after[k] for k in before} == before  # nothing logged before changed
    assert "monitor/0.resume1.monitor.csv" in after and "eval/evaluations.resume1.npz" in after
    assert json.loads((out / "train.json").read_text())["resumed_from_steps"] == 48


def test_resume_refuses_other_env_kwargs_or_a_smaller_budget_unless_forced(tmp_path, capsys):
    from rhs_slam.cli import main

    out, hp = _finished_run(tmp_path)
    capsys.readouterr()
    other = _args(out, hp, "--resume", "--timesteps", "80")
    other[other.index("--env-kwargs") + 1] = json.dumps({**ENV_KWARGS, "lanes_count": 3})
    assert main(other) == 2
    err = capsys.readouterr().err
    assert "env_kwargs" in err and "lanes_count" in err and "--force" in err and "Traceback" not in err
    assert main(_args(out, hp, "--resume", "--timesteps", "32")) == 2
    err = capsys.readouterr().err
    assert "64 env steps already" in err and "--timesteps 32" in err and "--force" in err
    assert main(_args(out, hp, "--resume", "--timesteps", "32", "--force")) == 0
    assert json.loads((out / "train.json").read_text())["timesteps"] == 64


def test_out_onto_a_finished_run_is_refused_without_resume_or_force(tmp_path, capsys):
    from rhs_slam.cli import main

    out, hp = _finished_run(tmp_path)
    model = (out / "model.zip").read_bytes()
    capsys.readouterr()
    assert main(_args(out, hp)) == 2
    err = capsys.readouterr().err
    assert "finished run" in err and "--resume" in err and "--force" in err and "another --out" in err
    assert (out / "model.zip").read_bytes() == model
    (out / "checkpoints" / "ppo_16_steps.zip").rename(out / "checkpoints" / "ppo_999_steps.zip")  # a stale one
    assert main(_args(out, hp, "--timesteps", "16", "--force")) == 0
    assert [s for _, s in checkpoints(out, "ppo")] == [16]  # the earlier run's files went first


def test_an_unknown_resume_or_force_flag_combination_is_refused(tmp_path, capsys):
    from rhs_slam.cli import main

    hp = tmp_path / "ppo.yml"
    hp.write_text(_yaml(n_envs=1, n_steps=16, total=64))
    assert main(_args(tmp_path / "run", hp, "--resume")) == 2
    assert "no checkpoint" in capsys.readouterr().err
    assert main(["train", "--algo", "dagger", "--env", "rhs-highway-v0", "--out", str(tmp_path / "d"), "--force"]) == 2
    assert "--force is for --algo ppo / dqn" in capsys.readouterr().err


@pytest.mark.parametrize("text, words", [
    ("rhs-highway-v0:\n  policy: MlpPolicy\n  n_steps: 16\n  n_steps: 32\n", "n_steps"),
    ("a: &a [x, x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
     "c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b, *b]\nd: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c, *c]\n"
     "e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d, *d]\nf: &f [*e, *e, *e, *e, *e, *e, *e, *e, *e, *e]\n"
     "rhs-highway-v0: {policy: MlpPolicy, x: [*f, *f, *f, *f, *f, *f, *f, *f, *f, *f]}\n", "alias"),
])
def test_train_refuses_a_duplicate_key_or_an_alias_bomb_in_the_hyperparameters(tmp_path, capsys, text, words):
    from rhs_slam.cli import main

    hp = tmp_path / "shared.yml"
    hp.write_text(text)
    t0 = time.monotonic()
    code = main(["train", "--env", "rhs-highway-v0", "--hyperparams", str(hp), "--out", str(tmp_path / "run"),
                 "--timesteps", "8", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "shared.yml" in err and "Traceback" not in err, err
    assert words in err.lower() or "duplicate" in err.lower(), err
    assert time.monotonic() - t0 < 10


def test_a_trained_zip_carries_its_record_so_a_copy_or_a_link_drives_the_same_env(tmp_path):
    import shutil

    from stable_baselines3 import PPO

    from agents.evaluate import load_policy, resolve_env
    from agents.policies.policy_record import RECORD_MEMBER, embedded_record

    out, _ = _finished_run(tmp_path)
    side = json.loads((out / "model.json").read_text())
    assert embedded_record(out / "model.zip") == side and side["env_kwargs"] == ENV_KWARGS
    assert embedded_record(out / "checkpoints" / "ppo_32_steps.zip")["env_kwargs"] == ENV_KWARGS
    assert PPO.load(out / "model.zip", device="cpu").num_timesteps == 64  # stable-baselines3 skips the member
    copy = tmp_path / "elsewhere" / "copied.zip"
    copy.parent.mkdir()
    shutil.copyfile(out / "model.zip", copy)  # the zip alone, no copied.json beside it
    link = tmp_path / "elsewhere" / "linked.zip"
    link.symlink_to(out / "model.zip")
    for path in (copy, link, out / "model.zip"):
        assert resolve_env(path) == ("rhs-highway-v0", ENV_KWARGS), path
    bare = tmp_path / "bare.zip"
    PPO.load(out / "model.zip", device="cpu").save(bare)
    with pytest.raises(ValueError, match=r"bare\.json is missing"):
        resolve_env(bare)
    import gymnasium as gym

    import rhs_env  # noqa: F401

    with pytest.raises(ValueError, match=r"bare\.json is missing"):
        load_policy(bare, gym.make("rhs-highway-v0", **ENV_KWARGS))
    assert RECORD_MEMBER.endswith(".json")


def test_demo_refuses_the_shipped_policy_without_its_record(tmp_path, capsys):
    """The shipped zips carry no record inside (they are left as shipped): without their JSON they are refused."""
    import shutil

    from agents.evaluate import SHIPPED_POLICY
    from agents.policies.policy_record import embedded_record
    from rhs_slam.cli import main

    assert embedded_record(SHIPPED_POLICY) is None and Path(SHIPPED_POLICY).with_suffix(".json").exists()
    lone = tmp_path / Path(SHIPPED_POLICY).name
    shutil.copyfile(SHIPPED_POLICY, lone)  # what deleting the shipped record leaves
    code = main(["demo", "--policy", str(lone), "--out", str(tmp_path / "demo")])
    err = capsys.readouterr().err
    assert code == 2 and f"{lone.with_suffix('.json')} is missing" in err and "Traceback" not in err, err
    assert not (tmp_path / "demo" / "demo.json").exists()
