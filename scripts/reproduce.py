"""Regenerate every file in ``results/`` and the pages that show them, or only some of them.

Runs :mod:`rhs_studies.upkeep.reproduce` (its docstring has the options), as ``python -m rhs_studies.upkeep.reproduce`` does.
"""

import sys

from rhs_studies.upkeep.reproduce import main

if __name__ == "__main__":
    sys.exit(main())
