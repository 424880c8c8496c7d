"""Calibrate the fast radar on the exact radar's measured detector (the package's table for the default radar).

Runs :mod:`rhs_studies.radar.calibrate_fast_radar` (its docstring has the options), as
``python -m rhs_studies.radar.calibrate_fast_radar`` does.
"""

import sys

from rhs_studies.radar.calibrate_fast_radar import main

if __name__ == "__main__":
    sys.exit(main())
