"""Antenna model: twin beam of the closed-form hologram, phased-array baseline, config validation."""

from __future__ import annotations

import numpy as np
import pytest

from rhs_env.array_models import (
    RHSConfig,
    ScanConfig,
    hologram_pattern,
    phased_array,
    rhs_antenna,
)

TWIN_LIMIT = 2 * np.sqrt(3.0) - 1.0 / 0.25 + 1.0  # sin(theta) <= 0.464: the Tx twin is visible


def _fine_s(n: int = 20001) -> np.ndarray:
    return np.linspace(-1.0, 1.0, n)


@pytest.mark.parametrize("angle_deg", [-40.0, -20.0, 0.0, 15.0, 25.0])
def test_hologram_twin_is_exact_and_strong(angle_deg: float) -> None:
    cfg = RHSConfig()
    ant = rhs_antenna(
        cfg,
        hologram_pattern(cfg, [angle_deg], cfg.tx_feed),
        hologram_pattern(cfg, [angle_deg], cfg.rx_feed),
        [angle_deg],
        name="hologram",
    )
    s = np.sin(np.deg2rad(angle_deg))
    assert s <= TWIN_LIMIT
    for feed, gain in ((cfg.tx_feed, ant.tx_gain), (cfg.rx_feed, ant.rx_gain)):
        twins = cfg.twin_sin(s, feed)
        twins = twins[np.isfinite(twins)]
        if feed == cfg.tx_feed:
            assert twins.size >= 1  # visible for sin(theta) <= 0.464
        if twins.size == 0:
            continue
        g_main = np.abs(gain(np.arcsin(np.array([s]))))[0, 0]
        g_twin = np.abs(gain(np.arcsin(twins)))[0]
        np.testing.assert_allclose(g_twin, g_main, rtol=1e-9)  # |t(theta')| = |t(theta)| exactly
        peak = np.max(np.abs(gain(np.arcsin(_fine_s())))[0])
        assert 20 * np.log10(g_twin.min() / peak) > -1.0  # a lobe as strong as the main lobe


@pytest.mark.parametrize("angle_deg", [28.5, 35.0, 44.5])
def test_hologram_twin_not_visible_beyond_limit(angle_deg: float) -> None:
    cfg = RHSConfig()
    s = np.sin(np.deg2rad(angle_deg))
    assert s > TWIN_LIMIT
    assert np.all(np.isnan(cfg.twin_sin(s, cfg.tx_feed)))


def test_phased_array_beamwidth_and_sidelobe() -> None:
    n = 60
    ant = phased_array(RHSConfig(), np.array([0.0]), elements=n)
    s = _fine_s(200001)
    p = np.abs(ant.tx_gain(np.arcsin(s))[0]) ** 2
    p_db = 10 * np.log10(p / p.max())
    above = s[p_db >= 10 * np.log10(0.5)]
    hpbw = above.max() - above.min()
    expect = 0.886 / (n * 0.5)  # 0.886 lambda / (N d) in sin(theta)
    assert abs(hpbw / expect - 1.0) < 0.05
    # first sidelobe: the largest local maximum outside the first null at 1/(N d)
    outside = np.abs(s) > 1.0 / (n * 0.5)
    assert abs(p_db[outside].max() - (-13.26)) < 0.5


def test_invalid_configs_name_the_field() -> None:
    with pytest.raises(ValueError, match="elements"):
        RHSConfig(elements=1)
    with pytest.raises(ValueError, match="spacing_wl"):
        RHSConfig(spacing_wl=0.0)
    with pytest.raises(ValueError, match="spacing_wl"):
        RHSConfig(spacing_wl=-0.1)
    with pytest.raises(ValueError, match="grid_deg"):
        ScanConfig(grid_deg=7.0, sector_deg=90.0)
    cfg = RHSConfig(elements=4)
    good = np.full((1, 4), 0.5)
    with pytest.raises(ValueError, match=r"tx amplitudes must lie in \[0, 1\]"):
        rhs_antenna(cfg, good + 1.0, good, [0.0])
    with pytest.raises(ValueError, match=r"rx amplitudes must lie in \[0, 1\]"):
        rhs_antenna(cfg, good, good - 1.0, [0.0])
