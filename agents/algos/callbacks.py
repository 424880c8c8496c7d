"""Training callbacks for stable-baselines3 (imported by :func:`agents.algos.train.train` when it runs)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import torch
from stable_baselines3.common.callbacks import BaseCallback

__all__ = ["AtomicCheckpoint", "CrashRateCallback", "PhaseTimer", "TqdmCallback", "UpdateThreads", "best_eval_return"]


class TqdmCallback(BaseCallback):
    """Progress bar over environment steps (SB3's own needs the rich package)."""

    def __init__(self, total: int):
        super().__init__()
        self.total = total

    def _on_training_start(self) -> None:
        from tqdm.auto import tqdm

        self.bar = tqdm(total=self.total, desc="train", unit="step")

    def _on_step(self) -> bool:
        self.bar.update(self.training_env.num_envs)
        return True

    def _on_training_end(self) -> None:
        self.bar.close()


class CrashRateCallback(BaseCallback):
    """Logs ``rollout/crash_rate``: the fraction of the recent episodes (SB3's episode buffer) that crashed."""

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        flags = [float(e["crashed"]) for e in self.model.ep_info_buffer or () if "crashed" in e]
        if flags:
            self.logger.record("rollout/crash_rate", sum(flags) / len(flags))


class PhaseTimer(BaseCallback):
    """Wall-clock times of a run's phases: each rollout (env steps + policy) and each update after it.

    ``steady()`` gives the throughput once the run is going: env steps per second from the start of the
    second rollout to the end of training (the first rollout carries the one-off costs: the workers' first
    reset, their kernel-cache loads, torch's first passes), which is what hours of training run at.
    """

    def __init__(self) -> None:
        super().__init__()
        self.started = self.ended = float("nan")
        self.rollouts: list[tuple[float, int]] = []  # (perf_counter at rollout start, num_timesteps then)
        self.rollout_ends: list[float] = []
        self.final_timesteps = 0

    def _on_training_start(self) -> None:
        self.started = time.perf_counter()

    def _on_rollout_start(self) -> None:
        self.rollouts.append((time.perf_counter(), int(self.model.num_timesteps)))

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        self.rollout_ends.append(time.perf_counter())

    def _on_training_end(self) -> None:
        self.ended = time.perf_counter()
        self.final_timesteps = int(self.model.num_timesteps)

    def phases(self, decision_interval: int = 1) -> dict:
        """``first_rollout_s`` (first rollout and its update), ``steady_s`` / ``steady_timesteps`` /
        ``steady_steps_per_s`` (from the second rollout on; None with fewer than two rollouts), and the mean
        seconds per rollout's env stepping and per update in the steady part (env steps: decisions x
        ``decision_interval``)."""
        out: dict = {"rollouts": len(self.rollouts), "first_rollout_s": None, "steady_s": None,
                     "steady_timesteps": None, "steady_steps_per_s": None, "steady_collect_s_per_rollout": None,
                     "steady_update_s_per_rollout": None}
        if not self.rollouts:
            return out
        ends = [*self.rollouts[1:], (self.ended, self.final_timesteps)]
        out["first_rollout_s"] = round(ends[0][0] - self.rollouts[0][0], 3)
        if len(self.rollouts) < 2:
            return out
        (t1, n1), (t2, n2) = self.rollouts[1], (self.ended, self.final_timesteps)
        steps = (n2 - n1) * decision_interval
        out.update(steady_s=round(t2 - t1, 3), steady_timesteps=steps,
                   steady_steps_per_s=round(steps / max(t2 - t1, 1e-9), 2))
        steady = range(1, min(len(self.rollouts), len(self.rollout_ends)))
        if steady:
            collect = [self.rollout_ends[i] - self.rollouts[i][0] for i in steady]
            update = [ends[i][0] - self.rollout_ends[i] for i in steady]
            out["steady_collect_s_per_rollout"] = round(sum(collect) / len(collect), 3)
            out["steady_update_s_per_rollout"] = round(sum(update) / len(update), 3)
        return out


class UpdateThreads(BaseCallback):
    """torch's intra-op threads: ``collect`` while the env workers step, ``update`` during the gradient updates.

    On-policy training is synchronous: while the learner updates, the ``n_envs`` subprocess workers wait,
    so the update may use their cores; while they step, the learner keeps to ``collect`` threads (its
    policy forwards are small) and does not compete with them.
    """

    def __init__(self, collect: int, update: int) -> None:
        super().__init__()
        self.collect, self.update = int(collect), int(update)

    def _on_rollout_start(self) -> None:
        torch.set_num_threads(self.collect)

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        torch.set_num_threads(self.update)

    def _on_training_end(self) -> None:
        torch.set_num_threads(self.collect)


class AtomicCheckpoint(BaseCallback):
    """Every ``save_freq`` calls (decisions per env), ``out/checkpoints/<algo>_<steps>_steps.zip`` as
    stable-baselines3's ``CheckpointCallback`` names it, but written atomically with ``record`` inside
    (:func:`agents.algos.resume.save_checkpoint`; no replay buffer, as ``CheckpointCallback`` by default): a signal,
    a crash or a full disk mid-write leaves the earlier checkpoints whole."""

    def __init__(self, save_freq: int, out: str | Path, algo: str, record: dict[str, Any] | None = None) -> None:
        super().__init__()
        self.save_freq, self.out, self.algo, self.record = int(save_freq), Path(out), algo, record

    def _on_step(self) -> bool:
        from agents.algos.resume import save_checkpoint

        if self.n_calls % self.save_freq == 0:
            save_checkpoint(self.model, self.out, self.algo, self.record, replay_buffer=False)
        return True


def best_eval_return(folder: str | Path) -> float:
    """The best mean return of the evaluations logged in ``folder`` (``evaluations*.npz``; -inf: none), so a
    resumed run's ``EvalCallback`` replaces ``best_model.zip`` only with a better one."""
    import numpy as np

    best = -np.inf
    for path in sorted(Path(folder).glob("evaluations*.npz")):
        try:
            with np.load(path) as z:
                results = np.asarray(z["results"], dtype=float)
        except (OSError, ValueError, KeyError):
            continue
        if results.size:
            best = max(best, float(np.max(results.reshape(len(results), -1).mean(axis=1))))
    return float(best)
