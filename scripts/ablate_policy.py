"""Short, measured ablations of what limits learning to drive.

Runs :mod:`rhs_studies.driving.ablate_policy` (its docstring has the options),
as ``python -m rhs_studies.driving.ablate_policy`` does.
"""

import sys

from rhs_studies.driving.ablate_policy import main

if __name__ == "__main__":
    sys.exit(main())
