"""``rhs-slam record`` writes a Minari dataset that ``minari.load_dataset`` reads back, with its documented schema;
``scripts/bc_from_dataset.py`` clones a policy from it."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

minari = pytest.importorskip("minari", reason="minari needs Python >= 3.11 (the dataset extra)")

from agents import record  # noqa: E402
from rhs_slam.cli import main  # noqa: E402

SMALL = {"radar": {"scan": {"grid_deg": 5}}, "duration": 2, "max_episode_steps": 6}
DATASET_ID = "rhs-slam/highway-slam/headway-v0"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Two short episodes of the headway expert on rhs-highway-slam-v0, in a temporary Minari folder."""
    root = tmp_path_factory.mktemp("minari")
    old = os.environ.get("MINARI_DATASETS_PATH")
    args = ["record", "--policy", "headway", "--episodes", "2", "--seed", "3", "--reference-episodes", "1",
            "--env-kwargs", json.dumps(SMALL), "--out", str(root)]
    try:
        code = main(args)
        assert code == 0
        os.environ["MINARI_DATASETS_PATH"] = str(root)
        yield root, minari.load_dataset(DATASET_ID)
    finally:
        if old is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old


def test_the_dataset_loads_with_minari_and_has_the_two_episodes(recorded):
    _, ds = recorded
    assert ds.total_episodes == 2 and ds.total_steps == 12  # max_episode_steps 6 truncates each
    episodes = list(ds.iterate_episodes())
    assert [len(e.actions) for e in episodes] == [6, 6]
    assert all(bool(e.truncations[-1]) and not e.terminations.any() for e in episodes)
    import rhs_env  # noqa: F401

    env = ds.recover_environment()
    try:
        assert env.observation_space == ds.observation_space
        assert set(episodes[0].observations) == set(env.observation_space.spaces)
        obs, _ = env.reset(seed=3)  # the first episode's seed replays its first observation
        np.testing.assert_array_equal(obs["points"], episodes[0].observations["points"][0])
    finally:
        env.close()


def test_the_infos_follow_the_schema(recorded):
    _, ds = recorded
    ep = next(ds.iterate_episodes())
    n = len(ep.actions) + 1
    info = ep.infos
    expected = {"expert_action": (n,), "kinematics": (n, record.KINEMATICS_VEHICLES, len(record.KINEMATICS_FEATURES)),
                "world_pose": (n, 3), "crashed": (n,), "speed": (n,), "points_cov": (n, 256, 2, 2),
                "true_pose": (n, 3), "slam_pose_cov": (n, 3, 3), "slam_pose_std": (n, 3), "slam_health": (n,),
                "slam_lost": (n,), "position_error_m": (n,)}
    assert {k: v.shape for k, v in info.items()} == expected
    # the expert drove: every action is the label of the state it was taken in (a label one step off would differ)
    np.testing.assert_array_equal(ep.actions, info["expert_action"][:-1])
    assert set(np.unique(info["expert_action"])) <= set(range(5))
    # the Kinematics table: the ego first, present, absolute, at its own speed
    assert (info["kinematics"][:, 0, 0] == 1).all()
    np.testing.assert_allclose(np.hypot(info["kinematics"][:, 0, 3], info["kinematics"][:, 0, 4]), info["speed"], rtol=1e-5)
    # per-point covariance: symmetric, positive on the real points, zero on the padding
    mask = ep.observations["points_mask"] > 0
    cov = info["points_cov"]
    assert mask.any() and not mask.all()
    np.testing.assert_array_equal(cov, np.swapaxes(cov, -1, -2))
    assert (np.linalg.eigvalsh(cov[mask].astype(float)) > 0).all() and (cov[~mask] == 0).all()
    # the SLAM pose of the observation and its covariance in info
    np.testing.assert_allclose(np.sqrt(np.diagonal(info["slam_pose_cov"], axis1=1, axis2=2))[:, :2],
                               info["slam_pose_std"][:, :2], rtol=1e-4, atol=1e-6)


def test_the_reference_scores_normalise_returns(recorded):
    _, ds = recorded
    meta = ds.storage.metadata
    assert {"ref_min_score", "ref_max_score"} <= set(meta) and meta["num_episodes_average_score"] == 1
    lo, hi = meta["ref_min_score"], meta["ref_max_score"]
    np.testing.assert_allclose(minari.get_normalized_score(ds, np.array([lo, hi])), [0.0, 1.0])


def test_an_existing_dataset_and_bad_flags_are_clean_errors(recorded, capsys):
    root, _ = recorded
    assert main(["record", "--policy", "headway", "--episodes", "1", "--out", str(root)]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["record", "--episodes", "0", "--out", str(root)]) == 2
    assert "--episodes must be in [1, 100000]" in capsys.readouterr().err
    assert main(["record", "--dataset-id", "no version", "--out", str(root)]) == 2
    assert "--dataset-id" in capsys.readouterr().err


def test_default_ids():
    assert record.default_dataset_id("rhs-highway-slam-v0", "agents/data/x.zip") == "rhs-slam/highway-slam/x-v0"
    assert record.default_dataset_id("rhs_env:rhs-paper-v0", "constant:4") == "rhs-slam/paper/constant_4-v0"


