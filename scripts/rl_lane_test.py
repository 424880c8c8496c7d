"""The RL fine-tune behind a stricter lane-change rule of the radar shield: the rule chosen on validation seeds, the
choice tested once on fresh seeds.

Runs :mod:`rhs_studies.rl_lane_test` (its docstring has the protocol and the options), as ``python -m rhs_studies.rl_lane_test`` does.
"""

import sys

from rhs_studies.rl_lane_test import main

if __name__ == "__main__":
    sys.exit(main())
