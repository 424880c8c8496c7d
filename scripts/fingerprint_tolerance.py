"""Measure how far each results fingerprint moves when nothing but the machine changes, and record its tolerance.

Runs :mod:`rhs_studies.upkeep.fingerprint_tolerance` (its docstring has the options),
as ``python -m rhs_studies.upkeep.fingerprint_tolerance`` does.
"""

import sys

from rhs_studies.upkeep.fingerprint_tolerance import main

if __name__ == "__main__":
    sys.exit(main())
