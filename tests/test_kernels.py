"""The compiled kernels (rhs_env.kernels, slam.core.kernels) against the numpy reference, and their cache / notice."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from rhs_common.jit import NOTICE
from rhs_env.radar import DetectionConfig, RadarConfig, RadarSystem
from rhs_env.radar.estimation import peak_offsets
from rhs_env.scatterers import Occluders, Scatterers
from slam.core.rbpf import SlamConfig

ROOT = Path(__file__).resolve().parents[1]


def _scene(rng: np.random.Generator) -> tuple[Scatterers, Occluders]:
    """A small random road scene in the vehicle frame: roadside landmarks and a few moving vehicles (points)."""
    n_static, n_cars = int(rng.integers(2, 9)), int(rng.integers(0, 4))
    xs = rng.uniform(-90.0, 90.0, n_static)
    ys = rng.choice([-1.0, 1.0], n_static) * rng.uniform(8.0, 14.0, n_static)
    car = np.stack([rng.uniform(-60.0, 60.0, n_cars), rng.choice([-4.0, 0.0, 4.0], n_cars)], 1)
    xy = np.concatenate([np.stack([xs, ys], 1), car])
    vel = np.concatenate([np.tile([-25.0, 0.0], (n_static, 1)), np.stack([rng.uniform(-8, 8, n_cars), np.zeros(n_cars)], 1)])
    rcs = np.concatenate([rng.uniform(0.5, 10.0, n_static), rng.uniform(5.0, 30.0, n_cars)])
    sc = Scatterers(xy, vel, rcs, np.arange(len(xy)), np.arange(len(xy)) < n_static)
    return sc, Occluders.empty()


def _compare_clouds(a, b) -> None:
    assert len(a) == len(b)
    np.testing.assert_array_equal(a.radar, b.radar)
    assert np.abs(a.points[:, :2] - b.points[:, :2]).max(initial=0.0) < 1e-3  # positions within 1 mm
    assert np.abs(a.points[:, 2] - b.points[:, 2]).max(initial=0.0) < 1e-2  # Doppler within 1 cm/s


def _pair(**kw) -> dict[str, RadarSystem]:
    return {k: RadarSystem(RadarConfig(kernels=k, **kw), np.random.default_rng(7)) for k in ("numpy", "numba")}


def test_kernels_field_is_validated():
    with pytest.raises(ValueError, match="kernels"):
        RadarConfig(kernels="cython")
    with pytest.raises(ValueError, match="kernels"):
        SlamConfig(kernels="fortran")
    assert "kernels" not in RadarConfig().flat_dict()  # the default leaves the config's identity as it was
    assert RadarConfig(kernels="numpy").flat_dict()["kernels"] == "numpy"


def test_compiled_radar_matches_numpy_on_120_scenes():
    """Same detections, same point count, positions within 1 mm and Doppler within 1 cm/s on every scene."""
    radars = _pair()
    rng = np.random.default_rng(2024)
    n_points = 0
    for _ in range(120):
        spec = radars["numpy"].synthesize_spectrum(*_scene(rng))
        det = {k: r.detector.detect(spec) for k, r in radars.items()}
        np.testing.assert_array_equal(det["numpy"][0], det["numba"][0])
        np.testing.assert_array_equal(det["numpy"][1], det["numba"][1])
        clouds = {k: r.process_spectrum(spec)[0] for k, r in radars.items()}
        _compare_clouds(clouds["numpy"], clouds["numba"])
        n_points += len(clouds["numpy"])
    assert n_points > 300  # the scenes do produce points


def test_compiled_synthesis_matches_numpy():
    """The compiled tone spectra and product operands give the numpy spectrum (the same noise draws)."""
    radars = _pair()
    rng = np.random.default_rng(5)
    for _ in range(5):
        scene = _scene(rng)
        a, b = (r.synthesize_spectrum(*scene).copy() for r in radars.values())
        assert np.abs(a - b).max() <= 1e-6 * np.abs(a).max()


def test_compiled_noise_and_bin_gather_are_the_numpy_values():
    """The fused noise passes draw the numpy reference's noise spectrum bit for bit (same generator state), and
    the one-pass gather reads the OMP's data and the neighbouring bins exactly as the numpy indexing does."""
    from rhs_env.kernels import gather_bins

    radars = _pair()
    shape = (4, radars["numpy"].config.scan.slots, radars["numpy"].config.waveform.chirps_per_slot)
    for _ in range(3):
        a, b = (r.noise.spectrum(shape, r.rng).copy() for r in radars.values())
        np.testing.assert_array_equal(a, b)
        assert np.abs(a).max() > 0
    radar = radars["numba"]
    spec = radar.synthesize_spectrum(*_scene(np.random.default_rng(3)))
    rd, kd = radar.detector.detect(spec)
    assert rd.size > 0
    kk = radar.estimator.neighbour_bins(kd, spec.shape[-1])
    win, yd = gather_bins(spec, rd.astype(np.int64), kk, kk.shape[1] // 2)
    np.testing.assert_array_equal(yd, spec[rd, :, :, kd].astype(np.complex128))
    np.testing.assert_array_equal(win, np.moveaxis(spec[rd[:, None], :, :, kk], 1, -1))


@pytest.mark.parametrize("kw", [
    {"detection": DetectionConfig(statistic="summed")},
    {"detection": DetectionConfig(method="ca")},
    {"detection": DetectionConfig(mode="fixed")},
    {"antenna": "phased"},
    {"antenna": "random"},
    {"antenna": "hologram"},
    {"fidelity": "iq"},
], ids=["summed", "ca", "fixed", "phased", "random", "hologram", "iq"])
def test_non_default_paths_match_numpy(kw):
    """Every non-default path runs with kernels="numba" (compiled or the numpy fallback) and gives the numpy clouds."""
    radars = _pair(**kw)
    rng = np.random.default_rng(11)
    for _ in range(4):
        scene = _scene(rng)
        clouds = [r.scan(*scene) for r in radars.values()]
        _compare_clouds(*clouds)


def test_taylor_atoms_match_the_direct_product():
    """The compiled atoms (series in sin(theta)) equal the product with [w_T | w_R] to ~1e-13, inside and past the grid."""
    dic = RadarSystem(RadarConfig(kernels="numpy"), np.random.default_rng(0)).dictionaries[0]
    th = np.random.default_rng(1).uniform(dic.candidates[0] - 3 * dic.step, dic.candidates[-1] + 3 * dic.step, 500)
    ref = dic._atom_rows(th, 2)
    dic.use_kernels("numba")
    new = dic._atom_rows(th, 2)
    for o in range(3):
        scale = np.abs(ref[o]).max(axis=1, keepdims=True)
        assert (np.abs(new[o] - ref[o]) / scale).max() < 1e-12, o



@pytest.mark.parametrize("jitter", [0.0, 0.01], ids=["uniform", "non-uniform"])
def test_taylor_table_kinds_match_the_direct_product(jitter):
    """Uniform elements take the two-way gain's own series (2 I columns), others the one-way [t~ | r~] (4 I); both
    give the direct product's h, h', h'' to 1e-13 (measured: <= 1e-14) (the kernels tell them apart by the table's width)."""
    from rhs_env import kernels

    dic = RadarSystem(RadarConfig(kernels="numpy"), np.random.default_rng(0)).dictionaries[0]
    jittered = dic.antenna.positions_wl + jitter * np.random.default_rng(2).standard_normal(dic._x.size)
    dic._set_weights(dataclasses.replace(dic.antenna, positions_wl=jittered))  # a copy: the radar's antenna stays
    table, u_c, x_c = kernels.taylor_tables(dic._w2, dic._x, dic.candidates)
    n_i = dic.slots
    assert table.shape == (dic.candidates.size, (kernels.PRODUCT_ORDER if jitter == 0 else kernels.TAYLOR_ORDER) + 1,
                           n_i if jitter == 0 else 2 * n_i)
    th = np.random.default_rng(1).uniform(dic.candidates[0], dic.candidates[-1], 300)
    ref = dic._atom_rows(th, 2)
    new = kernels.taylor_atoms(table.view(np.float64), u_c, x_c, float(dic.candidates[0]), float(dic.step), dic._w2,
                               dic._x, th, 2)
    for o in range(3):
        scale = np.abs(ref[o]).max(axis=1, keepdims=True)
        assert (np.abs(new[o] - ref[o]) / scale).max() < 1e-13, o

@pytest.mark.parametrize("slam", [{}, {"variant": "fastslam1"}, {"association": "nearest"}], ids=["default", "fastslam1", "nearest"])
def test_compiled_slam_matches_numpy_over_an_episode(slam):
    """The SLAM env with compiled and numpy kernels: estimated poses within 1e-6 m over 25 steps."""
    import gymnasium as gym

    import rhs_env  # noqa: F401

    envs = [gym.make("rhs-highway-slam-v0", slam={**slam, "kernels": k}) for k in ("numpy", "numba")]
    for e in envs:
        e.reset(seed=4)
    worst = 0.0
    for a in np.random.default_rng(4).choice([1, 1, 1, 3, 4], size=25):
        out = [e.step(int(a)) for e in envs]
        worst = max(worst, float(np.abs(out[0][4]["estimated_pose"][:2] - out[1][4]["estimated_pose"][:2]).max()))
        np.testing.assert_allclose(out[0][4]["estimated_pose"][2], out[1][4]["estimated_pose"][2], atol=1e-8)
        if out[0][2] or out[0][3]:
            break
    assert worst < 1e-6


def _doppler_cases(rng: np.random.Generator, n_cases: int) -> list:
    """Doppler fit inputs: static points around radars with a turning ego, traffic, few points, one line of sight."""
    cases = []
    for q in range(n_cases):
        n = int(rng.integers(0, 40))
        sensors = rng.choice([[2.5, 0.8], [2.5, -0.8], [-2.5, 0.8], [-2.5, -0.8]], n)
        pts = np.column_stack([rng.uniform(-60, 60, (n, 2)), np.zeros(n), rng.uniform(1, 20, n)])
        if q % 7 == 0 and n:  # one line of sight: rank-deficient
            pts[:, :2] = sensors + np.outer(rng.uniform(5, 40, n), [1.0, 0.3])
        v, w = rng.normal([20.0, 0.0], [5.0, 0.5]), rng.normal(0, 0.3)
        d = pts[:, :2] - sensors
        u = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)[:, None]
        pts[:, 2] = -(u @ v + w * (sensors[:, 0] * u[:, 1] - sensors[:, 1] * u[:, 0])) + rng.normal(0, 0.05, n)
        pts[rng.random(n) < 0.3, 2] += rng.uniform(-10, 10)  # moving points
        prior = {} if q % 3 == 0 else {"prior": v + rng.normal(0, 1, 2), "max_change": 2.0}
        cases.append((pts, sensors, prior, q % 4 == 1))
    return cases


