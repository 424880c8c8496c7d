"""Count the research kit's shape in one or more checkouts: modules, lines, parsers, study-to-study imports,
process pools, ``--seed`` defaults, ``kernels ==`` branches, the largest radar-kernel file and duplicate pairs.

The figures of a before/after comparison come from this script, not from hand counts. Each checkout is one column
of the table: every ``--rev`` (a commit of this repository, read with ``git archive``) first, then every
``--root`` (a checkout on disk; default this one).

    python scripts/kit_counts.py --rev 8adb345              # the tree before the kit, then this checkout
    python scripts/kit_counts.py --root /tmp/old /tmp/new   # two checkouts on disk

Everything but the duplicates is read with :mod:`ast` (no file is imported or run). The definitions:

* **modules, lines**: every ``.py`` file under ``rhs_studies/`` (``__init__.py`` files included, and also counted
  apart); lines as ``wc -l`` counts them, and the non-blank ones. The kit is ``rhs_studies/kit/``.
* **study**: a module outside the kit, not an ``__init__.py``, that defines a top-level ``main()``. A shared module
  of a tree without a kit (``provenance``, ``episodes``: no ``main``) is no study, nor is a part of a study without
  its own ``main`` (``claim_study_report``).
* **study-to-study imports**: distinct (importing study, imported study) pairs, the two different, over every
  import statement of the importer (lazy ones inside functions too); the statements are counted apart. An import
  is resolved in the measured tree: ``import rhs_studies.a.b``, ``from rhs_studies import a``, ``from
  rhs_studies.a import b`` (``b`` a module, else ``a``) and relative imports; a name with no file of its own
  there (an old path that ``rhs_studies`` maps to a module's new place) is the one module of that name in the
  tree. *Across rooms*: the two modules in different rooms (the first folder below ``rhs_studies/``), or either
  one at the top of the package, where a tree without rooms keeps every study; *within a room*: the rest (the
  parts ``tests/test_architecture.py`` allows by name).
* **parsers written out**: calls of ``ArgumentParser`` and of ``add_parser``; **options written out**: calls of
  ``add_argument``; **option fields**: calls of ``option`` (the kit runner's fields, one flag each); **runner
  studies**: modules calling ``run_study`` or ``parser_for``.
* **process pools**: the modules that name ``ProcessPoolExecutor``, ``Pool`` (``multiprocessing``'s, also as
  ``get_context(...).Pool``), ``parallel_map``, or the kit's pool (``rhs_studies.kit.pool``: ``map_seeds``,
  ``map_jobs``), the kit's own modules apart; and those defining a top-level ``_chunk``.
* **``--seed`` defaults**: the ``default=`` of each ``add_argument("--seed", ...)`` and the default of each
  ``seed = option(...)`` field, as source text (``first("rl_confirm_test")`` names a set of the seed ledger);
  ``distinct`` counts the different texts.
* **``kernels ==`` branches**: comparisons (``==``, ``!=``) with a name or attribute ``kernels`` on either side,
  in ``rhs_env/``, ``slam/``, ``agents/`` and ``rhs_common/``: a call site branching on the numba/numpy choice.
* **largest kernel file**: ``rhs_env/kernels.py``, or the longest file of the ``rhs_env/kernels/`` package: its
  lines and its functions (every ``def``, nested ones too).
* **duplicate pairs**: the first line of the ``duplicates`` command over ``rhs_studies/`` (pairs of places that
  share 6 or more lines of the same shape; ``--repo rhs_studies --most 1``). Where the command is not installed
  (CI machines), the count is null and the note says so; nothing else depends on it.
"""

from __future__ import annotations

import ast
import io
import re
import shutil
import subprocess
import tarfile
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rhs_studies.kit.runner import Study, option, run_study

ROOT = Path(__file__).resolve().parents[2]
STUDIES = "rhs_studies"
KIT = f"{STUDIES}.kit"
#: the folders whose ``kernels ==`` branches count (the packages below the studies)
KERNEL_DIRS = ("rhs_env", "slam", "agents", "rhs_common")
#: the folders a ``--rev`` reads from git
TREE_DIRS = (STUDIES, *KERNEL_DIRS)
#: pool style -> the names whose use marks it
POOL_NAMES = {"ProcessPoolExecutor": {"ProcessPoolExecutor"}, "multiprocessing Pool": {"Pool"},
              "parallel_map": {"parallel_map"}, "kit pool": {"map_seeds", "map_jobs", f"{KIT}.pool"}}
