"""Ray RLlib backend: ``rhs-slam train --backend rllib`` end to end (one PPO iteration on a
small SLAM env with one Ray env runner, so the env is rebuilt in a Ray worker from its gym id and
kwargs), then ``rhs-slam evaluate`` on its checkpoint.

Skipped where Ray RLlib is not installed (the base install). CI runs it in a second venv:

    python -m venv .venv-rllib && . .venv-rllib/bin/activate
    pip install torch==2.13.0 && pip install -e ".[rllib,test]"
    OMP_NUM_THREADS=1 python -m pytest -q tests/test_rllib.py
"""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from conftest import small_env_kwargs, tiny_hyperparams

pytest.importorskip("ray.rllib", reason="Ray RLlib is an optional extra: pip install -e '.[rllib]'")
torch = pytest.importorskip("torch")

import rhs_env  # noqa: E402, F401  (registers the ids)
from agents.evaluate import evaluate, load_policy, resolve_env  # noqa: E402
from agents.rllib import CHECKPOINT_DIR, RLlibPolicy, is_rllib_checkpoint  # noqa: E402
from rhs_slam.cli import main as cli_main  # noqa: E402

SLAM = "rhs-highway-slam-v0"
SMALL = small_env_kwargs(vehicles_count=5, lanes_count=3, duration=4)
TINY = tiny_hyperparams(SLAM, n_envs=1, n_timesteps=64, n_steps=64, batch_size=32, n_epochs=2, learning_rate=3.0e-4,
                        gamma=0.9)


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("rllib")
    (out / "ppo.yml").write_text(TINY)
    rc = cli_main([
        "train", "--backend", "rllib", "--env", SLAM, "--hyperparams", str(out / "ppo.yml"),
        "--env-kwargs", json.dumps(SMALL), "--out", str(out / "run"), "--num-env-runners", "1",
        "--timesteps", "64", "--eval-freq", "0", "--checkpoint-freq", "64", "--no-progress",
    ])  # fmt: skip
    assert rc == 0
    return {"dir": out / "run", "ckpt": out / "run" / CHECKPOINT_DIR}


def test_training_writes_checkpoint_metadata_and_logs(trained):
    d = trained["dir"]
    meta = json.loads((d / f"{CHECKPOINT_DIR}.json").read_text())
    assert meta == json.loads((d / "train.json").read_text())
    assert meta["backend"] == "rllib" and meta["env_id"] == SLAM and meta["env_kwargs"] == SMALL
    assert meta["timesteps"] >= 64 and meta["num_env_runners"] == 1
    it = meta["iterations"]
    assert len(it) == 1 and it[0]["env_steps"] == meta["timesteps"]
    # 64 steps of 20-step episodes: at least two finished, each with a finite return of at most 20 x max reward 1
    assert it[0]["episode_return_mean"] is not None and 0.0 <= it[0]["episode_return_mean"] <= 20.0
    assert it[0]["crash_rate"] is not None and 0.0 <= it[0]["crash_rate"] <= 1.0
    s = meta["rllib_settings"]
    assert (s["train_batch_size_per_learner"], s["minibatch_size"], s["num_epochs"], s["gamma"]) == (64, 32, 2, 0.9)
    assert is_rllib_checkpoint(trained["ckpt"])
    assert any((d / "checkpoints").glob("step_*")) and any((d / "tb").iterdir())


def test_checkpoint_policy_acts_on_dict_observations(trained):
    env = gym.make(SLAM, **SMALL)
    policy = load_policy(trained["ckpt"], env)
    assert isinstance(policy, RLlibPolicy)
    obs, _ = env.reset(seed=3)
    a, _ = policy.predict(obs, deterministic=True)
    assert env.action_space.contains(a)
    # greedy = arg-max of the module's logits; the point-set encoder ignores padded points
    batch = {k: torch.as_tensor(np.asarray(v))[None] for k, v in obs.items()}
    logits = policy.module.forward_inference({"obs": batch})["action_dist_inputs"][0]
    assert a == int(torch.argmax(logits))
    noisy = dict(obs)
    noisy["points"] = np.where(obs["points_mask"][:, None] > 0, obs["points"], 1e3).astype(np.float32)
    assert policy.predict(noisy)[0] == a
    # a wrong observation layout is refused
    with pytest.raises(ValueError, match="trained on observations"):
        load_policy(trained["ckpt"], gym.make(SLAM, **{**SMALL, "max_points": 32}))
    env.close()


def test_evaluate_accepts_the_checkpoint(trained, tmp_path):
    assert resolve_env(trained["ckpt"]) == (SLAM, SMALL)
    out = tmp_path / "eval.json"
    rc = cli_main(["evaluate", "--policy", str(trained["ckpt"]), "--episodes", "2", "--seed", "5",
                   "--out", str(out), "--no-progress"])  # fmt: skip
    assert rc == 0
    s = json.loads(out.read_text())
    assert s["env_id"] == SLAM and s["episodes"] == 2 and s["seeds"] == [5, 6]
    assert all(r["steps"] >= 1 and np.isfinite(r["return"]) for r in s["runs"])
    again = evaluate(trained["ckpt"], episodes=1, seed=5, progress=False)
    assert again["runs"][0]["return"] == s["runs"][0]["return"]


def test_rllib_flags_are_checked(tmp_path):
    base = ["train", "--backend", "rllib", "--out", str(tmp_path / "x"), "--timesteps", "8"]
    assert cli_main([*base, "--algo", "dqn"]) == 2
    assert cli_main([*base, "--n-envs", "2"]) == 2
    assert cli_main([*base, "--num-env-runners", "-1"]) == 2
    assert cli_main(["train", "--out", str(tmp_path / "y"), "--num-env-runners", "2"]) == 2