def test_compiled_doppler_fits_are_the_numpy_fits():
    """The Doppler ego-motion fits (velocity, velocity + yaw rate, speed-only prior) compiled: the same draws, the same
    hypotheses, the same None / fit as numpy on 300 clouds, fits within 1e-9."""
    from slam.core.association import estimate_ego_velocity
    from slam.core.pipeline import doppler_ego_motion

    found = 0
    for pts, sensors, prior, speed_only in _doppler_cases(np.random.default_rng(11), 300):
        dop = np.column_stack([pts[:, :2] - sensors, pts[:, 2:]])
        fits = [estimate_ego_velocity(dop, 0.25, np.random.default_rng(1), prior=prior.get("prior"),
                                      max_change=prior.get("max_change", np.inf), kernels=k) for k in ("numpy", "numba")]
        fits += [doppler_ego_motion(pts, sensors, 0.25, np.random.default_rng(2), speed_only=speed_only, kernels=k,
                                    **prior) for k in ("numpy", "numba")]
        for a, b in (fits[:2], fits[2:]):
            assert (a is None) == (b is None)
            if a is not None:
                found += 1
                np.testing.assert_allclose(b, a, rtol=0, atol=1e-9)
    assert found > 300  # most clouds give a fit


def _filter_pair(rng: np.random.Generator):
    """Two RBPF SLAMs (numpy, numba kernels) in one random state: 6 particles, 8 landmark slots, 5 observations."""
    from slam.core.rbpf import Observations, RBPFSlam, SlamConfig

    filters = [RBPFSlam(SlamConfig(n_particles=6, max_landmarks=8, kernels=k), rng=1) for k in ("numpy", "numba")]
    P, L = filters[0].mean.shape[:2]
    pose = np.column_stack([rng.normal(0, 3, (P, 2)), rng.uniform(-np.pi, np.pi, P)])
    mean = rng.normal(0, 30, (P, L, 2))
    a = rng.normal(0, 0.3, (P, L, 2, 2))
    cov = a @ a.transpose(0, 1, 3, 2) + 0.01 * np.eye(2)
    for f in filters:
        f.pose, f.mean, f.cov = pose.copy(), mean.copy(), cov.copy()
        f.cycle = 7
    b = rng.normal(0, 0.2, (5, 2, 2))
    obs = Observations(z=rng.normal(0, 30, (5, 2)), Q=b @ b.transpose(0, 2, 1) + 0.01 * np.eye(2), amp=np.ones(5))
    pp = np.repeat(np.arange(P), 3)
    mm = np.tile([0, 2, 4], P)
    ll = np.concatenate([rng.choice(L, 3, replace=False) for _ in range(P)])  # distinct slots per particle
    return filters, obs, pp, mm, ll


