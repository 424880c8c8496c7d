"""The research kit's counts (rhs_studies.upkeep.kit_counts): exact on a tiny tree, and this checkout keeps its rules."""

from __future__ import annotations

import json
from pathlib import Path

from rhs_studies.upkeep import kit_counts as kc

ROOT = Path(__file__).resolve().parents[1]

STUDY_A = '''import argparse


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--out")
    return 0
'''
STUDY_B = '''from rhs_studies.a import main as run_a
from rhs_studies.kit import shared


def main(argv=None):
    from . import a  # the same pair again: a second statement
    return run_a(argv)
'''


def _tiny_tree(root: Path) -> Path:
    studies = root / "rhs_studies"
    (studies / "kit").mkdir(parents=True)
    (studies / "__init__.py").write_text("")
    (studies / "kit" / "__init__.py").write_text("")
    (studies / "kit" / "shared.py").write_text("def main():\n    return 0\n")  # the kit: no study, main or not
    (studies / "a.py").write_text(STUDY_A)
    (studies / "b.py").write_text(STUDY_B)
    (root / "rhs_env").mkdir()
    (root / "rhs_env" / "radar.py").write_text('def f(cfg):\n    if cfg.kernels == "numba":\n        return 1\n'
                                               '    return 0 if kernels != "numpy" else 2\n')
    return root


def test_the_counts_of_a_tiny_tree_are_exact(tmp_path):
    c = kc.measure(_tiny_tree(tmp_path))
    assert (c["modules"]["files"], c["modules"]["init_files"], c["modules"]["kit"]["files"]) == (5, 2, 2)
    assert c["modules"]["lines"] == 8 + 7 + 2 + 0 + 0 and c["modules"]["non_blank_lines"] == 6 + 5 + 2
    assert c["mains"] == 2
    assert c["imports"] == {"studies": 2, "pairs": 1, "statements": 2, "across_rooms": 1, "within_room": 0,
                            "list": ["b -> a"]}
    assert c["argparse"] == {"parsers": 1, "options": 2, "option_fields": 0, "runner_studies": 0}
    assert c["seed_defaults"] == {"options": 1, "distinct": 1, "values": ["7"]}
    assert c["kernel_branches"] == {"branches": 2, "files": 1, "per_file": {"rhs_env/radar.py": 2}}
    assert c["kernel_file"] is None
    assert c["duplicates"]["pairs"] is None  # not run unless asked


def test_imports_resolve_to_the_modules_of_the_tree(tmp_path):
    studies = tmp_path / "rhs_studies"
    (studies / "slam").mkdir(parents=True)
    for f in ("__init__.py", "slam/__init__.py", "slam/x.py", "slam/y.py"):
        (studies / f).write_text("")
    tree = kc.Tree(tmp_path)
    assert tree.resolve("rhs_studies.slam.x", []) == ["rhs_studies.slam.x"]
    assert tree.resolve("rhs_studies.slam.x.f", []) == ["rhs_studies.slam.x"]
    assert tree.resolve("rhs_studies", ["x", "ROOMS"]) == ["rhs_studies.slam.x", "rhs_studies"]  # an old path
    assert tree.resolve("rhs_studies.slam", ["y", "x"]) == ["rhs_studies.slam.y", "rhs_studies.slam.x"]
    assert tree.resolve("rhs_studies.slam.x", ["f"]) == ["rhs_studies.slam.x"]
    (studies / "slam" / "y.py").write_text("from .x import f\nfrom .. import slam\nimport numpy\n")
    tree = kc.Tree(tmp_path)
    assert [t for _, t in tree.imports("rhs_studies.slam.y")] == ["rhs_studies.slam.x", "rhs_studies.slam"]


def test_main_writes_the_table_without_the_duplicates_command(tmp_path, monkeypatch):
    monkeypatch.setattr(kc.shutil, "which", lambda name: None)  # a CI machine: no duplicates command
    root = _tiny_tree(tmp_path / "tree")
    assert kc.main(["--root", str(root), "--out-dir", str(tmp_path / "out")]) == 0
    data = json.loads((tmp_path / "out" / "kit_counts.json").read_text())
    (col,) = data["checkouts"]
    assert col["counts"]["duplicates"] == {"pairs": None, "note": "the duplicates command is not installed on this "
                                                                   "machine"}
    assert data["provenance"]["command"][1] == "scripts/kit_counts.py"
    md = (tmp_path / "out" / "kit_counts.md").read_text()
    assert "| study-to-study imports: pairs / statements | 1 / 2 |" in md and "Duplicates null" in md


def test_the_duplicates_line_is_read():
    assert kc.parse_duplicates("5 pairs of places (67 files read), each sharing runs\nD1 a.py:1-9 ~ b.py:3-11") == 5
    assert kc.parse_duplicates("1 pair of places (2 files read), each") == 1
    assert kc.parse_duplicates("no duplicates (12 files read)") == 0
    assert kc.parse_duplicates("incomplete: usage: duplicates [--change]") is None
    assert kc.parse_duplicates("") is None


def test_this_checkout_has_no_study_import_across_rooms_and_no_kernels_branch():
    """A study imports the kit, not another study: none across rooms, and within a room only the parts that
    tests/test_architecture.py allows by name; no call site of the packages branches on ``kernels ==``."""
    from test_architecture import ROOM_PARTS, UPKEEP_READS

    c = kc.measure(ROOT)
    assert c["imports"]["across_rooms"] == 0, c["imports"]["list"]
    allowed = {f"{a} -> {b}" for a, b in ROOM_PARTS} | {
        f"upkeep.{p.stem} -> {r.removeprefix('rhs_studies.')}" for r in UPKEEP_READS
        for p in (ROOT / "rhs_studies" / "upkeep").glob("*.py")}
    assert set(c["imports"]["list"]) <= allowed
    assert c["kernel_branches"]["branches"] == 0, c["kernel_branches"]["per_file"]
    assert c["modules"]["files"] > 38 and c["mains"] >= 32 and c["kernel_file"]["lines"] < 2016