DUPLICATES_LINE = re.compile(r"^(?:(?P<pairs>\d+) pairs? of places|no duplicates) \((?P<files>\d+) files? read\)")


@dataclass(frozen=True)
class Options:
    """The checkouts to count (one column each) and where the table goes."""

    root: tuple[Path, ...] = option((ROOT,), "checkouts to count, one column each, after the --rev columns")
    rev: tuple[str, ...] = option((), "commits of this repository to count (git archive), one column each, first")
    no_duplicates: bool = option(False, "do not run the duplicates command (its count reads null)")
    duplicates_seconds: int = option(120, "the duplicates command's time limit per checkout, s")
    out_dir: Path = option(ROOT / "results", "where kit_counts.json / .md go")

    def __post_init__(self) -> None:
        if not self.root and not self.rev:
            raise ValueError("give a --root or a --rev")
        if not 2 <= self.duplicates_seconds <= 600:
            raise ValueError(f"duplicates_seconds={self.duplicates_seconds}: must lie in [2, 600]")


# --------------------------------------------------------------------------- the modules of a tree
def module_name(path: Path, root: Path) -> str:
    """``ROOT/rhs_studies/slam/x.py`` -> ``rhs_studies.slam.x`` (a package's ``__init__.py`` -> the package)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def py_files(folder: Path) -> list[Path]:
    """The ``.py`` files below ``folder``, sorted (none where it is missing)."""
    return sorted(p for p in folder.rglob("*.py") if p.is_file()) if folder.is_dir() else []


class Tree:
    """The parsed ``rhs_studies`` modules of one checkout: name -> syntax tree, with import resolution."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.paths = {module_name(p, root): p for p in py_files(root / STUDIES)}
        self.trees = {name: ast.parse(p.read_text(), str(p)) for name, p in self.paths.items()}
        by_stem: dict[str, list[str]] = {}
        for name in self.paths:
            by_stem.setdefault(name.rsplit(".", 1)[-1], []).append(name)
        self._by_stem = by_stem

    def is_package(self, name: str) -> bool:
        return self.paths[name].name == "__init__.py"

    def find(self, name: str) -> str | None:
        """The module ``name`` of this tree: itself, or the one module of its last name (an old path), or None."""
        if name in self.paths:
            return name
        head, _, stem = name.rpartition(".")
        if head == STUDIES and len(self._by_stem.get(stem, ())) == 1:
            return self._by_stem[stem][0]
        return None

    def resolve(self, module: str, names: list[str]) -> list[str]:
        """The modules of this tree that ``from module import names`` (``names`` empty: ``import module``) reads."""
        if not names:  # import a.b.c: the longest prefix that is a module here
            parts = module.split(".")
            found = [m for i in range(len(parts), 0, -1) if (m := self.find(".".join(parts[:i])))]
            return found[:1]
        out = []
        base = self.find(module)
        for n in names:
            sub = self.find(f"{base or module}.{n}") if base is None or self.is_package(base) else None
            out.append(sub or base)
        return [m for m in out if m]

    def imports(self, name: str) -> Iterator[tuple[ast.AST, str]]:
        """(statement, module of this tree) for every import of module ``name`` (lazy ones included)."""
        package = name if self.is_package(name) else name.rpartition(".")[0]
        for node in ast.walk(self.trees[name]):
            if isinstance(node, ast.Import):
                targets = [t for a in node.names for t in self.resolve(a.name, [])]
            elif isinstance(node, ast.ImportFrom):
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1]) if node.level else ""
                module = ".".join(p for p in (base, node.module or "") if p)
                targets = self.resolve(module, [a.name for a in node.names]) if module.startswith(STUDIES) else []
            else:
                continue
            yield from ((node, t) for t in dict.fromkeys(targets))


def defines(tree: ast.Module, name: str) -> bool:
    """Whether the module defines a top-level function ``name``."""
    return any(isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.name == name for n in tree.body)


