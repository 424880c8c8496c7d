"""Compiled scene geometry (numba): the vehicles' face scatterers and the radars' line of sight.

:func:`face_scatterers` is :func:`rhs_env.scene._face_scatterers` in one pass over the boxes; :func:`line_of_sight`
is :func:`rhs_env.scatterers.visible_mask` per (radar, point) pair, only where a candidate needs it.
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import njit

__all__ = ["face_scatterers", "line_of_sight"]


@njit
def face_scatterers(pos: np.ndarray, heading: np.ndarray, vel: np.ndarray, yaw_rate: np.ndarray, length: np.ndarray,
                    width: np.ndarray, ego: np.ndarray, points_per_face: int,
                    vehicle_rcs: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`rhs_env.scene._face_scatterers`' points and occluders of V boxes, vehicle frame, in one pass.

    World-frame boxes (``pos`` (V, 2), ``heading``, ``vel`` (V, 2), ``yaw_rate``, ``length``, ``width`` (V,)) seen
    from the ego ``ego = (x, y, heading, vx, vy, yaw rate)``: centre ``c = R^T (pos - p_ego)``, faces f with
    outward normals n_f and tangents t_f (the box's rotation by ``heading - heading_ego`` applied to
    ``(1, 0), (0, 1), (-1, 0), (0, -1)`` and ``(0, 1), (-1, 0), (0, -1), (1, 0)``), half-extents
    ``(L, W, L, W) / 2`` and lengths ``(W, L, W, L)``; ``mid = c + n_f half_f``; a face is visible when
    ``cos_inc = -n_f . mid / |mid| > 1e-9`` and shares ``vehicle_rcs`` in proportion to ``len_f cos_inc`` over its
    ``points_per_face`` points ``mid + t_f ((k + 1/2) / P - 1/2) len_f``, whose velocity is
    ``R^T (v - v_ego) + w x (q - c) - w_ego x q``. Returns the points of the visible faces in (box, face,
    point) order: xy, velocity (K, 2), rcs (K,), each point's box (K,) int64; and every face as an occluder
    segment (corner, end) (4 V, 2, 2). The numpy reference's operations element by element.
    """
    n_v = pos.shape[0]
    p = points_per_face
    ct, st = np.cos(-ego[2]), np.sin(-ego[2])  # R^T = rotation(-heading_ego)
    xy = np.empty((4 * n_v * p, 2))
    velocity = np.empty((4 * n_v * p, 2))
    rcs = np.empty(4 * n_v * p)
    box = np.empty(4 * n_v * p, np.int64)
    segments = np.empty((4 * n_v, 2, 2))
    face = np.empty((4, 6))  # per face: mid x, mid y, tangent x, tangent y, length, weight
    q = 0
    for v in range(n_v):
        d0, d1 = pos[v, 0] - ego[0], pos[v, 1] - ego[1]
        c0, c1 = d0 * ct + d1 * -st, d0 * st + d1 * ct
        e0, e1 = vel[v, 0] - ego[3], vel[v, 1] - ego[4]
        w0, w1 = e0 * ct + e1 * -st, e0 * st + e1 * ct
        cr, sr = np.cos(heading[v] - ego[2]), np.sin(heading[v] - ego[2])
        total = 0.0
        for f in range(4):  # normal (cr, sr) turned by f quarter turns, the tangent a quarter turn further
            sign = 1.0 if f < 2 else -1.0
            even = f % 2 == 0
            n0 = sign * cr if even else sign * -sr
            n1 = sign * sr if even else sign * cr
            half = (length[v] if even else width[v]) / 2
            flen = width[v] if even else length[v]
            m0 = c0 + n0 * half
            m1 = c1 + n1 * half
            cos_inc = -(n0 * m0 + n1 * m1) / max(np.sqrt(m0 * m0 + m1 * m1), 1e-9)
            wgt = flen * cos_inc if cos_inc > 1e-9 else 0.0
            total += wgt
            face[f, 0], face[f, 1], face[f, 2], face[f, 3], face[f, 4], face[f, 5] = m0, m1, -n1, n0, flen, wgt
            h0, h1 = -n1 * (flen / 2), n0 * (flen / 2)
            segments[4 * v + f, 0, 0], segments[4 * v + f, 0, 1] = m0 - h0, m1 - h1
            segments[4 * v + f, 1, 0], segments[4 * v + f, 1, 1] = m0 + h0, m1 + h1
        for f in range(4):
            if face[f, 5] <= 0:
                continue
            share = face[f, 5] / total if total > 0 else 0.0
            for k in range(p):
                frac = (k + 0.5) / p - 0.5
                x0 = face[f, 0] + face[f, 2] * (frac * face[f, 4])
                x1 = face[f, 1] + face[f, 3] * (frac * face[f, 4])
                xy[q, 0], xy[q, 1] = x0, x1
                velocity[q, 0] = (w0 + yaw_rate[v] * -(x1 - c1)) - ego[5] * -x1
                velocity[q, 1] = (w1 + yaw_rate[v] * (x0 - c0)) - ego[5] * x0
                rcs[q] = vehicle_rcs * share / p
                box[q] = v
                q += 1
    return xy[:q], velocity[:q], rcs[:q], box[:q], segments


# --------------------------------------------------------------------------- line of sight
@njit
def line_of_sight(origins: np.ndarray, points: np.ndarray, segments: np.ndarray, point_object: np.ndarray,
                  segment_object: np.ndarray, candidates: np.ndarray, eps: float) -> np.ndarray:
    """``candidates & visible_mask(origins, ...)`` (R, K) of :func:`rhs_env.scatterers.visible_mask`, per pair.

    The segment ``o -> p`` of radar r and point k is hidden when it crosses an occluder segment ``a -> a + e``
    of another object: with ``d = p - o``, ``f = a - o`` and ``x(u, v) = u_x v_y - u_y v_x``,
    ``den = x(d, e)``, ``u = x(f, e) / den``, ``w = x(f, d) / den``, a crossing is ``|den| > 1e-12``,
    ``eps < u < 1 - eps``, ``0 <= w <= 1``: the reference's operations per (r, k, s), evaluated only for the
    candidate pairs (in the field of view) and up to the first crossing.
    """
    n_r, n_k = candidates.shape
    n_s = segments.shape[0]
    out = np.zeros((n_r, n_k), np.bool_)
    e0 = np.empty(n_s)
    e1 = np.empty(n_s)
    for s in range(n_s):
        e0[s] = segments[s, 1, 0] - segments[s, 0, 0]
        e1[s] = segments[s, 1, 1] - segments[s, 0, 1]
    u_hi = 1.0 - eps
    for r in range(n_r):
        for k in range(n_k):
            if not candidates[r, k]:
                continue
            d0 = points[k, 0] - origins[r, 0]
            d1 = points[k, 1] - origins[r, 1]
            seen = True
            for s in range(n_s):
                if point_object[k] == segment_object[s]:
                    continue
                f0 = segments[s, 0, 0] - origins[r, 0]
                f1 = segments[s, 0, 1] - origins[r, 1]
                den = d0 * e1[s] - d1 * e0[s]
                if not abs(den) > 1e-12:
                    continue
                u = (f0 * e1[s] - f1 * e0[s]) / den
                w = (f0 * d1 - f1 * d0) / den
                if u > eps and u < u_hi and w >= 0.0 and w <= 1.0:
                    seen = False
                    break
            out[r, k] = seen
    return out
