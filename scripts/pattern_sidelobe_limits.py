"""How low can the two-way sidelobes go? The fast method under a sweep of sidelobe caps.

Runs :mod:`rhs_studies.patterns.pattern_sidelobe_limits` (its docstring has the options),
as ``python -m rhs_studies.patterns.pattern_sidelobe_limits`` does.
"""

import sys

from rhs_studies.patterns.pattern_sidelobe_limits import main

if __name__ == "__main__":
    sys.exit(main())
