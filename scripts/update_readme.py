"""Copy measured results from ``results/`` into README.md and the documentation pages.

Runs :mod:`rhs_studies.update_readme` (its docstring has the options), as ``python -m rhs_studies.update_readme`` does.
"""

import sys

from rhs_studies.update_readme import main

if __name__ == "__main__":
    sys.exit(main())
