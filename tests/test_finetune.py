"""PPO fine-tuning of a student: the privileged critic, the weight transfer, the class-prior correction, the anchor."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import privileged_space, reward_two_env, small_env_kwargs, tiny_hyperparams
from stable_baselines3 import PPO
from stable_baselines3.common.policies import MultiInputActorCriticPolicy

from agents.algos.finetune import (
    AnchoredPPO,
    FinetuneConfig,
    PrivilegedCriticPolicy,
    actor_parameters,
    anchor_coef,
    correct_class_prior,
    export_actor,
    load_actor,
)
from agents.policies.expert import HeadwayDriver, bumper_gap
from agents.policies.privileged import (
    GAP_SCALE_M,
    LANE_FEATURES,
    PRIVILEGED_DIM,
    PRIVILEGED_KEY,
    privileged_features,
    without_privileged,
)

SPACE = privileged_space()
POLICY_KWARGS = {"features_extractor_class": __import__("agents.policies.features", fromlist=["x"]).PointSetExtractor,
                 "features_extractor_kwargs": {"point_dim": 8, "box_dim": 4}, "net_arch": [8]}


def _obs(rng: np.random.Generator, n: int = 6) -> dict[str, torch.Tensor]:
    return {k: torch.as_tensor(np.stack([space.sample() for _ in range(n)]), dtype=torch.float32)
            for k, space in SPACE.spaces.items()}


def _logits(policy, obs) -> torch.Tensor:
    with torch.no_grad():
        return policy.get_distribution(obs).distribution.logits


def _pair(seed: int = 0):
    torch.manual_seed(seed)
    SPACE.seed(seed)
    lr = lambda _: 1e-3
    student = MultiInputActorCriticPolicy(without_privileged(SPACE), gym.spaces.Discrete(5), lr, **POLICY_KWARGS)
    tuned = PrivilegedCriticPolicy(SPACE, gym.spaces.Discrete(5), lr, **POLICY_KWARGS)
    return student, tuned


def test_the_actor_ignores_the_privileged_key_and_the_critic_reads_it():
    _, policy = _pair()
    obs = _obs(np.random.default_rng(0))
    other = {**obs, PRIVILEGED_KEY: -obs[PRIVILEGED_KEY]}
    assert torch.equal(_logits(policy, obs), _logits(policy, other))
    with torch.no_grad():
        assert not torch.allclose(policy.predict_values(obs), policy.predict_values(other))


def test_the_student_moves_into_the_actor_and_back_unchanged():
    student, policy = _pair()
    obs = _obs(np.random.default_rng(1))
    actor_obs = {k: v for k, v in obs.items() if k != PRIVILEGED_KEY}
    assert not torch.allclose(_logits(student, actor_obs), _logits(policy, obs))
    load_actor(policy, student)
    torch.testing.assert_close(_logits(student, actor_obs), _logits(policy, obs))
    with torch.no_grad():  # fine-tuning moves the actor; the export carries the move
        for p in policy.mlp_extractor.policy_net.parameters():
            p.add_(0.1)

    class Holder:  # export_actor writes into a PPO's policy
        pass

    holder = Holder()
    holder.policy = student  # type: ignore[attr-defined]
    export_actor(policy, holder)  # type: ignore[arg-type]
    torch.testing.assert_close(_logits(student, actor_obs), _logits(policy, obs))


def test_the_class_prior_correction_recovers_the_unweighted_posterior():
    """A weighted fit's optimum on one state is pi_w(a) ~ w_a p(a); the correction gives p(a) back."""
    student, _ = _pair()
    p = np.array([0.05, 0.8, 0.03, 0.07, 0.05])
    counts = np.round(p * 2000)
    w = (counts.sum() / (5 * counts)) ** 0.5
    with torch.no_grad():
        student.action_net.weight.zero_()
        student.action_net.bias.copy_(torch.as_tensor(np.log(w * p), dtype=torch.float32))
    obs = {k: v for k, v in _obs(np.random.default_rng(2), 1).items() if k != PRIVILEGED_KEY}
    before = torch.softmax(_logits(student, obs), -1).numpy()[0]
    assert before[1] < 0.7  # the weights pushed probability towards the rare actions
    correct_class_prior(student, counts, 0.5)
    after = torch.softmax(_logits(student, obs), -1).numpy()[0]
    np.testing.assert_allclose(after, counts / counts.sum(), atol=1e-5)


