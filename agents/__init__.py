"""Driving agents: training, evaluation, policies, the demo."""
