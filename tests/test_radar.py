"""Radar synthesis + processing end to end (rhs_env.radar, rhs_env.scatterers)."""

from __future__ import annotations

import numpy as np
import pytest

from rhs_env.array_models import RHSConfig, ScanConfig
from rhs_env.radar import DetectionConfig, LinkBudgetConfig, RadarConfig, RadarSystem, WaveformConfig
from rhs_env.radar.noise import uniform32
from rhs_env.scatterers import Occluders, Scatterers, visible_mask

BIN = 0.6  # c / 2B, m


def _polar(radar: RadarSystem, r: int, rng_m: float, theta_deg: float) -> np.ndarray:
    a = radar.boresights[r] + np.deg2rad(theta_deg)
    return radar.positions[r] + rng_m * np.array([np.cos(a), np.sin(a)])


def _nearest(cloud, xy):
    d = np.hypot(*(cloud.xy - xy).T)
    return int(np.argmin(d)), float(d.min())


@pytest.fixture(scope="module")
def noiseless():
    return RadarSystem(RadarConfig(antenna="hologram", link=LinkBudgetConfig(add_noise=False)), np.random.default_rng(0))


def test_config_validation_names_field():
    with pytest.raises(ValueError, match="pfa"):
        DetectionConfig(pfa=0.0)
    with pytest.raises(ValueError, match="antenna"):
        RadarConfig(antenna="horn")
    with pytest.raises(ValueError, match="max_range_m"):
        RadarConfig(max_range_m=500.0)
    with pytest.raises(ValueError, match="chirps_per_slot"):
        WaveformConfig(chirps_per_slot=1)
    cfg = RadarConfig()
    assert cfg.waveform.samples == 400 and abs(cfg.waveform.range_resolution_m - 0.5996) < 1e-3


def test_single_noiseless_target_range_and_angle(noiseless):
    radar = noiseless
    for r, rng_m, th in [(0, 23.37, 7.3), (1, 41.9, -18.55), (2, 12.2, 33.1), (3, 57.0, -0.4)]:
        xy = _polar(radar, r, rng_m, th)
        cloud = radar.scan(Scatterers.static_points([xy]))
        assert len(cloud) == 1, cloud.points
        assert cloud.radar[0] == r
        assert abs(cloud.range_m[0] - rng_m) < 0.1 * BIN
        assert abs(np.rad2deg(cloud.angle_rad[0]) - th) < 0.1 * radar.config.scan.grid_deg
        assert abs(cloud.points[0, 2]) < 0.05  # static, ego at rest


def test_two_targets_same_range_resolved(noiseless):
    radar = noiseless
    pts = [_polar(radar, 0, 30.0, -4.0), _polar(radar, 0, 30.0, 6.0)]
    cloud = radar.scan(Scatterers.static_points(pts))
    assert len(cloud) == 2, cloud.points
    for p in pts:
        assert _nearest(cloud, p)[1] < 0.2


def test_two_targets_same_range_resolved_with_noise():
    radar = RadarSystem(RadarConfig(antenna="phased"), np.random.default_rng(1))
    pts = [_polar(radar, 1, 35.0, 5.0), _polar(radar, 1, 35.0, 25.0)]
    cloud = radar.scan(Scatterers.static_points(pts))
    for p in pts:
        assert _nearest(cloud, p)[1] < 0.5, cloud.points


def test_occluded_target_not_seen(noiseless):
    radar = noiseless
    near, far = np.array([20.0, 1.0]), np.array([40.0, 1.0])
    occ = Occluders.from_boxes([[20.0, 1.0]], [0.0], 4.0, 2.0, object_id=[7])
    scat = Scatterers(np.array([near, far]), np.zeros((2, 2)), [5.0, 5.0], [7, 8], [False, True])
    mask = radar.visible(scat, occ)
    assert mask[0].tolist() == [True, False]
    cloud = radar.scan(scat, occ)
    assert _nearest(cloud, near)[1] < 0.3
    assert _nearest(cloud, far)[1] > 5.0
    # without the occluder both are seen
    cloud2 = radar.scan(scat)
    assert _nearest(cloud2, far)[1] < 0.3


def test_visible_mask_shapes_and_own_object():
    scat = Scatterers(np.array([[10.0, 0.0], [5.0, 0.0]]), np.zeros((2, 2)), [1, 1], [1, 2], [True, True])
    occ = Occluders(np.array([[[5.0, -1.0], [5.0, 1.0]]]), [2])  # point 1 lies on its own segment
    m1 = visible_mask(np.zeros(2), scat, occ)
    assert m1.shape == (2,) and m1.tolist() == [False, True]
    m2 = visible_mask(np.array([[0.0, 0.0], [20.0, 0.0]]), scat, occ)
    assert m2.shape == (2, 2) and m2.tolist() == [[False, True], [True, True]]
    assert visible_mask(np.zeros(2), scat, None).all()


