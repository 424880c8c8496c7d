"""The RL fine-tune behind a stricter lane-change rule of the radar shield: the rule chosen on validation seeds, the
choice tested once on fresh seeds.

Runs :mod:`rhs_studies.driving.rl_lane_rule_trial` (its docstring has the protocol and the options), as
``python -m rhs_studies.driving.rl_lane_rule_trial`` does; the launcher keeps the study's first name, which its results record.
"""

import sys

from rhs_studies.driving.rl_lane_rule_trial import main

if __name__ == "__main__":
    sys.exit(main())
