"""The training campaign (rhs_studies.driving.campaign): chunks that accumulate and resume from their saved state,
the checkpoint chosen on validation seeds, the curves over seeds, the seeds in the ledger (tiny configs)."""

import json

import numpy as np
import pytest
import torch

from rhs_studies.driving import campaign
from rhs_studies.kit.seeds import overlap, seed_set

TINY = campaign.Recipe("tiny", env_kwargs={**campaign.CAMPAIGN_ENV_KWARGS, "duration": 3},
                       hyperparams={"n_steps": 8, "batch_size": 8, "n_epochs": 1})


def _weights(folder):
    from stable_baselines3 import PPO

    return torch.cat([p.detach().reshape(-1) for p in PPO.load(folder / "model.zip", device="cpu").policy.parameters()])


def test_recipe_checks_and_records():
    with pytest.raises(ValueError, match="recipe.n_envs"):
        campaign.Recipe("x", n_envs=0)
    with pytest.raises(ValueError, match="unknown"):
        campaign.Recipe("x", hyperparams={"n_step": 8})
    with pytest.raises(ValueError, match="recipe.name"):
        campaign.Recipe("a/b")
    assert json.loads(json.dumps(campaign.RECIPES["ppo_scratch"].record()))["env_id"] == "rhs-highway-slam-fast-v0"
    assert campaign.RECIPES["ppo_scratch"].ppo_args()["policy_kwargs"]["net_arch"] == [64, 64]


def test_seeds_come_from_the_ledger_and_runs_do_not_share_them():
    train = seed_set("campaign_training")
    firsts = [campaign.training_seed(k, c, 2) for k in range(3) for c in (0, 1, 499_999)]
    assert all(s in train and s + 1 in train for s in firsts)
    assert len(set(firsts)) == len(firsts)
    assert campaign.training_seed(1, 0, 2) > campaign.training_seed(0, 499_999, 2) + 1
    with pytest.raises(ValueError, match="training seeds"):
        campaign.training_seed(0, 500_000, 2)
    val = campaign.validation_seeds(5)
    assert [s.name for s in overlap(val)] == ["campaign_validation"]
    assert not overlap(firsts, allow=("campaign_training",))


def test_rng_state_round_trip():
    torch.manual_seed(3)
    np.random.seed(3)  # noqa: NPY002
    saved = json.loads(json.dumps(campaign._rng_state()))
    a = (torch.rand(3), np.random.rand(3))  # noqa: NPY002
    torch.manual_seed(99)
    np.random.seed(99)  # noqa: NPY002
    campaign._set_rng_state(saved)
    b = (torch.rand(3), np.random.rand(3))  # noqa: NPY002
    assert torch.equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_chunks_accumulate_resume_exactly_and_keep_the_best(tmp_path):
    s1 = campaign.train_chunk(TINY, tmp_path / "a", 0, 32, validation_episodes=1)
    assert s1["env_steps"] >= 32 and s1["chunks"] == 1 and not s1["interrupted"]
    torch.manual_seed(12345)  # a session in between: the next chunk restores the saved RNG states
    np.random.seed(6)  # noqa: NPY002
    s2 = campaign.train_chunk(TINY, tmp_path / "a", 0, 32, validation_episodes=1)
    assert s2["chunks"] == 2 and s2["env_steps"] > s1["env_steps"]
    assert [p["env_steps"] for p in s2["curve"]] == [s1["env_steps"], s2["env_steps"]]
    assert s2["train_wall_s"] > s1["train_wall_s"] > 0
    best = max(s2["curve"], key=lambda p: p["validation"]["return"])
    assert s2["best"]["env_steps"] == best["env_steps"]
    run = tmp_path / "a" / "tiny" / "seed0"
    record = json.loads((run / "best.json").read_text())
    assert record["env_id"] == "rhs-highway-slam-v0" and record["decision_interval"] == 5
    assert (run / "model.zip").stat().st_size < 1_000_000
    # the same two chunks in another folder, without the disturbance: the same weights
    campaign.train_chunk(TINY, tmp_path / "b", 0, 32, validation_episodes=1)
    campaign.train_chunk(TINY, tmp_path / "b", 0, 32, validation_episodes=1)
    assert torch.allclose(_weights(run), _weights(tmp_path / "b" / "tiny" / "seed0"), atol=1e-6)
    with pytest.raises(ValueError, match="not tiny seed 1"):
        (tmp_path / "a" / "tiny" / "seed1").mkdir()
        (tmp_path / "a" / "tiny" / "seed1" / "state.json").write_text((run / "state.json").read_text())
        campaign.train_chunk(TINY, tmp_path / "a", 1, 32, validation_episodes=1)


