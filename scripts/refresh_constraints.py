"""Refresh the pinned environments (``constraints/*.txt``) that the README's two commands install with.

Runs :mod:`rhs_studies.upkeep.refresh_constraints` (its docstring has the options),
as ``python -m rhs_studies.upkeep.refresh_constraints`` does.
"""

import sys

from rhs_studies.upkeep.refresh_constraints import main

if __name__ == "__main__":
    sys.exit(main())