def test_compiled_landmark_update_and_proposal_terms_are_the_numpy_values():
    """The RBPF's per-pair Kalman update and proposal terms compiled: numpy's values bit for bit (state and returns)."""
    rng = np.random.default_rng(8)
    for _ in range(5):
        filters, obs, pp, mm, ll = _filter_pair(rng)
        terms = [f._proposal_terms(pp, mm, ll, obs) for f in filters]
        for x, y in zip(*terms):
            assert np.array_equal(x, y)
        lik = [f._landmark_update(pp, mm, ll, obs) for f in filters]
        assert np.array_equal(lik[0], lik[1])
        for name in ("mean", "cov", "hits", "last_seen"):
            assert np.array_equal(getattr(filters[0], name), getattr(filters[1], name)), name


def test_compiled_icp_equals_the_numpy_fit():
    """The compiled ICP (brute-force neighbours, fused iterations) gives the cKDTree / numpy estimate."""
    from rhs_common.geometry import apply_motion
    from slam.core.registration import ICPRegistration

    rng = np.random.default_rng(3)
    for trial in range(20):
        prev = np.column_stack([rng.uniform(-60, 60, (50, 2)), np.zeros(50), rng.uniform(1, 30, 50)])
        motion = np.array([rng.uniform(3, 6), rng.normal(0, 0.2), rng.normal(0, 0.02)])
        keep = rng.random(50) < 0.8
        cur = prev[keep].copy()
        # current-frame points: the previous ones seen after the motion, with noise and a few outliers
        c, s = np.cos(motion[2]), np.sin(motion[2])
        rel = cur[:, :2] - motion[:2]
        cur[:, :2] = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]])
        cur[:, :2] += rng.normal(0, 0.05, (len(cur), 2))
        cur[:3, :2] += rng.uniform(-20, 20, (3, 2))
        regs = [ICPRegistration(amplitude_weights=bool(trial % 2)) for _ in range(2)]
        regs[0].kernels = "numpy"
        est = [r.estimate(prev, cur, prior=np.array([4.5, 0.0, 0.0])) for r in regs]
        np.testing.assert_allclose(est[0], est[1], atol=1e-9)
        assert regs[0].last_pairs == regs[1].last_pairs
        np.testing.assert_allclose(regs[0].last_rmse, regs[1].last_rmse, rtol=1e-9)
        assert np.abs(apply_motion(cur[3:, :2], est[1]) - prev[keep][3:, :2]).max() < 0.5  # it does register


def test_compiled_points_are_the_numpy_values_bit_for_bit():
    """From the same OMP output, the compiled range offsets and points equal the numpy reference bit for bit."""
    from rhs_env.kernels import range_offsets

    radar = RadarSystem(RadarConfig(), np.random.default_rng(7))
    rng = np.random.default_rng(11)
    n_points = 0
    for _ in range(60):
        spec = radar.synthesize_spectrum(*_scene(rng))
        rd, kd = radar.detector.detect(spec)
        est = radar.estimator.estimate(spec, rd, kd)
        compiled, reference = radar.assembler._assemble_compiled(rd, kd, est), radar.assembler._assemble_numpy(rd, kd, est)
        for field in ("points", "radar", "range_m", "angle_rad", "range_std_m", "angle_std_rad"):
            np.testing.assert_array_equal(getattr(compiled, field), getattr(reference, field), err_msg=field)
        n_points += len(reference)
    assert n_points > 300
    for _ in range(50):  # log-powers with ties (a flat row) and non-concave peaks
        pw = rng.normal(size=(6, 3, 11)) * 10
        pw[0, 0] = 1.0
        pw[1, 2, 4:7] = [2.0, 3.0, 4.0]
        np.testing.assert_array_equal(range_offsets(pw, 5), peak_offsets(pw, 5))


def test_compiled_line_of_sight_is_the_numpy_mask():
    """The compiled visibility (field of view and occlusion, per pair up to its first crossing) is the numpy mask."""
    radars = _pair()
    rng = np.random.default_rng(21)
    hidden = 0
    for trial in range(40):
        n_cars = int(rng.integers(1, 12))
        centres = np.column_stack([rng.uniform(-60, 60, n_cars), rng.choice([-8.0, -4.0, 0.0, 4.0, 8.0], n_cars)])
        occ = Occluders.from_boxes(centres, rng.normal(0, 0.1, n_cars), 4.8, 1.9, np.arange(n_cars))
        sc, _ = _scene(rng)
        # the cars' own corners (on their occluders: not hidden by their own object) and points behind them
        corners = occ.segments[:, 0]
        xy = np.concatenate([sc.xy, corners, corners * 1.7])
        ids = np.concatenate([sc.object_id + 100, np.repeat(np.arange(n_cars), 4), np.full(len(corners), 99)])
        if trial % 4 == 0:
            xy[-3:] = occ.segments[:3, 1]  # exactly on an occluder's end point
        pts = Scatterers(xy, np.zeros_like(xy), np.ones(len(xy)), ids, np.ones(len(xy), bool))
        vis = {k: r.visible(pts, occ) for k, r in radars.items()}
        np.testing.assert_array_equal(vis["numba"], vis["numpy"])
        fov = radars["numpy"].visible(pts, None)
        hidden += int(np.sum(fov & ~vis["numpy"]))
    assert hidden > 50  # the scenes do hide points


