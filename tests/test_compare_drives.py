"""scripts/compare_drives.py: the paired comparison of two slam_accuracy driver runs."""

import json

import numpy as np
import pytest

from rhs_studies import compare_drives as cd


def _results(path, rmse: dict, nees_inside: int = 150):
    """A slam_accuracy results file with a drivers part: rmse maps (env, driver) -> per-seed RMSEs (seeds 0..)."""
    combos = {f"{env}/{driver}": {"env": env, "driver": driver,
                                   "runs": [{"seed": s, "position_rmse_m": float(v), "nees_cycles": 200,
                                             "nees_inside": nees_inside} for s, v in enumerate(vals)]}
              for (env, driver), vals in rmse.items()}
    path.write_text(json.dumps({"parts": {"drivers": {"combos": combos}}}))
    return path


def test_a_uniform_gain_is_found_with_its_interval_and_an_unpaired_drive_is_left_out(tmp_path, capsys):
    rng = np.random.default_rng(0)
    base = {("hw", "idm"): rng.uniform(0.2, 0.8, 30), ("hw", "random"): rng.uniform(0.05, 0.2, 30)}
    new = {k: v * 0.5 for k, v in base.items()}
    new[("hw", "idm")] = np.append(new[("hw", "idm")], 9.0)  # seed 30: only in the new run, not a pair
    a, b = _results(tmp_path / "a.json", base), _results(tmp_path / "b.json", new, nees_inside=190)
    rows = {(r.drivers, r.env): r for r in cd.compare(cd.load_drives(a), cd.load_drives(b))}
    idm = rows[("idm", "hw")]
    assert idm.drives == 30 and idm.new_worst_m == pytest.approx(base[("hw", "idm")].max() / 2)
    assert idm.paired_mean_m == pytest.approx(-base[("hw", "idm")].mean() / 2)
    assert idm.paired_ci95_m[0] < idm.paired_mean_m < idm.paired_ci95_m[1] < 0
    assert idm.geometric_ratio == pytest.approx(0.5)
    assert (idm.base_nees_inside, idm.new_nees_inside) == (0.75, 0.95)
    assert rows[("idm+policy", "both")].drives == 30 and ("policy", "hw") not in rows  # no policy drives: no row
    assert rows[("random", "both")].drives == 30
    assert cd.main([str(a), str(b), "--json", str(tmp_path / "c.json")]) == 0
    assert "| idm | hw | 30 |" in capsys.readouterr().out
    assert len(json.loads((tmp_path / "c.json").read_text())) == len(rows)


def test_identical_runs_give_a_zero_difference_and_bad_inputs_say_why(tmp_path):
    base = {("hw", "policy"): [0.3, 0.4, 0.5]}
    a = _results(tmp_path / "a.json", base)
    (row,) = [r for r in cd.compare(cd.load_drives(a), cd.load_drives(a)) if r.env == "hw" and r.drivers == "policy"]
    assert row.paired_mean_m == 0 and row.paired_ci95_m == (0, 0) and row.geometric_ratio == pytest.approx(1)
    (one,) = [r for r in cd.compare(cd.load_drives(a), cd.load_drives(_results(tmp_path / "n.json", {("hw", "policy"): [0.2]})))
              if r.env == "hw" and r.drivers == "policy"]
    assert one.drives == 1 and one.paired_mean_m == pytest.approx(-0.1) and np.isnan(one.paired_ci95_m[0])  # no spread of one
    (tmp_path / "x.json").write_text(json.dumps({"parts": {"highway": {}}}))
    with pytest.raises(ValueError, match="no drivers part"):
        cd.load_drives(tmp_path / "x.json")
    other = _results(tmp_path / "o.json", {("dense", "policy"): [0.3]})
    for argv in ([str(a), str(tmp_path / "x.json")], [str(a), str(other)]):
        with pytest.raises(SystemExit) as err:
            cd.main(argv)
        assert err.value.code == 2
