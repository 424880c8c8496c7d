"""Fast radar fidelity: the fast radar against the exact radar on the same scenes, the SLAM on paired seeds.

Runs :mod:`rhs_studies.radar.fast_radar_fidelity` (its docstring has the options and the acceptance), as
``python -m rhs_studies.radar.fast_radar_fidelity`` does.
"""

import sys

from rhs_studies.radar.fast_radar_fidelity import main

if __name__ == "__main__":
    sys.exit(main())
