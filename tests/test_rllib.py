"""Ray RLlib backend: ``rhs-slam train --backend rllib`` end to end (one PPO iteration on a
small SLAM env with one Ray env runner, so the env is rebuilt in a Ray worker from its gym id and
kwargs), then ``rhs-slam evaluate`` on its checkpoint; the fine-tuning stage on RLlib (the env
creator's decision interval and privileged key, the asymmetric RLModule, the SB3 student's actor
in and out of it, the decaying anchor in the learner's loss, ``--algo finetune`` end to end).

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
from conftest import privileged_space, reward_two_env, small_env_kwargs, tiny_hyperparams

pytest.importorskip("ray.rllib", reason="Ray RLlib is an optional extra: pip install -e '.[rllib]'")
torch = pytest.importorskip("torch")

import rhs_env  # noqa: E402, F401  (registers the ids)
from agents.algos.rllib import (  # noqa: E402
    CHECKPOINT_DIR,
    PointSetPPOModule,
    RLlibPolicy,
    env_config,
    export_module_actor,
    init_ray,
    is_rllib_checkpoint,
    make_env,
    student_actor_state,
)
from agents.evaluate import evaluate, load_policy, resolve_env  # noqa: E402
from agents.policies.decision import IDLE, HeldPolicy, HoldAction  # noqa: E402
from agents.policies.privileged import PRIVILEGED_DIM, PRIVILEGED_KEY, without_privileged  # noqa: E402
from rhs_slam.cli import main as cli_main  # noqa: E402

SLAM = "rhs-highway-slam-v0"
SMALL = small_env_kwargs(vehicles_count=5, lanes_count=3, duration=4)
TINY = tiny_hyperparams(SLAM, n_envs=1, n_timesteps=64, n_steps=64, batch_size=32, n_epochs=2, learning_rate=3.0e-4,
                        gamma=0.9)


@pytest.fixture(scope="module", autouse=True)
def ray_instance():
    """One local Ray instance for the whole file (the CLI runs join it instead of starting their own)."""
    import ray

    started = init_ray(None, 1)
    yield
    if started:
        ray.shutdown()


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
    assert cli_main([*base, "--algo", "ppo", "--init-policy", str(tmp_path / "student.zip")]) == 2
    assert cli_main([*base, "--algo", "finetune", "--init-policy", str(tmp_path / "missing.zip")]) == 2
    assert cli_main([*base, "--n-envs", "2"]) == 2
    assert cli_main([*base, "--num-env-runners", "-1"]) == 2
    assert cli_main(["train", "--out", str(tmp_path / "y"), "--num-env-runners", "2"]) == 2


# ---------------------------------------------------------------- the fine-tuning stage on RLlib

SPACE = privileged_space()
MODEL = {"net_arch": [8], "features_extractor_kwargs": {"point_dim": 8, "box_dim": 4}}


def _obs(space: gym.spaces.Dict, n: int = 6, seed: int = 0) -> dict:
    space.seed(seed)
    return {k: torch.as_tensor(np.stack([s.sample() for _ in range(n)]), dtype=torch.float32)
            for k, s in space.spaces.items()}


def _student(space: gym.spaces.Dict, seed: int = 0):
    from stable_baselines3.common.policies import MultiInputActorCriticPolicy

    from agents.policies.features import PointSetExtractor

    torch.manual_seed(seed)
    return MultiInputActorCriticPolicy(space, gym.spaces.Discrete(5), lambda _: 1e-3,
                                       features_extractor_class=PointSetExtractor,
                                       features_extractor_kwargs=MODEL["features_extractor_kwargs"],
                                       net_arch=MODEL["net_arch"])


def _sb3_logits(policy, obs) -> torch.Tensor:
    """A stable-baselines3 policy's action log-probabilities (its Categorical normalises the logits)."""
    with torch.no_grad():
        return policy.get_distribution(obs).distribution.logits


def _log_probs(logits: torch.Tensor) -> torch.Tensor:
    return torch.log_softmax(logits, dim=-1)


