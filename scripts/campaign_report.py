"""The campaign's page: the throughput floor, the learning curves over training seeds, the shield table.

Runs :mod:`rhs_studies.driving.campaign_report`::

    OMP_NUM_THREADS=1 python scripts/campaign_report.py floor
    python scripts/campaign_report.py page
"""

import sys

from rhs_studies.driving.campaign_report import main

if __name__ == "__main__":
    sys.exit(main())
