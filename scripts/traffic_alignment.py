"""Traffic alignment: the compiled traffic core against highway-env, 50 seeds x 200 steps per scene.

Runs :mod:`rhs_studies.bench.traffic_alignment` (its docstring has the options and the acceptance), as
``python -m rhs_studies.bench.traffic_alignment`` does.
"""

import sys

from rhs_studies.bench.traffic_alignment import main

if __name__ == "__main__":
    sys.exit(main())
