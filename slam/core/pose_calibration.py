"""The pose covariance calibrated for one radar configuration (``pose_covariance="calibrated"``).

The adaptive model (:mod:`slam.core.pose_uncertainty`) measures the drift's increment each cycle from the
static points paired with the map; its known limits are errors the scan-to-map residuals cannot see (a coarse
scan's angle quantisation, multipath that moves a point and its landmark alike, a dense roadside's wrong
pairings), so its covariance is right in shape but off in scale by a factor that depends on the radar, the
scene and the filter. The calibrated model keeps the adaptive one's terms, scales them with four factors and
adds the map's start with a fifth, all fitted on a few calibration drives of the configuration itself:

    ``C = s^2 (k_p diag(v) + G D G^T P G D G^T) + k_map B``,
    ``D = diag(sqrt(k_along), sqrt(k_cross), sqrt(k_heading))``,

``s^2`` the residuals' scale, ``v`` the particles' variances (the pose given the map), ``P`` the measured map
drift (map frame), ``G = diag(R(th), 1)`` at the estimated heading ``th`` (``D`` acts on the vehicle frame's
along-track, cross-track and heading axes; the correlations of ``P`` are kept), ``B`` the map-start heading
term (:class:`slam.core.drift.MapStartHeading`: one heading error of unit variance set over the map's first
metres and carried into cross-track by the distance driven) and ``k_map`` its variance (rad^2): the heading
error a new map starts with, which the random walk ``P`` (near zero at the start) does not model. The factors
maximise the
Gaussian likelihood of the calibration drives' pose errors ``e`` (3-dof, heading wrapped):

    ``min_k  mean_t [ ln det C_t(k) + min(e_t^T C_t(k)^-1 e_t, NEES_CAP) ] + PRIOR sum_i ln(k_i)^2``,

over the cycles where the filter is not lost (a lost filter reports the loss's std instead, unchanged). The
cap keeps one jump (a wrong association) from widening every cycle; the weak prior keeps a factor the drives
do not constrain (a term that is always small against the others) at 1. No factor is shared between
configurations: :mod:`slam.gym.pose_calibration` names each configuration by a key and fits, caches or ships
its own (:class:`PoseCalibration`).

:func:`nees_coverage` is the consistency summary the studies report: the fractions of cycles below, inside and
above the 95 % band of the chi-square distribution with 3 degrees of freedom, and the ANEES with its interval.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "CALIBRATION_VERSION",
    "NEES_FLOOR",
    "PoseCalibration",
    "ROW_COLUMNS",
    "calibrated_covariance",
    "fit_calibration",
    "nees",
    "nees_coverage",
    "row_nees",
]

#: the format of :class:`PoseCalibration` (a change of the model or its fit makes old caches stale; 2: the
#: map-start heading term)
CALIBRATION_VERSION = 2
#: std floors (m, m, rad) under the NEES, as the studies' ``pose_nees``
NEES_FLOOR = np.array([1e-3, 1e-3, 1e-4])
#: a cycle's NEES counts at most this much in the fit (a jump does not widen every cycle)
NEES_CAP = 50.0
#: weight of the prior ``sum ln(k)^2`` (a factor the drives do not constrain stays near 1)
PRIOR = 0.01
#: ``k_map``'s search range (rad^2): from no map-start term to a 1-rad heading std
MAP_HEADING_RANGE = (0.0, 1.0)
#: one calibration row per cycle: the pose error (3), the particles' variances (3), the drift P (9, row-major),
#: the residuals' scale, the estimated heading (rad), lost (0 / 1), the map-start term B (9, row-major)
ROW_COLUMNS = ("ex", "ey", "eth", "vx", "vy", "vth", *(f"p{i}{j}" for i in range(3) for j in range(3)),
               "scale", "heading", "lost", *(f"b{i}{j}" for i in range(3) for j in range(3)))


@dataclass(frozen=True)
class PoseCalibration:
    """The five factors of the calibrated covariance (module docstring) for the configuration ``key``.

    ``particles``, ``along``, ``cross``, ``heading``: ``k_p``, ``k_along``, ``k_cross``, ``k_heading`` (> 0);
    ``map_heading``: ``k_map``, the map-start heading variance (rad^2, in :data:`MAP_HEADING_RANGE`);
    ``key``: the configuration's name (:func:`slam.gym.pose_calibration.calibration_key`); ``seeds``,
    ``cycles``: the calibration drives; ``fit_cycles``: the cycles the fit used (not lost); ``setup``: what the
    key was computed from (a record, for the reader).
    """

    particles: float = 1.0
    along: float = 1.0
    cross: float = 1.0
    heading: float = 1.0
    map_heading: float = 0.0
    key: str = ""
    seeds: tuple[int, ...] = ()
    cycles: int = 0
    fit_cycles: int = 0
    version: int = CALIBRATION_VERSION
    setup: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)

    def __post_init__(self) -> None:
        for name in ("particles", "along", "cross", "heading"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or not 1e-6 <= v <= 1e6:
                raise ValueError(f"pose_calibration.{name} must be a number in [1e-6, 1e6], got {v!r}")
        lo, hi = MAP_HEADING_RANGE
        m = self.map_heading
        if not isinstance(m, (int, float)) or not math.isfinite(m) or not lo <= m <= hi:
            raise ValueError(f"pose_calibration.map_heading must be a variance in [{lo:g}, {hi:g}] rad^2, got {m!r}")

    @property
    def factors(self) -> np.ndarray:
        """``(k_p, k_along, k_cross, k_heading, k_map)``."""
        return np.array([self.particles, self.along, self.cross, self.heading, self.map_heading], dtype=float)

    def to_json(self) -> str:
        """The calibration as JSON text (:meth:`from_json` reads it)."""
        d = asdict(self)
        d["seeds"] = list(self.seeds)
        return json.dumps(d, indent=1, sort_keys=True, default=str) + "\n"

    @classmethod
    def from_json(cls, text: str) -> PoseCalibration:
        """Read :meth:`to_json`'s text; ``ValueError`` when the version is not :data:`CALIBRATION_VERSION`."""
        d = json.loads(text)
        if d.get("version") != CALIBRATION_VERSION:
            raise ValueError(f"pose calibration version {d.get('version')!r}, expected {CALIBRATION_VERSION}")
        d["seeds"] = tuple(int(s) for s in d.get("seeds", ()))
        return cls(**d)


