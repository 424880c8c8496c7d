"""CNN vs ICP registration in the SLAM loop on the paper scene (``rhs-paper-v0``).

Runs :mod:`rhs_studies.slam.registration_in_loop` (its docstring has the options),
as ``python -m rhs_studies.slam.registration_in_loop`` does.
"""

import sys

from rhs_studies.slam.registration_in_loop import main

if __name__ == "__main__":
    sys.exit(main())
