"""Low-SNR SLAM: RHS against the phased array with the slot-summed and the footprint detector.

Runs :mod:`rhs_studies.slam.low_snr_slam` (its docstring has the options),
as ``python -m rhs_studies.slam.low_snr_slam`` does.
"""

import sys

from rhs_studies.slam.low_snr_slam import main

if __name__ == "__main__":
    sys.exit(main())
