"""Point scatterers and opaque occluders in the vehicle frame, and line-of-sight tests.

Frames and units (docs/INTERFACES.md): vehicle frame, x forward, y left,
origin at the ego vehicle's centre; metres, m/s, m^2.

Occlusion model: a scatterer at ``p`` is hidden from a radar at ``o`` when the
segment ``o -> p`` properly crosses an occluder segment ``a -> b`` of another
object. Both segments are parametrised, ``o + u (p - o)`` and ``a + w (b - a)``;
with the 2-D cross product ``x(u, v) = u_x v_y - u_y v_x`` and ``d = p - o``,
``e = b - a``, ``f = a - o``:

    u = x(f, e) / x(d, e),   w = x(f, d) / x(d, e),

and they cross when ``0 < u < 1`` and ``0 <= w <= 1`` (parallel segments,
``x(d, e) = 0``, never hide). A segment never hides points of its own object,
so a vehicle's visible faces are not hidden by its own outline.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LOS_EPS", "Occluders", "Scatterers", "visible_mask"]

# Relative tolerance on the ray parameter u: a point lying on an occluder
# (u -> 1) is not hidden by it.
LOS_EPS = 1e-9


def _as_array(name: str, value: np.ndarray, shape_tail: tuple[int, ...], dtype) -> np.ndarray:
    arr = np.asarray(value, dtype=dtype)
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        want = "(K" + "".join(f", {s}" for s in shape_tail) + ")"
        raise ValueError(f"{name} must have shape {want}, got {arr.shape}")
    return arr


@dataclass
class Scatterers:
    """Point scatterers in the VEHICLE frame at the scan instant.

    Attributes:
        xy: (K, 2) positions, m.
        velocity: (K, 2) velocity relative to the ego vehicle, m/s (static
            objects: minus the ego velocity, rotation included).
        rcs: (K,) radar cross-section sigma, m^2 (>= 0).
        object_id: (K,) int, the object each point belongs to (occlusion, metrics).
        is_static: (K,) bool, True for roadside landmarks.
    """

    xy: np.ndarray
    velocity: np.ndarray
    rcs: np.ndarray
    object_id: np.ndarray
    is_static: np.ndarray

    def __post_init__(self) -> None:
        self.xy = _as_array("xy", self.xy, (2,), float).reshape(-1, 2)
        k = self.xy.shape[0]
        self.velocity = _as_array("velocity", np.reshape(self.velocity, (-1, 2)), (2,), float)
        self.rcs = np.asarray(self.rcs, dtype=float).reshape(-1)
        self.object_id = np.asarray(self.object_id).reshape(-1).astype(np.int64)
        self.is_static = np.asarray(self.is_static).reshape(-1).astype(bool)
        for name in ("velocity", "rcs", "object_id", "is_static"):
            if len(getattr(self, name)) != k:
                raise ValueError(f"{name} must have {k} rows (one per scatterer), got {len(getattr(self, name))}")
        for name in ("xy", "velocity", "rcs"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"{name} must be finite")
        if np.any(self.rcs < 0):
            raise ValueError(f"rcs must be >= 0 m^2, got min {self.rcs.min():.4g}")

    def __len__(self) -> int:
        return self.xy.shape[0]

    @classmethod
    def empty(cls) -> Scatterers:
        return cls(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0, int), np.zeros(0, bool))

    @classmethod
    def static_points(cls, xy: np.ndarray, rcs: float | np.ndarray = 5.0) -> Scatterers:
        """Static point landmarks (zero relative velocity), one object each."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        k = xy.shape[0]
        return cls(xy, np.zeros((k, 2)), np.broadcast_to(np.asarray(rcs, float), (k,)).copy(),
                   np.arange(k), np.ones(k, bool))

    def subset(self, mask: np.ndarray) -> Scatterers:
        return Scatterers(self.xy[mask], self.velocity[mask], self.rcs[mask], self.object_id[mask], self.is_static[mask])


