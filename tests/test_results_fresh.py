"""Results cannot silently disagree with the code (``rhs_studies/kit/provenance.py`` explains the design).

* every script's small-config ``fingerprint()`` still gives the hash recorded in
  ``results/fingerprints.json``; if not, the results it guards are stale;
* every ``results/*.json`` is written by a step of ``scripts/reproduce.py`` and carries
  provenance (commit: an ancestor of HEAD, command line, full config) or is shown as
  unverified on the pages that show it (README.md, docs/), as is every result whose fingerprint no longer matches;
* the mechanism itself: rounding, hashing, verification and the README warning.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rhs_studies import provenance as prov
from rhs_studies import reproduce, write_results_pages

SCRIPTS = Path(__file__).resolve().parent.parent / "scripts"

RESULTS = prov.RESULTS
OUTPUTS = ("fingerprints.json",)


def _fingerprinted() -> list[reproduce.Step]:
    return [s for s in reproduce.STEPS if not s.no_fingerprint]


def test_every_step_has_a_fingerprint_or_says_why_not():
    for s in reproduce.STEPS:
        has = reproduce.fingerprint_fn(s) is not None
        assert has or s.no_fingerprint, f"scripts/{s.script}: define fingerprint() or say why not (Step.no_fingerprint)"
    names = [prov.script_name(s.script) for s in _fingerprinted()]
    assert len(names) == len(set(names)), "one fingerprinted step per script (the others: Step.no_fingerprint)"


@pytest.mark.parametrize("step", _fingerprinted(), ids=lambda s: s.name)
def test_fingerprint_matches_the_code(step):
    recorded = prov.load_fingerprints().get(prov.script_name(step.script))
    files = ", ".join(f"results/{r}" for r in step.results)
    assert recorded is not None, f"{files}: no fingerprint recorded: rerun scripts/{step.script}"
    assert recorded.get("tolerance"), f"no measured tolerance: python scripts/fingerprint_tolerance.py --only {step.name}"
    now = prov.compute_fingerprint(reproduce.fingerprint_fn(step))
    ok, why = prov.fingerprint_matches(recorded, now["values"])
    if not ok:
        pytest.fail(
            f"{files} is stale: rerun scripts/{step.script} (python scripts/reproduce.py --only {step.name}); "
            f"the code's output on the fingerprint config changed beyond the tolerance measured across machines "
            f"and dependency versions ({why}). If the full rerun must wait, record it: "
            f"python scripts/reproduce.py --fingerprints-only --only {step.name} --reason '...' "
            "(the README then marks these results unverified)."
        )


def _odometry_bias(monkeypatch):
    """A real change of the SLAM: the filter's motion prediction takes the registration motion 1 % long."""
    from slam.core.rbpf import RBPFSlam

    predict = RBPFSlam._predict

    def biased(self, motion, dt):
        predict(self, None if motion is None else 1.01 * np.asarray(motion, dtype=float), dt)

    monkeypatch.setattr(RBPFSlam, "_predict", biased)


def _noisier_receiver(monkeypatch):
    """A real change of the radar: the receiver noise power kT F B one dB higher (k scaled by 10^0.1)."""
    import rhs_env.radar_config as rc

    monkeypatch.setattr(rc, "BOLTZMANN", rc.BOLTZMANN * 10 ** 0.1)


@pytest.mark.parametrize(("name", "change"), [("fig5c", _odometry_bias), ("radar_quality", _noisier_receiver)])
def test_a_real_change_of_the_output_fails_the_tolerance(monkeypatch, name, change):
    """The tolerance absorbs what another machine changes, not what another code computes."""
    step = reproduce.BY_NAME[name]
    entry = prov.load_fingerprints()[prov.script_name(step.script)]
    change(monkeypatch)
    now = prov.compute_fingerprint(reproduce.fingerprint_fn(step))["values"]
    ok, why = prov.fingerprint_matches(entry, now)
    assert not ok, f"{name}: a changed code still matched its fingerprint ({why})"


