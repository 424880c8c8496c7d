"""Point-cloud quality of the radar on the Fig. 5b scenes, with 95 % confidence intervals.

Runs :mod:`rhs_studies.radar.radar_quality` (its docstring has the options),
as ``python -m rhs_studies.radar.radar_quality`` does.
"""

import sys

from rhs_studies.radar.radar_quality import main

if __name__ == "__main__":
    sys.exit(main())
