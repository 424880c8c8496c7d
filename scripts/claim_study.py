"""Does the paper's claim hold? RHS vs the same-cost phased array, random and hologram patterns.

Runs :mod:`rhs_studies.slam.claim_study` (its docstring has the options),
as ``python -m rhs_studies.slam.claim_study`` does.
"""

import sys

from rhs_studies.slam.claim_study import main

if __name__ == "__main__":
    sys.exit(main())