def test_every_tolerance_was_measured_and_is_tight():
    """Each fingerprinted step carries the tolerance and spread measured by scripts/fingerprint_tolerance.py;
    only closed-loop driving steps may let values flip, and no step allows more than a few percent."""
    fps = prov.load_fingerprints()
    for s in _fingerprinted():
        tol = fps[prov.script_name(s.script)].get("tolerance")
        assert tol and {"rtol", "atol", "may_flip", "spread"} <= set(tol), f"{s.name}: no measured tolerance"
        spreads = [m["spread"] for m in tol.get("machines", {}).values()] or [tol["spread"]]  # each machine's own
        assert all({"native", "avx2-machine"} <= set(sp) for sp in spreads), f"{s.name}: spread not measured across CPUs"
        assert tol["rtol"] <= 0.05, f"{s.name}: rtol {tol['rtol']} is too loose to catch a real change"
        assert len(tol["may_flip"]) <= len(fps[prov.script_name(s.script)]["values"]) // 3, s.name


def test_every_results_file_has_a_step_and_provenance_or_is_flagged():
    flagged = []
    for f in sorted(RESULTS.glob("*.json")):
        if f.name in OUTPUTS or f.name.endswith(".partial.json"):
            continue
        step = reproduce.step_for_result(f.name)
        assert step is not None, f"results/{f.name} is written by no step of scripts/reproduce.py"
        data = json.loads(f.read_text())
        p = data.get("provenance") if isinstance(data, dict) else None
        if p is None:
            flagged.append(f.name)
            continue
        assert {"commit", "dirty", "command", "config", "wall_s"} <= set(p), f"results/{f.name}: incomplete provenance"
        assert p["command"][1] == f"scripts/{step.script}", f"results/{f.name} written by {p['command'][1]}"
        if p["commit"] is not None and prov.git_state()["commit"] is not None:
            assert prov.is_ancestor(p["commit"]) is not False, (
                f"results/{f.name} records commit {p['commit'][:10]}, not an ancestor of HEAD: rerun scripts/{step.script}"
            )
        if not step.no_fingerprint:
            assert p.get("fingerprint"), f"results/{f.name}: no fingerprint in its provenance"
    # files without provenance are legal only while the pages show them as unverified
    for page in write_results_pages.pages():
        text = page.read_text()
        for name in flagged:
            stem = Path(name).stem
            if f"<!-- results:{stem} -->" in text:
                block = text.split(f"<!-- results:{stem} -->")[1].split(f"<!-- /results:{stem} -->")[0]
                assert "**Unverified:**" in block, f"{page.name} shows results/{name} (no provenance) without a warning"


def test_readme_is_up_to_date_with_results_and_their_verification():
    """README.md and every docs page show the results as they are, with a warning on each unverified one."""
    for page in write_results_pages.pages():
        text = page.read_text()
        assert write_results_pages.render(text, RESULTS, page) == text, (
            f"{page.relative_to(prov.ROOT)} is out of date with results/ (or an unverified result lacks its "
            "warning): run python scripts/write_results_pages.py"
        )


def test_every_results_table_is_on_a_docs_page():
    """Each results/NAME.md is shown on the documentation site, and the README has its headline table."""
    shown = "".join(p.read_text() for p in write_results_pages.pages() if p.name != "README.md")
    for f in sorted(RESULTS.glob("*.md")):
        assert f"<!-- results:{f.stem} -->" in shown, f"results/{f.name} is on no page under docs/"
    assert "<!-- results:headline -->" in (prov.ROOT / "README.md").read_text()


