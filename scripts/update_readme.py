"""The former name of ``scripts/write_results_pages.py``, kept so that commands written with it still run.

Runs :mod:`rhs_studies.upkeep.write_results_pages`: copies measured results from ``results/`` into the documentation's results
pages (``docs/results/``) and the README's headline table.
"""

import sys

from rhs_studies.upkeep.write_results_pages import main

if __name__ == "__main__":
    sys.exit(main())
