"""Copy measured results from ``results/`` into the documentation's results pages and the README's headline table.

Runs :mod:`rhs_studies.upkeep.write_results_pages` (its docstring has the options),
as ``python -m rhs_studies.upkeep.write_results_pages``
does.
"""

import sys

from rhs_studies.upkeep.write_results_pages import main

if __name__ == "__main__":
    sys.exit(main())
