"""RHS radar simulation on highway-env: antennas, patterns, radar, point clouds, envs."""

from rhs_env.antenna import ANTENNA_KINDS, ArrayAntenna, RHSConfig, ScanConfig, make_antenna

__all__ = ["ANTENNA_KINDS", "ArrayAntenna", "RHSConfig", "ScanConfig", "make_antenna"]
__version__ = "0.1.0"
