"""Training callbacks for stable-baselines3 (imported by :func:`agents.train.train` when it runs)."""

from __future__ import annotations

from stable_baselines3.common.callbacks import BaseCallback


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