# --------------------------------------------------------------------------- the mechanism
def test_values_outside_the_tolerance():
    tol = {"rtol": 1e-3, "atol": 1e-6, "may_flip": [2]}
    assert prov.values_outside([1.0, 0.0, None], [1.0009, 5e-7, None], tol) == []
    assert prov.values_outside([1.0, 0.0, None], [1.0011, 2e-6, 3.0], tol) == [(0, 1.0, 1.0011), (1, 0.0, 2e-6), (2, None, 3.0)]
    entry = {"values": [1.0, 2.0, 3.0], "tolerance": tol}
    assert prov.fingerprint_matches(entry, [1.0, 2.0, 3.5])[0]  # the value that may flip
    assert not prov.fingerprint_matches(entry, [1.0, 2.5, 3.0])[0]  # another one
    assert not prov.fingerprint_matches(entry, [1.1, 2.0, 3.5])[0]
    assert not prov.fingerprint_matches(entry, [1.0, 2.0])[0]  # a value fewer
    assert prov.fingerprint_matches({"values": [1.0]}, [1.000004])[0]  # no tolerance: only the rounding


def test_the_tolerance_rule_on_measured_spreads():
    from rhs_studies import fingerprint_tolerance as ft

    recorded = [1.0, 2.0, 1e-9, 10.0]
    runs = {"native": [1.0, 2.0, 1e-9, 10.0], "avx2-machine": [1.00001, 2.0, 3e-9, 12.0]}
    tol = ft.tolerance(recorded, runs)
    assert tol["spread"]["avx2-machine"] == {"max_rel": 1e-05, "flipped": 1}  # 10 -> 12 flipped
    assert tol["rtol"] == pytest.approx(ft.SAFETY * 1e-5) and tol["may_flip"] == [3]
    assert prov.fingerprint_matches({"values": recorded, "tolerance": tol}, runs["avx2-machine"])[0]


def test_tolerances_of_two_machines_accumulate():
    """A tolerance measured on a second CPU is merged with the first one's: both machines' flips and spreads hold."""
    from rhs_studies import fingerprint_tolerance as ft

    recorded = [1.0, 2.0, 3.0, 10.0]
    first = ft.tolerance(recorded, {"native": [1.0, 2.0, 3.0, 12.0]})
    first["measured"]["machine"] = "Intel Xeon avx512"
    second = ft.tolerance(recorded, {"native": [1.0001, 2.5, 3.0, 10.0]})
    second["measured"]["machine"] = "AMD EPYC avx512"
    both = ft.merged(first, second)
    assert both["may_flip"] == [1, 3] and both["rtol"] == max(first["rtol"], second["rtol"])
    assert set(both["spread"]) == {"Intel Xeon avx512: native", "AMD EPYC avx512: native"}
    for machine_values in ([1.0, 2.0, 3.0, 12.0], [1.0001, 2.5, 3.0, 10.0]):
        assert prov.fingerprint_matches({"values": recorded, "tolerance": both}, machine_values)[0]
    again = ft.tolerance(recorded, {"native": [1.0, 2.0, 3.0, 10.0]})  # the second machine measured again
    again["measured"]["machine"] = "AMD EPYC avx512"
    now = ft.merged(both, again)  # replaces that machine's measurement, keeps the first machine's
    assert set(now["machines"]) == {"Intel Xeon avx512", "AMD EPYC avx512"} and now["may_flip"] == [3]
    assert prov.fingerprint_matches({"values": recorded, "tolerance": now}, [1.0, 2.0, 3.0, 12.0])[0]
    unnamed = {k: v for k, v in first.items() if k != "measured"}  # recorded before machines were named
    assert set(ft.merged(unnamed, second)["machines"]) == {ft.EARLIER_MACHINE, "AMD EPYC avx512"}


