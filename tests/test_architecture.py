"""The layering of the packages, checked on the source: imports flow one way, no cycles.

Layers, bottom to top: ``rhs_common`` <- ``rhs_env`` <- ``slam`` <- ``agents`` <- ``rhs_slam``; inside ``slam``,
the core (``slam/core/``) imports neither gymnasium nor ``rhs_env`` nor the gym layer (``slam/gym/``).
Every import statement counts, lazy ones inside functions and ``TYPE_CHECKING``
blocks included. Env ids may name upper layers in string entry points (not imports).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("rhs_common", "rhs_env", "slam", "agents", "rhs_slam")
#: the research kit on top (the studies behind results/; scripts/ launches them)
STUDIES = "rhs_studies"


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in LAYERS:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            out[name] = path
    return out


def _imports(path: Path, name: str, modules: dict[str, Path]) -> set[str]:
    """Project modules imported anywhere in the file (``from a.b import c`` -> a.b.c when a module, else a.b)."""
    is_pkg = path.name == "__init__.py"
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = name.split(".") if is_pkg else name.split(".")[:-1]
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        found.update(t for t in targets if t in modules and t != name)
    return found


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(path, name, modules) for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def _upward(graph: dict[str, set[str]], layer: str) -> list[str]:
    rank = LAYERS.index(layer)
    return sorted(
        f"{src} -> {dst}"
        for src, dsts in graph.items()
        if src.split(".")[0] == layer
        for dst in dsts
        if LAYERS.index(dst.split(".")[0]) > rank
    )


def test_the_checker_finds_a_cycle_and_an_upward_import(tmp_path):
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    src = tmp_path / "x.py"
    src.write_text("def f():\n    from slam.core.rbpf import SlamConfig\n")  # a lazy import counts
    modules = {"rhs_env.x": src, "slam.core.rbpf": tmp_path / "rbpf.py"}
    graph = {"rhs_env.x": _imports(src, "rhs_env.x", modules), "slam.core.rbpf": set()}
    assert _upward(graph, "rhs_env") == ["rhs_env.x -> slam.core.rbpf"]


def test_no_import_cycle_between_files():
    assert _cycles(_graph()) == []


@pytest.mark.parametrize("layer", LAYERS)
def test_imports_flow_one_way(layer):
    assert _upward(_graph(), layer) == []


#: what the SLAM core (every file under slam/core/) must not import, not even lazily: it runs on any point cloud
CORE_FORBIDDEN = ("gymnasium", "gym", "highway_env", "rhs_env", "slam.gym", "agents", "rhs_slam", STUDIES)


def _core_files() -> list[Path]:
    return sorted((ROOT / "slam" / "core").rglob("*.py"))


def _forbidden_in_core(path: Path) -> list[str]:
    """Imports of ``path`` (every statement, lazy ones included) that name a package the core must not use."""
    return [f"{path.name}: {a}" for a in _imported_names(path)
            if any(a == bad or a.startswith(bad + ".") for bad in CORE_FORBIDDEN)]


def test_the_core_check_sees_a_lazy_gym_import(tmp_path):
    src = tmp_path / "x.py"
    src.write_text("import numpy\ndef f():\n    import gymnasium as gym\n    from slam.gym.wrappers import SlamObservation\n")
    assert _forbidden_in_core(src) == ["x.py: gymnasium", "x.py: slam.gym.wrappers"]


def test_slam_core_imports_neither_gymnasium_nor_rhs_env_nor_the_gym_layer():
    """By folder: every file under slam/core/, on its source, and every module of it imported in a fresh interpreter."""
    files = _core_files()
    assert {f.stem for f in files} >= {"rbpf", "association", "registration", "pipeline", "metrics", "scenario"}
    assert [bad for path in files for bad in _forbidden_in_core(path)] == []
    names = [".".join(f.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__") for f in files]
    code = (f"import sys, {', '.join(names)}; "
            "print([m for m in sys.modules if m.split('.')[0] in ('gymnasium', 'highway_env', 'rhs_env') "
            "or m.startswith('slam.gym')])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]"


def _private_imports(path: Path) -> list[str]:
    """``from m import _name`` statements: a private name used outside the module that defines it."""
    return [
        f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path.name}:{node.lineno} "
        f"from {'.' * node.level}{node.module or ''} import {a.name}"
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.ImportFrom)
        for a in node.names
        if a.name.startswith("_") and not a.name.startswith("__")
    ]


def test_the_private_import_check_sees_one(tmp_path):
    src = tmp_path / "x.py"
    src.write_text("from a import b, _c\ndef f():\n    from .d import _e as e\n    from f import __version__\n")
    assert _private_imports(src) == ["x.py:1 from a import _c", "x.py:3 from .d import _e"]


def test_no_private_name_imported_across_modules():
    """A name with a leading underscore is its module's own; what another module needs is public (and documented)."""
    files = [path for pkg in (*LAYERS, STUDIES, "scripts") for path in sorted((ROOT / pkg).rglob("*.py"))]
    assert [f for path in files for f in _private_imports(path)] == []


