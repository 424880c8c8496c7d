"""Copy measured results from ``results/`` into README.md.

Each README block between ``<!-- results:NAME -->`` and ``<!-- /results:NAME -->``
is replaced by ``results/NAME.md`` (written by the script that measured it), so
every number in the README comes from a script a user can run. Blocks whose
file does not exist are left as they are.

    python scripts/update_readme.py            # rewrite README.md in place
    python scripts/update_readme.py --check    # exit 1 if README.md is out of date
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BLOCK = re.compile(r"(<!-- results:(?P<name>[\w.-]+) -->\n)(?P<body>.*?)(<!-- /results:(?P=name) -->)", re.S)


def render(readme: str, results_dir: Path) -> str:
    def sub(m: re.Match) -> str:
        f = results_dir / f"{m.group('name')}.md"
        if not f.exists():
            return m.group(0)
        return f"{m.group(1)}{f.read_text().rstrip()}\n{m.group(4)}"

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
