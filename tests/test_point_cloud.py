"""Range processing, CFAR, OMP, CRB and point-cloud metrics (rhs_env.point_cloud)."""

from __future__ import annotations

import numpy as np
import pytest

from rhs_env.antenna_factory import make_antenna
from rhs_env.array_models import RHSConfig, ScanConfig
from rhs_env.point_cloud import (
    AngleDictionary,
    angle_crb,
    ca_cfar_threshold,
    cfar_alpha,
    local_maxima,
    omp_angles,
    pointcloud_metrics,
    range_fft,
)
from rhs_env.radar import LinkBudgetConfig, RadarConfig, RadarSystem
from rhs_env.scatterers import Scatterers
from rhs_env.windows import make_window
from rhs_studies.scenes import landmark_scene


def test_range_fft_peak_at_beat_bin():
    n, z = 400, 2
    k_true = 123.25  # in zero-padded bins
    y = np.exp(2j * np.pi * k_true / (z * n) * np.arange(n)).astype(np.complex64)
    spec = np.abs(range_fft(y, make_window("hann", n), z)) ** 2
    assert abs(int(np.argmax(spec)) - k_true) <= 0.5


def test_cfar_false_alarm_rate_matches_design():
    rng = np.random.default_rng(0)
    looks, pfa = 20, 1e-2
    prof = rng.gamma(looks, 1.0, size=(200, 400))
    alpha = cfar_alpha(pfa, looks, 16)
    thr = ca_cfar_threshold(prof, guard=1, train=8, stride=1, alpha=alpha)
    rate = np.mean(prof[:, 20:-20] > thr[:, 20:-20])
    assert 0.5 * pfa < rate < 2 * pfa
    assert local_maxima(prof, thr).sum() > 0


def test_omp_resolves_two_off_grid_targets():
    scan = ScanConfig(grid_deg=2.0)
    ant = make_antenna("hologram", RHSConfig(), scan)
    dic = AngleDictionary(ant, scan.grid_deg, scan.sector_deg, 4)
    th = np.deg2rad([-12.37, 3.81])
    iota = (dic.atoms(th)[0] @ np.array([1.0, 0.7j]))[None]
    res = omp_angles(dic, iota, 3, np.array([1e-9 * np.vdot(iota, iota).real]), 1e-8)
    got = np.sort(res.theta[0, res.valid[0]])
    assert got.size == 2
    assert np.allclose(np.rad2deg(got), [-12.37, 3.81], atol=0.02)


def test_angle_crb_scales_with_snr_and_elements():
    scan = ScanConfig(grid_deg=1.0)
    small = make_antenna("hologram", RHSConfig(elements=30), scan)
    big = make_antenna("hologram", RHSConfig(elements=90), scan)
    th = np.deg2rad(10.0)
    c1, c2 = angle_crb(small, th, 100.0), angle_crb(small, th, 1000.0)
    assert np.isclose(c1 / c2, 10.0)
    assert angle_crb(big, th, 100.0) < c1
    radar = RadarSystem(RadarConfig(antenna="phased"), np.random.default_rng(0))
    assert radar.angle_crb(th, 30.0, 5.0) < radar.angle_crb(th, 60.0, 5.0)


def test_pointcloud_metrics():
    truth = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    pts = np.array([[0.1, 0.0], [10.0, 0.2], [50.0, 50.0]])
    m = pointcloud_metrics(pts, truth, gate_m=1.0)
    assert m["n_true"] == 3 and m["n_detected"] == 2 and m["false_points"] == 1
    assert np.isclose(m["rmse_m"], np.sqrt((0.01 + 0.04) / 2))
    m2 = pointcloud_metrics(pts, truth, 1.0, truth_object=[1, 1, 2])
    assert m2["n_true"] == 2 and m2["n_detected"] == 1


@pytest.mark.parametrize("kind", ["rhs", "phased", "hologram"])
def test_accuracy_static_landmarks_default_config(kind):
    cfg = RadarConfig() if kind == "rhs" else RadarConfig(antenna=kind)
    radar = RadarSystem(cfg, np.random.default_rng(10))
    scene_rng = np.random.default_rng(11)
    det, sq, false_pts = [], [], []
    for _ in range(6):
        scene = landmark_scene(scene_rng, radar)  # 24 landmarks 10-60 m in the sectors, ego at 20 m/s
        cloud = radar.scan(scene)
        m = radar.metrics(cloud, scene, gate_m=1.0)
        det.append(m["detection_rate"])
        sq.extend(m["sq_errors"])
        false_pts.append(m["false_points"])
    rate, rmse = float(np.mean(det)), float(np.sqrt(np.mean(sq)))
    print(f"{kind}: detection rate {rate:.3f}, RMSE {rmse:.3f} m, false points/cycle {np.mean(false_pts):.2f}")
    if kind == "rhs":
        assert rate >= 0.95 and rmse < 0.3
    else:
        assert rate >= 0.9 and rmse < 0.5


