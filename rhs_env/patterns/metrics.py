"""Pattern geometry and quality metrics shared by the optimizers and the reports.

Notation (paper eq. 3). ``s = sin(theta)``; element positions
``x_m = m d`` in wavelengths; feed phase ``q_m``; amplitude ``psi_m``.

* side-X one-way gain   ``x(s) = sum_m psi_m q_m exp(j 2 pi x_m s) = b(s)^T psi``
  (linear in ``psi``; ``b_m(s) = q_m exp(j 2 pi x_m s)``)
* normalised gains      ``t(s) / ||psi_T||``, ``r(s) / ||psi_R||`` (|.|^2 <= M, linear power ratio)
* two-way gain          ``h(s) = r(s) t(s)``, ``|h|^2 <= M^2``
* main lobe of grid i   ``|s - s_i| <= lambda / (M d)`` (``RHSConfig.mainlobe_halfwidth``)
* P1 objective          ``delta_i = |h(s_i)|^2 - max_{l in D} |h(s_l)|^2`` in normalised units
  (SNR difference with Tx power and Rx noise normalised, paper P1/P4)
* PSLR                  ``max_{|s - s_i| > hw} |h|^2 / max_s |h|^2`` in dB on a fine grid
* pointing error        ``argmax_theta |h(theta)|^2 - theta_i`` in degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rhs_env.array_models import RHSConfig, rhs_antenna

__all__ = [
    "FINE_GRID_POINTS", "GridReport", "delta_p1", "mainlobe_checks", "pattern_report", "pointing_error_deg",
    "side_matrix", "sidelobe_directions", "two_way_power",
]

FINE_GRID_POINTS = 8001  # points in sin(theta) over [-1, 1] for PSLR / pointing


def side_matrix(config: RHSConfig, sin_theta: np.ndarray, feed: int) -> np.ndarray:
    """B with rows ``b(s)^T``: ``B[l, m] = q_m exp(j 2 pi x_m s_l)``, shape s.shape + (M,).

    ``B @ psi`` is the (unnormalised) one-way gain of a line fed at ``feed``.
    """
    x = np.arange(config.elements) * config.spacing_wl
    s = np.asarray(sin_theta, dtype=float)
    return np.exp(2j * np.pi * s[..., None] * x) * config.feed_phase(feed)


def sidelobe_directions(config: RHSConfig, angle_deg: float, oversample: float = 4.0) -> np.ndarray:
    """The sidelobe set D of grid ``angle_deg`` as values of sin(theta), shape (L,).

    Uniform samples of ``s`` in [-1, 1] with spacing ``hw / oversample``
    (``hw = lambda / (M d)``, so ``oversample`` samples per sidelobe width), keeping
    those outside the main lobe ``|s - s_i| > hw``, plus the two main-lobe edges
    nudged just outside and the endfire points ``s = +-1``.
    """
    if not oversample > 0:
        raise ValueError(f"oversample must be > 0, got {oversample!r}")
    hw = config.mainlobe_halfwidth
    si = np.sin(np.deg2rad(angle_deg))
    n = int(np.ceil(2.0 / (hw / oversample))) + 1
    s = np.linspace(-1.0, 1.0, n)
    edges = si + np.array([-1.0, 1.0]) * hw * (1.0 + 1e-6)
    s = np.concatenate([s, edges[np.abs(edges) <= 1.0]])
    s = np.unique(s[np.abs(s - si) > hw])
    return s


def mainlobe_checks(config: RHSConfig, angle_deg: float, grid_deg: float, near: float = 0.45) -> np.ndarray:
    """sin(theta) samples inside the main lobe where the two-way gain must not exceed its centre value.

    ``theta_i +- near * grid_deg`` (with a unimodal main lobe and ``near = 0.45`` this
    bounds the pointing error by ``grid_deg / 2``; with a symmetric main lobe
    ``near = 0.9`` bounds it by about ``0.45 grid_deg`` and costs less gain) and
    ``s_i +- {0.3, 0.6, 0.9} hw`` (no secondary peak inside the main lobe). Samples
    outside [-1, 1] or the main lobe are dropped.
    """
    hw = config.mainlobe_halfwidth
    si = np.sin(np.deg2rad(angle_deg))
    near_s = np.sin(np.deg2rad(angle_deg + np.array([-near, near]) * grid_deg))
    far_s = si + np.array([-0.9, -0.6, -0.3, 0.3, 0.6, 0.9]) * hw
    s = np.concatenate([near_s, far_s])
    keep = (np.abs(s) <= 1.0) & (np.abs(s - si) <= hw) & (np.abs(s - si) > 1e-9)
    return np.unique(s[keep])


def two_way_power(config: RHSConfig, tx_psi: np.ndarray, rx_psi: np.ndarray, sin_theta: np.ndarray) -> np.ndarray:
    """Normalised two-way power ``|h(s)|^2 = |t(s) r(s)|^2 / (||psi_T||^2 ||psi_R||^2)``.

    ``tx_psi``, ``rx_psi``: (..., M); returns (...,) + sin_theta.shape (linear, <= M^2).
    """
    bt = side_matrix(config, sin_theta, config.tx_feed)
    br = side_matrix(config, sin_theta, config.rx_feed)
    tx_psi = np.asarray(tx_psi, dtype=float)
    rx_psi = np.asarray(rx_psi, dtype=float)
    t = np.einsum("...m,km->...k", tx_psi, bt.reshape(-1, config.elements))
    r = np.einsum("...m,km->...k", rx_psi, br.reshape(-1, config.elements))
    nt = np.sum(tx_psi**2, axis=-1)[..., None]
    nr = np.sum(rx_psi**2, axis=-1)[..., None]
    p = np.abs(t) ** 2 * np.abs(r) ** 2 / (nt * nr)
    return p.reshape(tx_psi.shape[:-1] + np.shape(sin_theta))


def pointing_error_deg(config: RHSConfig, tx_psi: np.ndarray, rx_psi: np.ndarray, angle_deg: float,
                       points: int = 801) -> float:
    """argmax of the two-way gain inside the main lobe of grid ``angle_deg`` minus ``angle_deg``, degrees.

    ``points`` uniform samples of ``s`` over ``s_i +- hw`` (clipped to [-1, 1]) plus ``s_i``.
    """
    hw = config.mainlobe_halfwidth
    si = float(np.sin(np.deg2rad(angle_deg)))
    s = np.unique(np.r_[np.clip(np.linspace(si - hw, si + hw, points), -1.0, 1.0), si])
    p = two_way_power(config, tx_psi, rx_psi, s)
    return float(np.rad2deg(np.arcsin(s[int(np.argmax(p))])) - angle_deg)


def delta_p1(
    config: RHSConfig, tx_psi: np.ndarray, rx_psi: np.ndarray, angle_deg: float, sidelobes: np.ndarray
) -> float:
    """P1 objective ``delta = |h(s_i)|^2 - max_{l in D} |h(s_l)|^2`` (normalised units) for one grid."""
    si = np.sin(np.deg2rad(angle_deg))
    p = two_way_power(config, tx_psi, rx_psi, np.concatenate([[si], sidelobes]))
    return float(p[0] - p[1:].max())


@dataclass
class GridReport:
    """Per-grid quality numbers of a pattern library."""

    angle_deg: np.ndarray  # (I,) grid centres
    mainlobe_gain_db: np.ndarray  # (I,) two-way |h(theta_i)|^2 in dB (normalised, <= 20 log10 M)
    pslr_db: np.ndarray  # (I,) peak sidelobe over peak, dB
    pointing_error_deg: np.ndarray  # (I,) argmax two-way minus grid centre
    delta: np.ndarray  # (I,) P1 objective on the optimisation set D, normalised units

    def rows(self) -> list[dict[str, float]]:
        return [
            {
                "angle_deg": float(a),
                "mainlobe_gain_db": float(g),
                "pslr_db": float(p),
                "pointing_error_deg": float(e),
                "delta": float(d),
            }
            for a, g, p, e, d in zip(
                self.angle_deg, self.mainlobe_gain_db, self.pslr_db, self.pointing_error_deg, self.delta
            )
        ]

    def summary(self) -> dict[str, float]:
        return {
            "grids": int(self.angle_deg.size),
            "worst_pslr_db": float(np.max(self.pslr_db)),
            "median_pslr_db": float(np.median(self.pslr_db)),
            "median_mainlobe_gain_db": float(np.median(self.mainlobe_gain_db)),
            "worst_pointing_error_deg": float(np.max(np.abs(self.pointing_error_deg))),
            "min_delta": float(np.min(self.delta)),
        }


def pattern_report(
    config: RHSConfig,
    tx_psi: np.ndarray,
    rx_psi: np.ndarray,
    angles_deg: np.ndarray,
    fine_points: int = FINE_GRID_POINTS,
    oversample: float = 4.0,
) -> GridReport:
    """Evaluate every grid: main-lobe gain, PSLR and pointing error on a fine sin(theta) grid.

    The fine grid has ``fine_points`` uniform samples of ``s`` in [-1, 1] plus every
    grid centre; gains come from :class:`rhs_env.array_models.ArrayAntenna` (normalised).
    ``delta`` is evaluated on the optimisation set D of :func:`sidelobe_directions`.
    """
    angles_deg = np.atleast_1d(np.asarray(angles_deg, dtype=float))
    ant = rhs_antenna(config, tx_psi, rx_psi, angles_deg)
    si = np.sin(np.deg2rad(angles_deg))
    s = np.unique(np.concatenate([np.linspace(-1.0, 1.0, fine_points), si]))
    p = np.abs(ant.two_way_gain(np.arcsin(s))) ** 2  # (I, S)
    hw = config.mainlobe_halfwidth
    outside = np.abs(s[None, :] - si[:, None]) > hw
    peak = p.max(axis=1)
    side = np.where(outside, p, 0.0).max(axis=1)
    p_centre = np.abs(ant.two_way_gain(np.deg2rad(angles_deg)))[np.arange(angles_deg.size), np.arange(angles_deg.size)] ** 2
    pointing = np.rad2deg(np.arcsin(s[np.argmax(p, axis=1)])) - angles_deg
    delta = np.array(
        [
            delta_p1(config, tx_psi[k], rx_psi[k], a, sidelobe_directions(config, a, oversample))
            for k, a in enumerate(angles_deg)
        ]
    )
    tiny = 1e-300
    return GridReport(
        angle_deg=angles_deg,
        mainlobe_gain_db=10 * np.log10(np.maximum(p_centre, tiny)),
        pslr_db=10 * np.log10(np.maximum(side, tiny) / np.maximum(peak, tiny)),
        pointing_error_deg=pointing,
        delta=delta,
    )
