"""Put a policy a study chose and tested under the shipped policy's role name (agents/data/shipped.zip).

Runs :mod:`rhs_studies.upkeep.ship_policy` (its docstring has the options), as
``python -m rhs_studies.upkeep.ship_policy`` does.
"""

import sys

from rhs_studies.upkeep.ship_policy import main

if __name__ == "__main__":
    sys.exit(main())
