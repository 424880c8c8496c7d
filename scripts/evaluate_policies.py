"""Shipped SLAM policy vs a random policy vs the ground-truth policy, on the same seeds.

Runs :mod:`rhs_studies.driving.evaluate_policies` (its docstring has the options),
as ``python -m rhs_studies.driving.evaluate_policies`` does.
"""

import sys

from rhs_studies.driving.evaluate_policies import main

if __name__ == "__main__":
    sys.exit(main())
