"""``python -m rhs_slam`` = ``rhs-slam``."""

import sys

from rhs_slam.cli import main

sys.exit(main())
