"""A long drive: 3,000 cycles of the highway SLAM env, no loop closure (NEES, drift, memory, step time).

Runs :mod:`rhs_studies.slam.long_drive` (its docstring has the options),
as ``python -m rhs_studies.slam.long_drive`` does.
"""

import sys

from rhs_studies.slam.long_drive import main

if __name__ == "__main__":
    sys.exit(main())
