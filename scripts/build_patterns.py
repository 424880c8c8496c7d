"""Build the shipped pattern libraries (or a small config for tests) with the fast method.

Runs :mod:`rhs_studies.patterns.build_patterns` (its docstring has the options),
as ``python -m rhs_studies.patterns.build_patterns`` does.
"""

import sys

from rhs_studies.patterns.build_patterns import main

if __name__ == "__main__":
    sys.exit(main())
