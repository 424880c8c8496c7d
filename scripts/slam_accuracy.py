"""SLAM accuracy against its targets: highway, paper scene at 30 dBm, dense landmark pairs.

Runs :mod:`rhs_studies.slam.slam_accuracy` (its docstring has the options), as ``python -m rhs_studies.slam.slam_accuracy`` does.
"""

import sys

from rhs_studies.slam.slam_accuracy import main

if __name__ == "__main__":
    sys.exit(main())