def test_the_anchor_decays_to_zero():
    config = FinetuneConfig(anchor_coef=2.0, anchor_fraction=0.4)
    coefs = [anchor_coef(config, t) for t in np.linspace(0, 1, 11)]
    assert coefs[0] == 2.0 and all(a >= b for a, b in zip(coefs, coefs[1:], strict=False))
    assert coefs[4] == pytest.approx(0.0) and coefs[-1] == 0.0
    with pytest.raises(ValueError, match="anchor_fraction"):
        FinetuneConfig(anchor_fraction=0.0)


def _kl_after_training(coef: float) -> float:
    torch.manual_seed(0)
    model = AnchoredPPO("MultiInputPolicy", reward_two_env(), n_steps=64, batch_size=32, n_epochs=4, learning_rate=3e-3,
                        seed=0, policy_kwargs=POLICY_KWARGS, device="cpu")
    model.finetune = FinetuneConfig(anchor_coef=coef, anchor_fraction=1.0, anchor_epochs=4)
    torch.manual_seed(1)
    teacher = MultiInputActorCriticPolicy(without_privileged(SPACE), gym.spaces.Discrete(5), lambda _: 1e-3,
                                          **POLICY_KWARGS)
    model.teacher = teacher
    model.learn(total_timesteps=256)
    obs = {k: v for k, v in _obs(np.random.default_rng(3), 64).items() if k != PRIVILEGED_KEY}
    with torch.no_grad():
        kl = torch.distributions.kl_divergence(teacher.get_distribution(obs).distribution,
                                               model.policy.get_distribution(obs).distribution)
    return float(kl.mean())


def test_the_anchor_pulls_the_policy_towards_the_teacher():
    assert _kl_after_training(20.0) < 0.5 * _kl_after_training(0.0)


def test_the_critic_warm_up_trains_the_critic_and_leaves_the_actor():
    torch.manual_seed(0)
    model = AnchoredPPO("MultiInputPolicy", reward_two_env(), n_steps=64, batch_size=32, n_epochs=4, learning_rate=3e-3,
                        seed=0, policy_kwargs={**POLICY_KWARGS, "share_features_extractor": False}, device="cpu")
    model.finetune = FinetuneConfig(critic_warmup_fraction=0.5)
    actor = {name: p.detach().clone() for name, p in model.policy.named_parameters()
             if any(p is q for q in actor_parameters(model.policy))}
    critic = {name: p.detach().clone() for name, p in model.policy.named_parameters() if name not in actor}
    assert actor and critic and any(name.startswith("vf_features_extractor.") for name in critic)
    model.learn(total_timesteps=128)  # two updates at t / T = 0.5 and 1.0: only the first is the warm-up
    changed = {name for name, p in model.policy.named_parameters()
               if not torch.equal(p.detach(), (actor | critic)[name])}
    assert changed & set(critic) and changed & set(actor)
    model.finetune = FinetuneConfig(critic_warmup_fraction=1.0)
    actor = {name: p.detach().clone() for name, p in model.policy.named_parameters() if name in actor}
    model.learn(total_timesteps=128)
    assert all(torch.equal(p.detach(), actor[name]) for name, p in model.policy.named_parameters() if name in actor)
    assert all(p.requires_grad for p in model.policy.parameters())  # unfrozen after each update
    with pytest.raises(ValueError, match="critic_warmup_fraction"):
        FinetuneConfig(critic_warmup_fraction=1.5)


