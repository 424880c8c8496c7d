"""The privileged expert (agents.policies.expert.HeadwayDriver) and DAgger (agents.algos.imitation).

Scenes are built by hand on an empty 3-lane road (vehicles placed at chosen gaps and
speeds), so each test asserts one rule of the driver; DAgger runs on the
ground-truth env with a few hundred steps. No test measures time.
"""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import rhs_env  # noqa: F401  (registers the ids)
from agents.algos.imitation import EXPERT_KEY, DaggerConfig, Dataset, ExpertActionInfo, agreement, fit
from agents.evaluate import evaluate, load_policy, policy_metadata
from agents.policies.decision import FASTER, IDLE, LANE_LEFT, LANE_RIGHT, SLOWER
from agents.policies.expert import HeadwayDriver, HeadwayDriverConfig

TRUTH = "rhs-highway-v0"


def _road(lane: int = 1, speed: float = 25.0, speed_index: int = 1):
    """An empty 3-lane road with the ego in ``lane`` at ``speed``; returns (env, ego)."""
    env = gym.make(TRUTH, vehicles_count=0, lanes_count=3, duration=4)
    env.reset(seed=0)
    base = env.unwrapped
    ego = base.vehicle
    lane_index = ("0", "1", lane)
    ego.lane_index = ego.target_lane_index = lane_index
    ego.lane = base.road.network.get_lane(lane_index)
    ego.position = ego.lane.position(100.0, 0.0)
    ego.heading = ego.lane.heading_at(100.0)
    ego.speed, ego.speed_index = speed, speed_index
    ego.target_speed = float(ego.target_speeds[speed_index])
    return env, ego


def _place(env, lane: int, ahead_m: float, speed: float):
    """A car ``ahead_m`` (centre to centre, negative: behind) of the ego in ``lane`` at ``speed``."""
    from highway_env.vehicle.behavior import IDMVehicle

    base = env.unwrapped
    road_lane = base.road.network.get_lane(("0", "1", lane))
    s = road_lane.local_coordinates(base.vehicle.position)[0] + ahead_m
    car = IDMVehicle(base.road, road_lane.position(s, 0.0), road_lane.heading_at(s), speed)
    car.lane_index, car.lane = ("0", "1", lane), road_lane
    base.road.vehicles.append(car)
    return car


def test_headway_config_is_validated_with_the_field_path():
    with pytest.raises(ValueError, match=r"expert\.headway_s must be in \(0\.0, 10\.0\]"):
        HeadwayDriver(gym.make(TRUTH, vehicles_count=0), {"headway_s": 0})
    with pytest.raises(ValueError, match="unknown"):
        HeadwayDriver(gym.make(TRUTH, vehicles_count=0), {"gap": 3})
    assert HeadwayDriverConfig().to_dict()["standstill_gap_m"] == 8.0


def test_free_road_speeds_up_to_cruise_and_keeps_right():
    env, ego = _road(lane=2, speed=20.0, speed_index=0)  # rightmost lane, nothing around
    assert HeadwayDriver(env).act() == FASTER
    env, ego = _road(lane=2, speed=25.0, speed_index=1)  # at the cruise speed: hold it
    assert HeadwayDriver(env).act() == IDLE
    assert HeadwayDriver(env, {"cruise_speed_mps": 30.0}).act() == FASTER
    env, ego = _road(lane=1, speed=25.0, speed_index=1)  # a free lane to the right: take it
    assert HeadwayDriver(env).act() == LANE_RIGHT


def test_slow_leader_close_ahead_with_side_lanes_blocked_means_slower():
    env, ego = _road(lane=1, speed=25.0, speed_index=1)
    _place(env, 1, 15.0, 20.0)  # v_safe = 20 + (10 - 8) / 1.5 < 25
    _place(env, 0, 2.0, 25.0)  # alongside, left
    _place(env, 2, 2.0, 25.0)  # alongside, right
    assert HeadwayDriver(env).act() == SLOWER
    # a leader at 21 m/s, 25 m ahead: v_safe = 21 + (20 - 8) / 1.5 = 29 allows 25 m/s but not 30 - 2: IDLE
    env, ego = _road(lane=2, speed=25.0, speed_index=1)
    _place(env, 2, 25.0, 21.0)
    _place(env, 1, 2.0, 25.0)
    assert HeadwayDriver(env, {"cruise_speed_mps": 30.0}).act() == IDLE