def test_behaviour_cloning_from_the_dataset(recorded, tmp_path):
    from agents.evaluate import load_policy, make_env, resolve_env
    from rhs_studies import bc_from_dataset

    _, ds = recorded
    obs, y = bc_from_dataset.load_samples(ds)
    assert len(y) == 12 and obs["points"].shape == (12, 256, 7)
    _, summary = bc_from_dataset.clone(ds, tmp_path, epochs=30)
    assert summary["samples"] == 12 and summary["env_id"] == "rhs-highway-slam-v0"
    assert summary["train_agreement"] > 0.5  # 30 passes over 12 samples fit most of them
    env_id, kwargs = resolve_env(tmp_path / "model.zip")
    env = make_env(env_id, kwargs)
    try:
        policy = load_policy(tmp_path / "model.zip", env)  # checks the spaces against the env
        o, _ = env.reset(seed=0)
        assert int(policy.predict(o)[0]) in range(5)
    finally:
        env.close()


def test_decision_labels_take_every_kth_recorded_action(recorded):
    from rhs_studies import bc_from_dataset

    _, ds = recorded
    ep = next(ds.iterate_episodes())
    rows, y = bc_from_dataset.label_rows(ep, "decisions", 5)
    assert rows.tolist() == [0, 5] and y.tolist() == np.asarray(ep.actions).reshape(-1)[[0, 5]].tolist()
    obs, y_all = bc_from_dataset.load_samples([ds, ds], "decisions", 5)
    assert len(y_all) == 8 and obs["points"].shape == (8, 256, 7)  # 2 datasets x 2 episodes x rows 0 and 5
    with pytest.raises(ValueError, match="decision interval"):
        bc_from_dataset.load_samples(ds, "decisions", 0)


def test_paired_ratio_interval():
    from rhs_studies.bc_from_dataset import paired_ratio

    a, b = [10.0, 20.0, 30.0, 40.0], [10.0, 21.0, 29.0, 41.0]
    r = paired_ratio(a, b)
    assert r["ratio"] == pytest.approx(100 / 101) and r["low"] <= r["ratio"] <= r["high"] and r["n"] == 4
    assert r["high"] - r["low"] < 0.1  # paired: the seeds' shared spread cancels
    with pytest.raises(ValueError, match="paired"):
        paired_ratio([1.0], [1.0])


def test_clone_like_a_policy_compared_on_paired_seeds(recorded, tmp_path, capsys):
    """--labels decisions --like (the shipped policy's interval, mode and shield) --compare, --results with
    provenance and its Markdown table; the compared runs are cached and reused."""
    from agents.evaluate import SHIPPED_POLICY, policy_metadata
    from rhs_studies import bc_from_dataset

    root, _ = recorded
    out, res = tmp_path / "bc", tmp_path / "bc.json"
    argv = ["--dataset-id", DATASET_ID, "--datasets", str(root), "--out", str(out), "--labels", "decisions",
            "--like", str(SHIPPED_POLICY), "--epochs", "2", "--eval-episodes", "2", "--eval-seed", "900",
            "--compare", "headway", "--results", str(res)]
    assert bc_from_dataset.main(argv) == 0
    summary = json.loads(res.read_text())
    shipped = policy_metadata(SHIPPED_POLICY)
    assert summary["decision_interval"] == shipped["decision_interval"] and summary["shield"] == shipped["shield"]
    assert summary["samples"] == 4 and summary["label_every"] == 5
    cmp_ = summary["comparison"]
    assert cmp_["ratio"]["n"] == 2 and [r["seed"] for r in summary["compare"]["runs"]] == [900, 901]
    assert "commit" in json.dumps(summary["provenance"]) and res.with_suffix(".md").read_text().count("|") > 6
    cached = (out / "compare_runs.json").stat().st_mtime
    assert bc_from_dataset.main(["--compare-only", *argv[:-2]]) == 0
    assert (out / "compare_runs.json").stat().st_mtime == cached  # same policy, env and seeds: reused
    assert bc_from_dataset.main([*argv[:-2], "--eval-episodes", "1"]) == 2
    assert "--eval-episodes >= 2" in capsys.readouterr().err


def test_ctrl_c_keeps_the_finished_episodes(tmp_path, monkeypatch, capsys):
    """Interrupted in the second episode, the first is written (without reference scores) and the exit is 130."""
    calls = []
    real = record.record_episode

    def interrupted_second(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(record, "record_episode", interrupted_second)
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    code = main(["record", "--policy", "headway", "--episodes", "3", "--env-kwargs", json.dumps(SMALL),
                 "--out", str(tmp_path)])
    assert code == 130
    summary = json.loads(capsys.readouterr().out)
    assert summary["interrupted"] == "SIGINT" and summary["episodes"] == 1 and summary["seeds"] == [0]
    ds = minari.load_dataset(DATASET_ID)
    assert ds.total_episodes == 1 and "ref_min_score" not in ds.storage.metadata


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT ignored by the shell"])
def test_a_signal_keeps_the_finished_episodes(sig, tmp_path, monkeypatch, capsys):
    """SIGTERM (kill, a scheduler), and SIGINT where a background job started with it ignored: the first episode
    is written and the exit is 128 + the signal number."""
    import signal

    signum = signal.SIGTERM if sig == "SIGTERM" else signal.SIGINT
    calls = []
    real = record.record_episode

    def signalled_second(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            os.kill(os.getpid(), signum)
        return real(*args, **kwargs)

    monkeypatch.setattr(record, "record_episode", signalled_second)
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    old = signal.signal(signal.SIGINT, signal.SIG_IGN) if signum == signal.SIGINT else None
    try:
        code = main(["record", "--policy", "headway", "--episodes", "3", "--env-kwargs", json.dumps(SMALL),
                     "--out", str(tmp_path)])
    finally:
        if old is not None:
            signal.signal(signal.SIGINT, old)
    assert code == 128 + int(signum)
    summary = json.loads(capsys.readouterr().out)
    assert summary["interrupted"] == signum.name and summary["episodes"] == 1 and summary["seeds"] == [0]
    assert minari.load_dataset(DATASET_ID).total_episodes == 1