def test_privileged_features_read_the_true_road():
    import rhs_env  # noqa: F401

    env = gym.make("rhs-highway-v0", vehicles_count=3)
    env.reset(seed=0)
    base = env.unwrapped
    ego = base.vehicle
    others = [v for v in base.road.vehicles if v is not ego]
    leader = others[0]
    leader.lane_index, leader.lane = ego.lane_index, ego.lane
    s, _ = ego.lane.local_coordinates(ego.position)
    leader.position = ego.lane.position(s + 30.0, 0.0)
    base.road.vehicles = [ego, leader]
    v = privileged_features(env)
    assert v.shape == (PRIVILEGED_DIM,)
    own = v[3:3 + LANE_FEATURES]
    assert own[0] == 1.0
    assert own[1] == pytest.approx(bumper_gap(ego, leader) / GAP_SCALE_M, abs=1e-6)
    assert own[1] == pytest.approx((30.0 - ego.LENGTH) / GAP_SCALE_M, abs=1e-3)
    assert own[3] == 1.0  # no follower: the gap reads as the scale
    assert int(np.argmax(v[-5:])) == HeadwayDriver(env).act()
    lanes = len(base.road.network.graph[ego.lane_index[0]][ego.lane_index[1]])
    left = v[3 + LANE_FEATURES:3 + 2 * LANE_FEATURES]
    assert left[0] == float(ego.lane_index[2] > 0) and lanes > 1
    time_left = v[3 + 3 * LANE_FEATURES]
    env.step(1)
    later = privileged_features(env)[3 + 3 * LANE_FEATURES]
    step_s = 1.0 / base.config["policy_frequency"]
    assert time_left - later == pytest.approx(step_s / base.config["duration"], abs=1e-6)
    env.close()


@pytest.mark.parametrize("shield", [None, {"front_time_s": 1.5}], ids=["plain", "shielded"])
def test_finetune_cli_trains_and_exports_a_plain_student(tmp_path, shield):
    """End to end on the small SLAM env: a student zip -> measured prior -> PPO with the anchor -> a plain zip;
    with a ``shield`` entry, PPO trains under the radar shield and the policy is loaded behind it."""
    from agents.algos.train import train
    from agents.evaluate import load_policy, make_env
    from agents.policies.shield import ShieldedPolicy

    env_id = "rhs-highway-slam-v0"
    kwargs = small_env_kwargs(duration=4)
    env = make_env(env_id, kwargs)
    student = PPO("MultiInputPolicy", env, device="cpu", seed=0,
                  policy_kwargs={**POLICY_KWARGS, "features_extractor_kwargs": {"point_dim": 16, "box_dim": 8},
                                 "net_arch": [16]})
    zip_path = tmp_path / "student.zip"
    student.save(zip_path)
    record = {"algo": "dagger", "env_id": env_id, "env_kwargs": kwargs, "decision_interval": 5,
              "decision_mode": "pulse", "dagger": {"class_weight_power": 0.5, "label_between": True}}
    zip_path.with_suffix(".json").write_text(json.dumps(record))
    env.close()
    hp = tmp_path / "finetune.yml"
    hp.write_text(tiny_hyperparams(env_id, n_envs=1, n_timesteps=80, decision_interval=5, decision_mode="pulse",
                                   n_steps=8, batch_size=8, n_epochs=2, gamma=0.8, anchor_coef=1.0,
                                   anchor_fraction=0.5, prior_steps=30,
                                   **({} if shield is None else {"shield": shield, "critic_warmup_fraction": 1.0})))
    out = tmp_path / "run"
    summary = train("finetune", env_id, None, out, hyperparams=hp, init_policy=zip_path, progress=False,
                    checkpoint_freq=0)
    assert summary["algo"] == "finetune" and summary["timesteps"] >= 80
    assert sum(summary["class_prior"]["label_counts"]) == 30
    saved = json.loads((out / "model.json").read_text())
    assert saved["decision_interval"] == 5 and saved["decision_mode"] == "pulse"
    assert (saved["shield"] is None) == (shield is None)
    if shield is not None:
        assert saved["shield"]["front_time_s"] == 1.5 and saved["shield"]["min_points"] == 2  # the full record
    model = PPO.load(out / "model.zip", device="cpu")
    assert PRIVILEGED_KEY not in model.observation_space.spaces  # the deployed actor needs only the sensors
    if shield is not None:  # a warm-up over the whole run: the actor is the student, its head's bias corrected
        assert saved["finetune"]["critic_warmup_fraction"] == 1.0
        trained, start = model.policy.state_dict(), student.policy.state_dict()
        assert all(torch.equal(trained[k], start[k]) for k in start if "action_net.bias" not in k and "value" not in k)
    full = AnchoredPPO.load(out / "finetune_full.zip", device="cpu")
    assert PRIVILEGED_KEY in full.observation_space.spaces
    env = make_env(env_id, kwargs)
    policy = load_policy(out / "model.zip", env)
    assert isinstance(policy, ShieldedPolicy) == (shield is not None)
    obs, _ = env.reset(seed=1)
    action, _ = policy.predict(obs, deterministic=True)
    assert int(np.asarray(action).reshape(-1)[0]) in range(5)
    tensor, _ = model.policy.obs_to_tensor(obs)
    priv = {**tensor, PRIVILEGED_KEY: torch.zeros((1, PRIVILEGED_DIM))}
    torch.testing.assert_close(_logits(model.policy, tensor), _logits(full.policy, priv))
    env.close()


