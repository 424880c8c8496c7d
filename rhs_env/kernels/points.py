"""Compiled point assembly (numba): the OMP's targets to points (:meth:`rhs_env.radar.points.PointAssembler.assemble`).

:func:`range_offsets` is the parabolic range offset of each target from its neighbouring bins
(:func:`rhs_env.point_cloud.parabolic_offset` on the first interior maximum); :func:`assemble_points` turns the
targets' range, angle, Doppler and amplitude into the cloud's rows.
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import njit

__all__ = ["assemble_points", "range_offsets"]


@njit
def range_offsets(pw: np.ndarray, half: int) -> np.ndarray:
    """Per-target range offset from the detection's bin (D, L), padded bins: :meth:`rhs_env.radar.estimation.AngleEstimator.target_bins`.

    ``pw[d, l, w] = log |s_dl(k_d + w - half)|^2`` over the W neighbouring bins; ``j`` the first interior maximum
    (``1 + argmax pw[d, l, 1:W-1]``), then the vertex of the parabola through ``(ym, y0, yp) = pw[d, l, j-1..j+1]``
    (:func:`rhs_env.point_cloud.parabolic_offset`): ``den = ym - 2 y0 + yp``, ``delta = 0.5 (ym - yp) / den`` where
    ``den < 0`` (else 0), clipped to [-0.5, 0.5]; the offset is ``j - half + delta``.
    """
    n_d, n_l, n_w = pw.shape
    out = np.empty((n_d, n_l))
    for d in range(n_d):
        for l in range(n_l):
            j = 1
            best = pw[d, l, 1]
            for w in range(2, n_w - 1):
                if pw[d, l, w] > best:
                    best, j = pw[d, l, w], w
            ym, y0, yp = pw[d, l, j - 1], pw[d, l, j], pw[d, l, j + 1]
            den = ym - 2.0 * y0 + yp
            delta = 0.5 * (ym - yp) / den if den < 0 else 0.0
            out[d, l] = (j - half) + min(max(delta, -0.5), 0.5)
    return out


@njit
def assemble_points(rd: np.ndarray, kd: np.ndarray, theta: np.ndarray, omega: np.ndarray, amp_abs: np.ndarray,
                    valid: np.ndarray, anorm: np.ndarray, tfrac: np.ndarray, positions: np.ndarray,
                    boresights: np.ndarray, wavelength: float, four_pi_chirp_s: float, sample_rate_hz: float,
                    zero_pad: float, samples: float, c0: float, slope: float, sigma_y: float, min_range_m: float,
                    max_range_m: float, leak: np.ndarray, same_angle: float,
                    margin: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The points of the valid targets (:meth:`rhs_env.radar.points.PointAssembler.assemble`), in ``np.nonzero(valid)`` order.

    Per valid target (d, l) of radar ``r = rd_d``: radial velocity ``v = wrap(omega) lambda / (4 pi T_c)``
    (``wrap(a) = (a + pi) mod 2 pi - pi``), beat frequency ``f = (kd_d + tfrac) f_s / (Z N) - 2 v / lambda``,
    range ``R = c0 f / (2 S)``, position ``p_r + R (cos, sin)(boresight_r + theta)``, amplitude
    ``a = |s| ||atom|| / sigma_Y`` (``amp_abs = |s|`` from numpy: its complex absolute value is its own SIMD
    algorithm, not ``hypot``). Kept: ``min_range_m <= R <= max_range_m`` and not a range sidelobe
    (:meth:`rhs_env.radar.points.PointAssembler.sidelobe_points`): with ``b = R 2 S / c0 Z N / f_s`` (padded bins),
    ``a^2 < margin max a'^2 leak(|rint(b - b')|)`` over the stronger targets of the same radar within
    ``same_angle`` is a sidelobe. Returns rows (x, y, v, a) (N, 4), radar (N,), R (N,) and theta (N,).
    """
    n_d, n_l = valid.shape
    n = 0
    for d in range(n_d):
        for l in range(n_l):
            n += valid[d, l]
    vel = np.empty(n)
    rng_m = np.empty(n)
    th = np.empty(n)
    a = np.empty(n)
    radar = np.empty(n, np.int64)
    q = 0
    two_pi = 2 * np.pi
    for d in range(n_d):
        for l in range(n_l):
            if not valid[d, l]:
                continue
            v = ((omega[d, l] + np.pi) % two_pi - np.pi) * wavelength / four_pi_chirp_s
            f_beat = (kd[d] + tfrac[d, l]) * sample_rate_hz / (zero_pad * samples) - 2 * v / wavelength
            vel[q] = v
            rng_m[q] = c0 * f_beat / (2 * slope)
            th[q] = theta[d, l]
            radar[q] = rd[d]
            a[q] = amp_abs[d, l] * anorm[d, l] / sigma_y
            q += 1
    keep = np.empty(n, np.bool_)
    n_keep = 0
    for p in range(n):
        side = False
        if n >= 2:
            bins_p = rng_m[p] * 2 * slope / c0 * zero_pad * samples / sample_rate_hz
            a2 = a[p] ** 2
            worst = 0.0
            for o in range(n):
                if radar[o] == radar[p] and abs(th[p] - th[o]) < same_angle and a[o] ** 2 > a2:
                    bins_o = rng_m[o] * 2 * slope / c0 * zero_pad * samples / sample_rate_hz
                    dk = min(int(abs(np.rint(bins_p - bins_o))), leak.size - 1)
                    worst = max(worst, a[o] ** 2 * leak[dk])
            side = a2 < margin * worst
        keep[p] = (rng_m[p] >= min_range_m) and (rng_m[p] <= max_range_m) and not side
        n_keep += keep[p]
    pts = np.empty((n_keep, 4))
    radar_k = np.empty(n_keep, np.int64)
    rng_k = np.empty(n_keep)
    th_k = np.empty(n_keep)
    q = 0
    for p in range(n):
        if keep[p]:
            ang = boresights[radar[p]] + th[p]
            pts[q, 0] = positions[radar[p], 0] + rng_m[p] * np.cos(ang)
            pts[q, 1] = positions[radar[p], 1] + rng_m[p] * np.sin(ang)
            pts[q, 2] = vel[p]
            pts[q, 3] = a[p]
            radar_k[q], rng_k[q], th_k[q] = radar[p], rng_m[p], th[p]
            q += 1
    return pts, radar_k, rng_k, th_k
