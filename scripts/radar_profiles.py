"""Speed against point-cloud quality of the radar's processing settings.

Runs :mod:`rhs_studies.radar.radar_profiles` (its docstring has the options),
as ``python -m rhs_studies.radar.radar_profiles`` does.
"""

import sys

from rhs_studies.radar.radar_profiles import main

if __name__ == "__main__":
    sys.exit(main())