def test_the_study_reads_learning_curves_from_monitor_files(tmp_path):
    """Two envs' monitor files -> episodes ordered by end time, env steps summed, rolling return and crash rate."""
    from rhs_studies.rl_finetune import learning_curve

    header = '#{"t_start": 0, "env_id": "x"}\nr,l,t,crashed\n'
    (tmp_path / "0.monitor.csv").write_text(header + "10,200,1.0,False\n2,30,3.0,True\n")
    (tmp_path / "1.monitor.csv").write_text(header + "8,200,2.0,False\n")
    curve = learning_curve(tmp_path, window=2)
    assert curve["env_steps"] == [400, 430]
    assert curve["return"] == pytest.approx([9.0, 5.0])
    assert curve["collision_rate"] == pytest.approx([0.0, 0.5])
    assert learning_curve(tmp_path / "none") == {"env_steps": [], "return": [], "collision_rate": []}


def test_the_study_pairs_by_seed_and_bounds_collisions():
    from rhs_studies.rl_finetune import paired, row_summary

    a = [{"seed": s, "return": 150.0 + s % 3, "crashed": s == 2, "mean_speed": 24.0} for s in range(10)]
    b = [{"seed": s, "return": 148.0 + s % 3, "crashed": False, "mean_speed": 23.0} for s in reversed(range(10))]
    d = paired(a, b)
    assert d["mean"] == pytest.approx(2.0) and d["low"] == pytest.approx(2.0) and d["n"] == 10
    s = row_summary(a)
    assert s["collisions"] == 1 and s["collision_interval"][0] < 0.1 < s["collision_interval"][1]
    assert s["return"]["half"] > 0


def test_the_study_judges_the_longest_fine_tune_against_its_own_budgets_control():
    from rhs_studies.rl_finetune import ARMS, SHIELD_ARMS, SHIELD_CONTROL, headline_arm, row_summary, targets

    def runs_of(base: float, crash_seed: int = -1) -> list[dict]:
        return [{"seed": s, "return": base + s % 3, "crashed": s == crash_seed, "mean_speed": 24.5} for s in range(10)]

    runs = {"student": runs_of(150.0), "finetune": runs_of(151.0), "dagger_continue": runs_of(150.0),
            "idm": runs_of(140.0), "finetune_horizon_80k": runs_of(156.0), "dagger_continue_80k": runs_of(155.0, 3)}
    arm, control = headline_arm(runs)
    assert (arm, control) == ("finetune_horizon_80k", "dagger_continue_80k")
    assert ARMS[arm].timesteps == ARMS[control].timesteps  # the control has the same env-step budget
    t = targets({k: row_summary(v) for k, v in runs.items()}, runs, arm, control)
    assert t["gain_over_student"]["mean"] == pytest.approx(6.0)
    assert t["gain_over_control"]["mean"] == pytest.approx(1.0)
    assert t["met"]["gain_over_student"] and t["met"]["beats_control"] and t["met"]["mean_speed"]
    del runs["finetune_horizon_80k"]
    assert headline_arm(runs) == ("finetune", "dagger_continue")
    # a shield arm is judged against its own start (the shipped policy) and the DAgger continuation under the shield
    runs.update(shipped=runs_of(158.0), shield_warmup=runs_of(161.5), shield_dagger=runs_of(162.0, 4))
    t = targets({k: row_summary(v) for k, v in runs.items()}, runs, "shield_warmup", SHIELD_CONTROL)
    assert ARMS["shield_warmup"].start == "shipped" and t["gain_over_student"]["mean"] == pytest.approx(3.5)
    assert t["gain_over_control"]["mean"] == pytest.approx(-0.5)
    assert t["met"]["gain_over_student"] and not t["met"]["beats_control"]
    assert ARMS[SHIELD_CONTROL].start == "shipped" and ARMS[SHIELD_CONTROL].timesteps == ARMS[SHIELD_ARMS[0]].timesteps


