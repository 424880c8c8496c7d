"""RadarConfig's groups: construction, nested mappings, the old flat names (DeprecationWarning), path-named errors."""

from __future__ import annotations

import dataclasses
import pickle
import warnings

import gymnasium as gym
import pytest
from conftest import small_env_kwargs

import rhs_env  # noqa: F401  (registers the ids)
from rhs_common.validation import build, flat_dict
from rhs_env.radar import (
    AngleEstimationConfig,
    DetectionConfig,
    LinkBudgetConfig,
    MountingConfig,
    RadarConfig,
    UncertaintyConfig,
    WaveformConfig,
)

#: RadarConfig().to_dict() before the grouping (the flat fields and their defaults)
FLAT_DEFAULTS = {
    "bandwidth_hz": 250e6, "chirp_s": 20e-6, "sample_rate_hz": 20e6, "chirps_per_slot": 4, "tx_power_dbm": 30.0,
    "noise_figure_db": 10.0, "temperature_k": 290.0, "add_noise": True, "min_range_m": 1.0, "max_range_m": 100.0,
    "antenna": "rhs", "detection": "cfar", "detector": "footprint", "cfar_guard": 2, "cfar_train": 8,
    "cfar_pfa": 1e-6, "cfar_method": "os", "cfar_rank": 0.75, "sidelobe_margin_db": 6.0, "cfar_cap_db": 10.0,
    "fixed_threshold_db": 15.0, "zero_pad": 2, "window": "hann", "omp_oversampling": 4, "omp_max_targets": 4,
    "omp_residual_pfa": 1e-3, "omp_residual_rel_db": -25.0, "omp_newton_steps": 2, "omp_min_snr_db": 15.0,
    "range_std_floor_m": 0.003, "angle_std_floor_deg": 0.003, "slot_doppler": True, "vehicle_length_m": 5.0,
    "vehicle_width_m": 2.0, "fidelity": "range",
}
#: a cheap radar env (closed-form antenna, coarse grid): construction only, nothing is scanned
CHEAP = {"antenna": "hologram", "vehicles_count": 2, "duration": 2}
CHEAP_RADAR = small_env_kwargs(slam=False)["radar"]


def _build(value, path="radar"):
    return build(RadarConfig, value, path)


def _no_warnings(fn, *args):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return fn(*args)


def _radar_env_config(radar: dict) -> RadarConfig:
    env = gym.make("rhs-highway-radar-v0", radar={**CHEAP_RADAR, **radar}, **CHEAP)
    try:
        return env.get_wrapper_attr("radar_config")
    finally:
        env.close()


# --------------------------------------------------------------------------- grouped construction
def test_groups_hold_the_former_defaults_and_the_flat_view_is_the_former_dict():
    cfg = RadarConfig()
    assert isinstance(cfg.waveform, WaveformConfig) and isinstance(cfg.link, LinkBudgetConfig)
    assert isinstance(cfg.detection, DetectionConfig) and isinstance(cfg.estimation, AngleEstimationConfig)
    assert isinstance(cfg.uncertainty, UncertaintyConfig) and isinstance(cfg.mounting, MountingConfig)
    flat = cfg.flat_dict()
    # a field added since (no flat name) shows under its path only where it changes what the radar does: the
    # converged refinement (8 passes at most, the stop at 1 % of the residual) did
    added = {"estimation.refine_passes": 8, "estimation.refine_tol": 0.01}
    assert {k: v for k, v in flat.items() if k not in ("rhs", "scan")} == {**FLAT_DEFAULTS, **added}
    assert dict(RadarConfig.ADDED_FIELDS) == {"estimation.refine_passes": 2, "estimation.refine_tol": 0.0, "kernels": "numba"}
    assert "estimation.refine_tol" not in _build({"estimation": {"refine_passes": 2, "refine_tol": 0.0}}).flat_dict()
    changed = _build({"estimation": {"refine_passes": 1}}).flat_dict()
    assert changed["estimation.refine_passes"] == 1 and changed != flat
    assert flat["rhs"] == cfg.rhs.to_dict() and flat["scan"] == cfg.scan.to_dict()
    assert flat_dict(cfg) == flat


