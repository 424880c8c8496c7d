"""Per-detection measurement uncertainty: range and angle standard deviations.

Each point of a :class:`rhs_env.point_cloud.PointCloud` is measured in its radar's
polar frame (range R from the radar, angle theta from its boresight). Its error
standard deviations follow from the Cramer-Rao bounds at the point's own SNR,
plus a floor for what the bound does not model:

* **SNR.** The point's amplitude ``a = |s| ||atom|| / sigma_Y`` is the amplitude
  SNR of the target over the whole sweep (slots x chirps, after the range
  window), so ``a^2`` is its coherent SNR. For the swept-beam vector
  ``iota = s h(theta) + n`` the per-slot SNR at unit two-way gain (the SNR of
  :func:`rhs_env.point_cloud.angle_crb`) is ``a^2 / ||h(theta)||^2``.
* **Angle.** ``CRB(theta) = ||h||^2 / (2 a^2 ||P_perp h'||^2)`` (rad^2),
  ``P_perp = I - h h^H / ||h||^2``, ``h' = dh/dtheta`` (the antenna's analytic
  derivative, :meth:`rhs_env.point_cloud.AngleDictionary.atoms`).
* **Range.** The frequency of a tone of total SNR ``a^2`` over N samples:
  ``var(f) >= 6 f_s^2 / ((2 pi)^2 a^2 (N^2 - 1))`` (Rife & Boorstyn), and
  ``R = c0 f / (2 S)`` (:func:`rhs_env.point_cloud.range_crb`), times
  :data:`RANGE_CRB_FACTOR`: the parabola through the log-power of the
  Hann-windowed, zero-padded spectrum is not efficient; on isolated targets at
  25-30 dB SNR its variance is 1.4-2.2x the bound (``tests/test_uncertainty.py``
  checks the resulting normalised errors).
* **Floor (model error).** ``sigma^2 = CRB + floor^2``. The floors cover the
  bias of the sub-bin range interpolation (parabola through the log-power of a
  Hann-windowed, zero-padded spectrum), the coupling of range and Doppler,
  dictionary mismatch, which the single-target bounds ignore. Defaults
  (``RadarConfig.uncertainty.range_std_floor_m`` = 3 mm,
  ``RadarConfig.uncertainty.angle_std_floor_deg`` = 0.003 deg) sit above the errors of isolated noiseless targets (0.7 mm,
  1e-4 deg RMS, ``tests/test_uncertainty.py``). Two targets in one range cell
  and errors outside the radar (timing, clustering) are not covered here: the
  SLAM filter adds its own floor (``slam.core.rbpf.SlamConfig.measurement_floor_m``).

A point's Cartesian covariance in the vehicle frame follows by linearising
``x = s + R (cos phi, sin phi)``, ``phi = boresight + theta``:
``Sigma = J diag(sigma_R^2, sigma_theta^2) J^T``, ``J = [u, R u_perp]``
(:func:`slam.core.association.point_covariance`, from the rows of :func:`point_rows`).
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import KernelTable
from rhs_env.point_cloud import AngleDictionary, range_crb

__all__ = ["RANGE_CRB_FACTOR", "angle_information", "point_std", "attach_uncertainty", "point_rows", "POINT_COLUMNS"]

#: variance of the sub-bin range estimate over its CRB (parabolic interpolation, Hann window, measured)
RANGE_CRB_FACTOR = 2.0


def angle_information(dic: AngleDictionary, theta_rad: np.ndarray) -> np.ndarray:
    """``||P_perp h'||^2 / ||h||^2`` (rad^-2) at the angles ``theta_rad`` (any shape).

    The angle CRB of a target of coherent SNR ``a^2`` is ``1 / (2 a^2 g)`` with this ``g``. With the
    dictionary's ``kernels="numba"`` the sums run compiled (:func:`rhs_env.kernels.angle_information`).
    """
    th = np.asarray(theta_rad, dtype=float)
    if th.size == 0:
        return np.zeros(th.shape)
    h, h1 = dic.atoms(th.reshape(-1), order=1)  # (I, T)
    return np.asarray(_STAGES.choose(getattr(dic, "kernels", "numpy")).information(h, h1)).reshape(th.shape)


#: the angle information's sums, compiled (:func:`rhs_env.kernels.angle_information`) or numpy, as the dictionary's
#: ``kernels``
_STAGES = KernelTable("rhs_env.uncertainty")


@_STAGES.stage("information", "numpy")
def _information_numpy(h: np.ndarray, h1: np.ndarray) -> np.ndarray:
    """``||P_perp h'||^2 / ||h||^2`` (T,) of the atoms h and their derivatives h1 (I, T), numpy (the reference)."""
    nh = np.sum(np.abs(h) ** 2, axis=0)
    proj = np.sum(np.abs(h1) ** 2, axis=0) - np.abs(np.sum(h.conj() * h1, axis=0)) ** 2 / nh
    return np.asarray(np.maximum(proj, 1e-300) / nh)