def test_the_studies_are_the_top_layer_and_edit_no_import_path():
    """rhs_studies (the research kit behind results/) imports the packages; no package imports it, and neither the
    kit nor scripts/ edits sys.path: the studies import each other as modules of one package."""
    upward = [
        f"{path.relative_to(ROOT)}: {a}"
        for pkg in LAYERS
        for path in sorted((ROOT / pkg).rglob("*.py"))
        for a in _imported_names(path)
        if a.split(".")[0] == STUDIES
    ]
    assert upward == []
    edits = [str(path.relative_to(ROOT)) for pkg in (STUDIES, "scripts") for path in sorted((ROOT / pkg).rglob("*.py"))
             if "sys.path.insert" in path.read_text() or "sys.path.append" in path.read_text()]
    assert edits == []


#: the imports a study may make of another module of its own room (importer, imported: why); none across rooms
ROOM_PARTS = {
    ("slam.claim_study", "slam.claim_study_report"): "the claim study's report: a part of that study (no main)",
    ("bench.benchmark", "bench.benchmark_radar"): "the benchmark suite runs the radar benchmark as its radar section",
    ("bench.benchmark", "bench.benchmark_patterns"): "the benchmark suite runs the pattern benchmark as its section",
    ("radar.radar_profiles", "radar.radar_quality"): "the radar profiles are scored with the radar quality metric",
    ("driving.campaign_report", "driving.campaign"): "the campaign's floor and page: a part of that study (its recipes)",
    ("driving.shield_table", "driving.campaign"): "the shield table drives the campaign's checkpoints (its folder, recipes)",
}
#: what the upkeep tools read besides the kit: the steps of the reproduction (the study registry, itself in upkeep)
UPKEEP_READS = ("rhs_studies.upkeep.reproduce",)