def test_grouped_construction_and_derived_quantities():
    cfg = RadarConfig(detection=DetectionConfig(pfa=1e-5, statistic="summed"), link=LinkBudgetConfig(tx_power_dbm=20.0),
                      waveform=WaveformConfig(chirps_per_slot=8), mounting=MountingConfig(vehicle_length_m=4.0))
    assert (cfg.detection.pfa, cfg.detection.statistic, cfg.link.tx_power_dbm) == (1e-5, "summed", 20.0)
    assert cfg.waveform.samples == 400 and cfg.waveform.slope == pytest.approx(250e6 / 20e-6)
    assert cfg.waveform.range_resolution_m == pytest.approx(0.5996, abs=1e-4)
    assert cfg.waveform.unambiguous_range_m == pytest.approx(239.83, abs=0.01)
    assert cfg.link.tx_power_w == pytest.approx(0.1)
    assert cfg.noise_power_w == pytest.approx(1.380649e-23 * 290 * 10 * 20e6)
    assert cfg.mounting.mounts()[0][0, 0] == 2.0
    assert pickle.loads(pickle.dumps(cfg)) == cfg and hash(cfg) == hash(dataclasses.replace(cfg))
    # an int for a float field is stored as a float inside a group too (equal configs compare equal)
    assert DetectionConfig(fixed_threshold_db=15) == DetectionConfig()


def test_to_dict_is_nested_and_builds_back_without_warnings():
    cfg = RadarConfig(detection=DetectionConfig(mode="fixed"), estimation=AngleEstimationConfig(max_targets=2))
    d = cfg.to_dict()
    assert d["detection"]["mode"] == "fixed" and d["estimation"]["max_targets"] == 2
    assert _no_warnings(_build, d) == cfg


def test_every_moved_field_names_an_attribute_of_its_group():
    cfg = RadarConfig()
    for old, new in RadarConfig.MOVED_FIELDS.items():
        group, name = new.split(".")
        assert hasattr(getattr(cfg, group), name), (old, new)
        assert name in {f.name for f in dataclasses.fields(getattr(cfg, group))}


# --------------------------------------------------------------------------- nested mappings
def test_nested_mapping_builds_the_groups_without_warnings():
    cfg = _no_warnings(_build, {"detection": {"pfa": 1e-5, "method": "ca"}, "link": {"tx_power_dbm": 10},
                                "waveform": {"window": "hamming"}, "uncertainty": {"range_std_floor_m": 0.01}})
    assert cfg.detection == DetectionConfig(pfa=1e-5, method="ca")
    assert cfg.link.tx_power_dbm == 10.0 and isinstance(cfg.link.tx_power_dbm, float)
    assert cfg.waveform.window == "hamming" and cfg.uncertainty.range_std_floor_m == 0.01


def test_gym_make_takes_nested_radar_kwargs():
    cfg = _no_warnings(_radar_env_config, {"detection": {"pfa": 1e-5}, "link": {"tx_power_dbm": 20.0}})
    assert cfg.detection.pfa == 1e-5 and cfg.link.tx_power_dbm == 20.0 and cfg.antenna == "hologram"


# --------------------------------------------------------------------------- the old flat names
@pytest.mark.parametrize(("flat", "nested", "new_path"), [
    ({"cfar_pfa": 1e-5}, {"detection": {"pfa": 1e-5}}, "radar.detection.pfa"),
    ({"tx_power_dbm": 10}, {"link": {"tx_power_dbm": 10}}, "radar.link.tx_power_dbm"),
    ({"detection": "fixed"}, {"detection": {"mode": "fixed"}}, "radar.detection.mode"),
    ({"detector": "summed"}, {"detection": {"statistic": "summed"}}, "radar.detection.statistic"),
    ({"omp_max_targets": 2}, {"estimation": {"max_targets": 2}}, "radar.estimation.max_targets"),
    ({"zero_pad": 4}, {"waveform": {"zero_pad": 4}}, "radar.waveform.zero_pad"),
    ({"angle_std_floor_deg": 0.1}, {"uncertainty": {"angle_std_floor_deg": 0.1}}, "radar.uncertainty.angle_std_floor_deg"),
    ({"vehicle_width_m": 1.8}, {"mounting": {"vehicle_width_m": 1.8}}, "radar.mounting.vehicle_width_m"),
])
def test_flat_name_maps_to_its_group_with_a_deprecation_warning(flat, nested, new_path):
    old = f"radar.{next(iter(flat))}"
    with pytest.warns(DeprecationWarning, match=f"^{old} is now {new_path}$") as rec:
        cfg = _build(flat)
    assert cfg == _build(nested)
    assert rec[0].filename == __file__  # the warning names the caller, not the config machinery


def test_flat_names_through_gym_make_warn_and_merge_with_nested_ones():
    with pytest.warns(DeprecationWarning) as rec:
        cfg = _radar_env_config({"cfar_pfa": 1e-5, "detection": {"guard": 3}, "tx_power_dbm": 10.0, "detector": "summed"})
    assert cfg.detection == DetectionConfig(pfa=1e-5, guard=3, statistic="summed")
    assert cfg.link.tx_power_dbm == 10.0
    messages = sorted(str(w.message) for w in rec if w.category is DeprecationWarning)
    assert messages == ["radar.cfar_pfa is now radar.detection.pfa", "radar.detector is now radar.detection.statistic",
                        "radar.tx_power_dbm is now radar.link.tx_power_dbm"]
    assert all(w.filename == __file__ for w in rec)


