"""The map-relative drift that every particle shares: an accumulated pose covariance.

The particle cloud of :class:`slam.core.rbpf.RBPFSlam` measures how well the current scan pins the pose
*against the particles' own map*. It cannot measure how far that map has drifted from the map frame
(the first pose): each landmark is initialised from the pose of the cycle that first saw it, the
filter hands the pose on from old landmarks to new ones as the car drives, and every hand-over
passes the pose error of that cycle into the map. Resampling then collapses the particles onto
one history, so all of them carry the same drift and their spread never shows it. On a forward
drive the shared error is a slow random walk of the heading that the distance driven turns into
a cross-track error (0.6-1.1 m after 900 m on the highway, heading errors of 1-2 mrad, while the
particles' std stays at 0.01-0.15 m and 0.5 mrad).

The model: a random walk per metre driven in the vehicle frame, with densities ``q_along``,
``q_cross`` (m^2/m) and ``q_heading`` (rad^2/m) (:class:`slam.core.pipeline.PipelineConfig`), propagated
through the pose composition like an odometry covariance. For the motion ``m = (dx, dy, dpsi)``
(vehicle frame of the previous cycle) from the pose ``p = (x, y, th)`` (map frame),
``p' = p (+) m``, the error ``e = p_hat - p`` propagates as

    ``P' = F P F^T + G diag(q_along d, q_cross d, q_heading d) G^T``,
    ``F = [[1, 0, -(s dx + c dy)], [0, 1, c dx - s dy], [0, 0, 1]]``,  ``G = diag(R(th), 1)``,

``c, s = cos th, sin th``, ``d = |(dx, dy)|`` (m). ``F`` carries a heading error into position in
proportion to the distance driven, so the cross-track variance grows as ``q_heading d^3 / 3``.
The reported pose covariance is the particles' covariance plus ``P`` (the two are independent:
one is the scatter of the pose given the map, the other the map's error). ``P`` starts at zero
with the map (the first pose is the map frame, known exactly) and restarts with a new map.

The map's start (:class:`MapStartHeading`): a random walk starts near zero and grows, but the drives show
a heading error set in the first cycles of a map (its first landmarks are placed from the first, least
pinned poses) and then held by the map (``rhs_studies.slam.pose_covariance.heading_origin``: each drive's
final cross-track error is its mean heading error times the distance, R^2 0.88-0.96). Its term is a unit
heading variance injected over the map's first metres, ``w = exp(-s/L) - exp(-(s + d)/L)`` in the cycle that
drives from ``s`` to ``s + d`` (m since the map began; ``L`` = :data:`MAP_START_M`), and carried by the same
``F``:

    ``B' = F B F^T + G diag(0, 0, w) G^T``,

so that after the first metres ``B`` is the covariance of one heading error of unit variance frozen into the
map: heading variance 1, cross-track variance ``(distance since the map began)^2``. The calibrated model
(:mod:`slam.core.pose_calibration`) scales it by the configuration's fitted map-start heading variance.
"""

from __future__ import annotations

import math

import numpy as np

from slam.core.pose_uncertainty import adaptive_drift_step

__all__ = ["DriftCovariance", "MAP_START_M", "MapStartHeading", "drift_step"]

#: the distance over which a new map's heading error is set (m; a few cycles: the drives' heading error at
#: cycle 5 is already its value at the end, ``rhs_studies.slam.pose_covariance.heading_origin``)
MAP_START_M = 10.0


def drift_step(cov: np.ndarray, heading: float, motion: np.ndarray, densities: tuple[float, float, float]) -> np.ndarray:
    """``P'`` after the motion ``motion`` (3,) from the heading ``heading`` (rad) (module docstring);
    ``densities`` = ``(q_along, q_cross, q_heading)`` (m^2/m, m^2/m, rad^2/m). Returns a new (3, 3) array."""
    m = np.asarray(motion, dtype=float).reshape(3)
    if not np.all(np.isfinite(m)):
        return np.array(cov, dtype=float, copy=True)
    c, s = math.cos(heading), math.sin(heading)
    F = np.array([[1.0, 0.0, -(s * m[0] + c * m[1])], [0.0, 1.0, c * m[0] - s * m[1]], [0.0, 0.0, 1.0]])
    G = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    d = math.hypot(m[0], m[1])
    Q = np.diag([densities[0] * d, densities[1] * d, densities[2] * d])
    out = F @ np.asarray(cov, dtype=float) @ F.T + G @ Q @ G.T
    return 0.5 * (out + out.T)


class DriftCovariance:
    """The accumulated drift covariance ``P`` (3, 3) of the map frame (module docstring)."""

    def __init__(self, densities: tuple[float, float, float]) -> None:
        if len(densities) != 3 or not all(math.isfinite(q) and q >= 0 for q in densities):
            raise ValueError(f"densities must be 3 finite values >= 0, got {densities!r}")
        self.densities = (float(densities[0]), float(densities[1]), float(densities[2]))
        self.reset()

    def reset(self) -> None:
        """A new map: the pose is the map frame's origin, no drift yet."""
        self.cov = np.zeros((3, 3))

    def step(self, heading: float, motion: np.ndarray) -> np.ndarray:
        """Propagate over one cycle's motion from the estimated heading (rad) before it; returns ``P``."""
        self.cov = drift_step(self.cov, heading, motion, self.densities)
        return self.cov

    def step_measured(self, heading: float, motion: np.ndarray, increment: np.ndarray) -> np.ndarray:
        """Propagate over one cycle's motion with the cycle's measured increment ``Q`` (3, 3) (map frame) in
        place of the densities (``pose_covariance="adaptive"``, :mod:`slam.core.pose_uncertainty`); returns ``P``."""
        self.cov = adaptive_drift_step(self.cov, heading, motion, increment)
        return self.cov


class MapStartHeading:
    """The map-start heading term ``B`` (3, 3) of a unit heading variance frozen into the map over its first
    ``length`` metres (module docstring)."""

    def __init__(self, length: float = MAP_START_M) -> None:
        if not (math.isfinite(length) and length > 0):
            raise ValueError(f"length must be a finite distance > 0 (m), got {length!r}")
        self.length = float(length)
        self.reset()

    def reset(self) -> None:
        """A new map: nothing injected yet, no distance driven."""
        self.cov = np.zeros((3, 3))
        self.travelled = 0.0

    def step(self, heading: float, motion: np.ndarray) -> np.ndarray:
        """Propagate over one cycle's motion (3,) from the estimated heading (rad) before it; returns ``B``."""
        m = np.asarray(motion, dtype=float).reshape(3)
        if not np.all(np.isfinite(m)):
            return self.cov
        d = math.hypot(m[0], m[1])
        w = math.exp(-self.travelled / self.length) - math.exp(-(self.travelled + d) / self.length)
        self.travelled += d
        self.cov = drift_step(self.cov, heading, m, (0.0, 0.0, w / d if d > 0 else 0.0))
        return self.cov
