"""Detection curves: Pd against SNR at a fixed P_fa, RHS and phased array, slot-summed and footprint detectors.

Runs :mod:`rhs_studies.radar.detection_curves` (its docstring has the options),
as ``python -m rhs_studies.radar.detection_curves`` does.
"""

import sys

from rhs_studies.radar.detection_curves import main

if __name__ == "__main__":
    sys.exit(main())