def test_flat_mode_string_and_other_flat_detection_fields_combine():
    with pytest.warns(DeprecationWarning) as rec:
        cfg = _build({"detection": "fixed", "fixed_threshold_db": 12.0})
    assert cfg.detection == DetectionConfig(mode="fixed", fixed_threshold_db=12.0)
    assert sorted(str(w.message) for w in rec) == ["radar.detection is now radar.detection.mode",
                                                   "radar.fixed_threshold_db is now radar.detection.fixed_threshold_db"]


def test_flat_names_do_not_touch_the_caller_mapping():
    value = {"cfar_pfa": 1e-5, "detection": {"guard": 3}}
    with pytest.warns(DeprecationWarning):
        _build(value)
    assert value == {"cfar_pfa": 1e-5, "detection": {"guard": 3}}


@pytest.mark.parametrize("value", [
    {"cfar_pfa": 1e-5, "detection": {"pfa": 1e-4}},
    {"detection": {"mode": "cfar", "pfa": 1e-4}, "cfar_guard": 2, "cfar_pfa": 1e-5},
    {"tx_power_dbm": 10.0, "link": {"tx_power_dbm": 20.0}},
])
def test_the_same_field_flat_and_nested_is_a_conflict(value):
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match=r"radar\.\w+ and radar\.\w+\.\w+ both given"):
        _build(value)


def test_a_flat_name_beside_its_whole_group_is_a_conflict():
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="radar.detection given as a whole"):
        _build({"cfar_pfa": 1e-5, "detection": DetectionConfig()})


# --------------------------------------------------------------------------- errors name the path
@pytest.mark.parametrize(("value", "exc", "message"), [
    ({"detection": {"pfa": 2}}, ValueError, r"^radar\.detection\.pfa must be in \(0\.0, 0\.5\], got 2\.0$"),
    ({"detection": {"mode": "cfat"}}, ValueError, r"^radar\.detection\.mode must be one of 'cfar', 'fixed'"),
    ({"estimation": {"max_targets": 0}}, ValueError, r"^radar\.estimation\.max_targets must be in \[1, 32\]"),
    ({"mounting": {"vehicle_length_m": 80}}, ValueError, r"^radar\.mounting\.vehicle_length_m must be in"),
    ({"waveform": {"sample_rate_hz": 20.01e6}}, ValueError, r"^radar\.waveform\.sample_rate_hz \* chirp_s must be a whole"),
    ({"waveform": {"sample_rate_hz": 2e6}}, ValueError, r"^radar\.max_range_m must be in \[1\.0, 22\.7"),
    ({"detection": {"bogus": 1}}, ValueError, r"^radar\.detection has unknown field\(s\) 'bogus'"),
    ({"bogus": 1}, ValueError, r"^radar has unknown field\(s\) 'bogus'"),
    ({"link": {"tx_power_dbm": "20"}}, TypeError, r"^radar\.link\.tx_power_dbm must be a number"),
    ({"link": {"add_noise": 1}}, TypeError, r"^radar\.link\.add_noise must be True or False"),
    ({"link": 5}, TypeError, r"^radar\.link must be a LinkBudgetConfig or a dict of its fields, got 5 \(int\)"),
    ({"waveform": {"chirps_per_slot": 4.0}}, TypeError, r"^radar\.waveform\.chirps_per_slot must be an integer"),
])
def test_errors_name_the_full_path(value, exc, message):
    with pytest.raises(exc, match=message):
        _no_warnings(_build, value)


def test_flat_name_errors_name_the_new_path():
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match=r"^radar\.detection\.pfa must be in"):
        _build({"cfar_pfa": 2})
    with pytest.warns(DeprecationWarning), pytest.raises(TypeError, match=r"^radar\.detection\.mode must be a string"):
        _build({"detection": 5})


def test_gym_make_errors_name_the_path():
    with pytest.raises(ValueError, match=r"radar\.detection\.pfa must be in \(0\.0, 0\.5\], got 2"):
        _radar_env_config({"detection": {"pfa": 2}})
    with pytest.raises(TypeError, match=r"radar\.link\.tx_power_dbm must be a number"):
        _radar_env_config({"link": {"tx_power_dbm": "20"}})


def test_direct_construction_checks_the_group_types():
    with pytest.raises(TypeError, match="detection must be a DetectionConfig or a dict of its fields"):
        RadarConfig(detection="cfar")  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        RadarConfig(cfar_pfa=1e-5)  # type: ignore[call-arg]  # the flat names live on in mappings only
    with pytest.raises(ValueError, match="max_range_m"):
        RadarConfig(waveform=WaveformConfig(sample_rate_hz=2e6))  # unambiguous range 24 m < 100 m
