"""The claim study (scripts/claim_study.py): its statistics, bounds and antenna physics, and a small end-to-end run."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rhs_env.antenna_factory import make_antenna
from rhs_env.point_cloud import angle_crb
from rhs_studies import claim_study as cs


def test_group_crb_reduces_to_the_single_target_crb_and_grows_as_targets_close_in():
    ant = make_antenna("phased")
    rng = np.random.default_rng(0)
    th = np.deg2rad([7.0])
    assert cs.group_crb(ant, th, 50.0, 8, rng)[0] == pytest.approx(float(angle_crb(ant, th, 50.0)[0]), rel=1e-5)
    single = float(angle_crb(ant, np.deg2rad([0.0]), 50.0)[0])
    far = cs.group_crb(ant, np.deg2rad([-20.0, 20.0]), 50.0, 64, rng)
    near = cs.group_crb(ant, np.deg2rad([-1.0, 1.0]), 50.0, 64, rng)
    assert far.mean() < 3 * single  # well apart: close to the single-target bound
    assert near.mean() > 10 * far.mean()  # inside one phased beam the pair is ill-conditioned


def test_antenna_properties_show_the_aperture_trade():
    rhs = cs.antenna_properties(make_antenna("rhs"), 90.0)
    pa = cs.antenna_properties(make_antenna("phased"), 90.0)
    # a 10-element lambda/2 array, uniform weights: -3 dB two-way beamwidth ~ 0.64 * 2/(N) rad ~ 7-8 deg
    assert 6.5 < pa["beamwidth_3db_deg"] < 9.5
    assert pa["beamwidth_3db_deg"] / rhs["beamwidth_3db_deg"] > 2.5
    assert pa["crb_deg_at_0db"] / rhs["crb_deg_at_0db"] > 2.5
    assert pa["peak_gain_db"] == pytest.approx(20.0, abs=0.05)  # N^2 = 100, two-way, power-normalised
    assert rhs["peak_gain_db"] > pa["peak_gain_db"]
    assert abs(rhs["swept_energy_db"] - pa["swept_energy_db"]) < 2.0  # no detection advantage
    assert pa["pslr_median_db"] == pytest.approx(-26.5, abs=1.0)  # uniform array: -13.26 dB one-way, twice


def test_ospa():
    c = 5.0
    assert cs.ospa(np.array([1.0, 2.0]), np.array([2.0, 1.0]), c) == 0.0
    assert cs.ospa(np.array([1.0, 2.0]), np.array([]), c) == c
    assert cs.ospa(np.array([0.0, 3.0]), np.array([1.5]), c) == pytest.approx(math.sqrt((1.5 ** 2 + c ** 2) / 2))
    # the intervals themselves: tests/test_stats.py (rhs_common.stats, against scipy)


def test_groups_share_a_range_cell_and_stay_in_their_radar():
    from rhs_env.radar import RadarConfig, RadarSystem
    from rhs_env.scatterers import Scatterers

    radar = RadarSystem(RadarConfig(antenna="phased", scan=cs.radar_config("phased", None, 5.0).scan),
                        np.random.default_rng(0))
    groups = cs.make_groups(radar, 3, 15.0, 30.0, 25.0, np.random.default_rng(2))
    for g in groups:
        sc = Scatterers(g.xy, np.zeros((3, 2)), np.ones(3), np.arange(3), np.ones(3, bool))
        vis = radar.visible(sc)
        assert vis[g.radar].all() and not np.delete(vis, g.radar, axis=0).any()
        rng_m, _, _ = radar.radar_frame(g.xy)
        assert np.ptp(rng_m[g.radar]) < 1e-9


def test_slam_scene_groups_are_sep_apart_seen_from_mid_drive():
    cfg = cs.SMALL
    lm, poses = cs.slam_scene(2, 6.0, cfg)
    assert lm.shape == (10, 2) and poses.shape == (cfg.slam_cycles, 3)
    mid = np.array([poses[-1, 0] / 2, 0.0])
    a = np.arctan2(*(lm[0::2] - mid).T[::-1])
    b = np.arctan2(*(lm[1::2] - mid).T[::-1])
    assert np.allclose(np.rad2deg(np.abs(b - a)), 6.0, atol=1e-6)
    assert np.allclose(np.hypot(*(lm[0::2] - mid).T), np.hypot(*(lm[1::2] - mid).T))  # same range cell


def test_config_validation_names_the_field():
    with pytest.raises(ValueError, match="antennas"):
        cs.StudyConfig(antennas=("rhs", "laser"))
    with pytest.raises(ValueError, match="phased"):
        cs.StudyConfig(antennas=("rhs",))
    with pytest.raises(ValueError, match="seeds"):
        cs.StudyConfig(seeds=1)


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("claim")
    assert cs.main(["--small", "--out-dir", str(out), "--no-progress"]) == 0
    return out


def test_small_study_writes_results_readme_section_and_figures(small_run):
    data = json.loads((small_run / "claim_study_small.json").read_text())
    assert set(data["levels"]) == {"pointcloud", "elements", "slam"}
    prov = data["provenance"]
    assert len(prov["commit"]) == 40 and prov["command"][1] == "scripts/claim_study.py"
    assert prov["config"]["study"]["seeds"] == cs.SMALL.seeds and "radar" in prov["config"]
    cells = data["pointcloud"]["cells"]
    assert len(cells) == 2 * len(cs.SMALL.separations_deg) * len(cs.SMALL.snr_db)
    for c in cells:
        assert c["n"] == cs.SMALL.seeds
        for m in ("resolution_prob", "ospa_deg", "detection_rate"):
            v, lo, hi = c[m]
            assert lo <= v <= hi
        assert c["crb_group_deg"] >= c["crb_single_deg"] * (1 - 1e-6) > 0
    r = data["pointcloud"]["ratios"][0]
    assert r["antenna"] == "rhs" and len(r["ospa_ratio"]) == 3
    sl = data["slam"]["cells"]
    assert {c["antenna"] for c in sl} == {"rhs", "phased"}
    for c in sl:
        assert c["n"] == cs.SMALL.slam_seeds and c["odometry"]["registration"] == "odometry"
        assert c["odometry"]["ate_m"][0] >= 0
    md = (small_run / "claim_study_small.md").read_text()
    assert md.startswith("Measured by `python scripts/claim_study.py")
    assert "CRB" in md and "two-way peak gain" in md and "ATE" in md
    for f in ("regime", "resolution", "slam", "elements"):
        assert (small_run / f"claim_study_small_{f}.png").stat().st_size > 1000


def test_small_study_resumes_from_its_cache(small_run, capsys):
    before = {p.name: p.read_text() for p in small_run.glob("*_cache_*.jsonl")}
    assert len(before) == 3
    assert cs.main(["--small", "--out-dir", str(small_run), "--no-progress", "--only", "pointcloud"]) == 0
    assert "0 to run" in capsys.readouterr().out
    assert {p.name: p.read_text() for p in small_run.glob("*_cache_*.jsonl")} == before


def test_shards_split_the_pending_units_into_their_own_cache_files(tmp_path):
    assert cs.main(["--small", "--out-dir", str(tmp_path), "--no-progress", "--only", "pointcloud",
                    "--shard", "1/2"]) == 0
    n_cells = 2 * len(cs.SMALL.separations_deg) * len(cs.SMALL.snr_db)
    shard = tmp_path / "claim_study_small_cache_pointcloud_shard1of2.jsonl"
    assert len(shard.read_text().splitlines()) == n_cells // 2
    assert cs.main(["--small", "--out-dir", str(tmp_path), "--no-progress", "--only", "pointcloud",
                    "--shard", "0/2"]) == 0
    data = json.loads((tmp_path / "claim_study_small.json").read_text())
    assert len(data["pointcloud"]["cells"]) == n_cells and data["pointcloud"]["ratios"]
    with pytest.raises(SystemExit):
        cs.main(["--small", "--shard", "2/2"])


def test_radar_part_of_the_cache_keys_and_seeds_is_unchanged_by_the_config_grouping():
    """Cells are keyed (and seeded) by the flat radar dict of before RadarConfig was grouped: same values, same cache.
    The keys changed twice since, on purpose, each time with a new radar output whose cached cells must not be
    reused: the default fidelity ("iq" -> "range") and the OMP's converged refinement (``estimation.refine_passes``
    2 -> 8 with ``refine_tol`` 0.01)."""
    for system, want in [(("rhs", None, 5.0), "57ccaa1cf2515fff"), (("phased", None, None), "dfc3248b38d246ee"),
                         (("rhs", 16, 2.0), "be22e967f3d72ab5")]:
        assert cs._fingerprint(cs.radar_config(*system).flat_dict()) == want, system