def test_compiled_icp_search_is_the_best_fit_per_start():
    """The one-call heading search equals icp_fit from every start with the (near, -rmse) tuple score, bit for bit."""
    from slam.core.kernels import icp_fit, icp_search
    from slam.core.registration import ICPRegistration

    reg = ICPRegistration()
    offsets = np.concatenate([[0.0], reg.yaw_offsets[reg.yaw_offsets != 0.0]])
    assert offsets.size > 1  # the default searches headings
    rng = np.random.default_rng(8)
    args = (reg.max_iterations, reg.max_gate_m, reg.min_gate_m, reg.outlier_factor, reg.tol_m, reg.tol_rad, reg.min_pairs)
    for trial in range(30):
        prev = rng.uniform(-40, 40, (int(rng.integers(3, 40)), 2))
        th = rng.normal(0, 0.1)
        c, s = np.cos(th), np.sin(th)
        cur = (prev[: max(3, len(prev) - 5)] - [3.0, 0.2]) @ np.array([[c, -s], [s, c]]) + rng.normal(0, 0.05, (1, 2))
        if trial % 3 == 0:
            cur = np.round(cur, 0)  # equal scores between starts
        amp_p, amp_c = rng.uniform(1, 20, len(prev)), rng.uniform(1, 20, len(cur))
        guess = np.array([-0.0, 0.0, rng.normal(0, 0.05)]) if trial % 2 else np.array([3.0, 0.2, 0.0])
        best = None
        for o in offsets:
            est, pairs, rmse, near = icp_fit(cur, prev, guess + np.array([0.0, 0.0, o]), amp_p, amp_c, bool(trial % 2),
                                             *args)
            if pairs and (best is None or (near, -rmse) > best[0]):
                best = ((near, -rmse), est, pairs, rmse)
        got, pairs, rmse, found = icp_search(cur, prev, guess, offsets, amp_p, amp_c, bool(trial % 2), *args)
        assert found == (best is not None)
        if best is not None:
            np.testing.assert_array_equal(got, best[1])
            assert pairs == best[2] and (rmse == best[3] or (np.isnan(rmse) and np.isnan(best[3])))


def test_shared_sort_phase_ramp_and_counting_os_cfar():
    """The shared insertion sort sorts; the phase ramp is exp(j x t) to round-off (uniform or not); the OS-CFAR
    test by counting equals the test against the rank-th smallest training cell, ties at the threshold included."""
    from rhs_common.jit import sort_small
    from rhs_env.kernels import RAMP, _cfar_pass, _ramp, _uniform

    rng = np.random.default_rng(3)
    for n in (0, 1, 2, 7, 16, 41):
        v = rng.normal(size=n)
        w = v.copy()
        sort_small(w)
        np.testing.assert_array_equal(w, np.sort(v))
    em, out = np.empty(RAMP, complex), np.empty(90, complex)
    for t, uniform in ((np.arange(90) * 4.0 + 3.0, True), (np.sort(rng.uniform(0.0, 360.0, 90)), False)):
        assert _uniform(t) == uniform
        for x in (-2.9, 0.013, 1.7):
            _ramp(x, t, uniform, em, out)
            assert np.abs(out - np.exp(1j * x * t)).max() < 1e-12  # |x t| <= 1e3 rad: its own rounding is ~1e-13
    line = rng.exponential(size=64).astype(np.float32)
    cells = np.arange(16) * 3
    vals = np.empty(16)
    alpha, floor, cap, rank = 4.0, 0.5, 3.0, 12
    z_os = np.sort(line[cells].astype(float))[rank - 1]
    z_ca = line[cells].astype(float).mean()
    levels = alpha * np.clip(line[cells].astype(float), floor, cap)
    for v in np.concatenate([rng.uniform(0.0, 14.0, 300), levels, [alpha * floor, alpha * cap]]):
        assert _cfar_pass(v, line, cells, 0, rank, alpha, floor, cap, vals) == (v > alpha * min(max(z_os, floor), cap))
        assert _cfar_pass(v, line, cells, 1, rank, alpha, floor, cap, vals) == (v > alpha * min(max(z_ca, floor), cap))


def _run(code: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "OMP_NUM_THREADS": "1", **env}, timeout=600)


