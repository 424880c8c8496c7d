"""Time the pattern-library build of an M=60, 1-degree radar (90 grids) per method.

Runs :mod:`rhs_studies.bench.benchmark_patterns` (its docstring has the options),
as ``python -m rhs_studies.bench.benchmark_patterns`` does.
"""

import sys

from rhs_studies.bench.benchmark_patterns import main

if __name__ == "__main__":
    sys.exit(main())
