"""Why a student crashes: its last decisions against the expert's, and whether the radar saw what it hit.

Runs :mod:`rhs_studies.driving.crash_analysis` (its docstring has the options),
as ``python -m rhs_studies.driving.crash_analysis`` does.
"""

import sys

from rhs_studies.driving.crash_analysis import main

if __name__ == "__main__":
    sys.exit(main())
