"""RHS radar simulation on highway-env: antennas, patterns, radar, point clouds, envs."""

from importlib import metadata as _metadata

from rhs_env.antenna_factory import make_antenna
from rhs_env.array_models import ANTENNA_KINDS, ArrayAntenna, RHSConfig, ScanConfig
from rhs_env.registration import register_envs

__all__ = ["ANTENNA_KINDS", "ArrayAntenna", "RHSConfig", "ScanConfig", "make_antenna", "register_envs"]
try:  # the one version string is pyproject.toml's, as installed
    __version__ = _metadata.version("rhs-slam")
except _metadata.PackageNotFoundError:  # imported from a checkout that was never installed
    __version__ = "0+unknown"

# Gymnasium ids (rhs-highway-v0, rhs-highway-radar-v0, ...) on import, also in subprocess vector envs.
register_envs()