def _is_studies_module(name: str) -> bool:
    """Whether the dotted ``name`` is a module or package file under rhs_studies/."""
    path = ROOT.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def _studies_imported(path: Path) -> list[str]:
    """The rhs_studies modules ``path`` imports (``from rhs_studies import x`` -> rhs_studies.x, ``from
    rhs_studies.room import x`` -> rhs_studies.room.x when x is a module), old names resolved to where the modules
    are now (rhs_studies.MOVED)."""
    from rhs_studies import MOVED

    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module == STUDIES:
            names = [f"{STUDIES}.{a.name}" for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").startswith(f"{STUDIES}."):
            names = [f"{node.module}.{a.name}" if _is_studies_module(f"{node.module}.{a.name}") else node.module
                     for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            names = [node.module or ""] if not node.level else [f"{STUDIES}.(relative import)"]
        else:
            continue
        for n in names:
            if n.split(".")[0] == STUDIES:
                parts = n.split(".")
                out.append(MOVED.get(parts[1], n) if len(parts) > 1 else n)
    return out


def _study_violations(path: Path, room: str) -> list[str]:
    """The imports of the study module ``path`` (in ``room``) of anything in rhs_studies but the kit."""
    me = f"{room}.{path.stem}"
    bad = []
    for target in _studies_imported(path):
        rest = target.removeprefix(f"{STUDIES}.")
        if target == f"{STUDIES}.kit" or target.startswith(f"{STUDIES}.kit."):
            continue
        if room == "upkeep" and target in UPKEEP_READS:
            continue
        if rest.split(".")[0] == room and (me, rest) in ROOM_PARTS:
            continue
        bad.append(f"{STUDIES}/{room}/{path.name}: {target}")
    return bad


def test_a_study_imports_the_kit_and_the_packages_never_another_study():
    """The studies live in topic rooms (rhs_studies.ROOMS); a study imports rhs_studies.kit and the packages, never
    another study: no import between rooms, and inside a room only the parts of ROOM_PARTS. The kit imports no
    study, and nothing of rhs_studies but itself."""
    from rhs_studies import ROOMS

    bad = [v for room in ROOMS for path in sorted((ROOT / STUDIES / room).glob("*.py")) if path.name != "__init__.py"
           for v in _study_violations(path, room)]
    assert bad == [], "move what studies share into rhs_studies/kit/: " + "; ".join(bad)
    kit = [f"{path.name}: {t}" for path in sorted((ROOT / STUDIES / "kit").glob("*.py")) for t in _studies_imported(path)
           if not (t == f"{STUDIES}.kit" or t.startswith(f"{STUDIES}.kit."))]
    assert kit == []
    rooms = {p.parent.name for p in (ROOT / STUDIES).glob("*/__init__.py")} - {"kit"}
    assert rooms == set(ROOMS), "every room folder is listed in rhs_studies.ROOMS"
    for room, names in ROOMS.items():
        assert {p.stem for p in (ROOT / STUDIES / room).glob("*.py")} - {"__init__"} == set(names), room


def test_the_study_rule_sees_an_import_of_another_study(tmp_path):
    study = tmp_path / "new_study.py"
    study.write_text("from rhs_studies.kit.tables import paired\nfrom rhs_studies.rl_finetune import ARMS\n"
                     "def f():\n    from rhs_studies.radar import radar_quality\n    from rhs_studies import reproduce\n")
    assert _study_violations(study, "driving") == [
        "rhs_studies/driving/new_study.py: rhs_studies.driving.rl_finetune",
        "rhs_studies/driving/new_study.py: rhs_studies.radar.radar_quality",
        "rhs_studies/driving/new_study.py: rhs_studies.upkeep.reproduce"]
    assert _study_violations(study, "upkeep")[-1:] == ["rhs_studies/upkeep/new_study.py: rhs_studies.radar.radar_quality"]


def _top_level_modules(package: Path) -> list[str]:
    """The Python files at the top of the research kit's folder other than its ``__init__.py``."""
    return sorted(p.name for p in package.glob("*.py") if p.name != "__init__.py")


def test_the_top_level_check_sees_a_new_module(tmp_path):
    (tmp_path / "__init__.py").write_text("")
    (tmp_path / "new_study.py").write_text("def main(argv=None):\n    return 0\n")
    assert _top_level_modules(tmp_path) == ["new_study.py"]


def test_the_top_of_rhs_studies_holds_no_module_and_the_old_paths_resolve():
    """Every study sits in a room (rhs_studies.ROOMS), every shared module in the kit (rhs_studies.KIT_MODULES): the top
    of rhs_studies/ holds its __init__.py alone. A module's path from before (rhs_studies.NAME, rhs_studies.MOVED)
    finds the file where it is now, and no old name is also a file (one module, one place)."""
    import importlib.util

    from rhs_studies import KIT_MODULES, MOVED

    assert _top_level_modules(ROOT / STUDIES) == [], "put a study into its room, a shared module into rhs_studies/kit/"
    assert {p.stem for p in (ROOT / STUDIES / "kit").glob("*.py")} >= set(KIT_MODULES)
    for old, new in MOVED.items():
        target = importlib.util.find_spec(new)
        assert target is not None and Path(target.origin).is_file(), new
        assert importlib.util.find_spec(f"{STUDIES}.{old}").origin == target.origin, old


def test_no_study_imports_an_old_path():
    """The old module paths (rhs_studies.MOVED) are kept for code and commands written before; the kit, the studies and
    the launchers in scripts/ import the modules where they are."""
    from rhs_studies import MOVED

    files = [path for pkg in (STUDIES, "scripts") for path in sorted((ROOT / pkg).rglob("*.py"))]
    old = []
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level and node.module == STUDIES:
                names = [f"{STUDIES}.{a.name}" for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                names = [node.module or ""]
            else:
                continue
            old += [f"{path.relative_to(ROOT)}:{node.lineno} {n}" for n in names
                    if n.split(".")[0] == STUDIES and len(n.split(".")) > 1 and n.split(".")[1] in MOVED]
    assert old == []


def _imported_names(path: Path) -> list[str]:
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level:
            out.append(node.module or "")
    return out


def test_configs_do_not_import_what_they_configure():
    """rhs_env.radar_config holds the radar's settings; the modules that use them import it, not the reverse."""
    graph = _graph()
    configured = {"rhs_env.radar", "rhs_env.point_cloud", "rhs_env.detection", "rhs_env.antenna_factory"}
    assert graph["rhs_env.radar_config"] & configured == set()
    assert graph["rhs_env.radar_config"] <= {"rhs_common.validation", "rhs_common.jit", "rhs_env.array_models", "rhs_env.windows"}


def _long_functions(path: Path, limit: int) -> list[str]:
    tree = ast.parse(path.read_text())
    return [
        f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path.name}:{n.name} ({n.end_lineno - n.lineno + 1} lines)"
        for n in ast.walk(tree)
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.end_lineno - n.lineno + 1 > limit
    ]


def test_the_length_check_sees_a_long_function(tmp_path):
    src = tmp_path / "long.py"
    src.write_text("def f():\n" + "    x = 1\n" * 81)
    assert len(_long_functions(src, 80)) == 1 and _long_functions(src, 82) == []


def test_no_function_over_80_lines():
    long = [f for pkg in LAYERS for path in sorted((ROOT / pkg).rglob("*.py")) for f in _long_functions(path, 80)]
    assert long == []


def test_an_integer_for_a_float_field_names_the_same_config():
    from rhs_env.array_models import ScanConfig

    assert ScanConfig(grid_deg=5) == ScanConfig(grid_deg=5.0) and isinstance(ScanConfig(grid_deg=5).grid_deg, float)


#: the agents modules users run (the top of the agents package, above its subpackages)
AGENTS_ENTRY = ("agents.evaluate", "agents.record", "agents.demo")


def test_the_agents_policies_import_nothing_of_the_training_side():
    """agents.policies (drivers and policy parts) sits below agents.algos (training) and the entry modules."""
    upward = sorted(f"{src} -> {dst}" for src, dsts in _graph().items() if src.startswith("agents.policies")
                    for dst in dsts if dst.startswith("agents.algos") or dst in AGENTS_ENTRY)
    assert upward == []


def test_no_module_imports_an_old_agents_path():
    """The old flat paths of agents (agents.OLD_PATHS) are kept for saved policies and code outside; the project's
    own modules, the studies and the scripts import the modules where they are."""
    from agents import OLD_PATHS

    files = [path for pkg in (*LAYERS, STUDIES, "scripts") for path in sorted((ROOT / pkg).rglob("*.py"))]
    old = [f"{path.relative_to(ROOT)}: {a}" for path in files
           if ".".join(path.relative_to(ROOT).with_suffix("").parts) not in OLD_PATHS
           for a in _imported_names(path) if a in OLD_PATHS]
    assert old == []