def calls(tree: ast.AST) -> Iterator[tuple[str, ast.Call]]:
    """(called name, call) of every call whose function is a name or an attribute."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            if isinstance(f, ast.Name):
                yield f.id, node
            elif isinstance(f, ast.Attribute):
                yield f.attr, node


def room(name: str) -> str | None:
    """``rhs_studies.slam.x`` -> ``slam``; a module at the top of the package -> None."""
    parts = name.split(".")
    return parts[1] if len(parts) > 2 else None


# --------------------------------------------------------------------------- the counts
def line_counts(paths: list[Path]) -> dict[str, int]:
    texts = [p.read_text() for p in paths]
    return {"files": len(paths), "lines": sum(len(t.splitlines()) for t in texts),
            "non_blank_lines": sum(1 for t in texts for line in t.splitlines() if line.strip())}


def module_counts(tree: Tree) -> dict[str, Any]:
    kit = [p for n, p in tree.paths.items() if n == KIT or n.startswith(f"{KIT}.")]
    return {**line_counts(list(tree.paths.values())),
            "init_files": sum(tree.is_package(n) for n in tree.paths),
            "kit": line_counts(kit),
            "rooms": sorted({r for n in tree.paths if (r := room(n)) and not n.startswith(KIT)}
                            | {n.split(".")[1] for n in tree.paths if n.count(".") == 1 and tree.is_package(n)
                               and n != KIT})}


def studies(tree: Tree) -> list[str]:
    """The study modules: outside the kit, not a package, with a top-level ``main()``."""
    return [n for n, t in tree.trees.items()
            if not (n == KIT or n.startswith(f"{KIT}.")) and not tree.is_package(n) and defines(t, "main")]


def import_counts(tree: Tree) -> dict[str, Any]:
    own = set(studies(tree))
    statements, pairs = 0, set()
    for name in sorted(own):
        seen: set[int] = set()
        for node, target in tree.imports(name):
            if target in own and target != name:
                pairs.add((name, target))
                if id(node) not in seen:
                    statements, seen = statements + 1, seen | {id(node)}
    across = sorted(p for p in pairs if room(p[0]) is None or room(p[0]) != room(p[1]))
    within = sorted(pairs - set(across))
    short = [f"{a.removeprefix(STUDIES + '.')} -> {b.removeprefix(STUDIES + '.')}" for a, b in sorted(pairs)]
    return {"studies": len(own), "pairs": len(pairs), "statements": statements, "across_rooms": len(across),
            "within_room": len(within), "list": short}


def parser_counts(tree: Tree) -> dict[str, int]:
    counts = dict.fromkeys(("parsers", "options", "option_fields", "runner_studies"), 0)
    for t in tree.trees.values():
        names = [n for n, _ in calls(t)]
        counts["parsers"] += sum(n in ("ArgumentParser", "add_parser") for n in names)
        counts["options"] += names.count("add_argument")
        counts["option_fields"] += names.count("option")
        counts["runner_studies"] += any(n in ("run_study", "parser_for") for n in names)
    return counts


def _names_used(tree: ast.AST) -> set[str]:
    """Every name, attribute and imported name (dotted module paths too) of a module."""
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            out.add(node.id)
        elif isinstance(node, ast.Attribute):
            out.add(node.attr)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            out |= {a.name for a in node.names} | ({node.module} if isinstance(node, ast.ImportFrom) and node.module
                                                   else set())
    return out


def pool_counts(tree: Tree) -> dict[str, Any]:
    styles: dict[str, list[str]] = {style: [] for style in POOL_NAMES}
    kit_own: dict[str, list[str]] = {style: [] for style in POOL_NAMES}
    for name, t in tree.trees.items():
        used = _names_used(t)
        for style, marks in POOL_NAMES.items():
            if used & marks and name != f"{KIT}.pool":
                (kit_own if name.startswith(f"{KIT}.") else styles)[style].append(name.removeprefix(STUDIES + "."))
    return {"modules": {s: len(m) for s, m in styles.items()}, "list": styles,
            "styles_outside_kit": sum(bool(m) for s, m in styles.items() if s != "kit pool"),
            "kit_modules": {s: m for s, m in kit_own.items() if m},
            "private_chunk": sorted(n.removeprefix(STUDIES + ".") for n, t in tree.trees.items() if defines(t, "_chunk"))}


def seed_defaults(tree: Tree) -> dict[str, Any]:
    found: list[str] = []
    for t in tree.trees.values():
        for name, call in calls(t):
            first = call.args[0] if call.args else None
            if name == "add_argument" and isinstance(first, ast.Constant) and first.value == "--seed":
                default = next((k.value for k in call.keywords if k.arg == "default"), None)
                found.append(ast.unparse(default) if default is not None else "(none)")
        for node in ast.walk(t):
            if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.target.id == "seed"
                    and isinstance(node.value, ast.Call) and getattr(node.value.func, "id", "") == "option"
                    and node.value.args):
                found.append(ast.unparse(node.value.args[0]))
    return {"options": len(found), "distinct": len(set(found)), "values": sorted(set(found))}


def _is_kernels(node: ast.AST) -> bool:
    return (isinstance(node, ast.Name) and node.id == "kernels") or (
        isinstance(node, ast.Attribute) and node.attr == "kernels")


def kernel_branches(root: Path) -> dict[str, Any]:
    """``kernels ==`` / ``!=`` comparisons in the packages (:data:`KERNEL_DIRS`), and the files holding them."""
    per_file: dict[str, int] = {}
    for d in KERNEL_DIRS:
        for p in py_files(root / d):
            n = sum(1 for node in ast.walk(ast.parse(p.read_text(), str(p))) if isinstance(node, ast.Compare)
                    and any(isinstance(op, (ast.Eq, ast.NotEq)) for op in node.ops)
                    and any(_is_kernels(x) for x in (node.left, *node.comparators)))
            if n:
                per_file[str(p.relative_to(root))] = n
    return {"branches": sum(per_file.values()), "files": len(per_file), "per_file": dict(sorted(per_file.items()))}


def largest_kernel_file(root: Path) -> dict[str, Any] | None:
    """``rhs_env/kernels.py`` or the longest file of ``rhs_env/kernels/``: path, lines, functions (None: neither)."""
    single = root / "rhs_env" / "kernels.py"
    files = [single] if single.is_file() else py_files(root / "rhs_env" / "kernels")
    if not files:
        return None
    p = max(files, key=lambda f: (len(f.read_text().splitlines()), str(f)))
    t = ast.parse(p.read_text(), str(p))
    return {"path": str(p.relative_to(root)), "lines": len(p.read_text().splitlines()),
            "functions": sum(isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) for n in ast.walk(t)),
            "package_files": len(files)}


def parse_duplicates(output: str) -> int | None:
    """The pair count of the ``duplicates`` command's first line (``no duplicates``: 0), or None."""
    m = DUPLICATES_LINE.match(output.strip().splitlines()[0] if output.strip() else "")
    return None if m is None else int(m["pairs"] or 0)


