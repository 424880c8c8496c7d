"""Holographic pattern optimisation for the RHS.

* :mod:`~rhs_env.patterns.metrics`: sidelobe set D, P1 delta, per-grid report (gain, PSLR, pointing).
* :mod:`~rhs_env.patterns.fast`: alternating phase-fixed SOCPs (default, fast).
* :mod:`~rhs_env.patterns.sdr`: the paper's alternating SDR (baseline).
* :mod:`~rhs_env.patterns.library`: hashed ``.npz`` libraries, shipped or cached (:func:`get_library`).
"""

from rhs_env.patterns.library import PatternLibrary, build_library, get_library, load

__all__ = ["PatternLibrary", "build_library", "get_library", "load"]