def test_kernels_as_python_under_disable_jit():
    """NUMBA_DISABLE_JIT=1 runs the kernels' Python source: the same detections and points as numpy on small cases."""
    code = """
        import numpy as np
        from numba import config
        assert config.DISABLE_JIT
        from rhs_env.radar import RadarConfig, RadarSystem
        from rhs_env.scatterers import Scatterers
        from slam.core.registration import ICPRegistration
        radars = {k: RadarSystem(RadarConfig(kernels=k), np.random.default_rng(1)) for k in ("numpy", "numba")}
        scene = Scatterers.static_points([[30.0, 10.0], [-45.0, -11.0], [60.0, -9.0]], rcs=8.0)
        spec = radars["numpy"].synthesize_spectrum(scene)
        a, b = (r.process_spectrum(spec)[0] for r in radars.values())
        assert len(a) == len(b) > 0 and np.abs(a.points[:, :3] - b.points[:, :3]).max() < 1e-3
        from rhs_env.scatterers import Occluders
        occ = Occluders.from_boxes([[20.0, 5.0]], [0.0], 4.8, 1.9, [7])  # hides (40, 10) from the front radar
        pts = Scatterers.static_points([[40.0, 10.0], [40.0, -10.0], [10.0, 2.0]])
        vis = [r.visible(pts, occ) for r in radars.values()]
        assert np.array_equal(vis[0], vis[1]) and not vis[1][0, 0] and vis[1][0, 1]
        radars = {k: RadarSystem(RadarConfig(kernels=k), np.random.default_rng(2)) for k in ("numpy", "numba")}
        s1, s2 = (r.synthesize_spectrum(scene).copy() for r in radars.values())
        assert np.abs(s1 - s2).max() <= 1e-6 * np.abs(s1).max()
        rng = np.random.default_rng(0)
        prev = np.column_stack([rng.uniform(-30, 30, (12, 2)), np.zeros(12), np.ones(12)])
        cur = prev.copy()
        cur[:, 0] -= 2.0
        regs = [ICPRegistration(yaw_search_rad=0.0) for _ in range(2)]
        regs[0].kernels = "numpy"
        e0, e1 = (r.estimate(prev, cur, prior=np.array([1.8, 0.0, 0.0])) for r in regs)
        assert np.abs(e0 - e1).max() < 1e-9 and abs(e1[0] - 2.0) < 1e-6
        from slam.core.association import mahalanobis_associate
        from slam.core.kernels import mahalanobis_association, proposal_information
        P, M, L = 3, 4, 5
        obs, mean = rng.uniform(0, 6, (P, M, 2)), rng.uniform(0, 6, (P, L, 2))
        a00, a11, a01 = rng.uniform(0.5, 1, (P, M)), rng.uniform(0.5, 1, (P, M)), rng.uniform(-0.1, 0.1, (P, M))
        cov = np.tile(np.eye(2) * 0.2, (P, L, 1, 1))
        active, used = np.ones((P, L), bool), np.arange(L)
        s00, s11, s01 = a00[:, :, None] + 0.2, a11[:, :, None] + 0.2, a01[:, :, None] + 0.0
        det = s00 * s11 - s01 * s01
        nx, ny = obs[:, :, None, 0] - mean[:, None, :, 0], obs[:, :, None, 1] - mean[:, None, :, 1]
        d2 = (s11 * nx * nx - 2 * s01 * nx * ny + s00 * ny * ny) / det
        want = mahalanobis_associate(d2, 3.5**2, 6.0**2, 3)
        got = mahalanobis_association(obs, a00, a01, a11, mean, cov, active, used, 3.5**2, 6.0**2, 3)
        assert np.array_equal(want, got)
        pp = np.array([0, 0, 1, 2, 2, 2])
        H, Si, nu, ok = rng.normal(size=(6, 2, 3)), rng.normal(size=(6, 2, 2)), rng.normal(size=(6, 2)), rng.random(6) < 0.7
        info, g = proposal_information(pp, H, Si, nu, ok, P)
        HtSi = np.einsum("kia,kij->kaj", H, Si) * ok[:, None, None]
        info0, g0 = np.zeros((P, 3, 3)), np.zeros((P, 3))
        np.add.at(info0, pp, np.einsum("kaj,kjb->kab", HtSi, H))
        np.add.at(g0, pp, np.einsum("kaj,kj->ka", HtSi, nu))
        assert np.allclose(info, info0, rtol=1e-13, atol=1e-13) and np.allclose(g, g0, rtol=1e-13, atol=1e-13)
        from slam.core.pipeline import doppler_ego_motion
        sensors = np.tile([[2.5, 0.8], [-2.5, -0.8]], (10, 1))
        pts = np.column_stack([rng.uniform(-40, 40, (20, 2)), np.zeros(20), np.ones(20)])
        d = pts[:, :2] - sensors
        u = d / np.hypot(d[:, 0], d[:, 1])[:, None]
        pts[:, 2] = -(u @ [15.0, 0.5] + 0.2 * (sensors[:, 0] * u[:, 1] - sensors[:, 1] * u[:, 0]))
        fits = [doppler_ego_motion(pts, sensors, 0.25, np.random.default_rng(0), kernels=k) for k in ("numpy", "numba")]
        assert np.allclose(fits[0], fits[1], atol=1e-9) and np.allclose(fits[1], [15.0, 0.5, 0.2], atol=1e-6)
        from tests.test_kernels import _filter_pair
        filters, obs, pp, mm, ll = _filter_pair(rng)
        lik = [f._landmark_update(pp, mm, ll, obs) for f in filters]
        assert np.allclose(lik[0], lik[1], rtol=1e-12) and np.allclose(filters[0].mean, filters[1].mean, rtol=1e-12)
        terms = [f._proposal_terms(pp, mm, ll, obs) for f in filters]
        assert all(np.allclose(x, y, rtol=1e-12) for x, y in zip(*terms))
        from rhs_env.kernels import face_scatterers
        xy, vel, rcs, box, seg = face_scatterers(np.array([[20.0, 3.0]]), np.array([0.1]), np.array([[20.0, 0.0]]),
                                                 np.array([0.01]), np.array([5.0]), np.array([2.0]),
                                                 np.array([0.0, 0.0, 0.0, 25.0, 0.0, 0.0]), 3, 10.0)
        assert len(xy) == 3 and abs(rcs.sum() - 10.0) < 1e-9 and seg.shape == (4, 2, 2) and np.all(box == 0)
        print("ok")
    """
    res = _run(code, NUMBA_DISABLE_JIT="1")
    assert res.returncode == 0 and res.stdout.strip().endswith("ok"), res.stderr[-3000:]


LOCK = "rhs-slam-background-compile.lock"


def test_cache_notice_once_then_silent(tmp_path):
    """A fresh cache compiles with the one-line notice; the next process loads the cache silently."""
    code = """
        import numpy as np
        from rhs_env.kernels import tone_spectra
        tone_spectra(np.zeros(1), np.ones(1, complex), 8, 2, 4, np.array([0.1]))
        tone_spectra(np.zeros(2), np.ones(2, complex), 8, 2, 4, np.array([0.2, 0.3]))
    """
    first = _run(code, NUMBA_CACHE_DIR=str(tmp_path))
    assert first.returncode == 0, first.stderr[-3000:]
    assert first.stderr.count(NOTICE) == 1
    assert any(tmp_path.rglob("*.nbi"))  # the index of the cached machine code
    second = _run(code, NUMBA_CACHE_DIR=str(tmp_path))
    assert second.returncode == 0 and NOTICE not in second.stderr