def duplicate_pairs(root: Path, seconds: int, run: bool = True) -> dict[str, Any]:
    """The ``duplicates`` command's pair count over ``root/rhs_studies`` (null where it is absent or skipped)."""
    exe = shutil.which("duplicates") if run else None
    if exe is None:
        return {"pairs": None, "note": "not run (--no-duplicates)" if not run else "the duplicates command is not "
                "installed on this machine"}
    try:
        out = subprocess.run([exe, "--repo", str(root / STUDIES), "--most", "1", "--seconds", str(seconds)],
                             capture_output=True, text=True, timeout=seconds + 60, check=False).stdout
    except (OSError, subprocess.TimeoutExpired) as err:
        return {"pairs": None, "note": f"duplicates failed: {err}"}
    lines = out.strip().splitlines()
    incomplete = [line for line in lines if line.startswith("incomplete:")]
    return {"pairs": parse_duplicates(out), "note": "; ".join(incomplete) or (lines[0] if lines else "no output")}


def measure(root: Path, duplicates: bool = False, seconds: int = 120) -> dict[str, Any]:
    """Every count of the checkout ``root`` (see the module's docstring for the definitions)."""
    tree = Tree(root)
    return {"modules": module_counts(tree), "mains": len(studies(tree)), "imports": import_counts(tree),
            "argparse": parser_counts(tree), "pools": pool_counts(tree), "seed_defaults": seed_defaults(tree),
            "kernel_branches": kernel_branches(root), "kernel_file": largest_kernel_file(root),
            "duplicates": duplicate_pairs(root, seconds, duplicates)}


# --------------------------------------------------------------------------- the checkouts
def _git(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, check=False, timeout=120)


def commit_of(root: Path) -> str | None:
    out = _git("rev-parse", "--short", "HEAD", cwd=root)
    return out.stdout.decode().strip() if out.returncode == 0 else None


def extract(rev: str, into: Path) -> str:
    """The :data:`TREE_DIRS` of commit ``rev`` of this repository written below ``into``; returns its short hash."""
    full = _git("rev-parse", "--short", f"{rev}^{{commit}}")
    if full.returncode != 0:
        raise ValueError(f"--rev {rev}: not a commit of this repository")
    top = set(_git("ls-tree", "--name-only", rev).stdout.decode().split())
    data = _git("archive", "--format=tar", rev, *[d for d in TREE_DIRS if d in top]).stdout
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(into, filter="data")
    return full.stdout.decode().strip()


