"""Interruptible training: stop cleanly on SIGTERM / SIGINT, resume from the last good checkpoint.

``rhs-slam train`` (:mod:`agents.algos.train`) uses these pieces:

* :class:`InterruptGuard`, the SIGTERM / SIGINT handlers of a whole run: the first signal only raises a flag
  (and says so on stderr); a second one exits at once (128 + the signal number) without writing anything, so
  the checkpoints already on disk stay as they are. The env workers ignore SIGINT
  (:func:`agents.algos.vec_env.make_vec_env`), so a Ctrl-C in a terminal, which signals the whole process group,
  reaches only this handler.
* :class:`StopOnSignal`, a stable-baselines3 callback that reads the flag: training stops at the start of
  the next rollout (PPO: after the current rollout and its gradient update; DQN: after the current
  ``train_freq`` steps), so a stop costs at most one rollout of latency and the saved model is exactly the
  model after ``k`` whole rollouts. The one env step taken by SB3 before the callback can stop it is not
  counted (its data is discarded).
* :func:`save_checkpoint` writes ``DIR/checkpoints/<algo>_<steps>_steps.zip`` (the name stable-baselines3's
  ``CheckpointCallback`` uses, plus the DQN replay buffer) atomically, with the run's record inside
  (:mod:`agents.policies.policy_record`): an interrupt or a crash mid-write leaves the previous checkpoints whole.
* :func:`usable_checkpoint` / :func:`load_latest`: the checkpoint with the most steps that is a whole zip
  and loads, with a warning naming each damaged one passed over.

Resumed with ``learn(total - done, reset_num_timesteps=False)``, a run interrupted at a
rollout boundary ends at the same step count as an uninterrupted one (SB3 rounds up
to whole rollouts in both cases), with the same learning-rate schedule progress.
"""

from __future__ import annotations

import io
import os
import re
import signal
import sys
import threading
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

__all__ = [
    "CHECKPOINT_DIR", "InterruptGuard", "StopOnSignal", "checkpoint_problem", "checkpoints", "latest_checkpoint",
    "load_checkpoint", "load_latest", "save_checkpoint", "usable_checkpoint", "usable_checkpoints",
]

CHECKPOINT_DIR = "checkpoints"
_STEPS = re.compile(r"^(?P<algo>[a-z0-9]+)_(?P<steps>\d+)_steps\.zip$")


def checkpoints(out: str | Path, algo: str) -> list[tuple[Path, int]]:
    """``(path, steps)`` of every ``out/checkpoints/<algo>_<steps>_steps.zip``, the most steps first."""
    folder = Path(out) / CHECKPOINT_DIR
    found = []
    for p in folder.glob(f"{algo}_*_steps.zip") if folder.is_dir() else ():
        m = _STEPS.match(p.name)
        if m and m["algo"] == algo:
            found.append((p, int(m["steps"])))
    return sorted(found, key=lambda item: -item[1])


def latest_checkpoint(out: str | Path, algo: str) -> tuple[Path, int] | None:
    """``(path, steps)`` of ``out/checkpoints/<algo>_<steps>_steps.zip`` with the most steps, or None."""
    found = checkpoints(out, algo)
    return found[0] if found else None


def checkpoint_problem(path: str | Path) -> str | None:
    """What is wrong with the checkpoint zip ``path`` (a truncated or overwritten file), or None when it is whole:
    every member's CRC checked, and stable-baselines3's ``data`` and ``policy.pth`` there."""
    try:
        with zipfile.ZipFile(path) as z:
            bad = z.testzip()
            names = set(z.namelist())
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as exc:
        return f"not a readable zip: {exc}"
    if bad is not None:
        return f"its member {bad} is corrupt"
    missing = sorted({"data", "policy.pth"} - names)
    return f"not a stable-baselines3 model (no {', '.join(missing)})" if missing else None


def _warn(message: str) -> None:
    print(f"rhs-slam train: warning: {message}", file=sys.stderr)


def usable_checkpoints(out: str | Path, algo: str,
                       warn: Callable[[str], None] = _warn) -> Iterator[tuple[Path, int]]:
    """The whole checkpoints of ``out``, the most steps first; ``warn`` names each damaged one passed over."""
    for path, steps in checkpoints(out, algo):
        problem = checkpoint_problem(path)
        if problem is None:
            yield path, steps
        else:
            warn(f"checkpoint {path} is damaged ({problem}); falling back to the previous checkpoint")


def usable_checkpoint(out: str | Path, algo: str, warn: Callable[[str], None] = _warn) -> tuple[Path, int] | None:
    """The whole checkpoint with the most steps (see :func:`usable_checkpoints`), or None."""
    return next(usable_checkpoints(out, algo, warn), None)


