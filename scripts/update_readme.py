"""Copy measured results from ``results/`` into README.md.

Each README block between ``<!-- results:NAME -->`` and ``<!-- /results:NAME -->``
is replaced by ``results/NAME.md`` (written by the script that measured it), so
every number in the README comes from a script a user can run. A heading on the
file's first line is dropped: the README section around the block has its own. Blocks whose
file does not exist are left as they are. When ``results/NAME.json`` is not
verified against the code (written before provenance existed, or the code's
fingerprint changed since the run, see ``scripts/_provenance.py``), the block
ends with a visible warning saying why and which step to rerun.

    python scripts/update_readme.py            # rewrite README.md in place
    python scripts/update_readme.py --check    # exit 1 if README.md is out of date
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))
from _provenance import load_fingerprints, verification

BLOCK = re.compile(r"(<!-- results:(?P<name>[\w.-]+) -->\n)(?P<body>.*?)(<!-- /results:(?P=name) -->)", re.DOTALL)


def warning(name: str, results_dir: Path, fingerprints: dict) -> str:
    """A README line when ``results/NAME.json`` is unverified, else ``""``."""
    from reproduce import step_for_result

    f = results_dir / f"{name}.json"
    if not f.exists():
        return ""
    ok, why = verification(f, fingerprints)
    if ok:
        return ""
    step = step_for_result(name)
    rerun = f"python scripts/reproduce.py --only {step.name}" if step else "its script"
    return f"\n> **Unverified:** {why}. These numbers may not match the code; rerun `{rerun}`.\n"


HEADING = re.compile(r"\A#{1,6} [^\n]*\n+")


def block_text(md: str) -> str:
    """A results ``.md`` as a README block: without its leading heading (the README's section has one)."""
    return HEADING.sub("", md.strip(), count=1).rstrip()


def render(readme: str, results_dir: Path) -> str:
    fingerprints = load_fingerprints(results_dir / "fingerprints.json")

    def sub(m: re.Match) -> str:
        f = results_dir / f"{m.group('name')}.md"
        if not f.exists():
            return m.group(0)
        warn = warning(m.group("name"), results_dir, fingerprints)
        return f"{m.group(1)}{block_text(f.read_text())}\n{warn}{m.group(4)}"

    return BLOCK.sub(sub, readme)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="only check that README.md is up to date")
    args = ap.parse_args()
    readme = ROOT / "README.md"
    old = readme.read_text()
    new = render(old, ROOT / "results")
    if args.check:
        if new != old:
            print("README.md is out of date with results/: run python scripts/update_readme.py", file=sys.stderr)
            return 1
        return 0
    readme.write_text(new)
    print(f"updated {readme}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
