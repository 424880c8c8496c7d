"""Paper Fig. 5a: vehicle and obstacle (map) RMSE of SLAM on ``rhs-paper-v0``, per antenna scheme.

Runs :mod:`rhs_studies.slam.fig5a_slam_rmse` (its docstring has the options),
as ``python -m rhs_studies.slam.fig5a_slam_rmse`` does.
"""

import sys

from rhs_studies.slam.fig5a_slam_rmse import main

if __name__ == "__main__":
    sys.exit(main())