def test_background_precompile_leaves_the_env_only_the_radar_front_end_to_compile(tmp_path):
    """After slam.gym.precompile's workload (what a SLAM env starts in a background process on a cold cache), a new
    process's SLAM env compiles none of the kernels it covers: the OMP's refinement and the one-call OMP, the points,
    the SLAM's; and its scans run the one-call OMP."""
    work = _run("from slam.gym.precompile import main; main([])", NUMBA_CACHE_DIR=str(tmp_path))
    assert work.returncode == 0, work.stderr[-3000:]
    code = """
        from rhs_common.jit import _numba
        from numba.core import event
        names = []
        class Rec(event.Listener):
            def on_start(self, ev):
                names.append(ev.data["dispatcher"].py_func.__qualname__)
            def on_end(self, ev):
                pass
        _numba()
        event.register("numba:compile", Rec())
        import gymnasium as gym, rhs_env
        from rhs_env.kernels import omp_doppler_tiered
        env = gym.make("rhs-highway-slam-v0")
        env.reset(seed=0)
        for _ in range(6):
            env.step(1)
        print(omp_doppler_tiered._compiled, sorted(set(names)))
    """
    env_run = _run(code, NUMBA_CACHE_DIR=str(tmp_path), RHS_SLAM_BACKGROUND_COMPILE="0")
    assert env_run.returncode == 0, env_run.stderr[-3000:]
    one_call, names = env_run.stdout.strip().splitlines()[-1].split(" ", 1)
    compiled = set(eval(names))
    covered = {"omp_doppler", "_new_atoms", "joint_refine", "_keep_rows", "_refit_rows", "bin_amplitudes",
               "range_offsets", "assemble_points", "landmark_update", "proposal_terms", "proposal_information",
               "mahalanobis_association", "icp_search", "icp_fit", "doppler_ransac"}
    assert not compiled & covered, compiled & covered
    assert one_call == "True"
    assert "footprint_detections" in compiled  # the env's own process still compiled the detector: the cache was cold


def _fake_kernel(folder: Path, compiled: bool = False):
    """A stand-in for a cached numba dispatcher: its cache index path under ``folder`` and its signatures."""
    from types import SimpleNamespace

    index = SimpleNamespace(_index_path=str(folder / "kernels.omp_doppler-1658.py311.nbi"))
    return SimpleNamespace(_cache=SimpleNamespace(_cache_file=index), signatures=[("sig",)] if compiled else [],
                           py_func=lambda: "python body")


def test_background_precompile_starts_once_on_a_cold_cache_only(tmp_path, monkeypatch):
    """slam.gym.precompile.start: one background process per cold cache (a lock holding its pid), none while one runs,
    when warm or switched off."""
    import subprocess as sp
    from types import SimpleNamespace

    from slam.gym import precompile

    started = []
    monkeypatch.setattr(sp, "Popen", lambda *a, **k: started.append(a[0]) or SimpleNamespace(pid=os.getpid()))
    omp, last = _fake_kernel(tmp_path), _fake_kernel(tmp_path / "slam")
    monkeypatch.setattr(precompile, "_probes", lambda: (omp, last))
    monkeypatch.delenv("RHS_SLAM_BACKGROUND_COMPILE", raising=False)
    assert precompile.start() and started[-1][-3:] == ["slam.gym.precompile", "--lock", str(tmp_path / LOCK)]
    assert (tmp_path / LOCK).read_text() == str(os.getpid())  # the background process' pid
    assert not precompile.start() and len(started) == 1  # the lock: one at a time
    (tmp_path / LOCK).unlink()
    monkeypatch.setenv("RHS_SLAM_BACKGROUND_COMPILE", "0")
    assert not precompile.start()
    monkeypatch.delenv("RHS_SLAM_BACKGROUND_COMPILE")
    Path(omp._cache._cache_file._index_path).touch()  # the radar's kernels cached, the SLAM's not: still cold
    assert precompile.start() and len(started) == 2
    (tmp_path / LOCK).unlink()
    (tmp_path / "slam").mkdir()
    Path(last._cache._cache_file._index_path).touch()  # a warm cache
    assert not precompile.start() and len(started) == 2


def test_tiered_kernel_runs_its_python_body_only_while_a_background_compile_runs(tmp_path):
    """rhs_common.jit.Tiered: the Python body while a live process holds the lock beside the kernel's cache and the
    cache has no index; the compiled kernel once the index exists, the lock goes, its process dies or it goes stale."""
    from rhs_common.jit import COMPILE_LOCK, LOCK_STALE_S, Tiered, background_compile_running

    kernel = _fake_kernel(tmp_path)
    lock = tmp_path / COMPILE_LOCK
    assert not background_compile_running(kernel) and Tiered(kernel).use_compiled()  # no lock: compile here
    lock.write_text(str(os.getpid()))  # a live process
    tier = Tiered(kernel)
    assert background_compile_running(kernel) and not tier.use_compiled() and not tier._compiled
    tier.mode = "compiled"
    assert tier.use_compiled() and not tier._compiled  # a forced tier is not remembered
    tier.mode = "auto"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    lock.write_text(dead.stdout.strip())  # a process that has exited
    assert not background_compile_running(kernel) and tier.use_compiled() and tier._compiled
    lock.write_text(str(os.getpid()))
    os.utime(lock, (0, os.path.getmtime(lock) - LOCK_STALE_S - 1))  # a lock left by a compile that died
    assert not background_compile_running(kernel) and Tiered(kernel).use_compiled()
    lock.write_text(str(os.getpid()))
    Path(kernel._cache._cache_file._index_path).touch()  # the background compile has cached it
    assert Tiered(kernel).use_compiled()
    assert Tiered(_fake_kernel(tmp_path / "other", compiled=True)).use_compiled()  # compiled in this process


def test_tiered_omp_computes_the_compiled_omps_bits_on_30_scenes(monkeypatch):
    """The OMP's Python body on its compiled stages (what a scan runs while the background compile builds the one-call
    kernel) returns exactly the one-call kernel's numbers: the same points, bit for bit, on every scene."""
    from rhs_env import kernels

    radar = RadarSystem(RadarConfig(), np.random.default_rng(7))
    tier = kernels.omp_doppler_tiered
    rng = np.random.default_rng(99)
    n_points = 0
    for _ in range(30):
        spec = radar.synthesize_spectrum(*_scene(rng))
        clouds = {}
        for mode in ("compiled", "python"):
            monkeypatch.setattr(tier, "mode", mode)
            clouds[mode] = radar.process_spectrum(spec)[0]
        np.testing.assert_array_equal(clouds["compiled"].points, clouds["python"].points)
        np.testing.assert_array_equal(clouds["compiled"].radar, clouds["python"].radar)
        n_points += len(clouds["python"])
    assert n_points > 60  # the scenes do produce points
    assert tier._body.__globals__["joint_refine"] is kernels.joint_refine.py_func  # the python tier ran, refinement too


