"""Range-domain synthesis (fidelity="range") against the IQ reference (fidelity="iq").

Small, fast configs (hologram patterns, 5-degree grid, 24 elements, 60 m):
the spectrum of a tone in closed form equals the FFT of its samples; the noise
bins have the covariance of the windowed FFT of white noise; the CFAR
false-alarm rate on noise-only scans is the design Pfa; and on 200 random
scenes the point clouds are statistically the same as the IQ path's.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rhs_env.array_models import RHSConfig, ScanConfig
from rhs_env.point_cloud import tone_spectra, window_exponentials
from rhs_env.radar import DetectionConfig, LinkBudgetConfig, RadarConfig, RadarSystem
from rhs_env.scatterers import Scatterers
from rhs_env.windows import WINDOWS, make_window

SMALL = RadarConfig(antenna="hologram", scan=ScanConfig(grid_deg=5.0), rhs=RHSConfig(elements=24), max_range_m=60.0)


def test_fidelity_is_validated_and_selectable_through_the_config():
    with pytest.raises(ValueError, match="fidelity"):
        RadarConfig(fidelity="rf")
    assert RadarConfig(fidelity="iq").fidelity == "iq"


@pytest.mark.parametrize("window", WINDOWS)
def test_tone_spectrum_in_closed_form_equals_the_fft_of_the_samples(window):
    n, z, kb = 400, 2, 357
    freq = np.array([0.0, 0.1234, 0.25, 0.4101, 0.93])  # cycles/sample, on and off the bin grid, aliased
    w = make_window(window, n).astype(float)
    ref = np.fft.fft(w * np.exp(2j * np.pi * freq[:, None] * np.arange(n)), z * n)[:, :kb]
    got = tone_spectra(window, n, z, kb, freq)
    assert np.abs(got - ref).max() < 1e-7 * np.abs(ref).max()
    assert len(window_exponentials(window, n)[0]) <= 7  # a short cosine sum, not a fit of N terms


def test_noiseless_spectrum_matches_the_iq_path():
    """Same echoes (same generator state): the direct spectrum is the FFT of the synthesized samples."""
    cfg = replace(SMALL, link=LinkBudgetConfig(add_noise=False))
    scat = Scatterers(np.array([[20.0, 3.0], [-35.0, -8.0], [4.0, 41.0]]), np.array([[-20.0, 1.0], [3.0, 0.0], [0.0, 5.0]]),
                      [5.0, 10.0, 1.0], [0, 1, 2], [True, False, True])
    iq = RadarSystem(cfg, np.random.default_rng(3))
    rg = RadarSystem(replace(cfg, fidelity="range"), np.random.default_rng(3))
    ref = iq.range_spectrum(iq.synthesize(scat))
    got = rg.synthesize_spectrum(scat)
    assert got.shape == ref.shape
    assert np.abs(got - ref).max() < 1e-5 * np.abs(ref).max()


@pytest.mark.parametrize(("window", "rate"), [("hann", 2), ("boxcar", 1)])
def test_noise_bins_have_the_covariance_of_the_windowed_fft_of_white_noise(window, rate):
    """E[Y_k Y_{k+d}^*] = sigma^2 sum_n w[n]^2 exp(+j 2 pi d n / (Z N)) for d = 0..3 (half-bin lags included),
    whether the noise is drawn at half rate (Hann: the alias term is negligible) or at full rate (boxcar)."""
    cfg = replace(SMALL, fidelity="range", waveform=replace(SMALL.waveform, window=window))
    radar = RadarSystem(cfg, np.random.default_rng(5))
    assert radar.noise.rate == rate
    cfg = radar.config
    n, z = cfg.waveform.samples, cfg.waveform.zero_pad
    w2 = make_window(cfg.waveform.window, n).astype(float) ** 2
    ys = [radar.synthesize_spectrum(Scatterers.empty()).reshape(-1, radar.range_fft.bin_hi).astype(complex) for _ in range(4)]
    y = np.concatenate(ys) / np.sqrt(cfg.noise_power_w)
    for d in range(4):
        want = np.sum(w2 * np.exp(2j * np.pi * d * np.arange(n) / (z * n)))
        got = np.mean(y[:, : y.shape[1] - d] * np.conj(y[:, d:]))
        se = np.sum(w2) / np.sqrt(y.shape[0] * (y.shape[1] - d))  # std of the mean of |Y|^2-sized products
        assert abs(got - want) < 5 * se, (d, got, want)
    assert abs(np.mean(y.real * y.imag)) < 5 * np.sum(w2) / np.sqrt(y.size)  # circular


@pytest.mark.parametrize("fidelity", ["range", "iq"])
def test_cfar_false_alarm_rate_on_noise_only_scans_is_the_design_pfa(fidelity):
    pfa = 1e-3
    radar = RadarSystem(replace(SMALL, detection=DetectionConfig(pfa=pfa), fidelity=fidelity), np.random.default_rng(11))
    cfg = radar.config
    edge = cfg.waveform.zero_pad * (cfg.detection.guard + cfg.detection.train)  # cells with the full training window
    exceed = cells = 0
    for _ in range(250):
        if fidelity == "range":
            spec = radar.synthesize_spectrum(Scatterers.empty())
        else:
            spec = radar.range_spectrum(radar.synthesize(Scatterers.empty()))
        prof = radar.detector.profile(spec)[:, edge:-edge]
        thr = radar.detector.threshold(radar.detector.profile(spec))[:, edge:-edge]
        exceed += int(np.sum(prof > thr))
        cells += prof.size
    rate = exceed / cells
    print(f"{fidelity}: false-alarm rate {rate:.2e} over {cells} cells (design {pfa:.0e})")
    assert 0.7 * pfa < rate < 1.3 * pfa


def _scene(rng: np.random.Generator, radar: RadarSystem, n: int = 6) -> Scatterers:
    """Targets 8-55 m inside random radars' sectors, RCS 0.001-3 m^2 (log-uniform: many near the detection
    threshold, where the noise statistics decide), random velocities (Doppler +-20 m/s)."""
    r = rng.integers(0, 4, n)
    rng_m = rng.uniform(8, 55, n)
    th = radar.boresights[r] + np.deg2rad(rng.uniform(-40, 40, n))
    xy = radar.positions[r] + rng_m[:, None] * np.column_stack([np.cos(th), np.sin(th)])
    return Scatterers(xy, rng.uniform(-20, 20, (n, 2)), 10 ** rng.uniform(-3, 0.5, n), np.arange(n), np.ones(n, bool))


def _scan_metrics(fidelity: str, scenes: int = 200) -> dict[str, tuple[float, float]]:
    """(estimate, 95 % half-width) per metric of :func:`rhs_studies.radar_quality.evaluate` over ``scenes`` random
    scenes (the same scenes for both fidelities)."""
    from rhs_studies.radar_quality import evaluate

    metrics = evaluate(replace(SMALL, fidelity=fidelity), scenes, seed=21, scene=_scene)
    compared = ("detection_rate", "false_points_per_scan", "range_rmse_m", "angle_rmse_deg", "doppler_rmse_mps")
    return {k: (metrics[k]["rmse"] if "rmse" in metrics[k] else metrics[k]["mean"], metrics[k]["ci95"]) for k in compared}


def test_range_fidelity_point_clouds_equal_the_iq_path_on_200_scenes():
    """Detection rate, false points per scan, range / angle / Doppler RMSE: the 95 % CI of each difference holds 0."""
    iq, rg = _scan_metrics("iq"), _scan_metrics("range")
    for k in iq:
        (a, ha), (b, hb) = iq[k], rg[k]
        print(f"{k}: iq {a:.4g} +- {ha:.2g}, range {b:.4g} +- {hb:.2g}")
        assert abs(a - b) <= np.hypot(ha, hb), k  # the difference's 95 % interval (independent estimates) holds 0
    assert 0.6 < iq["detection_rate"][0] < 0.97  # the scenes are seen, many targets near the threshold


def test_noise_decimation_bounds_the_alias_term():
    """Half rate only where the alias term R(d + Z N / 2) is negligible on the searched bins."""
    from rhs_env.point_cloud import noise_decimation

    hann = make_window("hann", 400)
    assert noise_decimation(hann, 2, 334) == 2  # the default waveform and range
    assert noise_decimation(hann, 2, 400) == 1  # the searched band reaches the half-rate FFT's length
    assert noise_decimation(make_window("boxcar", 400), 2, 334) == 1  # slow sidelobes alias
    assert noise_decimation(make_window("hann", 401), 2, 334) == 1  # odd N
    r = np.abs(np.fft.fft(hann.astype(float) ** 2, 800))
    assert r[400 - 334 + 1 : 400 + 334].max() < 1e-4 * r[0]
