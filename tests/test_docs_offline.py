"""The documentation site works offline: every script, stylesheet, image and font it loads is served with it.

The built-in ``mkdocs`` theme would load highlight.js and its styles from a CDN; the site highlights code
when it is built instead (Pygments through ``pymdownx.highlight``, styled by ``docs/css/pygments.css``).
The test builds the site (not strict: the test command's ``mkdocs build --strict`` checks the warnings)
and reads every page and stylesheet.
"""

from __future__ import annotations

import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
REMOTE = re.compile(r"^(https?:)?//", re.IGNORECASE)
CSS_URL = re.compile(r"""(?:url\(\s*['"]?|@import\s+['"])([^'")\s]+)""", re.IGNORECASE)


class AssetLinks(HTMLParser):
    """The URLs a page loads by itself: script src, stylesheet / icon / preload href, img / source / iframe src."""

    def __init__(self) -> None:
        super().__init__()
        self.urls: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = {k: v or "" for k, v in attrs}
        if tag in ("script", "img", "iframe", "source", "video", "audio", "embed") and a.get("src"):
            self.urls.append(a["src"])
        if tag == "link" and a.get("href") and set(a.get("rel", "").lower().split()) & {
                "stylesheet", "icon", "preload", "modulepreload", "manifest"}:
            self.urls.append(a["href"])


def remote_assets(site: Path) -> list[str]:
    """``FILE: URL`` of every asset of the built ``site`` that is fetched from another host."""
    found = []
    for page in sorted(site.rglob("*.html")):
        parser = AssetLinks()
        parser.feed(page.read_text(encoding="utf-8"))
        found += [f"{page.relative_to(site)}: {u}" for u in parser.urls if REMOTE.match(u)]
    for css in sorted(site.rglob("*.css")):
        found += [f"{css.relative_to(site)}: {u}" for u in CSS_URL.findall(css.read_text(encoding="utf-8"))
                  if REMOTE.match(u)]
    return found


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--no-strict", "--quiet", "--site-dir", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out


def test_the_site_loads_nothing_from_another_host(site):
    assert (site / "index.html").exists()
    assert remote_assets(site) == []


def test_code_is_highlighted_at_build_time_with_a_local_stylesheet(site):
    index = (site / "index.html").read_text(encoding="utf-8")
    assert 'href="css/pygments.css"' in index and (site / "css" / "pygments.css").exists()
    assert re.search(r'<div class="highlight"><pre>.*<span class="kn">import</span>', index, re.DOTALL)
    assert ".highlight .kn " in (site / "css" / "pygments.css").read_text()


def test_the_check_sees_a_cdn_asset(tmp_path):
    (tmp_path / "index.html").write_text(
        '<html><head><link rel="stylesheet" href="https://cdn.example/x.css"><script src="//cdn.example/x.js">'
        '</script><script src="js/local.js"></script><a href="https://example.org">a link is fine</a></head></html>')
    (tmp_path / "a.css").write_text("@import 'https://fonts.example/f.css'; .x { background: url(img/local.png) }")
    assert remote_assets(tmp_path) == ["index.html: https://cdn.example/x.css", "index.html: //cdn.example/x.js",
                                       "a.css: https://fonts.example/f.css"]