def _module(space: gym.spaces.Dict, seed: int = 1) -> PointSetPPOModule:
    torch.manual_seed(seed)
    return PointSetPPOModule(observation_space=space, action_space=gym.spaces.Discrete(5), model_config=MODEL)


def test_the_env_creator_adds_the_decision_interval_and_the_privileged_key():
    env = make_env(SLAM, env_config(SMALL, decision_interval=5, decision_mode="pulse", privileged=True))
    assert isinstance(env, HoldAction) and env.k == 5 and env.fill == IDLE
    obs, _ = env.reset(seed=0)
    assert obs[PRIVILEGED_KEY].shape == (PRIVILEGED_DIM,) and env.observation_space.contains(obs)
    *_, info = env.step(3)
    assert info["held_steps"] == 5  # one decision = five 5 Hz env steps (the episode is 20 long)
    env.close()
    plain = make_env(SLAM, env_config(SMALL))
    assert not isinstance(plain, HoldAction) and PRIVILEGED_KEY not in plain.observation_space.spaces
    plain.close()
    with pytest.raises(ValueError, match="decision_mode"):
        env_config(SMALL, decision_mode="repeat")


def test_the_module_actor_ignores_the_privileged_key_and_the_critic_reads_it():
    module = _module(SPACE)
    obs = _obs(SPACE)
    other = {**obs, PRIVILEGED_KEY: -obs[PRIVILEGED_KEY]}
    with torch.no_grad():
        logits = module.forward_inference({"obs": obs})["action_dist_inputs"]
        assert torch.equal(logits, module.forward_inference({"obs": other})["action_dist_inputs"])
        assert torch.equal(logits, module.forward_train({"obs": other})["action_dist_inputs"])
        values, moved = module.compute_values({"obs": obs}), module.compute_values({"obs": other})
    assert values.shape == (6,) and not torch.allclose(values, moved)
    # without the key the value shares the actor's encoder (SB3's MultiInputPolicy)
    plain = _module(without_privileged(SPACE))
    assert not hasattr(plain, "vf_encoder") and hasattr(module, "vf_encoder")


def test_the_corrected_student_moves_into_the_module_and_back():
    from agents.algos.finetune import correct_class_prior

    actor_space = without_privileged(SPACE)
    student = _student(actor_space)
    shift = correct_class_prior(student, np.array([100, 1500, 60, 240, 100]), 0.5)
    assert shift[1] > 0 > shift[2]  # the frequent IDLE gains, the rare lane change loses
    module = _module(SPACE)
    obs = _obs(SPACE, seed=2)
    actor_obs = {k: v for k, v in obs.items() if k != PRIVILEGED_KEY}
    with torch.no_grad():
        assert not torch.allclose(_log_probs(module.actor_logits(obs)), _sb3_logits(student, actor_obs))
        module.load_actor_state(student_actor_state(student, 1, privileged=True))
        torch.testing.assert_close(_log_probs(module.forward_inference({"obs": obs})["action_dist_inputs"]),
                                   _sb3_logits(student, actor_obs))
        # the critic's encoder starts from the student's extractor too (agents.algos.finetune.load_actor)
        torch.testing.assert_close(module.vf_encoder(actor_obs), module.encoder(actor_obs))
        for p in module.pi.parameters():  # training moves the actor; the export carries the move
            p.add_(0.1)
    export_module_actor(module, student)
    with torch.no_grad():
        torch.testing.assert_close(_log_probs(module.actor_logits(obs)), _sb3_logits(student, actor_obs))
    with pytest.raises(ValueError, match="policy_kwargs"):
        _module(SPACE).load_actor_state(student_actor_state(_student(actor_space), 2, privileged=True))


def _start_module(state: dict) -> PointSetPPOModule:
    module = _module(without_privileged(SPACE))
    module.load_actor_state(state)
    return module