def count_checkouts(opts: Options) -> dict[str, Any]:
    columns: list[dict[str, Any]] = []
    for rev in opts.rev:
        with tempfile.TemporaryDirectory(prefix="kit-counts-") as tmp:
            commit = extract(rev, Path(tmp))
            columns.append({"label": commit, "rev": rev, "commit": commit,
                            "counts": measure(Path(tmp), not opts.no_duplicates, opts.duplicates_seconds)})
    for root in opts.root:
        root = Path(root).resolve()
        head = commit_of(root)
        label = f"{head} (this checkout)" if root == ROOT else (head or root.name)
        columns.append({"label": label, "root": str(root) if root != ROOT else ".", "commit": head,
                        "counts": measure(root, not opts.no_duplicates, opts.duplicates_seconds)})
    return {"checkouts": columns}


# --------------------------------------------------------------------------- the table
#: (row label, counts -> cell)
ROWS: tuple[tuple[str, Any], ...] = (
    ("modules (.py files) / of them `__init__.py`", lambda c: f"{c['modules']['files']} / {c['modules']['init_files']}"),
    ("lines / non-blank", lambda c: f"{c['modules']['lines']:,} / {c['modules']['non_blank_lines']:,}"),
    ("the kit: modules / lines", lambda c: f"{c['modules']['kit']['files']} / {c['modules']['kit']['lines']:,}"),
    ("rooms", lambda c: len(c["modules"]["rooms"])),
    ("studies (a module with its own `main()`)", lambda c: c["mains"]),
    ("parsers written out (`ArgumentParser`, `add_parser`)", lambda c: c["argparse"]["parsers"]),
    ("options written out (`add_argument`) / kit option fields",
     lambda c: f"{c['argparse']['options']} / {c['argparse']['option_fields']}"),
    ("studies on the kit runner (`run_study`, `parser_for`)", lambda c: c["argparse"]["runner_studies"]),
    ("study-to-study imports: pairs / statements",
     lambda c: f"{c['imports']['pairs']} / {c['imports']['statements']}"),
    ("of the pairs: across rooms or outside any room / within a room",
     lambda c: f"{c['imports']['across_rooms']} / {c['imports']['within_room']}"),
    ("pools: `ProcessPoolExecutor` / `Pool` / `parallel_map` / kit pool (modules)",
     lambda c: " / ".join(str(n) for n in c["pools"]["modules"].values())),
    ("private `_chunk` functions", lambda c: len(c["pools"]["private_chunk"])),
    ("`--seed` options / distinct defaults",
     lambda c: f"{c['seed_defaults']['options']} / {c['seed_defaults']['distinct']}"),
    ("`kernels ==` branches / files", lambda c: f"{c['kernel_branches']['branches']} / {c['kernel_branches']['files']}"),
    ("largest radar-kernel file: lines / functions", lambda c: "-" if c["kernel_file"] is None else
     f"`{c['kernel_file']['path']}` {c['kernel_file']['lines']:,} / {c['kernel_file']['functions']}"),
    ("duplicate pairs in `rhs_studies/` (`duplicates`)",
     lambda c: "null" if c["duplicates"]["pairs"] is None else c["duplicates"]["pairs"]),
)


def markdown(result: dict[str, Any]) -> str:
    cols = result["checkouts"]
    lines = ["# Research kit counts", "",
             "| | " + " | ".join(c["label"] for c in cols) + " |", "|---|" + "---:|" * len(cols)]
    lines += [f"| {label} | " + " | ".join(str(cell(c["counts"])) for c in cols) + " |" for label, cell in ROWS]
    notes = [f"{c['label']}: {c['counts']['duplicates']['note']}" for c in cols if c["counts"]["duplicates"]["pairs"]
             is None]
    lines += ["", "Counted by `python scripts/kit_counts.py` (the definitions: `rhs_studies/upkeep/kit_counts.py`)."]
    lines += [f"Duplicates null: {'; '.join(notes)}." for _ in notes[:1]]
    return "\n".join(lines) + "\n"


STUDY = Study("kit_counts", "kit_counts.py", Options, count_checkouts, markdown, description=__doc__)


def main(argv: list[str] | None = None) -> int:
    return run_study(STUDY, argv)


if __name__ == "__main__":
    raise SystemExit(main())

__all__ = ["Options", "STUDY", "Tree", "count_checkouts", "duplicate_pairs", "kernel_branches", "largest_kernel_file",
           "main", "markdown", "measure", "parse_duplicates"]