def test_the_study_trains_each_arm_from_its_start(tmp_path):
    from agents.evaluate import resolve_env
    from rhs_studies.rl_finetune import ROOT, SHIPPED_START, STUDENT, train_command

    def flag(cmd: list[str], name: str) -> str | None:
        return cmd[cmd.index(name) + 1] if name in cmd else None

    assert flag(train_command("finetune", tmp_path, 20000, 0), "--init-policy") == str(STUDENT.relative_to(ROOT))
    warmup = train_command("shield_warmup", tmp_path, 20000, 0)
    assert flag(warmup, "--init-policy") == str(SHIPPED_START.relative_to(ROOT)) and flag(warmup, "--timesteps") == "60000"
    scratch = train_command("shield_scratch", tmp_path, 20000, 0)  # from scratch on the shipped policy's env
    assert "--init-policy" not in scratch
    assert json.loads(flag(scratch, "--env-kwargs")) == resolve_env(str(SHIPPED_START))[1]
    assert "--env-kwargs" not in train_command("scratch", tmp_path, 20000, 0)  # the first study's scratch: defaults


def test_the_study_keeps_earlier_rows_only_on_the_same_seeds_and_names_their_commit(tmp_path):
    from rhs_studies.rl_finetune import keep_rows, markdown, row_summary

    def runs_of(base: float, seeds=range(3000, 3010)) -> list[dict]:
        return [{"seed": s, "return": base + s % 3, "crashed": False, "mean_speed": 24.0} for s in seeds]

    earlier = tmp_path / "rl_finetune.json"
    earlier.write_text(json.dumps({"provenance": {"commit": "a" * 40}, "kept_rows": {"idm": "b" * 40},
                                   "runs": {"student": runs_of(150.0), "idm": runs_of(140.0)},
                                   "curves": {"student": {"env_steps": [1]}}}))
    seeds = list(range(3000, 3010))
    kept = keep_rows(earlier, ["student", "idm"], seeds)
    assert kept["commits"] == {"student": "a" * 40, "idm": "b" * 40}  # a row kept before keeps its first commit
    assert kept["runs"]["student"][0]["return"] == 150.0 and kept["curves"] == {"student": {"env_steps": [1]}}
    with pytest.raises(ValueError, match="no rows"):
        keep_rows(earlier, ["headway"], seeds)
    with pytest.raises(ValueError, match="other seeds"):
        keep_rows(earlier, ["idm"], list(range(3000, 3020)))
    with pytest.raises(ValueError, match="does not exist"):
        keep_rows(tmp_path / "missing.json", ["idm"], seeds)
    runs = kept["runs"]
    result = {"seeds": seeds, "episodes": 10, "timesteps": 20000, "rows": {k: row_summary(v) for k, v in runs.items()},
              "vs_student": {}, "kept_rows": kept["commits"]}
    assert "IDM + MOBIL (highway-env, scripted) (bbbbbbb)" in markdown(result)
    from rhs_studies.rl_finetune import main

    for argv in (["--arms", "finetune", "--keep", "finetune"],  # a row both kept and driven again
                 ["--arms", "finetune", "--keep", "idm", "--out-dir", str(tmp_path / "empty")],  # nothing to keep
                 ["--arms", "finetune", "--redrive", "finetune"],  # an arm both trained and driven again
                 ["--arms", "finetune", "--redrive", "shield_explore", "--ship-dir", str(tmp_path)]):  # no zip
        with pytest.raises(SystemExit):
            main([*argv, "--runs", str(tmp_path / "runs")])


