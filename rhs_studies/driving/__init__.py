"""Driving studies: the policies trained and judged, the RL fine-tune and its fresh tests, the teachers,
the crash analysis, the shield's sensing, behaviour cloning from the recorded datasets.

Each module is a study (or a part of one); it imports :mod:`rhs_studies.kit` and the packages, never another
study (``tests/test_architecture.py``).
"""

__all__: list[str] = []
