"""The driving results, one page per study: each page opens with its "how to reproduce" line, the index and the
site's nav list every page, and the line is built from the reproduce step it names."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from rhs_studies import reproduce
from rhs_studies.upkeep import write_results_pages

ROOT = Path(__file__).resolve().parent.parent
DRIVING = ROOT / "docs" / "results" / "driving"


def _pages() -> list[Path]:
    return sorted(DRIVING.glob("*.md"))


def test_every_driving_page_opens_with_a_command_that_exists():
    assert len(_pages()) >= 8
    for page in _pages():
        text = page.read_text()
        head = text[:1500]
        assert "**How to reproduce:**" in head, f"{page.name}: no 'How to reproduce' line near its top"
        line = head[head.index("**How to reproduce:**"):].split("\n")[0]
        scripts = re.findall(r"`python (scripts/\w+\.py)", line)
        assert scripts and all((ROOT / s).is_file() for s in scripts), f"{page.name}: {line}"
        for step in re.findall(r"--only (\w+)", line):
            assert step in reproduce.BY_NAME, f"{page.name}: no reproduce step {step}"


def test_the_index_and_the_nav_list_every_page_in_order():
    index = (ROOT / "docs" / "results" / "driving.md").read_text()
    linked = re.findall(r"\]\(driving/([\w-]+\.md)\)", index)
    assert sorted(linked) == sorted(p.name for p in _pages()) and len(linked) == len(set(linked))
    nav = yaml.safe_load("nav:\n" + (ROOT / "mkdocs.yml").read_text().split("\nnav:\n", 1)[1])  # the nav alone
    results = next(item["Results"] for item in nav["nav"] if "Results" in item)
    driving = next(item["Driving"] for item in results if "Driving" in item)
    assert [next(iter(x.values())) for x in driving] == ["results/driving.md", *(f"results/driving/{n}" for n in linked)]
    # the old sections' anchors still resolve on the index (links recorded elsewhere name them)
    for anchor in ("a-radar-safety-shield", "a-fresh-test-of-the-rl-stage", "what-limits-learning",
                   "a-stricter-lane-rule-and-the-shipped-rl-policy", "crash-analysis", "a-teacher-that-looks-ahead",
                   "reinforcement-learning-on-top-of-imitation"):
        assert f'id="{anchor}"' in index, anchor


def test_a_reproduce_block_is_filled_from_its_step_and_an_unknown_step_is_refused(tmp_path):
    text = "x\n<!-- results:reproduce.policies -->\nstale\n<!-- /results:reproduce.policies -->\n"
    out = write_results_pages.render(text, ROOT / "results", DRIVING / "policies.md")
    step = reproduce.BY_NAME["policies"]
    assert f"`python scripts/reproduce.py --only policies` (it runs `python scripts/{step.script}`" in out
    assert "stale" not in out and "`results/policies.json`" in out
    with pytest.raises(ValueError, match="no step 'nope'"):
        write_results_pages.render(text.replace("policies", "nope"), ROOT / "results")
    # the README's headline rows link the study's own page
    assert all(Path(ROOT / p).is_file() for p in write_results_pages.PAGE.values())


def test_the_campaign_row_reads_the_test_shield_off_and_waits_for_the_runs():
    from rhs_studies.driving import shield_table as st

    def ep(seed, ret, crashed):
        return {"seed": seed, "return": ret, "crashed": crashed, "steps": 10, "mean_speed": 20.0, "overrides": None}

    eps = {"idm": {"exact": {"off": [ep(0, 100.0, False), ep(1, 100.0, False)]}}}
    d = {"table": st.table(eps), "policies": {}, "training_seeds": {"exact_off": None}}
    assert write_results_pages._campaign_test(d) is None  # the runs have not joined the table
    for k, ret in enumerate((104.0, 108.0)):
        eps[f"campaign:ppo_scratch:seed{k}"] = {"exact": {"off": [ep(0, ret, k == 0), ep(1, ret, False)],
                                                          "on": [ep(0, ret + 1, False), ep(1, ret + 1, False)]}}
    d = {"table": st.table(eps), "training_seeds": {"exact_off": None},
         "policies": {"campaign:ppo_scratch:seed0": {"timesteps": 2_000_000},
                      "campaign:ppo_scratch:seed1": {"timesteps": 2_010_000}}}
    what, value = write_results_pages._campaign_test(d)
    assert "2 training seeds; checkpoints at 2.00-2.01M env steps" in what and "shield off" in what
    assert value == ("1.040 x / 1.080 x, 1/2 / 0/2: target not met (IDM + MOBIL: 100.0, 0/2; behind the shield: "
                     "1.050 x / 1.090 x, 0/2 / 0/2)")
    eps["campaign:ppo_scratch:seed0"]["exact"]["off"][0]["crashed"] = False  # both >= 1.05 x (seed 0 not: 1.04 x)
    assert "target not met" in write_results_pages._campaign_test({**d, "table": st.table(eps)})[1]
    for k in (0, 1):
        for e in eps[f"campaign:ppo_scratch:seed{k}"]["exact"]["off"]:
            e["return"] = 106.0
    assert "target met" in write_results_pages._campaign_test({**d, "table": st.table(eps)})[1]


def test_the_imitation_rl_row_holds_speed_the_pairing_and_whether_the_shipped_policy_needs_its_shield():
    from rhs_studies.driving import shield_table as st

    def ep(seed, ret, crashed, speed=25.0):
        return {"seed": seed, "return": ret, "crashed": crashed, "steps": 10, "mean_speed": speed, "overrides": None}

    start = "agents/data/dagger_rhs_highway_slam.zip"
    eps = {"idm": {"exact": {"off": [ep(0, 100.0, False), ep(1, 100.0, False)]}},
           start: {"exact": {"off": [ep(0, 105.0, False), ep(1, 105.0, False)]}}}
    d = {"table": st.table(eps), "policies": {}, "versus": {"reference": start}}
    assert write_results_pages._campaign_student(d) is None  # the runs have not joined the table
    eps["campaign:ppo_student:seed0"] = {"exact": {"off": [ep(0, 112.0, False), ep(1, 112.0, False)],
                                                   "on": [ep(0, 113.0, False), ep(1, 113.0, False)]}}
    eps["agents/data/shipped.zip"] = {"exact": {"off": [ep(0, 80.0, True), ep(1, 90.0, False)],
                                                "on": [ep(0, 110.0, False), ep(1, 110.0, False)]}}
    d = {"table": st.table(eps), "policies": {"campaign:ppo_student:seed0": {"timesteps": 2_000_000}},
         "versus": {"reference": start,
                    "exact_off": {"pooled": {"runs": 1, "seeds": 2, "return_diff": 7.0, "interval": [7.0, 7.0]}}}}
    what, value = write_results_pages._campaign_student(d)
    assert "1 training seeds; checkpoints at 2.00-2.00M env steps" in what and ">= 24 m/s" in what
    assert value.startswith("1.120 x, 0/2, 25.0 m/s: target met; over its start, pooled: +7.0 [+7.0, +7.0]")
    assert "the shipped policy, which needs its shield: shield off 0.850 x, 1/2, behind it 1.100 x, 0/2" in value
    eps["campaign:ppo_student:seed0"]["exact"]["off"][0]["mean_speed"] = 22.0  # below 24 m/s: not met
    assert "target not met" in write_results_pages._campaign_student({**d, "table": st.table(eps)})[1]
