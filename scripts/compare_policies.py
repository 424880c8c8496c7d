"""Any driving comparison written as a spec file (rhs_studies/driving/specs/*.yml): chosen on validation seeds,
tested once on fresh seeds.

Runs :mod:`rhs_studies.driving.comparisons` (its docstring has the options),
as ``python -m rhs_studies.driving.comparisons`` does.
"""

import sys

from rhs_studies.driving.comparisons import main

if __name__ == "__main__":
    sys.exit(main())