def _kl_after_training(coef: float, warmup: float = 0.0) -> tuple[float, list[float]]:
    """KL(start || trained) on fresh observations after 4 PPO iterations of 64 decisions, anchor ``coef``, critic
    warm-up over ``warmup`` of the run; with ``coef`` 0, the second list is the ``critic_warmup`` flag per update."""
    import copy

    from agents.algos.finetune import FinetuneConfig
    from agents.algos.rllib import build_config, ppo_settings

    env_id = "rhs-test-reward-two-v0"
    if env_id not in gym.registry:
        gym.register(env_id, entry_point=reward_two_env)
    settings = ppo_settings({"n_steps": 64, "batch_size": 32, "n_epochs": 4, "learning_rate": 3e-3,
                             "gamma": 0.9}, n_envs=1, timesteps=256)
    finetune = FinetuneConfig(anchor_coef=coef, anchor_fraction=1.0, critic_warmup_fraction=warmup)
    learner_config = {"anchor_total_steps": 256, "finetune": {**finetune.__dict__}}
    algo = build_config(env_id, env_config({}), settings, MODEL, 0, 0, learner_config=learner_config).build_algo()
    try:
        start = student_actor_state(_student(without_privileged(SPACE), seed=5), 1, privileged=False)
        algo.learner_group.foreach_learner(lambda learner: learner.start_from(start, coef > 0))
        algo.env_runner_group.sync_weights(from_worker_or_learner_group=algo.learner_group, inference_only=True)
        sampler = algo.env_runner_group.local_env_runner.module
        obs = _obs(without_privileged(SPACE), 4, seed=4)
        with torch.no_grad():  # the runner samples with the student's actor from the first step
            torch.testing.assert_close(sampler.actor_logits(obs), _start_module(start).actor_logits(obs))
        key = "anchor_coef" if coef > 0 else "critic_warmup"
        coefs = [algo.train()["learners"]["default_policy"].get(key, 0.0) for _ in range(4)]
        trained = next(iter(algo.learner_group.foreach_learner(lambda learner: copy.deepcopy(
            learner.module["default_policy"].unwrapped())))).get()
    finally:
        algo.stop()
    teacher = _start_module(start)
    obs = _obs(without_privileged(SPACE), 64, seed=3)
    with torch.no_grad():
        target = torch.log_softmax(teacher.actor_logits(obs), -1)
        current = torch.log_softmax(trained.actor_logits(obs), -1)
    return float((target.exp() * (target - current)).sum(-1).mean()), coefs


def test_the_anchor_in_the_learner_loss_pulls_the_policy_towards_the_student():
    free, free_coefs = _kl_after_training(0.0)
    held_kl, coefs = _kl_after_training(20.0)
    assert free_coefs == [0.0] * 4
    # lambda(t) = 20 (1 - t / T) with t the decisions sampled before each update: 64, 128, 192, 256 of 256
    assert coefs == pytest.approx([15.0, 10.0, 5.0, 0.0])
    assert free > 0.01 and held_kl < 0.5 * free


def test_the_critic_warm_up_in_the_learner_leaves_the_actor_alone():
    kl, warming = _kl_after_training(0.0, warmup=1.0)
    assert warming == [1.0] * 4, warming
    # the same 4 updates without the warm-up move the actor by KL > 0.01 (the test above); this module shares its
    # encoder with the critic (no privileged key), which the value loss alone nudges
    assert kl < 1e-4


