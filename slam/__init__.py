"""Localization and mapping: registration, data association, RBPF, metrics."""