@dataclass
class Occluders:
    """Opaque segments in the vehicle frame.

    Attributes:
        segments: (S, 2, 2) endpoints ``[[x0, y0], [x1, y1]]``, m.
        object_id: (S,) int; a segment never hides points of its own object.
    """

    segments: np.ndarray
    object_id: np.ndarray

    def __post_init__(self) -> None:
        self.segments = np.asarray(self.segments, dtype=float).reshape(-1, 2, 2)
        self.object_id = np.asarray(self.object_id).reshape(-1).astype(np.int64)
        if len(self.object_id) != self.segments.shape[0]:
            raise ValueError(
                f"object_id must have {self.segments.shape[0]} entries (one per segment), got {len(self.object_id)}"
            )
        if not np.all(np.isfinite(self.segments)):
            raise ValueError("segments must be finite")

    def __len__(self) -> int:
        return self.segments.shape[0]

    @classmethod
    def empty(cls) -> Occluders:
        return cls(np.zeros((0, 2, 2)), np.zeros(0, int))

    @classmethod
    def from_boxes(cls, centers: np.ndarray, headings: np.ndarray, length: float | np.ndarray,
                   width: float | np.ndarray, object_id: np.ndarray) -> Occluders:
        """The four sides of oriented rectangles (vehicles): 4 segments per box."""
        c = np.asarray(centers, float).reshape(-1, 2)
        n = c.shape[0]
        h = np.broadcast_to(np.asarray(headings, float), (n,))
        half_l = 0.5 * np.broadcast_to(np.asarray(length, float), (n,))
        half_w = 0.5 * np.broadcast_to(np.asarray(width, float), (n,))
        local = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], float)  # corners, CCW
        corners_l = local[None] * np.stack([half_l, half_w], -1)[:, None, :]  # (n, 4, 2)
        cos, sin = np.cos(h)[:, None], np.sin(h)[:, None]
        corners = np.stack([cos * corners_l[..., 0] - sin * corners_l[..., 1],
                            sin * corners_l[..., 0] + cos * corners_l[..., 1]], -1) + c[:, None, :]
        seg = np.stack([corners, np.roll(corners, -1, axis=1)], axis=2)  # (n, 4, 2, 2)
        oid = np.repeat(np.asarray(object_id).reshape(-1), 4)
        return cls(seg.reshape(-1, 2, 2), oid)


def visible_mask(radar_xy: np.ndarray, scatterers: Scatterers, occluders: Occluders | None) -> np.ndarray:
    """Line-of-sight mask of every scatterer from one or several radars.

    Args:
        radar_xy: (2,) one radar or (R, 2) several, vehicle frame, m.
        scatterers: the K points.
        occluders: S opaque segments, or None (nothing hidden).

    Returns:
        (K,) bool for a single radar, (R, K) for several: True where the
        segment radar -> scatterer crosses no occluder segment of another object.
        Vectorised over R x K x S (see the module docstring for the test).
    """
    o = np.asarray(radar_xy, dtype=float)
    single = o.ndim == 1
    o = o.reshape(-1, 2)
    k = len(scatterers)
    if occluders is None or len(occluders) == 0 or k == 0:
        out = np.ones((o.shape[0], k), bool)
        return out[0] if single else out
    p = scatterers.xy
    a = occluders.segments[:, 0]  # (S, 2)
    e = occluders.segments[:, 1] - a  # (S, 2)
    d = p[None, :, :] - o[:, None, :]  # (R, K, 2)
    f = a[None, :, :] - o[:, None, :]  # (R, S, 2)

    def cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

    den = cross(d[:, :, None, :], e[None, None, :, :])  # (R, K, S)
    num_u = cross(f, e[None])[:, None, :]  # (R, 1, S)
    num_w = cross(f[:, None, :, :], d[:, :, None, :])  # (R, K, S)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = num_u / den
        w = num_w / den
    hit = (np.abs(den) > 1e-12) & (u > LOS_EPS) & (u < 1.0 - LOS_EPS) & (w >= 0.0) & (w <= 1.0)
    hit &= scatterers.object_id[None, :, None] != occluders.object_id[None, None, :]
    out = ~np.any(hit, axis=2)
    return out[0] if single else out
