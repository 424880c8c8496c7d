"""Train the CNN registration on point clouds of this simulator and compare it with ICP.

Runs :mod:`rhs_studies.slam.train_registration` (its docstring has the options),
as ``python -m rhs_studies.slam.train_registration`` does.
"""

import sys

from rhs_studies.slam.train_registration import main

if __name__ == "__main__":
    sys.exit(main())
