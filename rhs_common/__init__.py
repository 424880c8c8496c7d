"""The bottom layer: configuration building and validation, angles and frames, stage timing.

Imports nothing from the rest of the project and nothing heavier than numpy, so
every layer above (``rhs_env`` <- ``slam`` <- ``agents`` <- ``rhs_slam``) can use it.
"""

__all__: list[str] = []