def test_the_study_derives_a_control_yaml_with_the_keys_set(tmp_path):
    import yaml

    from rhs_studies.rl_finetune import hyperparams_file

    path = hyperparams_file("finetune.yml:anchor_coef=0;learning_rate=5.0e-4;reward_shaping={ttc_s: 2.0}", tmp_path,
                            "control")
    assert path == tmp_path / "control.yml"
    table = yaml.safe_load(path.read_text())
    assert table["rhs-highway-slam-v0"]["anchor_coef"] == 0
    assert table["rhs-highway-slam-v0"]["learning_rate"] == pytest.approx(5e-4)
    assert table["rhs-highway-slam-v0"]["reward_shaping"] == {"ttc_s": 2.0}
    assert table["rhs-highway-slam-v0"]["anchor_fraction"] == 0.5  # the rest as shipped


def test_time_to_collision_shaping_penalises_closing_in_on_a_leader():
    import rhs_env  # noqa: F401
    from agents.algos.shaping import RewardShaping, ShapingConfig, time_to_collision, ttc_penalty

    env = RewardShaping(gym.make("rhs-highway-v0", vehicles_count=3), {"ttc_s": 3.0, "weight": 0.5})
    env.reset(seed=0)
    base = env.unwrapped
    ego = base.vehicle
    leader = next(v for v in base.road.vehicles if v is not ego)
    leader.lane_index, leader.lane = ego.lane_index, ego.lane
    s, _ = ego.lane.local_coordinates(ego.position)
    leader.position = ego.lane.position(s + 20.0, 0.0)
    base.road.vehicles = [ego, leader]
    leader.speed = ego.speed - 10.0  # closing at 10 m/s from (20 - L) m: TTC ~ 1.5 s
    ttc = time_to_collision(env)
    assert ttc == pytest.approx((20.0 - ego.LENGTH) / 10.0, rel=1e-6)
    assert ttc_penalty(ttc, ShapingConfig(ttc_s=3.0, weight=0.5)) == pytest.approx(0.5 * (1 - ttc / 3.0))
    leader.speed = ego.speed + 5.0  # pulling away: no danger
    assert time_to_collision(env) == float("inf")
    with pytest.raises(ValueError, match="reward_shaping.ttc_s"):
        RewardShaping(env.env, {"ttc_s": 0.0})
    env.close()


def test_the_shield_cost_is_charged_on_the_steps_the_shield_replaced():
    import rhs_env  # noqa: F401
    from agents.algos.shaping import RewardShaping

    class Shielded(gym.Wrapper):  # the shield's report, one replaced step in two
        n = 0

        def step(self, action):
            obs, reward, terminated, truncated, info = self.env.step(action)
            self.n += 1
            return obs, reward, terminated, truncated, {**info, "shield": "front" if self.n % 2 else None}

    def shaped(cost: float) -> list[float]:
        env = RewardShaping(Shielded(gym.make("rhs-highway-v0", vehicles_count=3)),
                            {"ttc_s": 3.0, "weight": 0.0, "shield_cost": cost})
        env.reset(seed=0)
        out = [env.step(1)[4]["shaping"] for _ in range(4)]
        env.close()
        return out

    assert shaped(0.0) == [0.0] * 4  # off by default
    assert shaped(0.7) == pytest.approx([-0.7, 0.0, -0.7, 0.0])
    with pytest.raises(ValueError, match="reward_shaping.shield_cost"):
        RewardShaping(gym.make("rhs-highway-v0", vehicles_count=3), {"shield_cost": -1.0})


