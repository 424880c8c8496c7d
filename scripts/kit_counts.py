"""Count the research kit's shape (modules, lines, parsers, study-to-study imports, pools, seed defaults,
``kernels ==`` branches, duplicate pairs) in one or more checkouts, one column each.

Runs :mod:`rhs_studies.upkeep.kit_counts` (its docstring has the options and the definitions),
as ``python -m rhs_studies.upkeep.kit_counts`` does.
"""

import sys

from rhs_studies.upkeep.kit_counts import main

if __name__ == "__main__":
    sys.exit(main())
