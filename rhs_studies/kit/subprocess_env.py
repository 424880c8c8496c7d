"""The environment a study runs in when the kit starts it in a subprocess (``reproduce``, ``fingerprint_tolerance``).

The parent's environment, with

* one OpenMP thread (``OMP_NUM_THREADS=1``, as the tests run), and with ``blas_single_thread`` one
  OpenBLAS / MKL thread too: results do not depend on how many cores the machine lends;
* matplotlib's ``Agg`` backend and SDL's dummy video driver: no window opens;
* ``extra`` on top (a setting's variables may override the thread counts);
* the repository first on ``PYTHONPATH``: the studies import the packages from this checkout.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

from rhs_studies.kit.provenance import ROOT

#: the thread-count variables of OpenMP, OpenBLAS and MKL
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def study_env(extra: Mapping[str, str] | None = None, *, blas_single_thread: bool = True) -> dict[str, str]:
    """The variables of a study's subprocess (module docstring)."""
    threads = THREAD_VARIABLES if blas_single_thread else THREAD_VARIABLES[:1]
    return {**os.environ, **dict.fromkeys(threads, "1"), "MPLBACKEND": "Agg", "SDL_VIDEODRIVER": "dummy",
            **(extra or {}), "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
