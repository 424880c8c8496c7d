"""The privileged teachers on validation seeds: the headway driver against lookahead variants.

Runs :mod:`rhs_studies.driving.teachers` (its docstring has the options),
as ``python -m rhs_studies.driving.teachers`` does.
"""

import sys

from rhs_studies.driving.teachers import main

if __name__ == "__main__":
    sys.exit(main())