def calibrated_covariance(
    variances: np.ndarray, drift: np.ndarray, heading: float, scale: float, factors: np.ndarray,
    map_start: np.ndarray | None = None,
) -> np.ndarray:
    """``C = s^2 (k_p diag(v) + G D G^T P G D G^T) + k_map B`` (module docstring).

    Args:
        variances: (3,) the particles' variances (m^2, m^2, rad^2).
        drift: (3, 3) the measured drift ``P`` (map frame).
        heading: the estimated heading ``th`` (rad).
        scale: the residuals' scale ``s^2``.
        factors: (5,) ``(k_p, k_along, k_cross, k_heading, k_map)``; (4,): ``k_map`` = 0.
        map_start: (3, 3) the map-start heading term ``B`` (:class:`slam.core.drift.MapStartHeading`); None: 0.

    Returns:
        (3, 3) the covariance (m^2, m rad, rad^2; map frame).
    """
    k = np.asarray(factors, dtype=float)
    c, s = math.cos(heading), math.sin(heading)
    G = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    M = G @ np.diag(np.sqrt(k[1:4])) @ G.T
    out = scale * (k[0] * np.diag(np.asarray(variances, dtype=float)) + M @ np.asarray(drift, dtype=float) @ M.T)
    if map_start is not None and len(k) > 4:
        out = out + k[4] * np.asarray(map_start, dtype=float).reshape(3, 3)
    return 0.5 * (out + out.T)


def nees(err: np.ndarray, cov: np.ndarray, std: np.ndarray | None = None) -> float:
    """3-dof NEES ``e^T P^-1 e`` of ``err`` (3,) against ``cov`` (3, 3), its diagonal raised to
    ``max(std, NEES_FLOOR)^2`` (``std``: the reported std, e.g. the loss's; None: the floors only)."""
    P = np.array(cov, dtype=float).reshape(3, 3)
    floor = NEES_FLOOR**2 if std is None else np.maximum(np.square(np.asarray(std, float)), NEES_FLOOR**2)
    P[np.diag_indices(3)] = np.maximum(np.diag(P), floor)
    return float(err @ np.linalg.solve(P, err))


def _batch(rows: np.ndarray, factors: np.ndarray, floor: np.ndarray = NEES_FLOOR) -> tuple[np.ndarray, np.ndarray]:
    """NEES (T,) and ``ln det C`` (T,) of rows (T, 27) under ``factors`` (5,), the std floors ``floor``,
    vectorised."""
    e, v, P, B = rows[:, 0:3], rows[:, 3:6], rows[:, 6:15].reshape(-1, 3, 3), rows[:, 18:27].reshape(-1, 3, 3)
    scale, th = rows[:, 15], rows[:, 16]
    k = np.asarray(factors, dtype=float)
    c, s = np.cos(th), np.sin(th)
    G = np.zeros((len(rows), 3, 3))
    G[:, 0, 0], G[:, 0, 1], G[:, 1, 0], G[:, 1, 1], G[:, 2, 2] = c, -s, s, c, 1.0
    M = G @ np.diag(np.sqrt(k[1:4]))[None] @ np.transpose(G, (0, 2, 1))
    C = scale[:, None, None] * (k[0] * v[:, None, :] * np.eye(3)[None] + M @ P @ np.transpose(M, (0, 2, 1))) + k[4] * B
    i = np.arange(3)
    C[:, i, i] = np.maximum(C[:, i, i], np.square(floor))
    if not np.all(floor > 0):  # without floors a zero term (no drift yet, one particle) would be singular
        C[:, i, i] += 1e-300
    x = np.einsum("ni,ni->n", e, np.linalg.solve(C, e[..., None])[..., 0])
    return x, np.linalg.slogdet(C)[1]


