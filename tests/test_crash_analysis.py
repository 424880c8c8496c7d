"""scripts/crash_analysis.py: frames, the hazard's points and the crash categories."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from rhs_studies import crash_analysis as ca


def test_ego_frame_puts_highway_left_on_positive_y():
    # highway-env: x along the road, y to the right (lanes numbered left to right)
    ego = SimpleNamespace(position=np.array([100.0, 4.0]), heading=0.0)
    xy, heading = ca.ego_frame(ego, np.array([106.5, 0.0]), 0.0)  # 6.5 m ahead, one lane to the left
    assert xy == pytest.approx([6.5, 4.0])
    assert heading == pytest.approx(0.0)
    ego_turned = SimpleNamespace(position=np.zeros(2), heading=np.pi / 2)  # driving along +y (to the right)
    xy, _ = ca.ego_frame(ego_turned, np.array([0.0, 10.0]), np.pi / 2)
    assert xy == pytest.approx([10.0, 0.0], abs=1e-12)


def test_points_in_box_counts_the_grown_oriented_outline():
    centre = np.array([10.0, 3.0])
    pts = np.array([[10.0, 3.0], [12.4, 3.9], [13.4, 3.0], [14.0, 3.0], [10.0, 4.9], [10.0, 5.1]])
    assert ca.points_in_box(pts, centre, 0.0, 5.0, 2.0, 0.0) == 2  # centre and (12.4, 3.9)
    assert ca.points_in_box(pts, centre, 0.0, 5.0, 2.0, 1.0) == 4  # + (13.4, 3) and (10, 4.9)
    # rotated 90 deg: the 5 m side runs along y
    assert ca.points_in_box(np.array([[10.0, 5.4], [12.4, 3.0]]), centre, np.pi / 2, 5.0, 2.0, 0.0) == 1


@pytest.mark.parametrize(("student", "expert", "points", "expected"), [
    ("LANE_LEFT", "LANE_LEFT", 0, "expert too"),
    ("LANE_LEFT", "SLOWER", 3, "seen, student disagreed"),
    ("FASTER", "IDLE", 0, "not seen"),
    ("FASTER", "IDLE", None, "not seen"),
])
def test_category(student, expert, points, expected):
    assert ca.category({"student": student, "expert": expert, "hazard_points": points}) == expected


def test_summary_and_markdown():
    crash = {"decision_step": 85, "student": "LANE_LEFT", "expert": "SLOWER", "hit_found": True,
             "student_window": ["IDLE", "LANE_LEFT"], "expert_window": ["IDLE", "SLOWER"],
             "hazard_xy": [6.5, 4.0], "hazard_points": 2, "category": "seen, student disagreed"}
    runs = [{"seed": 2000, "crashed": False, "agreement": 0.9},
            {"seed": 2001, "crashed": True, "agreement": 0.7, "crash": crash}]
    s = ca.summarize(runs)
    assert s["collisions"] == 1 and s["categories"]["seen, student disagreed"] == 1
    assert s["agreement"] == pytest.approx(0.8) and s["agreement_crash_episodes"] == pytest.approx(0.7)
    clean = [{"seed": 2000, "crashed": False, "agreement": 0.95}, {"seed": 2001, "crashed": False, "agreement": 0.9}]
    md = ca.markdown({"seed_starts": [2000], "episodes": 2, "margin_m": 1.0, "window": 2,
                      "policies": [{"policy": "p.zip", "timesteps": 40000, "summary": s, "runs": runs},
                                   {"policy": "q.zip", "timesteps": None, "summary": ca.summarize(clean), "runs": clean}]})
    assert "| `p.zip` | 40000 | 1/2 | 1/2 | - | 80.0 % (70.0 %) | 1 / 0 / 0 |" in md
    assert "| `q.zip` | - | 0/2 | 0/2 | 1.000 | 92.5 % | 0 / 0 / 0 |" in md
    assert "| p (40000) | 2001 | IDLE, LANE_LEFT | IDLE, SLOWER | 85 | (6.5, 4.0) | 2 | seen, student disagreed |" in md
    assert "the expert: the headway driver" not in md
    faster = ca.markdown({"seed_starts": [2000], "episodes": 2, "margin_m": 1.0, "window": 2,
                          "expert": {"cruise_speed_mps": 30.0}, "policies": [{"policy": "q.zip", "timesteps": None,
                                                                               "summary": ca.summarize(clean), "runs": clean}]})
    assert 'the expert: the headway driver with {"cruise_speed_mps": 30.0}.' in faster


def test_expert_settings_reach_the_labelling_driver(monkeypatch, tmp_path):
    seen = []
    monkeypatch.setattr(ca, "run_seeds", lambda policy, seeds, margin, window, workers, expert=None: seen.append(expert) or [])
    monkeypatch.setattr(ca, "write_json", lambda out, result, *a: None)
    monkeypatch.setattr(ca, "markdown", lambda result: "")
    monkeypatch.setattr(ca, "summarize", lambda runs: {})
    ca.main(["--policy", __file__, "--episodes", "1", "--expert", '{"cruise_speed_mps": 30, "margin_mps": 1}',
             "--out", str(tmp_path / "crash.json")])
    assert seen == [{"cruise_speed_mps": 30, "margin_mps": 1}]


def test_fisher_p_separates_9_from_1_in_100():
    a, b = {"collisions": 9, "episodes": 100}, {"collisions": 1, "episodes": 100}
    assert ca.fisher_p(a, b) == pytest.approx(0.0183, abs=5e-4)
    assert ca.fisher_p(a, a) == pytest.approx(1.0)


def test_run_seeds_labels_with_a_headway_driver_of_those_settings(monkeypatch):
    """run_seeds -> _chunk -> HeadwayDriver(env, expert): the settings reach the driver that labels the decisions."""
    import agents.evaluate
    import agents.policies.expert

    class Env:
        def close(self):
            pass

    made = []
    monkeypatch.setattr(agents.evaluate, "resolve_env", lambda policy, env_id, kwargs: ("rhs-highway-slam-v0", {}))
    monkeypatch.setattr(agents.evaluate, "make_env", lambda env_id, kwargs: Env())
    monkeypatch.setattr(agents.evaluate, "load_policy", lambda policy, env, seed: SimpleNamespace())
    monkeypatch.setattr(agents.policies.expert, "HeadwayDriver", lambda env, config=None: made.append(config) or "driver")
    monkeypatch.setattr(ca, "run_labelled", lambda env, labelled, seed, margin, window: {"seed": seed,
                                                                                       "expert": labelled.expert})
    runs = ca.run_seeds("p.zip", [7, 8], 1.0, 3, 1, {"cruise_speed_mps": 30})
    assert made == [{"cruise_speed_mps": 30}] and [r["seed"] for r in runs] == [7, 8]
    made.clear()
    ca.run_seeds("p.zip", [7], 1.0, 3, 1)
    assert made == [None]  # the driver's defaults