def test_standstill_gap_sets_how_near_the_driver_follows():
    """v_safe = v_f + (g - d0) / T: at a 10 m bumper gap behind a 23 m/s leader and T = 2 s, d0 = 8 m gives 24 m/s
    (below the 25 m/s target: SLOWER), d0 = 5 m gives 25.5 m/s (hold 25 m/s: IDLE)."""
    def scene():
        env, _ = _road(lane=2, speed=25.0, speed_index=1)
        _place(env, 2, 15.0, 23.0)  # bumper gap 15 - 5 = 10 m
        _place(env, 1, 2.0, 25.0)  # alongside, left: no lane change
        return env

    far = HeadwayDriver(scene(), {"headway_s": 2.0, "standstill_gap_m": 8.0})
    near = HeadwayDriver(scene(), {"headway_s": 2.0, "standstill_gap_m": 5.0})
    assert near.safe_speed(("0", "1", 2)) - far.safe_speed(("0", "1", 2)) == pytest.approx(3.0 / 2.0)
    assert far.act() == SLOWER
    assert near.act() == IDLE


def test_overtakes_left_only_for_a_clear_gain_and_never_into_a_closing_follower():
    env, ego = _road(lane=2, speed=25.0, speed_index=1)
    _place(env, 2, 15.0, 21.0)  # slow leader in the right lane: v_safe = 21 + (10 - 8) / 1.5 = 22.3
    assert HeadwayDriver(env).act() == LANE_LEFT
    # a faster car 10 m behind in the left lane: the lane is not open
    env, ego = _road(lane=2, speed=25.0, speed_index=1)
    _place(env, 2, 15.0, 21.0)
    _place(env, 1, -10.0, 30.0)
    driver = HeadwayDriver(env)
    assert not driver.is_open(("0", "1", 1))
    assert driver.act() == SLOWER


def test_headway_driver_is_a_scripted_policy_that_beats_always_slower_on_same_seeds():
    kw = {"vehicles_count": 15, "duration": 8}
    head = evaluate("headway", TRUTH, episodes=3, seed=7, env_kwargs=kw, progress=False)
    slow = evaluate("constant:4", TRUTH, episodes=3, seed=7, env_kwargs=kw, progress=False)
    assert head["collision_rate"] == 0.0
    assert head["mean_speed_mps"]["mean"] > slow["mean_speed_mps"]["mean"] + 1.0
    assert head["return"]["mean"] > slow["return"]["mean"]


def test_headway_k_decides_every_k_steps_and_idles_between():
    env, _ = _road(lane=2, speed=20.0, speed_index=0)  # empty road, right lane: it speeds up to its cruise speed
    plain = load_policy("headway", env)
    assert isinstance(plain, HeadwayDriver)
    pulsed = load_policy("headway:3", env)
    actions = [int(pulsed.predict(None)[0]) for _ in range(6)]
    assert actions == [FASTER, IDLE, IDLE, FASTER, IDLE, IDLE]  # the expert says FASTER at every step here
    assert plain.predict(None)[0] == FASTER
    with pytest.raises(ValueError, match="headway:<decision interval>"):
        load_policy("headway:x", env)
    with pytest.raises(ValueError, match="decision_interval"):
        load_policy("headway:0", env)


def test_expert_action_info_labels_reset_and_every_step():
    env = ExpertActionInfo(gym.make(TRUTH, vehicles_count=5, duration=2))
    _, info = env.reset(seed=1)
    labels = [info[EXPERT_KEY]]
    for _ in range(5):
        _, _, term, trunc, info = env.step(info[EXPERT_KEY])
        labels.append(info[EXPERT_KEY])
    assert all(a in range(5) for a in labels)


def test_dagger_config_is_validated():
    with pytest.raises(ValueError, match=r"dagger\.beta_decay must be in \[0\.0, 1\.0\]"):
        from rhs_common.validation import build

        build(DaggerConfig, {"beta_decay": 1.5}, "dagger")
    with pytest.raises(ValueError, match="iterations"):
        DaggerConfig(iterations=0)


