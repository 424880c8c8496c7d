"""Where the four radars sit on the ego vehicle and what each one sees: the mounting and the field of view.

A stage of :class:`rhs_env.radar.RadarSystem` (its ``mounts``): the geometry every other stage reads (the radar
of a point, its range and bearing) and the visibility test that decides which scatterers echo at all.
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import KernelTable
from rhs_env.radar_config import RadarConfig
from rhs_env.scatterers import LOS_EPS, Occluders, Scatterers, visible_mask

__all__ = ["RADAR_NAMES", "RadarMounts", "wrap_angle"]

#: the four radars, in their index order (``PointCloud.radar``)
RADAR_NAMES = ("front", "left", "rear", "right")


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi): ``(a + pi) mod 2 pi - pi`` (rad)."""
    return (a + np.pi) % (2 * np.pi) - np.pi


class RadarMounts:
    """The radars' mounting and field of view.

    Mounting: radars at the middle of the front, left, rear and right sides of a
    ``mounting.vehicle_length_m`` x ``mounting.vehicle_width_m`` box, boresights 0, +90, 180, -90 deg
    (:data:`RADAR_NAMES`, vehicle frame: x forward, y left). Far-field model: the array apertures
    (<= 0.3 m) are treated as points, so a point ``p`` is seen by radar r at range ``R = |p - m_r|`` (m)
    and angle ``theta = wrap(atan2(p - m_r) - b_r)`` (rad from boresight ``b_r``).

    Field of view: the scan sector ``|theta| <= sector / 2`` (+-45 deg) and ``min_range_m <= R <=
    max_range_m``; hidden scatterers (:func:`rhs_env.scatterers.visible_mask`) return nothing. With
    ``kernels="numba"`` the line of sight is tested compiled, only for the pairs in the field of view
    (:func:`rhs_env.kernels.line_of_sight`, the same mask).

    Args:
        config: :class:`rhs_env.radar_config.RadarConfig` (``mounting``, ``scan.sector_deg``, the range limits).

    Attributes:
        positions: (4, 2) radar positions in the vehicle frame, m.
        boresights: (4,) boresight angles, rad.
    """

    def __init__(self, config: RadarConfig) -> None:
        self.config = config
        self.positions, self.boresights = config.mounting.mounts()
        self._impl = _STAGES.choose(config.kernels)  # the compiled or the numpy line of sight

    def frame(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Range (4, K) m, angle from boresight (4, K) rad and unit vectors (4, K, 2) of points xy (K, 2)."""
        d = np.asarray(xy, float)[None, :, :] - self.positions[:, None, :]
        rng_m = np.hypot(d[..., 0], d[..., 1])
        ang = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - self.boresights[:, None])
        unit = d / np.maximum(rng_m, 1e-12)[..., None]
        return rng_m, ang, unit

    def visible(self, scatterers: Scatterers, occluders: Occluders | None = None,
                frame: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """(4, K) bool: inside radar r's sector and range interval and in line of sight (``frame``: :meth:`frame`'s)."""
        rng_m, ang, _ = self.frame(scatterers.xy) if frame is None else frame
        half = np.deg2rad(self.config.scan.sector_deg) / 2
        fov = (np.abs(ang) <= half) & (rng_m <= self.config.max_range_m) & (rng_m >= self.config.min_range_m)
        return np.asarray(self._impl.line_of_sight(self, fov, scatterers, occluders), dtype=bool)

    def _line_of_sight_numpy(self, fov: np.ndarray, scatterers: Scatterers, occluders: Occluders | None) -> np.ndarray:
        """``fov & visible_mask(...)`` (4, K) in numpy (the reference of :meth:`visible`)."""
        return np.asarray(fov & visible_mask(self.positions, scatterers, occluders), dtype=bool)

    def in_view(self, scatterers: Scatterers, occluders: Occluders | None = None) -> np.ndarray:
        """(K,) bool: seen by at least one radar."""
        return np.asarray(self.visible(scatterers, occluders).any(axis=0), dtype=bool)


#: the mounting's stage with a compiled twin (:mod:`rhs_env.kernels`), chosen once by ``RadarConfig.kernels``
_STAGES = KernelTable("rhs_env.radar.mounting")
_STAGES.stage("line_of_sight", "numpy")(RadarMounts._line_of_sight_numpy)


@_STAGES.stage("line_of_sight", "numba")
def _line_of_sight_compiled(mounts: RadarMounts, fov: np.ndarray, scatterers: Scatterers,
                            occluders: Occluders | None) -> np.ndarray:
    """:meth:`RadarMounts.visible`'s line of sight compiled (:func:`rhs_env.kernels.line_of_sight`): the same test per
    (radar, point) in the field of view, up to its first crossing; numpy without occluders or scatterers."""
    if occluders is None or not len(occluders) or not len(scatterers):
        return mounts._line_of_sight_numpy(fov, scatterers, occluders)
    from rhs_env.kernels import line_of_sight

    return np.asarray(line_of_sight(mounts.positions, np.ascontiguousarray(scatterers.xy, dtype=float),
                                    np.ascontiguousarray(occluders.segments, dtype=float),
                                    np.ascontiguousarray(scatterers.object_id), np.ascontiguousarray(occluders.object_id),
                                    np.ascontiguousarray(fov), LOS_EPS))
