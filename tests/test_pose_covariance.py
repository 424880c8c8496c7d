"""The adaptive pose covariance (slam.core.pose_uncertainty, pipeline option pose_covariance="adaptive")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam.core.pipeline import PipelineConfig
from slam.core.pose_uncertainty import adaptive_drift_step, cycle_information


def _scene(rng: np.random.Generator, n: int = 25) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Landmarks (map frame), the true pose, and each point's vehicle-frame covariance (range / angle stds)."""
    pose = np.array([12.0, -3.0, 0.3])
    rng_m = rng.uniform(5.0, 60.0, n)
    bearing = rng.uniform(-1.2, 1.2, n)
    local = np.column_stack([rng_m * np.cos(bearing), rng_m * np.sin(bearing)])
    c, s = math.cos(pose[2]), math.sin(pose[2])
    lm = local @ np.array([[c, -s], [s, c]]).T + pose[:2]
    # range std 0.1 m, angle std 5 mrad, rotated into the vehicle frame along each bearing
    cov = np.zeros((n, 2, 2))
    for i, (r, b) in enumerate(zip(rng_m, bearing)):
        u, v = np.array([math.cos(b), math.sin(b)]), np.array([-math.sin(b), math.cos(b)])
        cov[i] = 0.1**2 * np.outer(u, u) + (r * 0.005) ** 2 * np.outer(v, v)
    return lm, pose, cov


def _observe(rng: np.random.Generator, lm: np.ndarray, pose: np.ndarray, cov: np.ndarray, gain: float) -> np.ndarray:
    """The landmarks in the true vehicle frame plus noise of ``gain^2`` times the stated covariance."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    local = (lm - pose[:2]) @ np.array([[c, -s], [s, c]])
    noise = np.stack([rng.multivariate_normal(np.zeros(2), gain**2 * C) for C in cov])
    return local + noise


@pytest.mark.parametrize("gain", [1.0, 0.5])
def test_cycle_information_matches_the_known_noise(gain: float) -> None:
    """Known per-point noise: the fitted pose scatters as ``s^2 J^-1`` and ``s^2`` reads the noise's gain^2."""
    rng = np.random.default_rng(3)
    lm, pose, cov = _scene(rng)
    lcov = np.repeat(1e-8 * np.eye(2)[None], len(lm), axis=0)  # landmarks known
    fits, scales, J_inv = [], [], None
    for _ in range(300):
        pts = _observe(rng, lm, pose, cov, gain)
        start = pose + rng.normal(0.0, [0.02, 0.02, 0.0005])  # a predicted pose off the truth
        info = cycle_information(start, pts, cov, lm, lcov, np.zeros(len(lm), dtype=bool), born=0)
        assert info.cov is not None and info.fitted is not None and info.n_old >= 0.8 * len(lm)
        fits.append(info.fitted - pose)
        scales.append(info.chi2 / info.dof)
        J_inv = info.cov
    emp = np.cov(np.asarray(fits).T)
    assert J_inv is not None
    ratio = np.diag(emp) / (gain**2 * np.diag(J_inv))
    assert np.all((ratio > 0.75) & (ratio < 1.33)), ratio
    assert float(np.mean(scales)) == pytest.approx(gain**2, rel=0.1)


def test_cycle_information_fraction_and_new_landmarks() -> None:
    """New landmarks are not paired; ``f = n_new / (n_new + n_old)``; too few pairs give no covariance."""
    rng = np.random.default_rng(4)
    lm, pose, cov = _scene(rng, 10)
    lcov = np.repeat(1e-4 * np.eye(2)[None], len(lm), axis=0)
    pts = _observe(rng, lm, pose, cov, 1.0)
    new = np.zeros(len(lm), dtype=bool)
    new[:4] = True
    info = cycle_information(pose, pts, cov, lm, lcov, new)
    assert (info.n_old, info.n_new) == (6, 4) and info.fraction == pytest.approx(0.4)
    new[:9] = True
    few = cycle_information(pose, pts, cov, lm, lcov, new, born=12)
    assert few.cov is None and few.n_new == 12 and few.fraction == pytest.approx(12 / 13)


