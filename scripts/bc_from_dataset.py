"""Behaviour cloning from a Minari dataset of ``rhs-slam record``.

Runs :mod:`rhs_studies.driving.bc_from_dataset` (its docstring has the options),
as ``python -m rhs_studies.driving.bc_from_dataset`` does.
"""

import sys

from rhs_studies.driving.bc_from_dataset import main

if __name__ == "__main__":
    sys.exit(main())