def test_fov_and_max_range(noiseless):
    radar = noiseless
    out_of_range = _polar(radar, 0, 120.0, 0.0)
    outside_sector = _polar(radar, 0, 20.0, 50.0) * np.array([1, 1])
    scat = Scatterers.static_points([out_of_range])
    assert not radar.visible(scat).any()
    assert len(radar.scan(scat)) == 0
    _r, a, _ = radar.radar_frame(outside_sector[None])
    assert np.abs(np.rad2deg(a[0, 0])) > 45


@pytest.mark.parametrize("slot_doppler", [True, False])
def test_radial_velocity_measured(slot_doppler):
    radar = RadarSystem(RadarConfig(antenna="phased", waveform=WaveformConfig(slot_doppler=slot_doppler)), np.random.default_rng(3))
    xy = _polar(radar, 0, 35.0, 12.0)
    u = (xy - radar.positions[0]) / np.linalg.norm(xy - radar.positions[0])
    vel = np.array([[-22.0, 3.0]])
    cloud = radar.scan(Scatterers(xy[None], vel, [10.0], [0], [False]))
    i, d = _nearest(cloud, xy)
    assert d < 0.3, cloud.points
    assert abs(cloud.points[i, 2] - float(vel[0] @ u)) < 0.2


def test_same_seed_same_cloud_different_seed_differs():
    scat = Scatterers.static_points([[30.0, 5.0], [-20.0, 4.0], [10.0, 30.0]])
    clouds = []
    for seed in (5, 5, 6):
        radar = RadarSystem(RadarConfig(antenna="random"), np.random.default_rng(seed))
        clouds.append(radar.scan(scat).points)
    assert np.array_equal(clouds[0], clouds[1])
    assert clouds[0].shape != clouds[2].shape or not np.array_equal(clouds[0], clouds[2])


@pytest.mark.parametrize("fidelity", ["range", "iq"])
def test_a_scan_is_its_stages_in_order(fidelity):
    """RadarSystem composes its stages: running them by hand (synthesis, range FFT for "iq", detection, estimation,
    points) on the same generator gives the scan's cloud bit for bit, and the radar's attributes are the stages'."""
    cfg = RadarConfig(fidelity=fidelity, scan=ScanConfig(grid_deg=2.0))
    a, b = (RadarSystem(cfg, np.random.default_rng(4)) for _ in range(2))
    scat = Scatterers.static_points([_polar(a, 0, 25.0, 10.0), _polar(a, 1, 40.0, -20.0), _polar(a, 3, 60.0, 5.0)])
    occ = Occluders.empty()
    cloud = a.scan(scat, occ)
    if fidelity == "iq":
        spec = b.range_fft.spectrum(b.synthesizer.samples(scat, occ, b.rng))
    else:
        spec = b.synthesizer.spectrum(scat, occ, b.rng)
    rd, kd = b.detector.detect(spec)
    by_hand = b.assembler.assemble(rd, kd, b.estimator.estimate(spec, rd, kd))
    assert len(cloud) >= 3
    for field in ("points", "radar", "range_m", "angle_rad", "range_std_m", "angle_std_rad"):
        np.testing.assert_array_equal(getattr(cloud, field), getattr(by_hand, field), err_msg=field)
    assert a.positions is a.mounts.positions and a.dictionaries is a.beams.dictionaries
    assert a.antennas is a.beams.antennas and a.boresights is a.mounts.boresights
    a.rng = np.random.default_rng(4)  # a new generator reaches every stage at the next scan
    np.testing.assert_array_equal(a.scan(scat, occ).points, RadarSystem(cfg, np.random.default_rng(4)).scan(scat, occ).points)


@pytest.mark.parametrize("kind", ["rhs", "phased", "random", "hologram"])
def test_every_antenna_kind_detects(kind):
    radar = RadarSystem(RadarConfig(antenna=kind), np.random.default_rng(2))
    pts = [_polar(radar, 0, 25.0, 10.0), _polar(radar, 2, 40.0, -20.0)]
    cloud = radar.scan(Scatterers.static_points(pts))
    for p in pts:
        assert _nearest(cloud, p)[1] < 1.0, (kind, cloud.points)
    assert set(cloud.stage_times) >= {"synthesis", "range_cfar", "omp"}


def test_empty_scene_has_few_false_points():
    radar = RadarSystem(RadarConfig(antenna="phased"), np.random.default_rng(4))
    n = [len(radar.scan(Scatterers.empty())) for _ in range(5)]
    assert sum(n) <= 1


def test_coarser_grid_works():
    radar = RadarSystem(RadarConfig(antenna="hologram", scan=ScanConfig(grid_deg=5.0)), np.random.default_rng(0))
    xy = _polar(radar, 0, 30.0, 8.0)
    cloud = radar.scan(Scatterers.static_points([xy]))
    assert _nearest(cloud, xy)[1] < 0.5