def row_nees(rows: np.ndarray, factors: np.ndarray, floor: np.ndarray = NEES_FLOOR) -> np.ndarray:
    """The NEES (T,) of calibration rows (T, 27) (:data:`ROW_COLUMNS`) under ``factors`` (5,), lost cycles
    included (their std is the loss's: the model's covariance there is what :func:`fit_calibration` skips);
    ``floor`` (3,): the std floors (m, m, rad; zeros: the model's covariance alone)."""
    return _batch(np.asarray(rows, dtype=float).reshape(-1, len(ROW_COLUMNS)), factors,
                  np.asarray(floor, dtype=float))[0]


def fit_calibration(rows: np.ndarray) -> tuple[np.ndarray, int]:
    """The factors ``(k_p, k_along, k_cross, k_heading, k_map)`` that maximise the likelihood of the rows'
    errors (module docstring), by Nelder-Mead (restarted until it stops improving) on ``ln k`` from the adaptive
    model (the four scale factors 1, a map-start heading std of 0.1 mrad; the prior pulls only the four scale
    factors towards 1).

    Args:
        rows: (T, 27) calibration rows (:data:`ROW_COLUMNS`) of the configuration's drives.

    Returns:
        The factors (5,) and the number of cycles used (rows not lost, finite); with fewer than 10 such cycles
        the scale factors are 1 and ``k_map`` 0 (nothing to fit).
    """
    from scipy.optimize import minimize

    r = np.asarray(rows, dtype=float).reshape(-1, len(ROW_COLUMNS))
    r = r[(r[:, 17] < 0.5) & np.all(np.isfinite(r), axis=1)]
    if len(r) < 10:
        return np.array([1.0, 1.0, 1.0, 1.0, 0.0]), len(r)
    lo = np.array([-12.0, -12.0, -12.0, -12.0, -40.0])
    hi = np.array([12.0, 12.0, 12.0, 12.0, math.log(MAP_HEADING_RANGE[1])])

    def loss(q: np.ndarray) -> float:
        x, logdet = _batch(r, np.exp(np.clip(q, lo, hi)))
        return float(np.mean(logdet + np.minimum(x, NEES_CAP)) + PRIOR * np.sum(q[:4] ** 2))

    # Nelder-Mead (the capped NEES is not smooth), restarted from where it stopped until the loss stops falling:
    # in five dimensions its simplex can collapse before the minimum (a synthetic test: 0.41 nats short)
    q, best = np.array([0.0, 0.0, 0.0, 0.0, 2 * math.log(1e-4)]), math.inf
    for _ in range(6):
        res = minimize(loss, q, method="Nelder-Mead", options={"maxiter": 6000, "xatol": 1e-4, "fatol": 1e-7})
        q, done = res.x, best - float(res.fun) < 1e-6
        best = min(best, float(res.fun))
        if done:
            break
    k = np.exp(np.clip(q, lo, hi))
    if q[4] <= lo[4]:  # the drives want no map-start term
        k[4] = 0.0
    return k, len(r)


def nees_coverage(values: np.ndarray, dof: int = 3, level: float = 0.95) -> dict[str, Any]:
    """Below / inside / above the two-sided ``level`` band of chi-square(``dof``), and the ANEES with its
    interval ``chi2(dof n) / n`` (``n`` cycles taken as independent: successive cycles are correlated, so it
    is narrower than the ANEES's real spread).

    Args:
        values: (n,) NEES per cycle.
        dof: degrees of freedom of each NEES.
        level: the band's level.

    Returns:
        ``cycles``, ``below``, ``inside``, ``above`` (fractions), ``median``, ``anees``, ``anees_interval``,
        ``anees_inside``, ``goal_met`` (inside >= 0.9 and neither tail above 0.07); ``{"cycles": 0}`` for none.
    """
    from scipy import stats

    x = np.asarray(values, dtype=float).reshape(-1)
    n = len(x)
    if not n:
        return {"cycles": 0}
    lo, hi = float(stats.chi2.ppf((1 - level) / 2, dof)), float(stats.chi2.ppf((1 + level) / 2, dof))
    a_lo, a_hi = (float(stats.chi2.ppf(q, dof * n)) / n for q in ((1 - level) / 2, (1 + level) / 2))
    below, above = float(np.mean(x < lo)), float(np.mean(x > hi))
    inside = 1.0 - below - above
    anees = float(np.mean(x))
    return {"cycles": n, "below": below, "inside": inside, "above": above, "median": float(np.median(x)),
            "anees": anees, "anees_interval": [a_lo, a_hi], "anees_inside": bool(a_lo <= anees <= a_hi),
            "goal_met": bool(inside >= 0.9 and below <= 0.07 and above <= 0.07)}