def test_python_body_swaps_only_the_named_callees():
    """rhs_common.jit.python_body: the kernel's own function, its named callees as Python, the others compiled."""
    from rhs_common.jit import python_body
    from rhs_env import kernels

    body = python_body(kernels.omp_doppler, "joint_refine")
    assert body.__code__ is kernels.omp_doppler.py_func.__code__
    assert body.__globals__["joint_refine"] is kernels.joint_refine.py_func
    assert body.__globals__["_new_atoms"] is kernels._new_atoms  # still the compiled kernel
    assert kernels.joint_refine is not kernels.joint_refine.py_func  # the module itself is untouched


def test_watch_compiles_names_the_kernels_compiled_inside_the_block(tmp_path):
    """rhs_common.jit.watch_compiles (the benchmark's check that nothing compiles while timed): inside the block the
    kernels compiled on a cold cache, nothing once they are compiled, nothing after the block."""
    code = """
        import numpy as np
        from rhs_common.jit import watch_compiles
        from rhs_env.kernels import tone_spectra
        args = (np.zeros(1), np.ones(1, complex), 8, 2, 4, np.array([0.1]))
        with watch_compiles() as first:
            tone_spectra(*args)
        with watch_compiles() as again:
            tone_spectra(*args)
        print(sorted(first), sorted(again))
    """
    res = _run(code, NUMBA_CACHE_DIR=str(tmp_path))
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.strip().splitlines()[-1] == "['rhs_env.kernels.tone_spectra'] []"


def test_read_only_install_caches_in_the_user_directory(tmp_path):
    """Where the package directory is not writable, the cache goes to the user cache directory."""
    code = f"""
        import os
        os.environ.pop("NUMBA_CACHE_DIR", None)
        import platformdirs
        platformdirs.user_cache_dir = lambda name: os.path.join({str(tmp_path)!r}, name)
        from rhs_common import jit
        jit._writable = lambda path: False
        jit._numba()
        from numba.core import config
        assert os.environ["NUMBA_CACHE_DIR"] == config.CACHE_DIR == os.path.join({str(tmp_path)!r}, "rhs-slam", "numba")
        print("ok")
    """
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    res = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, capture_output=True, text=True, env=env,
                         timeout=300)
    assert res.returncode == 0 and "ok" in res.stdout, res.stderr[-3000:]


@pytest.mark.parametrize("span", [0.05, 0.4, np.pi], ids=["narrow", "wider", "fft"])
def test_doppler_peak_matches_the_numpy_search(span):
    """The compiled Doppler search (direct samples or its radix-2 FFT) finds the numpy search's d_omega per row."""
    from rhs_env import kernels
    from rhs_env.point_cloud import _doppler_grid_refine, _dtft_kernel_split, _time_index, _twiddles

    rng = np.random.default_rng(3)
    tgrid = np.arange(90 * 4, dtype=float).reshape(90, 4)
    d = 12
    w_true = rng.uniform(-0.8, 0.8, d) * span
    h = rng.normal(size=(d, 90)) + 1j * rng.normal(size=(d, 90))
    r = h[:, :, None] * np.exp(1j * w_true[:, None, None] * tgrid) + 0.3 * (rng.normal(size=(d, 90, 4)) + 1j * rng.normal(size=(d, 90, 4)))
    want = _doppler_grid_refine(h, r, tgrid, np.full(d, span))
    t, n_t, _ = _time_index(tgrid)
    nfft = 2048
    e_re, e_im = _twiddles(nfft)
    tables = [_dtft_kernel_split(n_t, nfft, h)[1:] for h in (1, 64)]  # too small (twiddles used), every narrow half
    for row in range(d):
        q = np.zeros(n_t, complex)
        np.add.at(q, t, (h[row].conj()[:, None] * r[row]).reshape(-1))
        for tab in tables:
            got = kernels._doppler_peak(q.real.copy(), q.imag.copy(), span, nfft, e_re, e_im, np.empty(nfft),
                                        np.empty(nfft), *tab)
            assert abs(got - want[row]) < 1e-6
        assert abs(got - w_true[row]) < 5e-3  # and it is the tone's frequency


def test_fft_pow2_is_the_dft():
    from rhs_env import kernels
    from rhs_env.point_cloud import _twiddles

    x = np.random.default_rng(0).normal(size=64) + 1j * np.random.default_rng(1).normal(size=64)
    re, im = x.real.copy(), x.imag.copy()
    kernels._fft_pow2(re, im, *_twiddles(64))
    np.testing.assert_allclose(re + 1j * im, np.fft.fft(x), rtol=0, atol=1e-12)


def test_whole_omp_runs_compiled_on_the_default_radar(monkeypatch):
    """The default radar takes the one-call OMP (not the step-by-step path) and it gives the numpy result."""
    import rhs_env.omp as pc

    radars = _pair()
    used = []
    orig = pc._compiled_omp
    monkeypatch.setattr(pc, "_compiled_omp", lambda *a, **k: used.append(1) or orig(*a, **k))
    sc = Scatterers.static_points([[30.0, 10.0], [-45.0, -11.0], [60.0, -9.0], [61.0, -9.5]], rcs=8.0)
    spec = radars["numpy"].synthesize_spectrum(sc, Occluders.empty())
    a, b = (r.process_spectrum(spec)[0] for r in radars.values())
    assert len(used) and pc._compiled_omp(radars["numba"].dictionaries[0], np.ones((1, 90, 4), complex),
                                          radars["numba"].estimator.chirp_index, 2, np.ones(1), 1.0, 0.0, 0.0, 2, 2, True) is not None
    _compare_clouds(a, b)


