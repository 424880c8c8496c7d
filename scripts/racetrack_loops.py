"""Loops on the racetrack: the SLAM over several laps with the loop closure off and on, and a persistent map.

Runs :mod:`rhs_studies.slam.racetrack_loops` (its docstring has the options),
as ``python -m rhs_studies.slam.racetrack_loops`` does.
"""

import sys

from rhs_studies.slam.racetrack_loops import main

if __name__ == "__main__":
    sys.exit(main())
