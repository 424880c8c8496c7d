"""Radar studies: detection curves, point-cloud quality, the radar profiles, Fig. 5b, the fast radar's calibration and
its fidelity against the exact radar.

Each module is a study (or a part of one); it imports :mod:`rhs_studies.kit` and the packages, never another
study (``tests/test_architecture.py``).
"""

__all__: list[str] = []