def test_fit_learns_the_expert_labels():
    """Maximum likelihood on expert data: the student goes from chance to agreeing with the expert."""
    from stable_baselines3 import PPO

    env = ExpertActionInfo(gym.make(TRUTH, vehicles_count=20, duration=16))
    data = Dataset()
    for seed in (0, 1, 2):
        obs, info = env.reset(seed=seed)
        done = False
        while not done:
            data.add(obs, info[EXPERT_KEY])
            obs, _, term, trunc, info = env.step(info[EXPERT_KEY])
            done = term or trunc
    model = PPO("MlpPolicy", env, seed=0, device="cpu", policy_kwargs={"net_arch": [64, 64]})
    import torch

    torch.manual_seed(0)
    obs, actions = data.arrays()
    counts = np.bincount(actions, minlength=5)
    before = agreement(model, obs, actions)
    optimizer = torch.optim.Adam(model.policy.parameters(), lr=1e-3)
    loss = fit(model, data, DaggerConfig(epochs=60, batch_size=64), np.random.default_rng(0), optimizer)
    after = agreement(model, obs, actions)
    assert (counts > 0).sum() >= 3, counts  # the expert does more than hold its lane and speed
    # every action the expert took is learned, not just the most frequent one (balanced accuracy)
    recall = [agreement(model, *_subset(obs, actions, a)) for a in np.flatnonzero(counts >= 5)]
    assert after >= 0.9 and after > before and min(recall) >= 0.5, (before, after, recall, counts)
    assert loss < 1.0  # chance: ln 5 = 1.61


def _subset(obs, actions, action):
    idx = np.flatnonzero(actions == action)
    return obs[idx], actions[idx]


def test_rhs_slam_train_dagger_writes_a_policy_that_evaluate_loads(tmp_path):
    from agents.algos.train import train

    hp = tmp_path / "dagger.yml"
    hp.write_text(
        f"{TRUTH}:\n  policy: MlpPolicy\n  n_envs: 1\n  n_timesteps: 240\n  iterations: 3\n  beta_decay: 0.5\n"
        "  decision_interval: 2\n  decision_mode: pulse\n"
        "  epochs: 2\n  batch_size: 32\n  learning_rate: 1.0e-3\n  expert: {headway_s: 1.2}\n"
        "  policy_kwargs:\n    net_arch: [16]\n"
    )
    kw = {"vehicles_count": 5, "duration": 4}
    summary = train("dagger", TRUTH, None, tmp_path / "run", hyperparams=hp, env_kwargs=kw, progress=False)
    assert summary["algo"] == "dagger" and summary["decisions"] == 120 and summary["timesteps"] == 240
    assert (summary["decision_interval"], summary["decision_mode"]) == (2, "pulse")
    assert [r["beta"] for r in summary["iterations"]] == [1.0, 0.5, 0.25]
    assert summary["iterations"][0]["agreement_before_fit"] is None
    assert all(0.0 <= r["agreement_before_fit"] <= 1.0 for r in summary["iterations"][1:])
    assert summary["expert"]["headway_s"] == 1.2
    meta = policy_metadata(tmp_path / "run" / "model.zip")
    assert meta["algo"] == "dagger" and meta["env_kwargs"] == kw
    assert json.loads((tmp_path / "run" / "iterations.json").read_text())[-1]["samples"] == 120
    rounds = sorted(p.name for p in (tmp_path / "run" / "checkpoints").glob("dagger_round_*.zip"))
    assert rounds == ["dagger_round_00.zip", "dagger_round_01.zip", "dagger_round_02.zip"]
    logged = list((tmp_path / "run").rglob("progress.csv"))
    assert logged and "dagger/agreement_before_fit" in logged[0].read_text().splitlines()[0]
    env = gym.make(TRUTH, **kw)
    policy = load_policy(tmp_path / "run" / "model.zip", env)
    assert (policy.k, policy.fill) == (2, 1)  # decides every 2 steps, IDLE between (pulse)
    obs, _ = env.reset(seed=0)
    action, _ = policy.predict(obs, deterministic=True)
    assert int(action) in range(5) and policy.predict(obs)[0] == 1


