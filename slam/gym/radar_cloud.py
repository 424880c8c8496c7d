"""Point clouds of the simulated RHS radar for a scripted run of :func:`slam.core.scenario.run_scenario`.

The SLAM core takes any ``cloud_fn(t, true_pose) -> (N, 4 | 7)``; :class:`RadarCloud` is the one
that scans scripted world landmarks with :class:`rhs_env.radar.RadarSystem` (it lives in the layer
that may import ``rhs_env``).
"""

from __future__ import annotations

import math

import numpy as np

from rhs_common.geometry import points_in_frame, relative_motion
from rhs_common.validation import check_range
from rhs_env.scatterers import Scatterers
from rhs_env.uncertainty import point_rows

__all__ = ["RadarCloud"]


class RadarCloud:
    """Point clouds of the simulated RHS radar for a scripted run (callable ``(t, true_pose) -> (N, 7)``).

    Rows: x, y, radial velocity, amplitude, range std, angle std, radar index
    (:func:`rhs_env.uncertainty.point_rows`).

    The world landmarks (K, 2) are static point scatterers of RCS ``rcs_m2``; each
    cycle they are moved into the vehicle frame of the true pose, their velocity
    relative to the ego is ``-(v + w z x r)`` with the ego velocity ``v`` and yaw
    rate ``w`` from the scripted poses (finite differences over ``dt``), and the
    four radars of :class:`rhs_env.radar.RadarSystem` scan them (echo synthesis,
    range FFT, CFAR, OMP). ``last_true_xy`` holds the scatterers in view.
    """

    def __init__(self, landmarks: np.ndarray, poses: np.ndarray, dt: float, radar, rcs_m2: float = 5.0) -> None:
        check_range("dt", dt, 0.0, 1e3, low_open=True)
        check_range("rcs_m2", rcs_m2, 0.0, 1e4)
        self.landmarks = np.asarray(landmarks, dtype=float).reshape(-1, 2)
        self.poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        self.dt = float(dt)
        self.radar = radar
        self.rcs_m2 = float(rcs_m2)
        self.last_true_xy = np.zeros((0, 2))

    @property
    def sensor_xy(self) -> np.ndarray:
        """(S, 2) positions of the radars in the vehicle frame (m): their mounts."""
        return self.radar.config.mounting.mounts()[0]

    def __call__(self, t: int, true_pose: np.ndarray) -> np.ndarray:
        pose = np.asarray(true_pose, dtype=float).reshape(3)
        lo, hi = max(t - 1, 0), min(t + 1, len(self.poses) - 1)
        if hi > lo:  # central (or one-sided) difference of the scripted trajectory
            m = relative_motion(self.poses[lo], self.poses[hi])
            frac = relative_motion(self.poses[lo], pose)[2]
            c, s = math.cos(frac), math.sin(frac)  # velocity of the lo frame -> current frame
            v_prev = m[:2] / ((hi - lo) * self.dt)
            v = np.array([c * v_prev[0] + s * v_prev[1], -s * v_prev[0] + c * v_prev[1]])
            w = m[2] / ((hi - lo) * self.dt)
        else:
            v, w = np.zeros(2), 0.0
        xy = points_in_frame(self.landmarks, pose)
        rel_v = -(v[None, :] + w * np.stack([-xy[:, 1], xy[:, 0]], axis=1))
        k = len(xy)
        sc = Scatterers(xy, rel_v, np.full(k, self.rcs_m2), np.arange(k), np.ones(k, bool))
        self.last_true_xy = xy[self.radar.in_view(sc)]
        return point_rows(self.radar.scan(sc))