def test_typical_scene_benchmark_runs(tmp_path):
    from rhs_studies.benchmark_radar import benchmark_radar

    res = benchmark_radar("hologram", repeats=2, out=tmp_path / "b.json")
    assert (tmp_path / "b.json").exists()
    assert set(res["stage_ms_median"]) >= {"synthesis", "range_cfar", "omp"}
    assert res["detection_rate"] > 0.8


def test_refine_passes_reach_the_omp_and_the_profiles_table_flags_a_quality_change(tmp_path):
    """estimation.refine_passes is the OMP's most re-refinement passes (8 with the convergence stop, the default;
    0 gives another point cloud of the same echoes); radar_profiles marks a metric outside the two-sample 95 %
    interval and says whether the metrics that differ are better."""
    from rhs_env.radar import RadarSystem
    from rhs_studies import radar_profiles
    from rhs_studies.scenes import typical_scene

    scene, occ = typical_scene(np.random.default_rng(1))
    clouds = {}
    for passes in (None, 8, 0):
        est = {} if passes is None else {"estimation": {"refine_passes": passes}}
        cfg = radar_profiles.radar_config(est, 5.0)
        clouds[passes] = RadarSystem(cfg, np.random.default_rng(0)).scan(scene, occ).points
    assert np.array_equal(clouds[None], clouds[8])
    assert clouds[0].shape != clouds[8].shape or not np.allclose(clouds[0], clouds[8])
    ref = {k: {"mean": 1.0, "ci95": 0.1} for k in radar_profiles.QUALITY}
    near = {**ref, "point_rmse_m": {"rmse": 1.12, "ci95": 0.1}}  # within sqrt(0.1^2 + 0.1^2) = 0.141
    far = {**ref, "doppler_rmse_mps": {"rmse": 1.2, "ci95": 0.1}}
    assert all(radar_profiles.same_quality(near, ref).values())
    assert radar_profiles.same_quality(far, ref) == {k: k != "doppler_rmse_mps" for k in radar_profiles.QUALITY}
    low = {**ref, "doppler_rmse_mps": {"rmse": 0.8, "ci95": 0.1}, "detection_rate": {"mean": 1.2, "ci95": 0.01}}
    for metrics, want in ((near, "same"), (far, "worse"), (low, "better")):
        assert radar_profiles.verdict(metrics, ref, radar_profiles.same_quality(metrics, ref)) == want


def test_radar_quality_pools_noise_draws_of_the_same_scenes():
    """evaluate(..., noise_draws=k) scans the same scenes k times with independent noise: k x the scenes and
    targets, and its first draw is the single-draw evaluation."""
    from rhs_env.array_models import ScanConfig
    from rhs_env.radar import RadarConfig
    from rhs_studies.radar_quality import evaluate

    cfg = RadarConfig(scan=ScanConfig(grid_deg=5.0))
    one, two = evaluate(cfg, 2, 0), evaluate(cfg, 2, 0, noise_draws=2)
    assert (one["detection_rate"]["n"], two["detection_rate"]["n"]) == (2, 4)
    assert 1.5 * one["point_rmse_m"]["n"] <= two["point_rmse_m"]["n"] <= 2.5 * one["point_rmse_m"]["n"]
    assert two != one


def test_os_cfar_false_alarm_rate_matches_design():
    from rhs_env.point_cloud import os_cfar_alpha, os_cfar_threshold

    rng = np.random.default_rng(1)
    looks, pfa = 20, 1e-2
    prof = rng.gamma(looks, 1.0, size=(300, 400))
    alpha = os_cfar_alpha(pfa, looks, 16, 12)
    thr = os_cfar_threshold(prof, guard=1, train=8, stride=1, alpha=alpha, rank=12)
    rate = np.mean(prof[:, 20:-20] > thr[:, 20:-20])
    assert 0.7 * pfa < rate < 1.4 * pfa