def test_dagger_resume_goes_on_from_the_last_finished_round(tmp_path, monkeypatch):
    """A run killed after round 1 of 3 resumes with round 2 only: the saved data, records and beta schedule go on,
    the total decisions are the planned ones; a resume with another budget is refused."""
    from agents.algos import imitation
    from agents.algos.train import train

    hp = tmp_path / "dagger.yml"
    hp.write_text(
        f"{TRUTH}:\n  policy: MlpPolicy\n  n_envs: 1\n  n_timesteps: 240\n  iterations: 3\n  beta_decay: 0.5\n"
        "  decision_interval: 2\n  decision_mode: pulse\n"
        "  epochs: 2\n  batch_size: 32\n  learning_rate: 1.0e-3\n  policy_kwargs:\n    net_arch: [16]\n"
    )
    kw, out = {"vehicles_count": 5, "duration": 4}, tmp_path / "run"
    log_round = imitation.RoundLog.__call__

    def killed_after_round_1(self, record):
        log_round(self, record)
        if record["iteration"] == 1:
            raise KeyboardInterrupt

    monkeypatch.setattr(imitation.RoundLog, "__call__", killed_after_round_1)
    with pytest.raises(KeyboardInterrupt):
        train("dagger", TRUTH, None, out, hyperparams=hp, env_kwargs=kw, progress=False)
    monkeypatch.undo()
    first = json.loads((out / "iterations.json").read_text())
    assert [r["iteration"] for r in first] == [0, 1] and not (out / "model.zip").exists()
    with np.load(out / imitation.STATE_DATA) as z:
        assert len(z["actions"]) == first[-1]["samples"] == 80
    with pytest.raises(ValueError, match="resume"):  # another budget: another schedule
        train("dagger", TRUTH, 200, out, hyperparams=hp, env_kwargs=kw, resume=True, progress=False)
    state = json.loads((out / imitation.STATE_META).read_text())  # round 0 as saved before records kept their time
    del state["records"][0]["wall_s"]
    (out / imitation.STATE_META).write_text(json.dumps(state))
    summary = train("dagger", TRUTH, None, out, hyperparams=hp, env_kwargs=kw, resume=True, progress=False)
    assert summary["resumed_from_round"] == 2 and summary["decisions"] == 120
    assert summary["iterations"][1:2] == first[1:] and summary["iterations"][0]["fit_loss"] == first[0]["fit_loss"]
    # the wall time counts the earlier process's timed rounds too (each record keeps its round's time);
    # steps/s counts only the env steps of timed rounds: 80 decisions x 2 (round 0's 40 were not timed)
    assert summary["untimed_rounds"] == [0] and all(r["wall_s"] > 0 for r in summary["iterations"][1:])
    assert summary["wall_time_s"] >= sum(r["wall_s"] for r in summary["iterations"][1:]) - 0.1
    wall = summary["wall_time_s"]  # rounded to 0.1 s
    assert 160 / (wall + 0.05) <= summary["steps_per_s"] <= 160 / (wall - 0.05)
    assert [r["beta"] for r in summary["iterations"]] == [1.0, 0.5, 0.25]
    assert summary["iterations"][2]["samples"] == 120 and summary["iterations"][2]["agreement_before_fit"] is not None
    assert (out / "model.zip").exists() and len(json.loads((out / "iterations.json").read_text())) == 3


def test_dagger_continuation_starts_from_the_parent_and_counts_its_budget(tmp_path):
    """--init-policy: the student starts with the parent's weights (it agrees with the parent on every state before
    any fit), beta starts at first_beta, and the record adds the parent's env steps to this run's."""
    import torch

    from agents.algos.imitation import load_student
    from agents.algos.train import train

    hp = tmp_path / "dagger.yml"
    base = (f"{TRUTH}:\n  policy: MlpPolicy\n  n_envs: 1\n  n_timesteps: 120\n  iterations: 2\n  beta_decay: 0.5\n"
            "  epochs: 2\n  batch_size: 32\n  learning_rate: 1.0e-3\n  policy_kwargs:\n    net_arch: [16]\n")
    hp.write_text(base)
    kw = {"vehicles_count": 5, "duration": 4}
    train("dagger", TRUTH, None, tmp_path / "parent", hyperparams=hp, env_kwargs=kw, progress=False)
    hp.write_text(base + "  first_beta: 0.2\n")
    child = train("dagger", TRUTH, 60, tmp_path / "child", hyperparams=hp, env_kwargs=kw, progress=False,
                  init_policy=tmp_path / "parent" / "model.zip")
    assert [r["beta"] for r in child["iterations"]] == [0.2, 0.1]
    assert child["iterations"][0]["agreement_before_fit"] is not None  # a trained student is scored in round 0
    assert child["total_timesteps"] == 120 + 60 and child["init_policy"].endswith("model.zip")

    from stable_baselines3 import PPO

    fresh = PPO("MlpPolicy", gym.make(TRUTH, **kw), seed=5, device="cpu", policy_kwargs={"net_arch": [16]})
    assert load_student(fresh, tmp_path / "parent" / "model.zip")["timesteps"] == 120
    parent = PPO.load(tmp_path / "parent" / "model.zip", device="cpu")
    for a, b in zip(fresh.policy.state_dict().values(), parent.policy.state_dict().values()):
        assert torch.equal(a, b)
    wider = PPO("MlpPolicy", gym.make(TRUTH, **kw), device="cpu", policy_kwargs={"net_arch": [32]})
    with pytest.raises(ValueError, match="another network"):
        load_student(wider, tmp_path / "parent" / "model.zip")
    with pytest.raises(FileNotFoundError):
        load_student(wider, tmp_path / "missing.zip")
    with pytest.raises(ValueError, match="init-policy"):
        train("ppo", TRUTH, 64, tmp_path / "ppo", init_policy=tmp_path / "parent" / "model.zip", progress=False)
    with pytest.raises(ValueError, match=r"dagger\.first_beta must be in \[0\.0, 1\.0\]"):
        from rhs_common.validation import build

        build(DaggerConfig, {"first_beta": 2.0}, "dagger")


