"""What the radar shield can trust in a scan: Doppler errors, ghosts, and how its leader estimate alarms.

Runs :mod:`rhs_studies.driving.shield_sensing` (its docstring has the options),
as ``python -m rhs_studies.driving.shield_sensing`` does.
"""

import sys

from rhs_studies.driving.shield_sensing import main

if __name__ == "__main__":
    sys.exit(main())
