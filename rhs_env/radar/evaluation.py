"""A radar point cloud against the truth: per-target errors and point-cloud metrics of the scatterers in view.

Used by :meth:`rhs_env.radar.RadarSystem.point_errors` and :meth:`rhs_env.radar.RadarSystem.metrics`; not a stage
of the scan (it reads the truth).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rhs_env.point_cloud import PointCloud, pointcloud_metrics
from rhs_env.radar.mounting import RadarMounts, wrap_angle
from rhs_env.scatterers import Occluders, Scatterers

__all__ = ["cloud_metrics", "point_errors"]


def point_errors(mounts: RadarMounts, cloud: PointCloud, scatterers: Scatterers, occluders: Occluders | None = None,
                 gate_m: float = 1.0) -> dict[str, Any]:
    """Per-target errors of ``cloud`` against the scatterers in view of ``mounts``.

    Each scatterer in view is matched to its nearest point; it is detected when
    that point lies within ``gate_m``. For the detected ones, the errors of the
    point's own measurement against the truth seen from the point's radar:
    ``xy`` (m, Euclidean), ``range`` (m), ``angle`` (rad, wrapped) and ``doppler``
    (radial velocity, m/s, ``u . v`` with u the unit vector radar -> scatterer).
    Returns ``n_true``, ``n_detected``, ``false_points`` and the error arrays.
    """
    view = mounts.in_view(scatterers, occluders)
    truth = scatterers.xy[view]
    out: dict[str, Any] = {"n_true": int(view.sum()), "n_points": len(cloud)}
    empty = np.zeros(0)
    if len(cloud) == 0 or truth.shape[0] == 0:
        return {**out, "n_detected": 0, "false_points": len(cloud),
                "xy": empty, "range": empty, "angle": empty, "doppler": empty}
    d2 = np.sum((truth[:, None, :] - cloud.xy[None, :, :]) ** 2, axis=-1)  # (T, P)
    j = np.argmin(d2, axis=1)
    hit = d2[np.arange(truth.shape[0]), j] <= gate_m ** 2
    p, t = j[hit], np.flatnonzero(view)[hit]
    rng_m, ang, unit = mounts.frame(scatterers.xy[t])
    r = cloud.radar[p]
    k = np.arange(p.size)
    v_true = np.einsum("kd,kd->k", unit[r, k], scatterers.velocity[t])
    return {**out, "n_detected": int(hit.sum()), "false_points": int(np.sum(d2.min(axis=0) > gate_m ** 2)),
            "xy": np.sqrt(d2[hit, p]), "range": cloud.range_m[p] - rng_m[r, k],
            "angle": wrap_angle(cloud.angle_rad[p] - ang[r, k]), "doppler": cloud.points[p, 2] - v_true}


def cloud_metrics(mounts: RadarMounts, cloud: PointCloud, scatterers: Scatterers, occluders: Occluders | None = None,
                  gate_m: float = 1.0, per_object: bool = False) -> dict:
    """Point-cloud metrics of ``cloud`` against the scatterers in view of ``mounts``
    (:func:`rhs_env.point_cloud.pointcloud_metrics`)."""
    view = mounts.in_view(scatterers, occluders)
    return pointcloud_metrics(cloud.xy, scatterers.xy[view], gate_m,
                              scatterers.object_id[view] if per_object else None)