def test_the_confirmation_chooses_on_validation_seeds_and_judges_the_choice_once_on_other_seeds(monkeypatch, tmp_path):
    """rl_confirm: the candidate with the higher validation gain is the one the test drives and judges; the
    validation seeds never reach the test, and the test drives the start, the DAgger control and IDM + MOBIL."""
    from rhs_studies import rl_confirm

    calls = []
    base = {"shipped": 160.0, "shield_explore": 161.0, "shield_flank_explore": 163.0, "shield_dagger": 160.5,
            "idm": 150.0}

    def fake_drive(row, seeds):  # one row of the protocol on seeds
        calls.append((row.name, seeds[0]))
        # on the test seeds the other candidate would win: the test must not choose again
        shift = {"shield_explore": 5.0} if seeds[0] < 7000 else {}
        return [{"seed": s, "return": base[row.name] + shift.get(row.name, 0.0) + s % 3,
                 "crashed": s == seeds[0] and row.name == "idm", "mean_speed": 24.5} for s in seeds]

    result = rl_confirm.confirm(list(range(7000, 7010)), list(range(6000, 6010)), 1, drive=fake_drive)
    assert [k for k, s in calls if s == 7000] == ["shipped", "shield_explore", "shield_flank_explore"]
    assert result["validation"]["chosen"] == "shield_flank_explore"
    assert [k for k, s in calls if s == 6000] == ["shipped", "shield_flank_explore", "shield_dagger", "idm"]
    assert list(result["test"]["vs_start"]) == ["shield_flank_explore", "shield_dagger"]
    t = result["test"]["targets"]
    assert t["arm"] == "shield_flank_explore" and t["gain_over_student"]["mean"] == pytest.approx(3.0)
    assert t["gain_over_control"]["mean"] == pytest.approx(2.5) and t["met"]["gain_over_student"]
    assert "Chosen: **" in rl_confirm.markdown(result)
    with pytest.raises(SystemExit):  # validation and test seeds must not overlap
        rl_confirm.main(["--validation-seed", "6050", "--out-dir", str(tmp_path)])

    # PPO from scratch: chosen on its sampled actions on the validation seeds, tested sampled and greedy against
    # the fine-tune part's IDM + MOBIL episodes
    driven = []

    def fake_scratch(row, seeds):
        driven.append((row.policy, seeds[0], row.deterministic))
        mean = {"shield_scratch": 150.0, "shield_scratch_explore": 155.0, "shield_scratch_cost": 152.0}[row.policy]
        mean -= 8.0 * row.deterministic  # greedy: the reflex
        return [{"seed": s, "return": mean + s % 3, "crashed": False, "mean_speed": 20.0} for s in seeds]

    idm = result["test"]["runs"]["idm"]
    part = rl_confirm.confirm_scratch(list(range(7000, 7010)), list(range(6000, 6010)), 1, idm=idm, drive=fake_scratch)
    assert [d for d in driven if d[1] == 7000] == [(a, 7000, False) for a in rl_confirm.SCRATCH_CANDIDATES]
    assert part["validation"]["chosen"] == "shield_scratch_explore"
    assert [d for d in driven if d[1] == 6000] == [("shield_scratch_explore", 6000, False),
                                                   ("shield_scratch_explore", 6000, True)]
    t = part["test"]
    assert t["runs"]["idm"] == idm and t["targets"]["return_vs_idm"] == pytest.approx(156.0 / 151.0, rel=1e-3)
    assert t["targets"]["met"] == {"return_vs_idm": True, "collisions": True}
    assert "greedy actions" in "\n".join(rl_confirm.scratch_markdown(part))
    # a part kept must be on the same seeds
    (tmp_path / "rl_confirm.json").write_text(json.dumps({**result, "provenance": {"commit": "c" * 40}}))
    kept, commits = rl_confirm.kept_parts(tmp_path / "rl_confirm.json", ["finetune"], list(range(7000, 7010)),
                                          list(range(6000, 6010)))
    assert kept["validation"]["chosen"] == "shield_flank_explore" and commits == {"finetune": "c" * 40}
    with pytest.raises(ValueError, match="no finetune part"):
        rl_confirm.kept_parts(tmp_path / "rl_confirm.json", ["finetune"], list(range(7000, 7020)),
                              list(range(6000, 6010)))
    with pytest.raises(ValueError, match="no scratch part"):
        rl_confirm.kept_parts(tmp_path / "rl_confirm.json", ["scratch"], list(range(7000, 7010)),
                              list(range(6000, 6010)))


