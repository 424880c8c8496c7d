"""A fresh test of the RL study's shield arms (the fine-tune, PPO from scratch): chosen on new validation seeds,
judged once on new test seeds.

Runs :mod:`rhs_studies.driving.rl_confirm` (its docstring has the protocol and the options),
as ``python -m rhs_studies.driving.rl_confirm`` does.
"""

import sys

from rhs_studies.driving.rl_confirm import main

if __name__ == "__main__":
    sys.exit(main())
