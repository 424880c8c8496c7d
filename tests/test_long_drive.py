"""The long-drive study (rhs_studies.slam.long_drive): its flatness figures and a short drive's bookkeeping."""

import numpy as np
import pytest


def test_flatness_tells_a_flat_step_time_from_a_growing_one():
    from rhs_studies.slam.long_drive import flatness

    rng = np.random.default_rng(0)
    flat = 0.05 + 0.002 * rng.standard_normal(3000)
    f = flatness(flat, 500)
    assert f["last_over_first"] == pytest.approx(1.0, abs=0.03)
    assert abs(f["slope_ms_per_1000_cycles"]) < 0.5
    growing = 0.05 + 0.05 * np.arange(3000) / 3000
    g = flatness(growing, 500)
    assert g["last_over_first"] > 1.7
    assert g["slope_ms_per_1000_cycles"] == pytest.approx(1000 * 0.05 / 3, rel=0.02)


def test_options_refuse_out_of_range_values():
    from rhs_studies.slam.long_drive import Options

    with pytest.raises(ValueError, match="cycles"):
        Options(cycles=5)
    with pytest.raises(ValueError, match="window"):
        Options(cycles=100, window=80)
    with pytest.raises(ValueError, match="speed"):
        Options(speed=100.0)


def test_a_short_drive_keeps_its_books():
    from rhs_studies.slam.long_drive import Options, drive, pooled

    o = Options(seeds=(0,), cycles=30, window=5, no_plot=True)
    r, rows = drive(0, o)
    assert r["cycles"] == len(rows) == 30
    assert rows.shape == (30, 8)
    assert 0 < r["slots_max"] <= r["max_landmarks"]
    assert 0.0 <= r["nees_coverage"] <= 1.0
    assert r["nees_inside"] + r["nees_below"] + r["nees_above"] == 30
    assert r["path_m"] > 50  # 6 s at about 15 m/s
    assert r["position_rmse_m"] < 1.0
    assert np.all(rows[:, 2] > 0) and np.all(rows[:, 3] >= 0)
    s = pooled([r])
    assert s["cycles"] == 30 and s["targets"]["slots_bounded"]


def test_the_pose_covariance_option_names_its_results():
    """The default covariance writes long_drive.*; another model writes long_drive_<model>.* beside it, so the two
    runs of the page do not overwrite each other; an unknown model is refused, naming the field."""
    from rhs_studies.slam.long_drive import Options

    assert Options().result_name == "long_drive"
    assert Options(pose_covariance="calibrated").result_name == "long_drive_calibrated"
    with pytest.raises(ValueError, match="pose_covariance"):
        Options(pose_covariance="exact")
