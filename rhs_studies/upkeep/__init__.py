"""Upkeep of the results: the reproduction (every results file's step), the pages written from them, the
fingerprints' tolerances, the constraints, the shipped policy, the front page's video.

Each module is a study (or a part of one); it imports :mod:`rhs_studies.kit` and the packages, never another
study (``tests/test_architecture.py``).
"""

__all__: list[str] = []