def test_thermal_noise_is_circular_gaussian_at_ktfb():
    cfg = RadarConfig(antenna="phased")
    radar = RadarSystem(cfg, np.random.default_rng(7))
    y = radar.synthesize(Scatterers.empty()).reshape(-1).astype(complex) / np.sqrt(cfg.noise_power_w)
    assert abs(np.mean(np.abs(y) ** 2) - 1.0) < 0.01
    assert abs(np.var(y.real) - 0.5) < 0.01 and abs(np.var(y.imag) - 0.5) < 0.01
    assert abs(np.mean(y.real * y.imag)) < 0.01
    kurt = np.mean(y.real ** 4) / np.mean(y.real ** 2) ** 2
    assert abs(kurt - 3.0) < 0.1


def test_link_budget_matches_radar_equation():
    cfg = RadarConfig()
    lam = cfg.wavelength
    assert np.isclose(cfg.echo_power_w(50.0, 5.0), 1.0 * 5.0 * lam ** 2 / ((4 * np.pi) ** 3 * 50.0 ** 4))
    assert np.isclose(cfg.noise_power_w, 1.380649e-23 * 290 * 10 * 20e6)


def test_strong_near_target_leaves_no_sidelobe_points():
    radar = RadarSystem(RadarConfig(antenna="phased"), np.random.default_rng(8))
    xy = _polar(radar, 0, 6.0, 3.0)
    cloud = radar.scan(Scatterers(xy[None], np.zeros((1, 2)), [100.0], [0], [True]))
    assert len(cloud) == 1, cloud.points
    assert np.hypot(*(cloud.xy[0] - xy)) < 0.2


def test_same_range_different_velocities_both_measured():
    radar = RadarSystem(RadarConfig(antenna="hologram"), np.random.default_rng(9))
    p1, p2 = _polar(radar, 0, 30.0, -12.0), _polar(radar, 0, 30.0, 15.0)
    vel = np.array([[-25.0, 0.0], [3.0, 0.0]])
    cloud = radar.scan(Scatterers(np.array([p1, p2]), vel, [5.0, 10.0], [0, 1], [True, False]))
    for p, v in zip((p1, p2), vel):
        i, d = _nearest(cloud, p)
        u = (p - radar.positions[0]) / np.linalg.norm(p - radar.positions[0])
        assert d < 0.3, cloud.points
        assert abs(cloud.points[i, 2] - float(v @ u)) < 0.3


@pytest.mark.parametrize("kw", [{"method": "ca"}, {"mode": "fixed", "fixed_threshold_db": 15.0}])
def test_detection_options_work(kw):
    radar = RadarSystem(RadarConfig(antenna="phased", detection=DetectionConfig(**kw)), np.random.default_rng(1))
    xy = _polar(radar, 1, 33.0, -7.0)
    cloud = radar.scan(Scatterers.static_points([xy]))
    assert _nearest(cloud, xy)[1] < 0.3


def test_two_targets_same_range_resolved_default_rhs():
    radar = RadarSystem(RadarConfig(link=LinkBudgetConfig(add_noise=False)), np.random.default_rng(0))
    pts = [_polar(radar, 3, 40.0, 2.0), _polar(radar, 3, 40.0, 12.0)]
    cloud = radar.scan(Scatterers.static_points(pts))
    assert len(cloud) == 2, cloud.points
    for p in pts:
        assert _nearest(cloud, p)[1] < 0.2


@pytest.mark.parametrize("seed", [0, 7, 123])
def test_fast_float32_uniforms_equal_the_generators_own(seed):
    """rhs_env.radar.noise.uniform32 draws PCG64's raw words itself (a speed-up): the same numbers and the same
    generator state afterwards as ``Generator.random(dtype=float32)``, so seeded outputs do not change
    (a numpy that changed its float32 recipe would fail here, not silently alter the noise)."""
    radar = RadarSystem(RadarConfig(scan=ScanConfig(grid_deg=10.0), rhs=RHSConfig(elements=16)),
                        rng=np.random.default_rng(seed))
    ref = np.random.default_rng(seed)
    for shape in [(2, 4, 6), (2, 3), (5,)]:  # even sizes take the fast path, odd ones the generator's call
        got = uniform32(radar.rng, np.empty(shape, np.float32))
        want = ref.random(dtype=np.float32, size=shape)
        np.testing.assert_array_equal(got, want)
        # the same state: the same position and buffered half word (a spent half word's stale value aside)
        a, b = radar.rng.bit_generator.state, ref.bit_generator.state
        assert a["state"] == b["state"] and a["has_uint32"] == b["has_uint32"]
        assert not a["has_uint32"] or a["uinteger"] == b["uinteger"]
    np.testing.assert_array_equal(radar.rng.random(9, dtype=np.float32), ref.random(9, dtype=np.float32))