def test_the_tolerance_script_measures_a_step_in_subprocesses(capsys):
    """``fingerprint_tolerance --dry-run`` reruns a fingerprint under two settings and prints its row."""
    from rhs_studies import fingerprint_tolerance as ft

    assert ft.main(["--only", "fig5b", "--settings", "native", "openblas-sandybridge", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "native" in out and "openblas-sandybridge" in out and "\nfig5b " in out


def test_a_study_subprocess_runs_single_threaded_and_headless_on_this_checkout(monkeypatch):
    """reproduce's steps: one OpenMP / OpenBLAS / MKL thread; the tolerance's settings: OpenMP only (as the
    tests run), a setting's own variables on top; both headless and with this checkout first on PYTHONPATH."""
    import os

    from rhs_studies.subprocess_env import study_env

    monkeypatch.setenv("PYTHONPATH", "/elsewhere")
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "8")
    env = study_env()
    assert env["OMP_NUM_THREADS"] == env["OPENBLAS_NUM_THREADS"] == env["MKL_NUM_THREADS"] == "1"
    assert env["MPLBACKEND"] == "Agg" and env["SDL_VIDEODRIVER"] == "dummy"
    assert env["PYTHONPATH"].split(os.pathsep) == [str(prov.ROOT), "/elsewhere"]
    setting = study_env({"OMP_NUM_THREADS": "2", "PYTHONPATH": "/x"}, blas_single_thread=False)
    assert setting["OMP_NUM_THREADS"] == "2" and setting["OPENBLAS_NUM_THREADS"] == "8"
    assert setting["PYTHONPATH"].split(os.pathsep)[0] == str(prov.ROOT)


def test_digest_rounds_to_significant_digits_and_detects_changes():
    h1, v1 = prov.digest([1.0, 0.123456789, None, float("nan"), 3])
    assert v1 == [1.0, 0.123457, None, None, 3.0]
    assert prov.digest([1.0 + 1e-12, 0.1234567891, None, None, 3])[0] == h1  # last-bit noise: same hash
    assert prov.digest([1.0, 0.12346, None, None, 3])[0] != h1  # a real change: another hash
    assert prov.digest([1.0, 0.123456789, None, None])[0] != h1  # a value fewer


def test_verification_and_readme_warning(tmp_path):
    res = tmp_path / "fig5c.json"
    fps = {"fig5c_trajectory_map": {"hash": "aaaa", "values": [], "note": "full run", "commit": "c0ffee"}}
    res.write_text(json.dumps({"x": 1}))
    ok, why = prov.verification(res, fps)
    assert not ok and "before results recorded their provenance" in why
    res.write_text(json.dumps({"x": 1, "provenance": {"fingerprint": {"name": "fig5c_trajectory_map", "hash": "aaaa"}}}))
    assert prov.verification(res, fps) == (True, "fingerprint matches the code")
    fps["fig5c_trajectory_map"].update(hash="bbbb", note="refreshed without rerun: SLAM changed")
    ok, why = prov.verification(res, fps)
    assert not ok and "SLAM changed" in why
    (tmp_path / "fingerprints.json").write_text(json.dumps(fps))
    (tmp_path / "fig5c.md").write_text("| table |\n")
    out = write_results_pages.render("a\n<!-- results:fig5c -->\nold\n<!-- /results:fig5c -->\n", tmp_path)
    assert "| table |" in out and "**Unverified:**" in out and "SLAM changed" in out
    assert "reproduce.py --only fig5c" in out


def test_figure_links_follow_the_page():
    """A results table's figure link (from the repository root) points at the figure from a docs page too."""
    md = "![map](results/fig5c.png) and [json](results/fig5c.json)"
    assert write_results_pages.figure_links(md, prov.ROOT / "README.md") == md
    assert write_results_pages.figure_links(md, prov.ROOT / "docs" / "results" / "fig5c.md") == "![map](fig5c.png) and [json](fig5c.json)"
    assert write_results_pages.figure_links(md, prov.ROOT / "docs" / "index.md") == md
    assert write_results_pages.figure_links(md, prov.ROOT / "docs" / "usage" / "x.md") == md.replace("](results/", "](../results/")


def test_headline_table_comes_from_the_results_and_flags_unverified_ones(tmp_path):
    """Every headline number is read from a results JSON; an unverified source gets its warning."""
    import shutil

    names = {name for name, _ in write_results_pages.HEADLINE}
    for name in names:
        if (RESULTS / f"{name}.json").exists() or name not in write_results_pages.OPTIONAL_HEADLINE:
            shutil.copy(RESULTS / f"{name}.json", tmp_path / f"{name}.json")
    fps = prov.load_fingerprints(RESULTS / "fingerprints.json")
    (tmp_path / "fingerprints.json").write_text(json.dumps(fps))
    table = write_results_pages.headline(tmp_path, fps)
    rows = sum(1 for name, build in write_results_pages.HEADLINE if (tmp_path / f"{name}.json").exists()
               and build(json.loads((tmp_path / f"{name}.json").read_text())) is not None)
    assert table is not None and table.count("\n| ") == rows >= len(write_results_pages.HEADLINE) - 1  # a row each
    data = json.loads((tmp_path / "registration.json").read_text())
    data["icp"]["translation_rmse_m"] = 0.4321
    data.pop("provenance", None)
    (tmp_path / "registration.json").write_text(json.dumps(data))
    table = write_results_pages.headline(tmp_path, fps)
    assert "0.432 m" in table and "**Unverified:**" in table and "registration.json" in table
    (tmp_path / "fig5a.json").unlink()
    assert write_results_pages.headline(tmp_path, fps) is None  # a missing source: the block is left as it is


def test_readme_block_drops_the_results_files_own_heading():
    """The README section has its heading; the block must not repeat it (or add an H1 mid-README)."""
    assert write_results_pages.block_text("# SLAM accuracy\n\n| a |\n") == "| a |"
    assert write_results_pages.block_text("### Claim\n| a |\n\n## kept\n") == "| a |\n\n## kept"
    assert write_results_pages.block_text("| a |\n# not first\n") == "| a |\n# not first"


def test_write_json_records_provenance_outside_results(tmp_path):
    out = tmp_path / "x.json"
    p = prov.write_json(out, {"v": 1}, SCRIPTS / "fig5c_trajectory_map.py", {"seed": 3, "path": tmp_path}, 0.0,
                        fingerprint_fn=lambda: [1.0, 2.0], argv=["--seed", "3"])
    data = json.loads(out.read_text())
    assert data["v"] == 1 and data["provenance"] == json.loads(json.dumps(p))
    assert p["command"] == ["python", "scripts/fig5c_trajectory_map.py", "--seed", "3"]
    assert p["config"] == {"seed": 3, "path": str(tmp_path)}
    assert p["fingerprint"]["hash"] == prov.digest([1.0, 2.0])[0]
    assert set(p) >= {"commit", "dirty", "dirty_files", "started_utc", "wall_s", "python", "numpy"}


def test_recorded_paths_inside_the_repository_are_relative(tmp_path):
    """A results file names no machine's folders: paths inside the repository are recorded from its root."""
    cfg = prov.jsonable({"lib": prov.ROOT / "rhs_env" / "patterns" / "data", "out": tmp_path / "x.json"})
    assert cfg["lib"] == "rhs_env/patterns/data" and cfg["out"] == str(tmp_path / "x.json")


def test_a_run_within_the_measured_tolerance_keeps_the_recorded_fingerprint():
    """Another CPU's last digits (within the step's measured tolerance) leave the recorded fingerprint the code's, so
    the results made with it stay verified; a value beyond the tolerance, or an entry without one, is new code."""
    entry = {"hash": "old", "values": [0.00153005, None, 1.0], "tolerance": {"rtol": 7.84e-05, "atol": 7.84e-08}}
    assert prov.same_code_elsewhere(entry, {"hash": "new", "values": [0.00153002, None, 1.0]})
    assert not prov.same_code_elsewhere(entry, {"hash": "new", "values": [0.00154, None, 1.0]})
    assert not prov.same_code_elsewhere(entry, {"hash": "new", "values": [0.00153002, 0.5, 1.0]})
    assert not prov.same_code_elsewhere({k: v for k, v in entry.items() if k != "tolerance"},
                                        {"hash": "new", "values": [0.00153002, None, 1.0]})
    assert not prov.same_code_elsewhere({}, {"hash": "new", "values": [1.0]})