def test_vector_env_workers_load_the_kernels_the_parent_compiled(tmp_path):
    """On an empty cache, make_vec_env compiles in the parent once; its SubprocVecEnv workers compile nothing.

    The workers inherit the parent's stderr: the compile notice appears once (the parent's warm-up) and a
    second vector env on the same cache neither warms up again nor compiles.
    """
    code = """
        import sys
        import numpy as np
        from agents.run_setup import make_vec_env, warm_kernels
        vec = make_vec_env("rhs_env:rhs-highway-slam-v0", n_envs=2, seed=0)
        print("parent warm-up done", file=sys.stderr, flush=True)
        vec.reset()
        for _ in range(25):
            vec.step(np.ones(2, int))
        vec.close()
        print("again", warm_kernels("rhs-highway-slam-v0", {}))
    """
    first = _run(code, NUMBA_CACHE_DIR=str(tmp_path))
    assert first.returncode == 0, first.stderr[-3000:]
    before, _, after = first.stderr.partition("parent warm-up done")
    assert before.count(NOTICE) == 1 and NOTICE not in after  # compiled in the parent only
    assert first.stdout.strip().endswith("again False")
    assert list(tmp_path.rglob("rhs-slam-warm-*"))


def test_footprint_statistic_sums_each_footprints_slots():
    """The compiled statistic: each hypothesis' slots summed (any slot set, contiguous or not) equals the dense
    product F^T E within float32 round-off, and the detector's two paths agree on a radar spectrum."""
    from rhs_env.kernels import footprint_statistic

    rng = np.random.default_rng(4)
    n_r, n_i, n_c, n_k, n_j = 2, 12, 3, 17, 9
    spec = (rng.normal(size=(n_r, n_i, n_c, n_k)) + 1j * rng.normal(size=(n_r, n_i, n_c, n_k))).astype(np.complex64)
    foot = rng.random((n_i, n_j)) < 0.3
    foot[rng.integers(0, n_i, n_j), np.arange(n_j)] = True  # no empty footprint
    slots = np.concatenate([np.flatnonzero(foot[:, j]) for j in range(n_j)]).astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(foot.sum(0))]).astype(np.int64)
    e = (np.abs(spec.astype(np.complex128)) ** 2).sum(axis=2)  # (R, I, K), float64
    want = np.einsum("ij,rik->rjk", foot.astype(float), e)
    got = footprint_statistic(spec.view(np.float32), slots, starts)
    assert got.dtype == np.float32 and got.shape == (n_r, n_j, n_k)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    radars = _pair()
    spec = radars["numpy"].synthesize_spectrum(*_scene(np.random.default_rng(9)))
    assert (radars["numba"].detector.footprint_detectors[0].kernels == "numba"
            and radars["numpy"].detector.footprint_detectors[0].kernels == "numpy")
    for view in (spec, spec[..., 3:-5]):  # whole profiles and a bin range (rows strided, as the radar passes them)
        a, b = (r.detector.footprint_detectors[0].statistic(view) for r in radars.values())
        np.testing.assert_allclose(b, a, rtol=1e-6)
        assert np.mean(a == b) > 0.9  # most cells bit for bit: sums of the same 2-4 terms


def test_no_taylor_table_past_the_build_limit(monkeypatch):
    """A dictionary whose table would exceed TABLE_WORK_MAX (thousands of elements) keeps the direct product: no
    table, the compiled path's atoms are numpy's (a 4096-element table took 22 GB and a minute to build)."""
    from rhs_env import kernels

    dic = RadarSystem(RadarConfig(kernels="numpy"), np.random.default_rng(0)).dictionaries[0]
    assert dic.candidates.size * dic._x.size * dic._w2.shape[1] <= kernels.TABLE_WORK_MAX  # the default builds one
    monkeypatch.setattr(kernels, "TABLE_WORK_MAX", 1.0)
    th = np.random.default_rng(1).uniform(-1.0, 1.0, 20)
    ref = dic._atom_rows(th, 1)
    dic.use_kernels("numba")
    assert dic._taylor is None
    for a, b in zip(dic._atom_rows(th, 1), ref):
        np.testing.assert_array_equal(a, b)


def test_kernel_tables_choose_once_and_cover_every_stage_twice():
    """rhs_common.jit.KernelTable: each radar module's stages have a numba and a numpy implementation, the choice is
    validated and cached, and the modules it serves compare no ``kernels`` string at a call site."""
    import re

    from rhs_common.jit import KernelTable
    from rhs_env import detection, omp, uncertainty
    from rhs_env.radar import antennas, estimation, mounting, noise, points, synthesis

    stage_modules = (antennas, estimation, mounting, noise, points, synthesis)  # the radar's stages with kernels
    for table in (detection._STAGES, omp._STAGES, uncertainty._STAGES, *(m._STAGES for m in stage_modules)):
        numba, numpy_ = table.choose("numba"), table.choose("numpy")
        assert numba is table.choose("numba") and numba.kernels == "numba" and numpy_.kernels == "numpy"
        assert all(set(impls) == {"numba", "numpy"} for impls in table.stages.values()), table.name
        assert all(getattr(numba, s) is not getattr(numpy_, s) for s in table.stages), table.name
    with pytest.raises(ValueError, match="kernels: expected one of 'numba', 'numpy', got 'fortran'"):
        mounting._STAGES.choose("fortran")
    half = KernelTable("half")
    half.stage("only", "numpy")(len)
    with pytest.raises(ValueError, match=r"half: stages without an implementation: only \(numba\)"):
        half.choose("numpy")
    branch = re.compile(r"kernels\"?\)?\s*(==|!=)\s*\"num(ba|py)\"")
    radar_files = sorted(Path(mounting.__file__).parent.glob("*.py"))  # every module of rhs_env.radar
    assert {Path(m.__file__) for m in stage_modules} < set(radar_files)
    for path in [Path(m.__file__) for m in (detection, omp, uncertainty)] + radar_files:
        assert not branch.search(path.read_text()), path.name
    radar = RadarSystem(RadarConfig(kernels="numpy"), np.random.default_rng(0))
    stages = {antennas: radar.beams, estimation: radar.estimator, mounting: radar.mounts, noise: radar.noise,
              points: radar.assembler, synthesis: radar.synthesizer}
    assert all(stage._impl is module._STAGES.choose("numpy") for module, stage in stages.items())
