"""Paper Fig. 5b: point-cloud RMSE vs number of RHS elements M, for dtheta = 1..5 deg.

Runs :mod:`rhs_studies.radar.fig5b_pointcloud_vs_elements` (its docstring has the options),
as ``python -m rhs_studies.radar.fig5b_pointcloud_vs_elements`` does.
"""

import sys

from rhs_studies.radar.fig5b_pointcloud_vs_elements import main

if __name__ == "__main__":
    sys.exit(main())
