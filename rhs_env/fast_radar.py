"""The fast radar: point clouds drawn from the exact radar's measured detector, without synthesising samples.

**A labelled variant** (the ``-fast-`` ids, ``radar_model="fast"``; the default ids keep the exact
:class:`rhs_env.radar.RadarSystem`). Per scan, vectorised over the visible (radar, scatterer) pairs:

1. geometry as the exact radar: range, angle from boresight, radial velocity, field of view and line of sight
   (the same :meth:`rhs_env.radar.RadarSystem.visible`);
2. each pair's expected coherent SNR from the same link budget and two-way pattern
   (:func:`rhs_env.fast_radar_calibration.expected_snr`);
3. detection with the calibrated ``P_d(SNR)`` of the pair's class (moving / static), measured on the exact
   radar's footprint OS-CFAR + OMP, so it carries the detector's real false-alarm setting (not the design
   ``P_fa``) and what merged cells do to vehicles' faces;
4. each detected pair's range, angle, radial-velocity and amplitude errors drawn as one measured vector from the
   pool of its SNR bin (bootstrap: the joint distribution as measured); extra points (a split target) at the
   measured rate;
5. false points: beside each visible pair, a Poisson number of *linked* false points at the measured rate of its
   class and SNR, each a measured offset from its pair (the split and displaced points the exact radar makes
   beside targets, most of its false points and its ghosts in the ego's path); and *free* ones, a count drawn
   from the measured per-scan counts, each a measured free false point (radar, range, angle, velocity,
   amplitude);
6. the per-point range / angle stds as the exact path computes them (:func:`rhs_env.uncertainty.attach_uncertainty`).

The table comes from :func:`rhs_env.fast_radar_calibration.load_table` (shipped for the default radar, keyed by
the radar settings). Its agreement with the exact radar is published by ``scripts/fast_radar_fidelity.py``
(``docs/results/fast-radar.md``). What it does not model: where the free false points fall relative to the scene,
errors that depend on the scene beyond SNR and class (two targets in one cell are only in the average), and
scenes unlike the calibration's highway.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

import numpy as np

from rhs_env.array_models import ArrayAntenna
from rhs_env.fast_radar_calibration import (
    FastRadarTable,
    MissingCalibrationError,
    cached_table_path,
    expected_snr,
    extra_rate_of,
    link_rate_of,
    load_table,
    measure,
    pd_of,
    refine,
)
from rhs_env.point_cloud import PointCloud
from rhs_env.radar import RadarSystem
from rhs_env.radar_config import RadarConfig
from rhs_env.scatterers import Occluders, Scatterers
from rhs_env.uncertainty import attach_uncertainty

__all__ = ["RADAR_MODELS", "FastRadarSystem", "calibrate", "load_or_calibrate"]

#: ``radar_model`` values of :class:`rhs_env.wrappers.RadarObservation`
RADAR_MODELS = ("exact", "fast", "fast-calibrate")


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


class FastRadarSystem(RadarSystem):
    """:class:`RadarSystem`'s ``scan`` interface, drawing points from a calibrated table (module docstring).

    Args:
        config: :class:`RadarConfig`.
        rng: numpy Generator of every draw.
        table: the calibration; default :func:`load_table` for ``config``.
        calibrate_missing: calibrate ``config`` now when no table exists (see :func:`load_table`).
        patterns: as :class:`RadarSystem`.
        antennas: as :class:`RadarSystem`.
    """

    def __init__(self, config: RadarConfig | None = None, rng: np.random.Generator | None = None,
                 table: FastRadarTable | None = None, calibrate_missing: bool = False,
                 patterns: tuple[np.ndarray, np.ndarray] | None = None,
                 antennas: ArrayAntenna | list[ArrayAntenna] | None = None) -> None:
        config = config or RadarConfig()
        self.table = table if table is not None else load_or_calibrate(config, calibrate_missing)
        super().__init__(config, rng, patterns=patterns, antennas=antennas)
        t = self.table
        self._pd_centres = 0.5 * (t.pd_edges_db[1:] + t.pd_edges_db[:-1])
        self._vmax = config.max_velocity_mps

    def scan(self, scatterers: Scatterers, occluders: Occluders | None = None) -> PointCloud:
        """One sensing cycle of the four radars -> :class:`PointCloud` (``stage_times``: ``draw``, ``total``)."""
        t0 = time.perf_counter()
        t, rng = self.table, self.rng
        if len(scatterers):
            frame = self.radar_frame(scatterers.xy)
            rr, kk = np.nonzero(self.visible(scatterers, occluders, frame))
        else:
            rr = kk = np.zeros(0, int)
        radar = [np.zeros(0, int)]
        rng_m, theta, vel, amp = [np.zeros(0)], [np.zeros(0)], [np.zeros(0)], [np.zeros(0)]
        if rr.size:
            r_all, a_all, unit = frame
            r_t, th_t = r_all[rr, kk], a_all[rr, kk]
            v_t = np.einsum("pd,pd->p", unit[rr, kk], scatterers.velocity[kk])
            snr = expected_snr(self, rr, r_t, th_t, scatterers.rcs[kk])
            snr_db = 10 * np.log10(np.maximum(snr, 1e-30))
            static = scatterers.is_static[kk].astype(bool)
            det = rng.random(rr.size) < pd_of(t, snr_db, static)
            # extra points of the detected pairs: Poisson at the measured rate (split targets)
            n_extra = rng.poisson(extra_rate_of(t, snr_db[det], static[det]))
            src = np.flatnonzero(det)
            err = self._draw_errors(snr_db[src], static[src])
            if n_extra.sum() and t.extra_pool.shape[0]:
                rep = np.repeat(src, n_extra)
                extra = t.extra_pool[rng.integers(0, t.extra_pool.shape[0], rep.size)]
                src, err = np.concatenate([src, rep]), np.concatenate([err, extra])
            # linked false points (split / displaced points beside a target): Poisson per visible pair, an offset each
            n_link = rng.poisson(link_rate_of(t, snr_db, static))
            if n_link.sum() and t.link_pool.shape[0]:
                rep_l = np.repeat(np.arange(rr.size), n_link)
                c = static[rep_l].astype(int)
                lo, hi = t.link_start[c], t.link_start[c + 1]
                empty = hi <= lo  # a class without linked points: the other class's
                lo, hi = np.where(empty, t.link_start[1 - c], lo), np.where(empty, t.link_start[2 - c], hi)
                off = t.link_pool[lo + np.floor(rng.random(rep_l.size) * (hi - lo)).astype(int)]
                src, err = np.concatenate([src, rep_l]), np.concatenate([err, off])
            radar.append(rr[src])
            rng_m.append(r_t[src] + err[:, 0])
            theta.append(_wrap(th_t[src] + err[:, 1]))
            vel.append(v_t[src] + err[:, 2])
            amp.append(np.sqrt(snr[src]) * np.exp(err[:, 3]))
        if t.false_counts.size and t.false_pool.shape[0]:
            n_false = int(t.false_counts[rng.integers(0, t.false_counts.size)])
            if t.false_scale > 1.0:  # the refined rate (:func:`rhs_env.fast_radar_calibration.refine`)
                n_false += int(rng.binomial(n_false, min(t.false_scale - 1.0, 1.0)))
            elif t.false_scale < 1.0:
                n_false = int(rng.binomial(n_false, t.false_scale))
            fp = t.false_pool[rng.integers(0, t.false_pool.shape[0], n_false)]
            radar.append(fp[:, 0].astype(int))
            rng_m.append(fp[:, 1])
            theta.append(fp[:, 2])
            vel.append(fp[:, 3])
            amp.append(fp[:, 4])
        cloud = self._cloud(np.concatenate(radar), np.concatenate(rng_m), np.concatenate(theta),
                            np.concatenate(vel), np.concatenate(amp))
        total = time.perf_counter() - t0
        cloud.stage_times = {"draw": total, "total": total}
        return cloud

    def _draw_errors(self, snr_db: np.ndarray, static: np.ndarray) -> np.ndarray:
        """One measured error vector (:data:`rhs_env.fast_radar_calibration.ERROR_COLUMNS`) per pair, from the pool
        of its class and SNR bin."""
        t = self.table
        n_e = t.err_edges_db.size - 1
        b = np.clip(np.digitize(snr_db, t.err_edges_db) - 1, 0, n_e - 1)
        c = static.astype(int)
        lo, hi = t.err_start[c, b], t.err_stop[c, b]
        idx = lo + np.floor(self.rng.random(snr_db.size) * (hi - lo)).astype(int)
        return t.err_pool[idx]

    def _cloud(self, radar: np.ndarray, rng_m: np.ndarray, theta: np.ndarray, vel: np.ndarray,
               amp: np.ndarray) -> PointCloud:
        """The points in the exact path's layout and order (radar, then range), inside the reported range."""
        cfg = self.config
        vmax = self._vmax
        vel = (vel + vmax) % (2 * vmax) - vmax  # the unambiguous interval, as the OMP's wrapped Doppler phase
        keep = (rng_m >= cfg.min_range_m) & (rng_m <= cfg.max_range_m)
        radar, rng_m, theta, vel, amp = radar[keep], rng_m[keep], theta[keep], vel[keep], amp[keep]
        o = np.lexsort((rng_m, radar))
        radar, rng_m, theta, vel, amp = radar[o], rng_m[o], theta[o], vel[o], amp[o]
        ang_v = self.boresights[radar] + theta
        xy = self.positions[radar] + rng_m[:, None] * np.stack([np.cos(ang_v), np.sin(ang_v)], -1)
        pts = np.column_stack([xy, vel, amp]) if radar.size else np.zeros((0, 4))
        cloud = PointCloud(points=pts, radar=radar.astype(int), range_m=rng_m, angle_rad=theta)
        attach_uncertainty(self, cloud)
        return cloud



