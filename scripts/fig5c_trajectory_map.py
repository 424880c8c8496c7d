"""Paper Fig. 5c: true and estimated trajectory and obstacle map on the paper scenario (``rhs-paper-v0``).

Runs :mod:`rhs_studies.slam.fig5c_trajectory_map` (its docstring has the options),
as ``python -m rhs_studies.slam.fig5c_trajectory_map`` does.
"""

import sys

from rhs_studies.slam.fig5c_trajectory_map import main

if __name__ == "__main__":
    sys.exit(main())
