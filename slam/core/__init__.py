"""The SLAM core: registration, data association, the RBPF, the pipeline, track health, metrics and scripted runs.

It runs on any point cloud and imports neither gymnasium nor ``rhs_env`` (tested).
"""

__all__: list[str] = []