def calibrate(config: RadarConfig, seeds: Iterable[int], steps: int = 40, gate_m: float = 1.0,
              env_kwargs: dict[str, Any] | None = None, progress: bool = False) -> FastRadarTable:
    """Measure the exact radar on highway scenes and build the fast radar's table, refined
    (:func:`rhs_env.fast_radar_calibration.measure`, :func:`rhs_env.fast_radar_calibration.refine`).

    Args:
        config: the radar settings.
        seeds: scene seeds, one episode each (disjoint from any fidelity check's).
        steps: steps per episode.
        gate_m: matching gate, m.
        env_kwargs: scene config (default: the project's highway).
        progress: print one line per episode.

    Returns:
        The table (not saved).
    """
    table, scenes, records = measure(config, seeds, steps, gate_m, env_kwargs, progress)
    return refine(table, FastRadarSystem(config, np.random.default_rng(0), table=table), scenes, records, gate_m)


def load_or_calibrate(config: RadarConfig, calibrate_missing: bool = False, scans: int = 400) -> FastRadarTable:
    """:func:`rhs_env.fast_radar_calibration.load_table`; a configuration without a table is calibrated now
    (``scans`` exact scans, a minute or more) and cached when ``calibrate_missing``, else refused (its
    :class:`rhs_env.fast_radar_calibration.MissingCalibrationError` says how to calibrate it)."""
    try:
        return load_table(config)
    except MissingCalibrationError:
        if not calibrate_missing:
            raise
    table = calibrate(config, seeds=range(10_000, 10_000 + max(1, scans // 40)), steps=40)
    table.save(cached_table_path(config))
    return table
