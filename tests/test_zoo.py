"""rl-baselines3-zoo trains every id with the shipped ``agents/hyperparams/ppo.yml`` as is.

Runs only where ``rl_zoo3`` is importable (it is not a dependency of the package; CI
runs this file in its own environment, see the README). The budget is tiny: 32 steps,
rollouts of 16 (``-params`` overrides the YAML's sizes, not its policy), 2-step episodes.
The command is the README's, with these additions.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

rl_zoo3 = pytest.importorskip("rl_zoo3")

ROOT = Path(__file__).resolve().parents[1]
IDS = ("rhs-highway-v0", "rhs-highway-radar-v0", "rhs-highway-slam-v0", "rhs-paper-v0")
RADAR_KWARGS = ["radar:dict(scan=dict(grid_deg=5.0),rhs=dict(elements=24),max_range_m=60.0)", "antenna:'hologram'",
                "max_points:32"]


def zoo_argv(env_id: str, log: Path) -> list[str]:
    env_kwargs = ["duration:0.4"] + ([] if env_id == "rhs-paper-v0" else ["vehicles_count:2"])
    if env_id != "rhs-highway-v0":
        env_kwargs += RADAR_KWARGS
    return ["rl_zoo3.train", "--algo", "ppo", "--env", env_id, "--gym-packages", "rhs_env",
            "-conf", str(ROOT / "agents" / "hyperparams" / "ppo.yml"), "-n", "32", "--eval-freq", "-1",
            "--log-folder", str(log), "--seed", "0", "-params", "n_steps:16", "batch_size:16", "n_epochs:1",
            "--env-kwargs", *env_kwargs]


@pytest.mark.parametrize("env_id", IDS)
def test_zoo_trains_with_the_shipped_yaml(env_id, tmp_path, monkeypatch):
    from rl_zoo3.train import train
    from stable_baselines3 import PPO

    from agents.policies.features import PointSetExtractor

    monkeypatch.setattr(sys, "argv", zoo_argv(env_id, tmp_path))
    train()
    [model_zip] = list((tmp_path / "ppo").glob(f"{env_id}_*/{env_id}.zip"))
    model = PPO.load(model_zip, device="cpu")
    assert model.num_timesteps == 32
    if env_id != "rhs-highway-v0":  # the point-cloud ids use the YAML's point-set extractor
        assert isinstance(model.policy.features_extractor, PointSetExtractor)