def save_checkpoint(model: Any, out: str | Path, algo: str, record: dict[str, Any] | None = None,
                    replay_buffer: bool = True) -> Path:
    """Save ``model`` (and, with ``replay_buffer``, a DQN's replay buffer) as
    ``out/checkpoints/<algo>_<steps>_steps.zip``, atomically, with ``record`` inside the zip when given."""
    from agents.policies.policy_record import save_model, write_bytes_atomic

    folder = Path(out) / CHECKPOINT_DIR
    folder.mkdir(parents=True, exist_ok=True)
    steps = int(model.num_timesteps)
    if replay_buffer and hasattr(model, "save_replay_buffer") and getattr(model, "replay_buffer", None) is not None:
        buf = io.BytesIO()
        model.save_replay_buffer(buf)  # first: a zip without its buffer is still a usable checkpoint
        write_bytes_atomic(folder / f"{algo}_replay_buffer_{steps}_steps.pkl", buf.getvalue())
    return save_model(model, folder / f"{algo}_{steps}_steps.zip", record)


def load_checkpoint(cls: Any, path: Path, env: Any, custom_objects: dict[str, Any] | None = None, **kwargs: Any):
    """``cls.load`` of a checkpoint onto ``env`` (CPU), with its DQN replay buffer when saved."""
    model = cls.load(path, env=env, device="cpu", custom_objects=custom_objects, **kwargs)
    m = _STEPS.match(path.name)
    if m and hasattr(model, "load_replay_buffer"):
        buf = path.parent / f"{m['algo']}_replay_buffer_{m['steps']}_steps.pkl"
        if buf.exists():
            model.load_replay_buffer(buf)
    return model


def load_latest(cls: Any, out: str | Path, algo: str, env: Any, warn: Callable[[str], None] = _warn,
                **kwargs: Any) -> tuple[Any, Path]:
    """The model of the newest checkpoint of ``out`` that is whole and loads (:func:`load_checkpoint`), and its path.

    Raises:
        ValueError: no checkpoint loads, naming the folder.
    """
    for path, _ in usable_checkpoints(out, algo, warn):
        try:
            return load_checkpoint(cls, path, env, **kwargs), path
        except (ValueError, KeyError, RuntimeError, EOFError, OSError, zipfile.BadZipFile) as exc:
            warn(f"checkpoint {path} does not load ({type(exc).__name__}: {exc}); falling back to the previous "
                 "checkpoint")
    raise ValueError(f"--resume: no checkpoint in {Path(out) / CHECKPOINT_DIR} loads; run without --resume to "
                     "start again (with --force to replace the run)")


class InterruptGuard:
    """SIGTERM / SIGINT handlers for a whole run (a context manager; see the module docstring).

    ``requested`` is the first signal's number (None: none yet). A second signal exits the process at once
    with 128 + its number. Outside the main thread it installs nothing (signals go to the main thread).

    Args:
        prog: the command named in the messages.
    """

    SIGNALS = (signal.SIGTERM, signal.SIGINT)

    def __init__(self, prog: str = "rhs-slam train") -> None:
        self.prog = prog
        self.requested: int | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> InterruptGuard:
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._previous.items():
            signal.signal(sig, old)
        self._previous.clear()

    def _say(self, text: str) -> None:
        # os.write, not print: the handler may interrupt a print to stderr (the progress bar's)
        os.write(2, f"\n{self.prog}: {text}\n".encode())

    def _handler(self, signum: int, frame: Any) -> None:
        name = signal.Signals(signum).name
        if self.requested is None:
            self.requested = signum
            self._say(f"{name}: stopping at the end of this rollout to save a checkpoint "
                      f"(send it again to exit at once, keeping the checkpoints saved so far)")
            return
        self._say(f"{name} again: exiting now; the checkpoints saved so far are kept")
        import multiprocessing

        for child in multiprocessing.active_children():  # the env workers: stopped quietly, not by a broken pipe
            child.kill()
        os._exit(128 + signum)


class StopOnSignal(BaseCallback):
    """Stops ``learn`` at the next rollout start once ``guard`` has a signal (see the module docstring).

    ``stopped`` tells the caller. Without a ``guard`` it installs an :class:`InterruptGuard` of its own for the
    duration of training (the previous handlers are restored when training ends).
    """

    SIGNALS = InterruptGuard.SIGNALS

    def __init__(self, guard: InterruptGuard | None = None) -> None:
        super().__init__()
        self.guard = guard
        self._own: InterruptGuard | None = None
        self.stopped = False
        self.checkpoint: Path | None = None  # where the caller saved the stopped model
        self._first_step = False

    @property
    def requested(self) -> int | None:
        """The signal that asked for the stop (None: none)."""
        guard = self.guard or self._own
        return guard.requested if guard is not None else None

    def _on_training_start(self) -> None:
        if self.guard is None:
            self._own = InterruptGuard().__enter__()

    def _on_rollout_start(self) -> None:
        self._first_step = True

    def _on_step(self) -> bool:
        first, self._first_step = self._first_step, False
        if self.requested is not None and first:
            # the step just taken belongs to a rollout that is discarded: do not count it
            self.model.num_timesteps -= self.training_env.num_envs
            self.stopped = True
            return False
        return True

    def _on_training_end(self) -> None:
        if self._own is not None:
            self._own.__exit__()