def test_selection_drives_the_candidates_and_goes_stale_with_training(tmp_path):
    from rhs_studies.driving.shield_table import arm_policy

    with pytest.raises(FileNotFoundError, match="train"):
        campaign.select_checkpoint(TINY, tmp_path, 0, episodes=2)
    for _ in range(2):
        campaign.train_chunk(TINY, tmp_path, 0, 32, validation_episodes=1)
    run = tmp_path / "tiny" / "seed0"
    assert campaign.chosen_policy(tmp_path, "tiny", 0) == run / "best.zip"  # never selected: the chunks' best
    sel = campaign.select_checkpoint(TINY, tmp_path, 0, episodes=2)
    state = campaign.load_state(run)
    assert sel["selected_at_env_steps"] == state["env_steps"] and sel["seeds"] == campaign.validation_seeds(2)
    assert sel["candidates"]["best"]["env_steps"] == state["best"]["env_steps"]
    assert set(sel["candidates"]) == ({"best"} if state["best"]["env_steps"] == state["env_steps"]
                                      else {"best", "final"})
    top = max(c["return"] for c in sel["candidates"].values())
    assert sel["candidates"][sel["chosen"]]["return"] == top
    src = run / ("best.zip" if sel["chosen"] == "best" else "model.zip")
    assert (run / "chosen.zip").read_bytes() == src.read_bytes()
    record = json.loads((run / "chosen.json").read_text())
    assert record["timesteps"] == sel["candidates"][sel["chosen"]]["env_steps"]
    assert record["model"] == "chosen.zip"  # beside its record, not an absolute path of the machine it ran on
    assert arm_policy("campaign:tiny:seed0", tmp_path) == str(run / "chosen.zip")
    from rhs_studies.driving.shield_table import arm_record

    rec = arm_record("campaign:tiny:seed0", tmp_path)
    assert rec["model"] == "chosen.zip" and rec["recipe"] == "tiny" and rec["seed"] == 0
    assert rec["timesteps"] == record["timesteps"] and rec["selection"]["chosen"] == sel["chosen"]
    campaign.train_chunk(TINY, tmp_path, 0, 32, validation_episodes=1)  # trained on: the selection is stale
    with pytest.raises(ValueError, match="select"):
        campaign.chosen_policy(tmp_path, "tiny", 0)


def test_a_signal_stops_the_chunk_with_whole_files(tmp_path):
    from agents.algos.resume import InterruptGuard

    guard = InterruptGuard("test")
    guard.requested = 2  # a SIGINT before the first rollout
    state = campaign.train_chunk(TINY, tmp_path, 0, 64, validation_episodes=1, guard=guard)
    assert state["interrupted"] and state["env_steps"] == 0  # nothing trained: nothing written
    assert campaign.load_state(tmp_path / "tiny" / "seed0") is None
    first = campaign.train_chunk(TINY, tmp_path, 0, 16, validation_episodes=1)
    again = campaign.train_chunk(TINY, tmp_path, 0, 64, validation_episodes=1, guard=guard)
    assert again["interrupted"] and again["env_steps"] == first["env_steps"]
    assert campaign.load_state(tmp_path / "tiny" / "seed0")["chunks"] == 1