def test_labels_between_decisions_come_with_the_next_decision_and_add_samples_not_steps(tmp_path):
    """ExpertActionInfo(between=k) inside HoldAction(k): each decision's info carries the k - 1 states passed
    through since the previous decision, each with the expert's action there; DAgger with label_between
    trains on them (k x the samples) while its budget stays the env steps."""
    from agents.algos.imitation import BETWEEN_KEY
    from agents.algos.train import train
    from agents.policies.decision import HoldAction

    kw = {"vehicles_count": 5, "duration": 6}
    env = HoldAction(ExpertActionInfo(gym.make(TRUTH, **kw), between=3), 3, fill=1)
    expert = env.env.driver
    obs, info = env.reset(seed=0)
    obs, _, term, trunc, info = env.step(info[EXPERT_KEY])
    assert len(info[BETWEEN_KEY]) == 2 and all(a in range(5) for _, a in info[BETWEEN_KEY])
    assert info[EXPERT_KEY] == expert.act()  # the returned state's label is the decision's, not in the list
    (first, _), (second, _) = info[BETWEEN_KEY]
    assert not np.array_equal(first, second) and not np.array_equal(second, obs)  # three different states
    hp = tmp_path / "dagger.yml"
    hp.write_text(f"{TRUTH}:\n  policy: MlpPolicy\n  n_envs: 1\n  n_timesteps: 90\n  iterations: 2\n"
                  "  decision_interval: 3\n  decision_mode: pulse\n  label_between: true\n"
                  "  epochs: 1\n  batch_size: 32\n  policy_kwargs:\n    net_arch: [16]\n")
    summary = train("dagger", TRUTH, None, tmp_path / "run", hyperparams=hp, env_kwargs=kw, progress=False)
    last = summary["iterations"][-1]
    assert summary["timesteps"] == 90 and last["decisions"] == 30
    assert 30 < last["samples"] <= 90  # an episode cut short by a crash has fewer states between
    with pytest.raises(TypeError, match="label_between"):
        DaggerConfig(label_between="yes")


class _Sets(gym.Env):
    """A point set and a pose (and, with ``velocity``, a third Box key): what a student's extractor reads."""

    def __init__(self, velocity: bool = False, drop_pose: bool = False):
        keys = {"points": gym.spaces.Box(-50.0, 50.0, (8, 7), np.float32), "points_mask": gym.spaces.MultiBinary(8)}
        if not drop_pose:
            keys["pose"] = gym.spaces.Box(-1e5, 1e5, (3,), np.float32)
        keys["pose_std"] = gym.spaces.Box(0.0, 1e5, (3,), np.float32)
        if velocity:
            keys["velocity"] = gym.spaces.Box(-1e5, 1e5, (3,), np.float32)
        self.observation_space = gym.spaces.Dict(keys)
        self.action_space = gym.spaces.Discrete(5)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return self.observation_space.sample(), {}

    def step(self, action):
        return self.observation_space.sample(), 0.0, False, False, {}


