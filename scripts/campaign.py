"""The resumable training campaign: train a recipe on the fast SLAM env a chunk at a time, choose each run's
checkpoint on validation seeds, or write the curves.

Runs :mod:`rhs_studies.driving.campaign` (its docstring has the layout and the options)::

    OMP_NUM_THREADS=1 python scripts/campaign.py train --recipe ppo_scratch --seeds 0 1 2 --steps 40000 --until 06:00
    OMP_NUM_THREADS=1 python scripts/campaign.py select --recipe ppo_scratch --seeds 0 1 2
    python scripts/campaign.py curves --recipe ppo_scratch --seeds 0 1 2
"""

import sys

from rhs_studies.driving.campaign import main

if __name__ == "__main__":
    sys.exit(main())
