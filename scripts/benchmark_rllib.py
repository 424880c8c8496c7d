"""Ray RLlib sampling throughput: PPO steps/s with 1 and 2 env runners, in one run.

Runs :mod:`rhs_studies.bench.benchmark_rllib` (its docstring has the options),
as ``python -m rhs_studies.bench.benchmark_rllib`` does.
"""

import sys

from rhs_studies.bench.benchmark_rllib import main

if __name__ == "__main__":
    sys.exit(main())
