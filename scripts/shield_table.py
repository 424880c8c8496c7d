"""The radar shield as a measured feature: every arm with and without it, on the exact and the fast env.

Runs :mod:`rhs_studies.driving.shield_table` (its docstring has the arms, the figures and the options)::

    OMP_NUM_THREADS=1 python scripts/shield_table.py --episodes 10
"""

import sys

from rhs_studies.driving.shield_table import main

if __name__ == "__main__":
    sys.exit(main())