def test_the_lane_test_chooses_the_rule_on_validation_seeds_and_drives_the_fine_tune_behind_it_once(monkeypatch, tmp_path):
    """rl_lane_test: each rule changes one field of the shield saved with the fine-tune; the rule with the fewest
    validation collisions is the one the test drives; the test drives the start, the DAgger control and IDM + MOBIL
    with their own shields; used seeds are refused."""
    from agents.evaluate import policy_metadata
    from rhs_studies import rl_lane_rule_trial
    from rhs_studies.kit import driving

    saved = policy_metadata(rl_lane_rule_trial.SHIPPED_DIR / f"{rl_lane_rule_trial.FINETUNE}.zip")["shield"]
    shields = []
    real = driving.drive_row

    def fake_run(policy, env_id, kwargs, seeds, workers, deterministic=True, shield=None):
        shields.append((seeds[0], shield))
        bad = seeds[0] < 8000 and shield["lane_gap_m"] != saved["lane_gap_m"]  # the gap rule crashes on validation
        return [{"seed": s, "return": 170.0 + s % 3, "crashed": bad and s == seeds[0], "mean_speed": 25.0}
                for s in seeds]

    def fake_drive(row, seeds):  # the fine-tune through the real row driver (its shield), the other rows faked
        if row.policy == rl_lane_rule_trial.FINETUNE:
            return real(row.policy, seeds, 1, rl_lane_rule_trial.SHIPPED_DIR, row.deterministic, row.shield)
        assert seeds[0] == 8000 and row.name in ("shipped", "shield_dagger", "idm")
        return [{"seed": s, "return": 160.0 + s % 3, "crashed": False, "mean_speed": 23.0} for s in seeds]

    monkeypatch.setattr(driving, "run_policy", fake_run)  # drive_row's
    result = rl_lane_rule_trial.lane_test(list(range(7000, 7010)), list(range(8000, 8010)), 1, drive=fake_drive)
    assert list(result["test"]["rows"]) == [rl_lane_rule_trial.FINETUNE, "shipped", "shield_dagger", "idm"]
    assert [s for s, _ in shields] == [7000, 7000, 8000]
    for (_, shield), rule in zip(shields, rl_lane_rule_trial.LANE_RULES.values()):
        assert shield == {**saved, **rule} and shield != saved  # one field changed, the rest as saved
    assert result["validation"]["chosen"] == "lane_time" and shields[2][1] == {**saved, "lane_time_s": 2.5}
    t = result["test"]["targets"]
    assert t["arm"] == rl_lane_rule_trial.FINETUNE and t["gain_over_student"]["mean"] == pytest.approx(10.0)
    assert t["met"]["gain_over_student"] and t["met"]["collisions"]
    assert "Chosen: **lane_time_s 2.5**" in rl_lane_rule_trial.markdown(result)
    with pytest.raises(SystemExit):  # a test set the project has judged on already
        rl_lane_rule_trial.main(["--seed", "6050", "--out-dir", str(tmp_path)])
    # shipping: refused unless every target was met; else the same zip, the record's shield with the rule's field
    import shutil

    for suffix in (".zip", ".json"):
        shutil.copyfile(rl_lane_rule_trial.SHIPPED_DIR / f"{rl_lane_rule_trial.FINETUNE}{suffix}",
                        tmp_path / f"{rl_lane_rule_trial.FINETUNE}{suffix}")
    result["test"]["targets"]["met"]["return_vs_idm"] = False
    with pytest.raises(ValueError, match="return_vs_idm"):
        rl_lane_rule_trial.ship(result, tmp_path / "rl_lane_test.json", tmp_path)
    result["test"]["targets"]["met"] = dict.fromkeys(result["test"]["targets"]["met"], True)
    out = rl_lane_rule_trial.ship(result, tmp_path / "rl_lane_test.json", tmp_path)
    assert out.name == f"{rl_lane_rule_trial.FINETUNE}_lane_time.zip"
    assert out.read_bytes() == (tmp_path / f"{rl_lane_rule_trial.FINETUNE}.zip").read_bytes()
    record = policy_metadata(out)
    assert record["shield"] == {**saved, "lane_time_s": 2.5} and record["shipped_by"]["shield_rule"] == {"lane_time_s": 2.5}
    assert {k: v for k, v in record.items() if k not in ("shield", "model", "shipped_by")} == \
        {k: v for k, v in policy_metadata(tmp_path / f"{rl_lane_rule_trial.FINETUNE}.zip").items() if k not in ("shield", "model")}
