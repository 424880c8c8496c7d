"""Speed of every stage of rhs-slam, in one run, as JSON (never in timed tests).

Runs :mod:`rhs_studies.benchmark` (its docstring has the options), as ``python -m rhs_studies.benchmark`` does.
"""

import sys

from rhs_studies.benchmark import main

if __name__ == "__main__":
    sys.exit(main())
