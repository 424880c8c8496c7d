"""Radar benchmark: time per stage of one four-radar scan on a typical highway scene.

Runs :mod:`rhs_studies.bench.benchmark_radar` (its docstring has the options),
as ``python -m rhs_studies.bench.benchmark_radar`` does.
"""

import sys

from rhs_studies.bench.benchmark_radar import main

if __name__ == "__main__":
    sys.exit(main())
