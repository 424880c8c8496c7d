"""Reinforcement learning on top of imitation: the PPO fine-tune of the DAgger student against its controls.

Runs :mod:`rhs_studies.driving.rl_finetune` (its docstring has the options),
as ``python -m rhs_studies.driving.rl_finetune`` does.
"""

import sys

from rhs_studies.driving.rl_finetune import main

if __name__ == "__main__":
    sys.exit(main())