def test_crb_is_a_lower_bound_of_the_measured_angle_error():
    """Single target at moderate SNR: the OMP angle error is within a small factor of the CRB, never below it."""
    cfg = RadarConfig(antenna="phased", link=LinkBudgetConfig(tx_power_dbm=0.0))
    radar = RadarSystem(cfg, np.random.default_rng(3))
    th, rng_m = np.deg2rad(8.3), 40.0
    xy = radar.positions[0] + rng_m * np.array([np.cos(th), np.sin(th)])
    errs = []
    for _ in range(25):
        cloud = radar.scan(Scatterers.static_points([xy]))
        sel = cloud.radar == 0
        if sel.any():
            i = np.argmin(np.abs(cloud.angle_rad[sel] - th))
            errs.append(cloud.angle_rad[sel][i] - th)
    rmse = float(np.sqrt(np.mean(np.square(errs))))
    crb = float(np.sqrt(radar.angle_crb(th, rng_m, 5.0)))
    print(f"angle RMSE {np.rad2deg(rmse):.4f} deg, CRB {np.rad2deg(crb):.4f} deg")
    assert len(errs) >= 24
    assert 0.7 * crb < rmse < 3.0 * crb


def _two_close_targets(kernels: str, sep_deg: float = 3.0):
    """Slot x chirp data of two targets ``sep_deg`` apart in one range cell (SNR 40 dB per sample), and a start
    0.3 deg off."""
    from rhs_env.point_cloud import _doppler_atoms

    radar = RadarSystem(RadarConfig(kernels=kernels), np.random.default_rng(0))
    dic, tgrid = radar.dictionaries[0], radar.estimator.chirp_index
    theta = np.deg2rad([10.0, 10.0 + sep_deg])
    omega = np.array([0.30, 0.32])
    data = (np.array([1.0, 0.8j]) @ _doppler_atoms(dic, theta, omega, tgrid)).reshape(1, *tgrid.shape)
    noise = np.random.default_rng(5).normal(size=data.shape + (2,)) @ np.array([1.0, 1j])
    data = data + 0.01 * np.sqrt(np.mean(np.abs(data) ** 2) / 2) * noise
    start = (theta + np.deg2rad([0.3, -0.3]))[None], (omega + 0.002)[None]
    span = np.array([min(np.pi, 8 * np.pi / float(tgrid.max() + 1))])
    return dic, data, tgrid, start, span, theta


@pytest.mark.parametrize("kernels", ["numpy", "numba"])
def test_converged_refinement_stops_when_the_fit_stops_improving(kernels):
    """``tol``: a cell stops once a pass lowers its residual by less than that fraction of it. A tolerance of 1
    stops every cell after its first pass; a small one keeps refining two close targets past the fixed two
    passes, to the fit that every further pass leaves as it is, nearer the truth."""
    from rhs_env.point_cloud import joint_refine

    dic, data, tgrid, (th0, om0), span, truth = _two_close_targets(kernels)
    valid = np.ones((1, 2), bool)

    def refine(passes: int, tol: float):
        return joint_refine(dic, data, tgrid, th0, om0, valid, span, passes=passes, tol=tol)

    one, stopped = refine(1, 0.0), refine(8, 1.0)
    for a, b in zip(one, stopped):
        np.testing.assert_array_equal(a, b)
    two, converged, all_passes = refine(2, 0.0), refine(10, 1e-6), refine(10, 0.0)
    err = [np.abs(np.rad2deg(r[0][0]) - np.rad2deg(truth)).max() for r in (two, converged)]
    assert err[1] < 0.5 * err[0] and err[1] < 0.01, err  # deg
    assert np.abs(converged[0] - all_passes[0]).max() < np.deg2rad(1e-3)  # further passes move it < 0.001 deg


def test_converged_refinement_compiled_matches_numpy():
    from rhs_env.point_cloud import joint_refine

    out = {}
    for k in ("numpy", "numba"):
        dic, data, tgrid, (th0, om0), span, _ = _two_close_targets(k)
        out[k] = joint_refine(dic, data, tgrid, th0, om0, np.ones((1, 2), bool), span, passes=6, tol=1e-4)
    np.testing.assert_allclose(out["numpy"][0], out["numba"][0], atol=1e-7)  # rad
    np.testing.assert_allclose(out["numpy"][1], out["numba"][1], atol=1e-5)  # rad per chirp: the two Doppler searches