def test_adaptive_drift_step_turns_heading_into_cross_track() -> None:
    """``P' = F P F^T + Q``: a heading variance grows the cross-track variance by ``d^2`` times it."""
    P = np.diag([0.0, 0.0, 1e-6])
    out = adaptive_drift_step(P, 0.0, np.array([10.0, 0.0, 0.0]), np.diag([1e-4, 2e-4, 3e-8]))
    assert out[1, 1] == pytest.approx(1e-4 + 2e-4)
    assert out[2, 2] == pytest.approx(1e-6 + 3e-8)
    assert out[0, 0] == pytest.approx(1e-4)


def test_pose_covariance_option_is_validated() -> None:
    assert PipelineConfig().pose_covariance == "drift-constants"  # the default stays the fitted densities
    with pytest.raises(ValueError, match="pose_covariance"):
        PipelineConfig(pose_covariance="learned")


def _drive_nees(model: str, cycles: int = 60, seed: int = 12011) -> tuple[np.ndarray, list[np.ndarray]]:
    import gymnasium as gym

    import rhs_env  # noqa: F401
    from agents.evaluate import load_policy
    from rhs_common.geometry import wrap_angle

    env = gym.make("rhs-highway-slam-v0", pipeline={"pose_covariance": model})
    policy = load_policy("idm", env, seed=seed)
    obs, info = env.reset(seed=seed)
    errors, covs, observed = [], [], []
    for _ in range(cycles):
        action, _ = policy.predict(obs, deterministic=True)
        obs, _, term, trunc, info = env.step(action)
        e = np.asarray(info["estimated_pose"], float) - np.asarray(info["true_pose"], float)
        e[2] = float(wrap_angle(e[2]))
        errors.append(e)
        covs.append(np.asarray(info["slam_pose_cov"], float))
        observed.append(np.asarray(obs["pose_std"], float))
        if term or trunc:
            break
    env.close()
    floor = np.array([1e-3, 1e-3, 1e-4]) ** 2
    nees = []
    for e, P in zip(errors, covs):
        P = P.copy()
        P[np.diag_indices(3)] = np.maximum(np.diag(P), floor)
        nees.append(float(e @ np.linalg.solve(P, e)))
    return np.asarray(nees), observed


def test_adaptive_covariance_is_calibrated_on_a_short_default_drive() -> None:
    """NEES on the default 1-degree env with the adaptive model: its median within a factor 4 of chi2(3)'s (2.37),
    so a covariance 3x too wide (NEES / 9) or too narrow (NEES x 9) in std fails; most cycles inside the band."""
    nees, observed = _drive_nees("adaptive")
    median = float(np.median(nees))
    assert 2.366 / 4 <= median <= 2.366 * 4, median
    inside = float(np.mean((nees >= 0.2158) & (nees <= 9.348)))
    assert inside >= 0.75, inside
    assert all(np.all(np.isfinite(o)) for o in observed)


def test_slam_accuracy_reports_below_and_above_the_band_separately() -> None:
    """``slam_accuracy``'s driver summary splits the cycles outside the NEES band into below and above."""
    from rhs_studies.slam_accuracy import pose_nees, summarize_driver

    def run(seed: int, inside: int, below: int, above: int) -> dict:
        n = inside + below + above
        return {"seed": seed, "cycles": n, "crashed": False, "position_rmse_m": 0.1, "episode_rmse_m": 0.1,
                "lost_episode": False, "cycles_above_lost": 0, "cycles_above_lost_flagged": 0,
                "cycles_below_good": n, "cycles_below_good_flagged": 0, "nees_cycles": n, "nees_inside": inside,
                "nees_below": below, "nees_above": above, "losses": 0, "losses_recovered": 0, "map_breaks": 0,
                "relocalised": 0}

    s = summarize_driver([run(1, 80, 15, 5), run(2, 90, 0, 10)])
    assert s["nees_coverage"] == pytest.approx(170 / 200)
    assert s["nees_below_fraction"] == pytest.approx(15 / 200)
    assert s["nees_above_fraction"] == pytest.approx(15 / 200)
    # the NEES itself: a covariance 3x too wide in std reads 1/9 of the consistent value
    e, std = np.array([0.1, -0.2]), np.array([0.1, 0.2, 0.01])
    assert pose_nees(e, 0.01, 3 * std) == pytest.approx(pose_nees(e, 0.01, std) / 9)