@_STAGES.stage("information", "numba")
def _information_numba(h: np.ndarray, h1: np.ndarray) -> np.ndarray:
    """:func:`_information_numpy` compiled (:func:`rhs_env.kernels.angle_information`: the same sums per angle)."""
    from rhs_env.kernels import angle_information as information

    return np.asarray(information(np.ascontiguousarray(h.T), np.ascontiguousarray(h1.T)))


def point_std(
    amplitude: np.ndarray,
    angle_information_: np.ndarray,
    *,
    samples: int,
    sample_rate_hz: float,
    slope_hz_per_s: float,
    range_floor_m: float,
    angle_floor_rad: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Range std (m) and angle std (rad) per point from its amplitude SNR ``a`` (linear).

    ``sigma_R = sqrt(RANGE_CRB_FACTOR CRB_R(a^2) + floor_R^2)``, ``sigma_theta = sqrt(1 / (2 a^2 g) + floor_theta^2)``
    with ``g`` from :func:`angle_information`; a zero amplitude gives an infinite std.
    """
    a2 = np.asarray(amplitude, dtype=float) ** 2
    g = np.asarray(angle_information_, dtype=float)
    with np.errstate(divide="ignore"):
        var_r = RANGE_CRB_FACTOR * range_crb(a2 / samples, samples, sample_rate_hz, slope_hz_per_s)
        var_t = 1.0 / (2.0 * a2 * g)
    return np.sqrt(var_r + range_floor_m**2), np.sqrt(var_t + angle_floor_rad**2)


def attach_uncertainty(system, cloud) -> None:
    """Fill ``cloud.range_std_m`` and ``cloud.angle_std_rad`` (N,) for a cloud of ``system``.

    ``system`` is the :class:`rhs_env.radar.RadarSystem` that produced ``cloud``: its
    per-radar dictionaries give the antenna's angle information, its config the
    waveform and the floors.
    """
    cfg = system.config
    n = len(cloud)
    dics = system.dictionaries
    groups: dict[int, tuple[AngleDictionary, list[int]]] = {}  # radars sharing a dictionary: one evaluation
    for r, dic in enumerate(dics):
        groups.setdefault(id(dic), (dic, []))[1].append(r)
    g = np.zeros(n)
    for dic, radars in groups.values():
        # a dictionary every radar shares (one antenna on the four radars, the default) takes every point
        sel = slice(None) if len(radars) == len(dics) else np.isin(cloud.radar, radars)
        g[sel] = angle_information(dic, cloud.angle_rad[sel])
    cloud.range_std_m, cloud.angle_std_rad = point_std(
        cloud.points[:, 3],
        g,
        samples=cfg.waveform.samples,
        sample_rate_hz=cfg.waveform.sample_rate_hz,
        slope_hz_per_s=cfg.waveform.slope,
        range_floor_m=cfg.uncertainty.range_std_floor_m,
        angle_floor_rad=np.deg2rad(cfg.uncertainty.angle_std_floor_deg),
    )


#: columns of a point row (:func:`point_rows`, the ``points`` observation)
POINT_COLUMNS = ("x", "y", "radial_velocity", "amplitude", "range_std", "angle_std", "radar")


def point_rows(cloud) -> np.ndarray:
    """(N, 7) rows ``x, y, radial velocity, amplitude, range std (m), angle std (rad), radar index``.

    A cloud without uncertainty (empty ``range_std_m``) gets infinite stds.
    """
    n = len(cloud)
    pts = np.asarray(cloud.points, dtype=float).reshape(-1, 4)
    rs = np.asarray(cloud.range_std_m, dtype=float)
    ast = np.asarray(cloud.angle_std_rad, dtype=float)
    if rs.shape != (n,) or ast.shape != (n,):
        rs, ast = np.full(n, np.inf), np.full(n, np.inf)
    return np.column_stack([pts, rs, ast, np.asarray(cloud.radar, dtype=float).reshape(n)])
