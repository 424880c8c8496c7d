"""Driving agents: training, evaluation, policies, the demo."""

__all__: list[str] = []