def test_tail_concentration_finds_the_drives_that_hold_the_upper_tail() -> None:
    """One drive whose NEES sits at 30 (above the band) among three inside it: the worst drive holds every cycle
    above, the others hold none, and a 4x wider covariance brings it inside while the others stay inside."""
    from rhs_studies.slam.pose_covariance import tail_concentration

    runs = [{"seed": s, "nees": {"calibrated": [30.0] * 5 if s == 2 else [3.0] * 5},
             "position_error_m": [0.5] * 5 if s == 2 else [0.05] * 5} for s in range(4)]
    t = tail_concentration({"runs": runs}, (0.216, 9.35), worst=1, scales=(4.0,))
    assert t["above"] == 5 and t["worst_above"] == 5 and t["worst_seeds"] == [2] and t["cycles"] == 20
    assert t["worst_median_error_m"] == [0.5] and t["others_median_error_m"] == 0.05 and t["others_above"] == 0.0
    assert t["scaled"] == [{"k": 4.0, "worst_above": 0.0, "others_below": 0.0}]


def test_heading_origin_finds_a_heading_error_turned_into_cross_track() -> None:
    """Drives whose heading error is a constant h and whose cross-track error grows as h times the distance (20 m a
    cycle): the cross-track error is all heading (R^2 1, the distance the drive covered), and a reported heading std
    half the drives' RMS error reads as a ratio of 2; the drive of the largest error is the worst."""
    from rhs_studies.slam.pose_covariance import heading_origin

    cycles, sd = 11, 1e-4
    runs = []
    for s, h in enumerate([2e-4, -2e-4, 2e-4, -2e-4, 6e-4]):
        parts = []
        for t in range(cycles):
            # error (3), particles' variances (3), drift P (9), residuals' scale, heading
            parts.append([0.0, h * 20.0 * t, h, 1e-4, 1e-4, sd**2, *np.zeros(9), 1.0, 0.0])
        nees = [float((h / sd) ** 2)] * cycles
        runs.append({"seed": s, "parts": parts, "nees": {"calibrated": nees}})
    config = {"runs": runs, "calibration": {"particles": 1.0, "along": 1.0, "cross": 1.0, "heading": 1.0}}
    h = heading_origin(config, (0.216, 9.35), at=5, worst=1)
    assert h["r2"] == pytest.approx(1.0) and h["slope_m"] == pytest.approx(20.0 * (cycles - 1))
    rms = np.sqrt(np.mean(np.square([2e-4, -2e-4, 2e-4, -2e-4, 6e-4])))
    assert h["spread_rad"] == pytest.approx(rms) and h["reported_rad"] == pytest.approx(sd)
    assert h["ratio"] == pytest.approx(rms / sd) and h["ratio_end"] == pytest.approx(rms / sd)
    assert h["worst_z"] == [pytest.approx(6.0)] and h["others_z"] == pytest.approx(2.0)
    assert heading_origin({"runs": runs}, (0.216, 9.35)) is None  # no calibration: nothing to compare with


def test_drive_intervals_resample_drives_not_cycles() -> None:
    """Ten drives of 50 cycles: nine inside the band, one above it throughout (10 % above). The interval over
    drives holds the 10 % and is wide (a drive is the independent unit: 0 or 3 such drives in a resample are
    likely), much wider than cycles taken as independent would give; with every drive alike it collapses."""
    from rhs_studies.slam.pose_covariance import drive_intervals

    runs = [{"seed": s, "nees": {"calibrated": [30.0] * 50 if s == 3 else [3.0] * 50}} for s in range(10)]
    ci = drive_intervals({"runs": runs})
    lo, hi = ci["above"]
    assert lo <= 0.1 <= hi and lo == 0.0 and hi >= 0.2
    assert ci["inside"][0] <= 0.9 <= ci["inside"][1] and ci["below"] == [0.0, 0.0]
    same = drive_intervals({"runs": [{"seed": s, "nees": {"calibrated": [3.0, 30.0]}} for s in range(10)]})
    assert same["above"] == [0.5, 0.5]
    assert drive_intervals({"runs": runs[:1]}) == {}
