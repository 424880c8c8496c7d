"""Train the driving policies and record how they were made.

Runs :mod:`rhs_studies.driving.train_policy` (its docstring has the options),
as ``python -m rhs_studies.driving.train_policy`` does.
"""

import sys

from rhs_studies.driving.train_policy import main

if __name__ == "__main__":
    sys.exit(main())
