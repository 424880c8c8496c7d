"""Pose covariance per radar configuration: the drift densities against the adaptive model.

Runs :mod:`rhs_studies.slam.pose_covariance` (its docstring has the options), as ``python -m rhs_studies.slam.pose_covariance`` does.
"""

import sys

from rhs_studies.slam.pose_covariance import main

if __name__ == "__main__":
    sys.exit(main())