def test_a_student_continues_onto_an_added_box_key_as_the_same_function(tmp_path):
    """``velocity_in_obs``: the parent's weights, zero on the new key's columns: the same logits whatever it holds."""
    import torch
    from stable_baselines3 import PPO

    from agents.algos.imitation import load_student
    from agents.policies.features import PointSetExtractor

    kw = {"features_extractor_class": PointSetExtractor, "features_extractor_kwargs": {"point_dim": 8, "box_dim": 4},
          "net_arch": [8]}
    parent = PPO("MultiInputPolicy", _Sets(), seed=1, device="cpu", policy_kwargs=kw, n_steps=16, batch_size=16)
    parent.save(tmp_path / "parent.zip")
    child = PPO("MultiInputPolicy", _Sets(velocity=True), seed=2, device="cpu", policy_kwargs=kw, n_steps=16,
                batch_size=16)
    load_student(child, tmp_path / "parent.zip")
    space = child.observation_space
    space.seed(0)
    for _ in range(4):
        obs = space.sample()
        old = {k: v for k, v in obs.items() if k != "velocity"}
        with torch.no_grad():
            a = child.policy.get_distribution(child.policy.obs_to_tensor(obs)[0]).distribution.logits
            b = parent.policy.get_distribution(parent.policy.obs_to_tensor(old)[0]).distribution.logits
        assert torch.allclose(a, b, atol=1e-6)
    w = child.policy.state_dict()["features_extractor.box_net.0.weight"]
    assert w.shape == (4, 2 + 3 + 3) and torch.all(w[:, 5:] == 0) and torch.any(w[:, :5] != 0)  # pose: y, heading
    dropped = PPO("MultiInputPolicy", _Sets(velocity=True, drop_pose=True), device="cpu", policy_kwargs=kw,
                  n_steps=16, batch_size=16)
    with pytest.raises(ValueError, match="another observation space"):
        load_student(dropped, tmp_path / "parent.zip")
    flat = PPO("MlpPolicy", gym.make("CartPole-v1"), device="cpu", n_steps=16, batch_size=16)
    with pytest.raises(ValueError, match="another observation space"):
        load_student(flat, tmp_path / "parent.zip")
    combined = PPO("MultiInputPolicy", _Sets(velocity=True), device="cpu", n_steps=16, batch_size=16)
    with pytest.raises(ValueError, match="another observation space"):  # SB3's extractor: no box_net to widen
        load_student(combined, tmp_path / "parent.zip")


def test_dagger_under_the_shield_drives_through_it_and_saves_it(tmp_path):
    """``shield`` in the YAML: every collected step goes through the radar shield (its info key is there), the
    labels stay the teacher's, and the record keeps the full shield so evaluation drives the student behind it."""
    from agents.algos.imitation import labelled_env
    from agents.algos.train import train
    from agents.policies.shield import ShieldAction, ShieldedPolicy

    radar = "rhs-highway-radar-v0"
    kw = {"vehicles_count": 5, "duration": 4}
    env = labelled_env(gym.make(radar, **kw), shield={"front_time_s": 1.5})
    assert isinstance(env, ExpertActionInfo) and isinstance(env.env, ShieldAction)
    env.reset(seed=0)
    _, _, _, _, info = env.step(FASTER)
    assert "shield" in info and info[EXPERT_KEY] in range(5)
    assert not isinstance(labelled_env(gym.make(TRUTH, **kw)).env, ShieldAction)  # no shield entry: none

    hp = tmp_path / "dagger.yml"
    base = (f"{radar}:\n  policy: MultiInputPolicy\n  n_envs: 1\n  n_timesteps: 40\n  iterations: 2\n"
            "  epochs: 1\n  batch_size: 16\n  policy_kwargs:\n    net_arch: [8]\n")
    hp.write_text(base + "  shield: {front_time_s: 1.5}\n")
    summary = train("dagger", radar, None, tmp_path / "run", hyperparams=hp, env_kwargs=kw, progress=False)
    assert summary["shield"]["front_time_s"] == 1.5 and summary["shield"]["min_points"] == 2  # the full record
    assert isinstance(load_policy(tmp_path / "run" / "model.zip", gym.make(radar, **kw)), ShieldedPolicy)
    hp.write_text(base + "  shield: {front_time_s: -1.0}\n")
    with pytest.raises(ValueError, match="shield.front_time_s"):
        train("dagger", radar, None, tmp_path / "bad", hyperparams=hp, env_kwargs=kw, progress=False)
    hp.write_text(base.replace(radar, TRUTH).replace("MultiInputPolicy", "MlpPolicy") + "  shield: {}\n")
    with pytest.raises(ValueError, match="points"):
        train("dagger", TRUTH, None, tmp_path / "truth", hyperparams=hp, env_kwargs=kw, progress=False)
    assert not (tmp_path / "truth").exists()  # refused with the settings, before any env or folder is made
