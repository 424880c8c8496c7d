"""SDR (paper) vs fast (alternating SOCP) pattern optimisation on the same grids, side by side.

Runs :mod:`rhs_studies.patterns.compare_pattern_methods` (its docstring has the options),
as ``python -m rhs_studies.patterns.compare_pattern_methods`` does.
"""

import sys

from rhs_studies.patterns.compare_pattern_methods import main

if __name__ == "__main__":
    sys.exit(main())
