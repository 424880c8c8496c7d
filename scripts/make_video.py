"""The front page's video (results/episode.gif): one drive of the shipped policy with radar points, SLAM estimate and health.

Runs :mod:`rhs_studies.upkeep.make_video` (its docstring has the options), as ``python -m rhs_studies.upkeep.make_video`` does.
"""

import sys

from rhs_studies.upkeep.make_video import main

if __name__ == "__main__":
    sys.exit(main())
