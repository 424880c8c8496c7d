"""The gym layer of the SLAM: the observation wrapper, the metrics in ``info``, the env entry points,
the radar cloud of a scripted run and the ``rhs-slam scenario`` subcommand (on ``rhs_env`` and gymnasium).
"""

__all__: list[str] = []
