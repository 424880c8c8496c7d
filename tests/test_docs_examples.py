"""The code blocks of README.md and of the documentation pages run as they are written.

Every fenced block tagged ``python`` or ``bash`` in README.md and in ``docs/**/*.md`` is
extracted and run, verbatim, from the repository root: a ``python`` block as a script
file (so a block that starts processes needs its ``if __name__ == "__main__":`` guard, as
a user's script would), a ``bash`` block with ``bash -euo pipefail`` (the ``rhs-slam``
command of this environment on the PATH). Blocks tagged otherwise (``text``, ``json``,
none) are not run.

The convention for a block that must not run here (it installs software, starts a
server, or trains for hours): an HTML comment ``<!-- skip: REASON -->`` among the comment
lines right above its opening fence. The reason is shown on the page's source and must
not be empty.

The examples write their outputs under ``/tmp/rhs-slam``, never into the repository; the
test checks that a run leaves the work tree as it found it.
"""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RUN = ("python", "bash")
#: fence languages the pages may use; anything else is probably a typo of a runnable one
KNOWN = {*RUN, "text", "json", "yaml", "console", ""}
FENCE = re.compile(r"^```(?P<lang>[\w+-]*)\s*$")
SKIP = re.compile(r"^<!-- skip:(?P<reason>.*)-->$")
COMMENT = re.compile(r"^<!--.*-->$")
TIMEOUT_S = 900


@dataclass(frozen=True)
class Block:
    page: Path
    line: int  # 1-based line of the opening fence
    lang: str
    code: str
    skip: str | None  # the reason, when marked skip

    @property
    def id(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def blocks(page: Path) -> list[Block]:
    """The fenced code blocks of a Markdown page, with the skip marker above each (if any)."""
    lines = page.read_text().splitlines()
    out = []
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        start, lang = i, m.group("lang")
        j = i + 1
        while j < len(lines) and lines[j].rstrip() != "```":
            j += 1
        assert j < len(lines), f"{page.name}:{start + 1}: code block never closed"
        skip = None
        k = start - 1
        while k >= 0 and COMMENT.match(lines[k].strip()):
            s = SKIP.match(lines[k].strip())
            if s:
                skip = s.group("reason").strip()
            k -= 1
        out.append(Block(page, start + 1, lang, "\n".join(lines[start + 1:j]) + "\n", skip))
        i = j + 1
    return out


ALL = [b for p in pages() for b in blocks(p)]
RUNNABLE = [b for b in ALL if b.lang in RUN and b.skip is None]


def test_blocks_are_found_and_marked_with_reasons():
    assert len(RUNNABLE) >= 10, "the README and the usage pages carry runnable examples"
    for b in ALL:
        assert b.lang in KNOWN, f"{b.id}: unknown code block language {b.lang!r} (runnable ones: {RUN})"
        assert b.skip is None or b.skip, f"{b.id}: <!-- skip: --> needs a reason"
    readme = [b for b in ALL if b.page.name == "README.md"]
    assert {b.lang for b in readme if b.skip is None} & set(RUN) == set(RUN), "the README's tour runs: a python and a bash block"


def test_the_parser_reads_fences_and_skip_markers(tmp_path):
    page = tmp_path / "p.md"
    page.write_text("text\n<!-- skip: installs things -->\n<!-- main-command -->\n```bash\npip install x\n```\n\n"
                    "```python\nprint(1)\n```\n<!-- skip: -->\n```json\n{}\n```\n")
    found = blocks(page)
    assert [(b.lang, b.skip, b.line) for b in found] == [("bash", "installs things", 4), ("python", None, 8), ("json", "", 12)]
    assert found[1].code == "print(1)\n"


def _git_status() -> str:
    out = subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"], cwd=ROOT,
                         capture_output=True, text=True, check=False)
    return out.stdout if out.returncode == 0 else ""


@pytest.mark.parametrize("block", RUNNABLE, ids=lambda b: b.id)
def test_code_block_runs_verbatim(block, tmp_path):
    env = {**os.environ, "MPLBACKEND": "Agg", "SDL_VIDEODRIVER": "dummy", "OMP_NUM_THREADS": "1",
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    if block.lang == "python":
        script = tmp_path / "example.py"
        script.write_text(block.code)
        cmd = [sys.executable, str(script)]
    else:
        cmd = ["bash", "-euo", "pipefail", "-c", block.code]
    before = _git_status()
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=TIMEOUT_S, check=False)
    assert proc.returncode == 0, (
        f"{block.id}: the {block.lang} block exited {proc.returncode}\n--- code\n{block.code}"
        f"--- stdout (tail)\n{proc.stdout[-3000:]}\n--- stderr (tail)\n{proc.stderr[-3000:]}"
    )
    new = set(_git_status().splitlines()) - set(before.splitlines())
    assert not new, f"{block.id}: the example wrote into the repository: {sorted(new)}"


def _load(path: Path):
    import importlib.util

    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_api_reference_lists_every_module_of_each_package():
    """The API pages are built from the package folders (docs/hooks/site.py), so a new module appears."""
    pytest.importorskip("mkdocs")
    site = _load(ROOT / "docs" / "hooks" / "site.py")
    for page in sorted((ROOT / "docs" / "api").glob("*.md")):
        package = page.stem
        assert f"<!-- api: {package} -->" in page.read_text()
        names = site.modules(package)
        old = getattr(importlib.import_module(package), "OLD_PATHS", {})  # modules kept only at an old path
        files = [p for p in (ROOT / package).rglob("*.py") if p.name == "__init__.py" or not p.name.startswith("_")]
        files = [p for p in files if ".".join(p.relative_to(ROOT).with_suffix("").parts) not in old]
        assert names[0] == package and len(names) == len(files), (package, names)
    text = site.on_page_markdown("# x\n\n<!-- api: rhs_slam -->\n", None, None, None)
    assert "::: rhs_slam\n\n::: rhs_slam.cli" in text


def test_sphinx_roles_become_inline_code():
    pytest.importorskip("griffe")
    roles = _load(ROOT / "docs" / "hooks" / "griffe_roles.py")
    assert roles.plain(":func:`~agents.evaluate.run_episode` and :class:`slam.core.rbpf.RBPFSlam`. Input::\n\n    {}") == (
        "`run_episode` and `slam.core.rbpf.RBPFSlam`. Input:\n\n    {}")
    assert roles.plain("a :: b, x::y") == "a :: b, x::y"


def test_readme_links_point_at_files_that_exist():
    """The README is read on its own (not built by MkDocs): its relative links must resolve in the repository."""
    text = (ROOT / "README.md").read_text()
    links = re.findall(r"\]\((?!https?://|#)(?P<target>[^)\s#]+)", text)
    assert any(t.startswith("docs/") for t in links)
    missing = [t for t in links if not (ROOT / t).exists()]
    assert not missing, f"README.md links to files that do not exist: {missing}"


def test_readme_is_a_front_page():
    """At most 250 lines: what it is, the two commands, a tour, the headline table, the layout, links."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    for marker in ("<!-- main-command -->", "<!-- test-command -->", "<!-- results:headline -->"):
        assert text.count(marker) == 1, marker
