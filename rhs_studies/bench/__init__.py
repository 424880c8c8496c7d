"""Benchmarks: env, radar, pattern and RLlib speed, start-up from a fresh clone, the compiled traffic against
highway-env (timings and alignment, no fingerprint).

Each module is a study (or a part of one); it imports :mod:`rhs_studies.kit` and the packages, never another
study (``tests/test_architecture.py``).
"""

__all__: list[str] = []
