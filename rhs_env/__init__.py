"""RHS radar simulation on highway-env: antennas, patterns, radar, point clouds, envs."""

from rhs_env.antenna_factory import make_antenna
from rhs_env.array_models import ANTENNA_KINDS, ArrayAntenna, RHSConfig, ScanConfig
from rhs_env.registration import register_envs

__all__ = ["ANTENNA_KINDS", "ArrayAntenna", "RHSConfig", "ScanConfig", "make_antenna", "register_envs"]
__version__ = "0.1.0"

# Gymnasium ids (rhs-highway-v0, rhs-highway-radar-v0, ...) on import, also in subprocess vector envs.
register_envs()
