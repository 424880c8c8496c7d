"""Localization and mapping: the core (:mod:`slam.core`: registration, data association, RBPF, metrics; no
gymnasium) and its gym layer (:mod:`slam.gym`: wrapper, metrics in info, env entry points)."""

__all__: list[str] = []
