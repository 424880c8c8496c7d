"""The shield table (rhs_studies.driving.shield_table): fresh seeds only, the override rates, the paired collisions
prevented / caused, the sim-to-sim gap, the training-seed statistics (synthetic episodes; one tiny drive)."""

import pytest

from rhs_studies.driving import shield_table as st


def _ep(seed, ret, crashed, overrides=None, steps=10):
    return {"seed": seed, "return": ret, "crashed": crashed, "steps": steps, "mean_speed": 20.0,
            "overrides": overrides}


def test_the_ledger_refuses_driven_seeds():
    assert st.test_seeds(21000, 10) == list(range(21000, 21010))  # its own set: may be driven again
    for first in (20000, 1000, 6050, 1_000_000):  # the campaign's validation, the policies table, a test set, training
        with pytest.raises(ValueError, match="overlap seeds already used"):
            st.test_seeds(first, 5)
    with pytest.raises(ValueError, match="campaign_validation"):
        st.test_seeds(20095, 10)  # a set that ends in the validation seeds
    assert st.test_seeds(9000, 3) == [9000, 9001, 9002]


def test_override_rates_and_paired_shield_effect():
    off = [_ep(0, 10.0, True), _ep(1, 20.0, False), _ep(2, 30.0, False)]
    on = [_ep(0, 15.0, False, {"front": 2, "faster": 0, "lane": 1}),
          _ep(1, 18.0, True, {"front": 0, "faster": 0, "lane": 0}),
          _ep(2, 30.0, False, {"front": 0, "faster": 1, "lane": 0})]
    s = st.summarize_arm(on)
    assert s["override_rate_step"] == pytest.approx(4 / 30)
    assert s["override_rate_episode"] == pytest.approx(2 / 3)
    assert s["overrides"] == {"front": 2, "faster": 1, "lane": 1}
    assert "override_rate_step" not in st.summarize_arm(off)
    t = st.table({"a": {"exact": {"off": off, "on": on}, "fast": {"off": off, "on": on}}})
    eff = t["a"]["exact"]["shield_effect"]
    assert eff["collisions_prevented"] == 1 and eff["collisions_caused"] == 1
    assert eff["return_gain"] == pytest.approx(1.0)
    assert eff["interval"][0] <= 1.0 <= eff["interval"][1]
    assert t["a"]["sim_to_sim"]["off"]["return_diff"] == 0.0
    with pytest.raises(ValueError, match="no seed in common"):
        st.paired(off, [_ep(9, 1.0, False)])


def test_training_seed_statistics_normalise_by_idm():
    idm = [_ep(s, 10.0, False) for s in range(4)]
    eps = {"idm": {"exact": {"off": idm}}}
    for k, scale in enumerate((0.9, 1.0, 1.2)):
        eps[f"campaign:r:seed{k}"] = {"exact": {"off": [_ep(s, 10.0 * scale, False) for s in range(4)]}}
    out = st.training_seed_stats(eps, "r", "exact", "off", reps=100)
    assert out["iqm"]["value"] == pytest.approx((0.9 + 4 * 1.0 + 1.2) / 6)  # 12 scores: 3 cut each end
    assert out["scores"][2] == [1.2] * 4
    assert st.training_seed_stats({"idm": eps["idm"]}, "r", "exact", "off") is None


def test_arms_resolve_and_a_tiny_drive(tmp_path):
    assert st.arm_policy("idm") == "idm"
    with pytest.raises(FileNotFoundError, match="train the run first"):
        st.arm_policy("campaign:ppo_scratch:seed7", tmp_path)
    with pytest.raises(ValueError, match="campaign:<recipe>"):
        st.arm_policy("campaign:x", tmp_path)
    kw = {"action": {"type": "DiscreteMetaAction", "target_speeds": [10, 15, 20, 25, 30]}, "duration": 2}
    eps = st.drive_all(["constant:3", "idm"], ["fast"], [21000], kw, log=lambda s: None)
    assert set(eps["constant:3"]["fast"]) == {"off", "on"} and set(eps["idm"]["fast"]) == {"off"}
    assert eps["constant:3"]["fast"]["on"][0]["overrides"] is not None
    assert eps["constant:3"]["fast"]["off"][0]["overrides"] is None


def test_merge_takes_only_the_same_seeds_and_settings(tmp_path):
    import json

    kw = {"duration": 2}
    (tmp_path / "a.json").write_text(json.dumps({"seeds": [21000], "env_kwargs": kw,
                                                 "episodes": {"idm": {"exact": {"off": [_ep(21000, 1.0, False)]}}}}))
    assert list(st._merged([tmp_path / "a.json"], [21000], kw)) == ["idm"]
    with pytest.raises(ValueError, match="other seeds or env settings"):
        st._merged([tmp_path / "a.json"], [21000, 21001], kw)