def test_campaign_round_robin_deadline_and_curves(tmp_path):
    import time

    assert campaign.train_campaign(TINY, tmp_path, [0, 1], 32, 32, 1, deadline=time.time() - 1,
                                   log=lambda s: None) == {0: {"env_steps": 0}, 1: {"env_steps": 0}}
    states = campaign.train_campaign(TINY, tmp_path, [0, 1], 32, 32, 1, log=lambda s: None)
    assert all(s["env_steps"] >= 32 for s in states.values())
    c = campaign.curves(tmp_path, "tiny", [0, 1, 2], points=5)
    assert sorted(c["runs"]) == ["0", "1"] and c["by_env_steps"]["runs"] == 2
    spread = c["by_env_steps"]
    assert all(lo <= m <= hi for lo, m, hi in zip(spread["min"], spread["mean"], spread["max"]))
    assert c["by_wall_s"]["train_wall_s"]
    assert campaign._deadline(None) is None
    with pytest.raises(ValueError, match="--until"):
        campaign._deadline("6h")


def test_the_checkpoints_live_outside_the_packages():
    """The campaign's checkpoints are a study's state, committed in the repository but not package data: their
    folder is none of the packages pyproject.toml ships, so they stay out of the wheel."""
    from pathlib import Path

    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    root = Path(__file__).resolve().parent.parent
    include = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]["include"]
    top = campaign.CAMPAIGN_DIR.relative_to(root).parts[0]
    assert not any(top == pattern.rstrip("*") for pattern in include), (top, include)
    assert not (campaign.CAMPAIGN_DIR / "__init__.py").exists()


def test_the_exact_env_never_gets_the_fast_radar():
    """The imitation + RL recipe trains on the fast radar calibrated for its 5-degree grid
    (``radar_model="fast-calibrate"``); on the exact id that setting would select the fast radar, so the records
    and the evaluation's exact env drop it."""
    import gymnasium as gym

    import rhs_env  # noqa: F401
    from rhs_env.fast_radar import FastRadarSystem

    student = campaign.RECIPES["ppo_student"]
    assert student.env_kwargs["radar_model"] == "fast-calibrate" and "radar_model" not in student.eval_env_kwargs()
    assert student.eval_env_kwargs()["radar"] == {"scan": {"grid_deg": 5}}
    record = campaign._policy_record(student, 0, {"env_steps": 10, "train_wall_s": 1.0}, campaign.CAMPAIGN_DIR / "x")
    assert record["env_kwargs"] == student.eval_env_kwargs() and record["train_env_kwargs"]["radar_model"]
    def radar_of(env):
        while getattr(env, "radar", None) is None:
            env = env.env
        return env.radar

    env = gym.make(record["env_id"], **record["env_kwargs"])
    assert not isinstance(radar_of(env), FastRadarSystem)  # with the training kwargs it would be one
    env.close()


def test_a_shaped_recipe_prices_the_crash_in_training_only():
    with pytest.raises(ValueError, match="recipe.reward_shaping.crash_penalty"):
        campaign.Recipe("x", reward_shaping={"crash_penalty": -1.0})
    with pytest.raises(ValueError, match="recipe.reward_shaping has unknown"):
        campaign.Recipe("x", reward_shaping={"crash": 1.0})
    safe = campaign.RECIPES["ppo_student_safe"]
    assert json.loads(json.dumps(safe.record()))["reward_shaping"]["crash_penalty"] == 500.0
    shaped = campaign.Recipe("tiny_shaped", env_id="rhs-highway-v0", eval_env_id="rhs-highway-v0",
                             env_kwargs={"duration": 20}, decision_interval=1,
                             reward_shaping={"crash_penalty": 500.0, "weight": 0.0})
    venv = campaign.make_train_env(shaped)
    try:
        venv.seed(0)
        venv.reset()
        faster = np.full(venv.num_envs, 3)
        for _ in range(200):  # always FASTER on a 30-vehicle road: a crash within seconds
            _, rewards, dones, infos = venv.step(faster)
            crashed = [i for i, info in enumerate(infos) if dones[i] and info.get("crashed")]
            if crashed:
                break
        assert crashed, "always FASTER did not crash in 200 steps"
        k = crashed[0]
        # highway-env's normalised reward is in [0, 1]: the step's reward is it minus the penalty
        assert -500.0 <= rewards[k] <= -499.0 and infos[k]["shaping"] == -500.0
    finally:
        venv.close()