def test_finetune_on_rllib_trains_from_the_student_and_exports_a_plain_zip(tmp_path):
    """`train --backend rllib --algo finetune --init-policy`: prior -> anchored PPO at 1 Hz pulse -> model.zip."""
    from conftest import TINY_POLICY_KWARGS
    from stable_baselines3 import PPO

    from agents.evaluate import make_env as eval_env

    env = eval_env(SLAM, SMALL)
    student = PPO("MultiInputPolicy", env, device="cpu", seed=0,
                  policy_kwargs={**TINY_POLICY_KWARGS, "features_extractor_class":
                                 __import__("agents.policies.features", fromlist=["x"]).PointSetExtractor})
    zip_path = tmp_path / "student.zip"
    student.save(zip_path)
    record = {"algo": "dagger", "env_id": SLAM, "env_kwargs": SMALL, "decision_interval": 5,
              "decision_mode": "pulse", "dagger": {"class_weight_power": 0.5, "label_between": True}}
    zip_path.with_suffix(".json").write_text(json.dumps(record))
    hp = tmp_path / "finetune.yml"
    hp.write_text(tiny_hyperparams(SLAM, n_envs=1, n_timesteps=80, decision_interval=5, decision_mode="pulse",
                                   n_steps=8, batch_size=8, n_epochs=2, gamma=0.8, anchor_coef=1.0,
                                   anchor_fraction=1.0, prior_steps=30, privileged_critic=True))
    out = tmp_path / "run"
    rc = cli_main(["train", "--backend", "rllib", "--algo", "finetune", "--init-policy", str(zip_path),
                   "--env", SLAM, "--hyperparams", str(hp), "--out", str(out), "--num-env-runners", "1",
                   "--eval-freq", "0", "--checkpoint-freq", "0", "--no-progress"])  # fmt: skip
    assert rc == 0
    s = json.loads((out / "train.json").read_text())
    assert (s["algo"], s["decision_interval"], s["decision_mode"]) == ("finetune", 5, "pulse")
    assert s["timesteps"] == 80 and s["decisions"] == 16 and len(s["iterations"]) == 2
    assert sum(s["class_prior"]["label_counts"]) == 30 and s["finetune"]["anchor"]
    # the anchor's lambda(t) = 1 - t / T at t = 8 and 16 of 16 decisions
    assert [it["anchor_coef"] for it in s["iterations"]] == pytest.approx([0.5, 0.0])
    # the checkpoint's actor acts at 1 Hz on the plain env; model.zip is that actor as an SB3 student
    ckpt = load_policy(out / CHECKPOINT_DIR, env)
    assert isinstance(ckpt, HeldPolicy) and ckpt.k == 5 and ckpt.fill == IDLE
    assert PRIVILEGED_KEY in ckpt.model.module.observation_space.spaces
    zipped = load_policy(out / "model.zip", env)
    assert isinstance(zipped, HeldPolicy) and zipped.k == 5
    model = PPO.load(out / "model.zip", device="cpu")
    assert PRIVILEGED_KEY not in model.observation_space.spaces
    assert json.loads((out / "model.json").read_text())["env_id"] == SLAM
    obs, _ = env.reset(seed=1)
    tensor, _ = model.policy.obs_to_tensor(obs)
    with torch.no_grad():
        torch.testing.assert_close(_sb3_logits(model.policy, tensor), _log_probs(ckpt.model.module.actor_logits(tensor)))
    env.close()
    summary = evaluate(out / "model.zip", episodes=1, seed=5, progress=False)
    assert summary["runs"][0]["steps"] >= 1 and np.isfinite(summary["runs"][0]["return"])


def test_finetune_on_rllib_without_a_student_is_ppo_from_scratch_with_the_privileged_critic(tmp_path):
    """No --init-policy: no prior, no anchor; the privileged critic still trains and model.zip is a fresh SB3 layout."""
    from stable_baselines3 import PPO

    hp = tmp_path / "finetune.yml"
    hp.write_text(tiny_hyperparams(SLAM, n_envs=1, n_timesteps=40, decision_interval=5, decision_mode="pulse",
                                   n_steps=8, batch_size=8, n_epochs=1, anchor_coef=1.0, privileged_critic=True))
    out = tmp_path / "run"
    rc = cli_main(["train", "--backend", "rllib", "--algo", "finetune", "--env", SLAM, "--hyperparams", str(hp),
                   "--env-kwargs", json.dumps(SMALL), "--out", str(out), "--num-env-runners", "0",
                   "--eval-freq", "0", "--checkpoint-freq", "0", "--no-progress"])  # fmt: skip
    assert rc == 0
    s = json.loads((out / "train.json").read_text())
    assert s["finetune"]["anchor"] is False and "class_prior" not in s and "init_policy" not in s
    assert s["decisions"] == 8 and not any("anchor_coef" in it for it in s["iterations"])
    module = RLlibPolicy(out / CHECKPOINT_DIR).module
    assert module.privileged and PRIVILEGED_KEY not in PPO.load(out / "model.zip").observation_space.spaces
