"""Train the driving policies and record how they were made.

Runs :mod:`rhs_studies.train_policy` (its docstring has the options), as ``python -m rhs_studies.train_policy`` does.
"""

import sys

from rhs_studies.train_policy import main

if __name__ == "__main__":
    sys.exit(main())
