"""Speed of every stage of rhs-slam, in one run, as JSON (never in timed tests).

Runs :mod:`rhs_studies.bench.benchmark` (its docstring has the options),
as ``python -m rhs_studies.bench.benchmark`` does.
"""

import sys

from rhs_studies.bench.benchmark import main

if __name__ == "__main__":
    sys.exit(main())
