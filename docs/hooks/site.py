"""MkDocs hooks of the documentation site (``mkdocs.yml``: ``hooks``).

* ``on_files``: the figures live in ``results/`` (written by the scripts, next to the
  tables they illustrate), outside ``docs/``. Every ``results/*.png`` (and ``*.gif``: the
  front page's video) is added to the site as ``results/NAME.png``, so a page in
  ``docs/results/`` shows one with ``![...](NAME.png)`` and MkDocs checks the link like any other.
* ``on_page_markdown``: a line ``<!-- api: PACKAGE -->`` in a page becomes one
  mkdocstrings ``::: MODULE`` directive per module of that package, found by walking its
  folder when the site is built, so the API reference follows the packages as they are. A module kept only at
  an old path (the package's ``OLD_PATHS``: ``agents.features`` is ``agents.policies.features``) is left out: its
  page is the module it stands for.
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[2]
API = re.compile(r"^<!-- api: (?P<package>[\w.]+) -->$", re.MULTILINE)


def on_files(files: Files, config) -> Files:
    for png in sorted([*(ROOT / "results").glob("*.png"), *(ROOT / "results").glob("*.gif")]):
        files.append(File(f"results/{png.name}", src_dir=str(ROOT), dest_dir=config["site_dir"],
                          use_directory_urls=config["use_directory_urls"]))
    return files


def modules(package: str) -> list[str]:
    """Dotted names of ``package`` and every module below it (``__main__`` and the old paths left out), in folder
    order."""
    folder = ROOT.joinpath(*package.split("."))
    old = getattr(importlib.import_module(package), "OLD_PATHS", {})
    names = []
    for path in sorted(folder.rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        if parts[-1] == "__main__" or any(p.startswith((".", "_")) and p != "__init__" for p in parts):
            continue
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        if name not in old:
            names.append(name)
    return sorted(names, key=lambda n: (n != package, n))


def on_page_markdown(markdown: str, page, config, files) -> str:
    def directives(m: re.Match) -> str:
        return "\n\n".join(f"::: {name}" for name in modules(m.group("package")))

    return API.sub(directives, markdown)
