"""SLAM studies: Fig. 5a / 5c, low SNR, registration in the loop and its CNN, drives, the claim study, the SLAM
accuracy against its targets, the pose covariance.

Each module is a study (or a part of one); it imports :mod:`rhs_studies.kit` and the packages, never another
study (``tests/test_architecture.py``).
"""

__all__: list[str] = []
