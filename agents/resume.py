"""Interruptible training: stop cleanly on SIGTERM / SIGINT, resume from the last checkpoint.

``rhs-slam train`` (:mod:`agents.train`) uses three pieces:

* :class:`StopOnSignal`, a stable-baselines3 callback that installs SIGTERM and
  SIGINT handlers for the duration of ``learn``. A signal only raises a flag;
  training stops at the start of the next rollout (PPO: after the current
  rollout and its gradient update; DQN: after the current ``train_freq``
  steps), so a stop costs at most one rollout of latency and the saved model is
  exactly the model after ``k`` whole rollouts. The one env step taken by SB3
  before the callback can stop it is not counted (its data is discarded).
* :func:`save_checkpoint` writes ``DIR/checkpoints/<algo>_<steps>_steps.zip``
  (the name stable-baselines3's ``CheckpointCallback`` uses, plus the DQN replay buffer).
* :func:`latest_checkpoint` / :func:`load_checkpoint`: the checkpoint with the most
  steps, loaded onto a new vector env.

Resumed with ``learn(total - done, reset_num_timesteps=False)``, a run interrupted at a
rollout boundary ends at the same step count as an uninterrupted one (SB3 rounds up
to whole rollouts in both cases), with the same learning-rate schedule progress.
"""

from __future__ import annotations

import re
import signal
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

__all__ = ["CHECKPOINT_DIR", "StopOnSignal", "latest_checkpoint", "load_checkpoint", "save_checkpoint"]

CHECKPOINT_DIR = "checkpoints"
_STEPS = re.compile(r"^(?P<algo>[a-z0-9]+)_(?P<steps>\d+)_steps\.zip$")


def latest_checkpoint(out: str | Path, algo: str) -> tuple[Path, int] | None:
    """``(path, steps)`` of ``out/checkpoints/<algo>_<steps>_steps.zip`` with the most steps, or None."""
    folder = Path(out) / CHECKPOINT_DIR
    best: tuple[Path, int] | None = None
    for p in folder.glob(f"{algo}_*_steps.zip") if folder.is_dir() else ():
        m = _STEPS.match(p.name)
        if m and m["algo"] == algo and (best is None or int(m["steps"]) > best[1]):
            best = (p, int(m["steps"]))
    return best


def save_checkpoint(model: Any, out: str | Path, algo: str) -> Path:
    """Save ``model`` (and a DQN's replay buffer) as ``out/checkpoints/<algo>_<steps>_steps.zip``."""
    folder = Path(out) / CHECKPOINT_DIR
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{algo}_{int(model.num_timesteps)}_steps.zip"
    model.save(path)
    if hasattr(model, "save_replay_buffer") and getattr(model, "replay_buffer", None) is not None:
        model.save_replay_buffer(folder / f"{algo}_replay_buffer_{int(model.num_timesteps)}_steps.pkl")
    return path


def load_checkpoint(cls: Any, path: Path, env: Any, custom_objects: dict[str, Any] | None = None, **kwargs: Any):
    """``cls.load`` of a checkpoint onto ``env`` (CPU), with its DQN replay buffer when saved."""
    model = cls.load(path, env=env, device="cpu", custom_objects=custom_objects, **kwargs)
    m = _STEPS.match(path.name)
    if m and hasattr(model, "load_replay_buffer"):
        buf = path.parent / f"{m['algo']}_replay_buffer_{m['steps']}_steps.pkl"
        if buf.exists():
            model.load_replay_buffer(buf)
    return model


class StopOnSignal(BaseCallback):
    """Stops ``learn`` at the next rollout start after SIGTERM or SIGINT (see the module docstring).

    ``stopped`` tells the caller; the previous handlers are restored when training ends.
    """

    SIGNALS = (signal.SIGTERM, signal.SIGINT)

    def __init__(self) -> None:
        super().__init__()
        self.requested: int | None = None
        self.stopped = False
        self._first_step = False
        self._previous: dict[int, Any] = {}

    def _handler(self, signum, frame) -> None:
        self.requested = signum

    def _on_training_start(self) -> None:
        for sig in self.SIGNALS:
            try:
                self._previous[sig] = signal.signal(sig, self._handler)
            except ValueError:  # not the main thread: no handlers, training runs uninterruptible
                pass

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
        for sig, old in self._previous.items():
            signal.signal(sig, old)
        self._previous.clear()
