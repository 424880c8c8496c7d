"""Paired comparison of two slam_accuracy driver runs, drive by drive.

Runs :mod:`rhs_studies.slam.compare_drives` (its docstring has the options),
as ``python -m rhs_studies.slam.compare_drives`` does.
"""

import sys

from rhs_studies.slam.compare_drives import main

if __name__ == "__main__":
    sys.exit(main())
