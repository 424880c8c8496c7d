"""Does the paper's claim hold? RHS vs the same-cost phased array, random and hologram patterns.

The paper claims the RHS radar gives about a third of the phased array's error.
The physics (SPEC section 11) says where that can show: the RHS's 3x aperture
gives ~3x lower angle CRB and ~3x finer resolution, while its two-way peak gain is
higher but its ~3x narrower beam collects about as much echo energy over a sweep.
This study measures the ratio over the regimes where each effect dominates.

**Point-cloud level** (``--only pointcloud``). One radar system per antenna kind
(package defaults otherwise: :class:`rhs_env.radar.RadarConfig`). A *group* of K = 2
or 3 static point targets lies in one range cell (all at the same range
``range_m`` from the radar, +-0.25 m common jitter), K angles
``c + (k - (K-1)/2) dtheta`` around a centre ``c ~ U(-25, 25)`` deg from boresight;
the ego is at rest (no Doppler: the angle model of the CRB). Every scan carries
four independent groups, one per radar (front, left, rear, right: their sectors do
not overlap at this range), so a cell of ``seeds`` trials costs ``seeds / 4`` scans.
The SNR axis is the per-slot SNR at unit two-way gain (``RadarConfig.unit_gain_snr``,
the SNR of :func:`rhs_env.point_cloud.angle_crb`), set through the targets' RCS at
``range_m``; the SNR an antenna sees is this plus its two-way gain. Per trial:

* *resolved*: the points of that radar within ``range_gate_m`` of the group's range
  are assigned to the K targets one-to-one on angle (Hungarian); the group is resolved
  when all K targets get a point within ``min(dtheta / 2, angle_gate_max_deg)``;
* angle error of the matched targets (deg), against the CRB of K targets with
  equal power and unknown complex amplitudes (:func:`group_crb`, averaged over
  random relative phases) and the single-target CRB;
* *group error* (the regime map's metric): OSPA distance (order 2, cut-off
  ``ospa_cutoff_deg``) between the K true angles and the angles of those points:
  accuracy, misses, merged targets and ghosts in one number (deg);
* detection rate (a target is detected when a point of its radar lies within 1 m)
  and false points (points of its radar farther than 1 m from every target),
  :func:`rhs_env.point_cloud.pointcloud_metrics`.

**Element sweep** (``--only elements``): the same for M RHS elements with the phased
array at round(M / 6), on a coarser beam grid (``elements_grid_deg``, 5 deg: a
library for a non-default M is optimised into the user cache on first use).

**SLAM level** (``--only slam``): the paper's Fig. 5c drive (start pose, five
obstacles; :data:`rhs_env.envs.PAPER_OBSTACLES`), each obstacle replaced by a group
of K landmarks spaced ``2 D tan(dtheta / 2)`` across the line of sight from the
middle of the drive (D its distance), the ego at ``slam_speed_mps`` straight ahead,
one cycle per ``slam_dt_s``; :class:`slam.gym.radar_cloud.RadarCloud` scans the landmarks
with the package's radar and :func:`slam.core.scenario.run_scenario` runs the package's
SLAM with its default registration and, on the same clouds, the odometry oracle
(the filter's own floor). Metrics: ATE (vehicle position RMSE), map RMSE, spurious
and missed landmarks.

Statistics: 95 % intervals, t-distribution (ddof=1) for means; Wilson intervals
for probabilities; percentile bootstrap for ratios. Per-cell raw trials are cached
(``--cache``, one JSON line per cell, keyed by the cell and the radar / SLAM
configuration), so a stopped run resumes. Outputs: ``results/claim_study.json``,
``results/claim_study.md`` (the README section "Does the paper's claim hold?"),
``results/claim_study_*.png``.

    OMP_NUM_THREADS=1 nice -n 10 python scripts/claim_study.py [--only pointcloud|slam|elements] [--small]
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import os
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from rhs_common.stats import mean_interval, ratio_bootstrap, wilson_interval
from rhs_common.validation import check_int, check_range
from rhs_env.array_models import ANTENNA_KINDS, ArrayAntenna
from rhs_env.point_cloud import angle_crb, pointcloud_metrics
from rhs_env.radar import RadarConfig, RadarSystem
from rhs_env.scatterers import Scatterers
from rhs_studies.kit.provenance import write_json

ROOT = Path(__file__).resolve().parents[2]

LEVELS = ("pointcloud", "elements", "slam")
PAPER_RATIO = 1.0 / 3.0


@dataclass(frozen=True)
class StudyConfig:
    """The grid of the study (angles in degrees, SNR in dB per slot at unit two-way gain)."""

    antennas: tuple[str, ...] = ANTENNA_KINDS
    range_m: float = 30.0
    group_sizes: tuple[int, ...] = (2, 3)
    separations_deg: tuple[float, ...] = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0)
    snr_db: tuple[float, ...] = (-20.0, -14.0, -8.0, -2.0, 4.0, 10.0, 16.0, 22.0, 28.0, 34.0)
    seeds: int = 24
    centre_max_deg: float = 25.0
    range_gate_m: float = 1.5
    angle_gate_max_deg: float = 2.5
    ospa_cutoff_deg: float = 5.0
    grid_deg: float | None = None  # None: the package's default beam grid
    crb_phase_draws: int = 256
    bootstrap: int = 2000
    # element sweep (coarser grid: non-default M builds a pattern library on first use)
    elements: tuple[int, ...] = (20, 40, 60, 80)
    elements_grid_deg: float = 5.0
    elements_separations_deg: tuple[float, ...] = (1.0, 2.0, 3.0, 5.0, 8.0, 12.0)
    elements_snr_db: tuple[float, ...] = (4.0, 28.0)
    # SLAM level: (group size, separation deg) per scene; extra antennas on the cells of slam_extra_groups
    slam_antennas: tuple[str, ...] = ("rhs", "phased")
    slam_groups: tuple[tuple[int, float], ...] = ((1, 0.0), (2, 2.0), (2, 4.0), (2, 8.0), (3, 4.0))
    slam_extra_antennas: tuple[str, ...] = ("random", "hologram")
    slam_extra_groups: tuple[tuple[int, float], ...] = ((2, 4.0),)
    slam_snr_db: tuple[float, ...] = (28.0, -2.0)
    slam_registrations: tuple[str, ...] = ("default", "odometry")
    slam_seeds: int = 20
    slam_cycles: int = 40
    slam_speed_mps: float = 6.0
    slam_dt_s: float = 0.2
    slam_grid_deg: float | None = None

    def __post_init__(self) -> None:
        for a in self.antennas + self.slam_antennas + self.slam_extra_antennas:
            if a not in ANTENNA_KINDS:
                raise ValueError(f"antennas must be among {ANTENNA_KINDS}, got {a!r}")
        if "phased" not in self.antennas or "phased" not in self.slam_antennas:
            raise ValueError("antennas and slam_antennas must include 'phased' (the reference of every ratio)")
        check_range("range_m", self.range_m, 2.0, 95.0)
        for k in self.group_sizes:
            check_int("group_sizes", k, 2, 4)
        for s in self.separations_deg + self.elements_separations_deg:
            check_range("separations_deg", s, 0.0, 30.0, low_open=True)
        check_int("seeds", self.seeds, 2, 10_000)
        check_int("slam_seeds", self.slam_seeds, 2, 10_000)
        check_int("slam_cycles", self.slam_cycles, 3, 10_000)
        check_range("centre_max_deg", self.centre_max_deg, 0.0, 30.0)
        check_range("ospa_cutoff_deg", self.ospa_cutoff_deg, 0.0, 90.0, low_open=True)
        check_range("angle_gate_max_deg", self.angle_gate_max_deg, 0.0, 90.0, low_open=True)
        check_range("range_gate_m", self.range_gate_m, 0.0, 10.0, low_open=True)
        check_range("slam_speed_mps", self.slam_speed_mps, 0.0, 60.0, low_open=True)
        check_range("slam_dt_s", self.slam_dt_s, 0.0, 10.0, low_open=True)
        for k, s in self.slam_groups + self.slam_extra_groups:
            check_int("slam_groups size", k, 1, 4)
            check_range("slam_groups separation", s, 0.0 if k == 1 else 0.1, 30.0)
        for m in self.elements:
            check_int("elements", m, 6, 4096)


SMALL = StudyConfig(
    antennas=("rhs", "phased"), group_sizes=(2,), separations_deg=(2.0, 12.0), snr_db=(25.0,), seeds=8,
    grid_deg=5.0, crb_phase_draws=32, bootstrap=200,
    elements=(60,), elements_separations_deg=(12.0,), elements_snr_db=(25.0,),
    slam_groups=((2, 6.0),), slam_extra_antennas=(), slam_extra_groups=(), slam_snr_db=(28.0,),
    slam_seeds=2, slam_cycles=6, slam_grid_deg=5.0,
)


# --------------------------------------------------------------------------- antennas and bounds
def radar_config(antenna: str, elements: int | None = None, grid_deg: float | None = None) -> RadarConfig:
    """The package's default radar with the antenna kind, RHS elements and beam grid changed."""
    base = RadarConfig()
    rhs = base.rhs
    if elements is not None:  # feeds in the second half of the line keep their place counted from its end
        m0 = rhs.elements
        feeds = {f: getattr(rhs, f) - (m0 if getattr(rhs, f) >= m0 / 2 else 0) for f in ("tx_feed", "rx_feed")}
        rhs = dataclasses.replace(rhs, elements=int(elements), **feeds)
    scan = base.scan if grid_deg is None else dataclasses.replace(base.scan, grid_deg=float(grid_deg))
    return dataclasses.replace(base, antenna=antenna, rhs=rhs, scan=scan)


def group_crb(antenna: ArrayAntenna, theta_rad: np.ndarray, snr: float, draws: int,
              rng: np.random.Generator) -> np.ndarray:
    """Per-target angle CRB (rad^2) of K targets in one range cell, averaged over their relative phases.

    Model ``iota = sum_k s_k h(theta_k) + n``, ``n ~ CN(0, I)``, ``|s_k|^2 = snr``
    (per-slot SNR at unit two-way gain), unknown angles and complex amplitudes.
    With ``A = [h(theta_k)]``, ``D = [dh/dtheta(theta_k)]`` and
    ``P = I - A (A^H A)^-1 A^H``, the Fisher information of the angles is

        J_kl = 2 Re( s_k^* s_l (D^H P D)_kl ),

    and CRB = diag(J^-1). The phases of s are uniform: the bound on the RMSE
    averaged over random phases is the mean of CRB over phase draws (returned).
    For K = 1 this is :func:`rhs_env.point_cloud.angle_crb`.
    """
    th = np.asarray(theta_rad, float)
    eps = 1e-6
    a = antenna.two_way_gain(th)  # (I, K)
    d = (antenna.two_way_gain(th + eps) - antenna.two_way_gain(th - eps)) / (2 * eps)
    q, _ = np.linalg.qr(a)
    pd = d - q @ (q.conj().T @ d)
    m = d.conj().T @ pd  # (K, K)
    s = math.sqrt(snr) * np.exp(2j * np.pi * rng.random((draws, th.size)))
    j = 2.0 * np.real(s.conj()[:, :, None] * s[:, None, :] * m[None])
    try:
        crb = np.diagonal(np.linalg.inv(j), axis1=1, axis2=2)
    except np.linalg.LinAlgError:
        return np.full(th.size, np.inf)
    crb = np.where(crb > 0, crb, np.inf)
    return crb.mean(axis=0)


def _mainlobe(p: np.ndarray, k: int) -> tuple[int, int]:
    """Indices [lo, hi] of the main lobe around the peak k of a sampled pattern p: out to the first minima."""
    lo = k
    while lo > 0 and p[lo - 1] <= p[lo]:
        lo -= 1
    hi = k
    while hi < p.size - 1 and p[hi + 1] <= p[hi]:
        hi += 1
    return lo, hi


def antenna_properties(antenna: ArrayAntenna, sector_deg: float, points: int = 3601) -> dict[str, float]:
    """Two-way peak gain, -3 dB beamwidth, PSLR, swept echo energy and angle CRB of an antenna.

    Per slot i on a fine grid of theta in [-90, 90] deg: peak gain ``max |h_i|^2``
    (dB, power-normalised two-way gain: the SNR gain over one element); -3 dB
    beamwidth, the width of the contiguous region around the peak above half of it;
    PSLR, the highest point outside the main lobe (out to the first minima) over the
    peak (dB). Swept echo energy ``E(theta) = sum_i |h_i(theta)|^2`` (dB, the energy a
    target at theta returns over one sweep, up to the chirps and the link budget),
    averaged over the sector. CRB: ``sqrt(angle_crb)`` at 0 dB unit-gain SNR (deg),
    median over the sector (divide by ``sqrt(SNR)`` for another SNR).
    Medians over slots; ``pslr_worst_db`` the worst slot.
    """
    th = np.deg2rad(np.linspace(-90.0, 90.0, points))
    p = np.abs(antenna.two_way_gain(th)) ** 2  # (I, T)
    step = 180.0 / (points - 1)
    peaks, bw, pslr = [], [], []
    for row in p:  # I <= 90 slots, once per antenna
        k = int(np.argmax(row))
        peaks.append(row[k])
        above = row >= row[k] / 2
        lo, hi = k, k
        while lo > 0 and above[lo - 1]:
            lo -= 1
        while hi < row.size - 1 and above[hi + 1]:
            hi += 1
        bw.append((hi - lo + 1) * step)
        mlo, mhi = _mainlobe(row, k)
        side = np.concatenate([row[:mlo], row[mhi + 1:]])
        pslr.append(10 * np.log10(side.max() / row[k]) if side.size else -np.inf)
    half = np.deg2rad(sector_deg / 2)
    sec = np.abs(th) <= half
    energy = p[:, sec].sum(axis=0)
    crb = np.sqrt(angle_crb(antenna, th[sec], 1.0))
    return {
        "elements": int(antenna.elements),
        "peak_gain_db": float(10 * np.log10(np.median(peaks))),
        "beamwidth_3db_deg": float(np.median(bw)),
        "pslr_median_db": float(np.median(pslr)),
        "pslr_worst_db": float(np.max(pslr)),
        "swept_energy_db": float(10 * np.log10(np.mean(energy))),
        "crb_deg_at_0db": float(np.rad2deg(np.median(crb))),
    }


# --------------------------------------------------------------------------- point-cloud level
@dataclass
class Group:
    """K targets of one radar in one range cell: radar index, range (m), angles from boresight (rad), xy (K, 2)."""

    radar: int
    range_m: float
    theta: np.ndarray
    xy: np.ndarray


def make_groups(radar: RadarSystem, k: int, sep_deg: float, range_m: float, centre_max_deg: float,
                rng: np.random.Generator) -> list[Group]:
    """One group per radar: K targets ``sep_deg`` apart around a random centre, all at one range."""
    out = []
    for r in range(4):
        c = rng.uniform(-centre_max_deg, centre_max_deg)
        th = np.deg2rad(c + (np.arange(k) - (k - 1) / 2) * sep_deg)
        rr = range_m + rng.uniform(-0.25, 0.25)
        ang = radar.boresights[r] + th
        xy = radar.positions[r] + rr * np.column_stack([np.cos(ang), np.sin(ang)])
        out.append(Group(r, float(rr), th, xy))
    return out


def ospa(truth: np.ndarray, est: np.ndarray, cutoff: float) -> float:
    """OSPA distance of order 2 with cut-off c between two angle sets (same unit as c).

    ``sqrt( (sum over the optimal assignment of min(d, c)^2 + c^2 |m - n|) / max(m, n) )``.
    """
    m, n = truth.size, est.size
    if max(m, n) == 0:
        return 0.0
    if min(m, n) == 0:
        return float(cutoff)
    d = np.minimum(np.abs(truth[:, None] - est[None, :]), cutoff) ** 2
    i, j = linear_sum_assignment(d)
    return float(math.sqrt((d[i, j].sum() + cutoff ** 2 * abs(m - n)) / max(m, n)))


def evaluate_group(cloud: Any, g: Group, sep_deg: float, cfg: StudyConfig) -> dict[str, Any]:
    """Metrics of one trial (one group in its radar's points): see the module docstring."""
    sel = np.asarray(cloud.radar) == g.radar
    pts_xy = np.asarray(cloud.xy)[sel]
    m = pointcloud_metrics(pts_xy, g.xy, gate_m=1.0)
    win = np.abs(np.asarray(cloud.range_m)[sel] - g.range_m) <= cfg.range_gate_m
    est = np.rad2deg(np.asarray(cloud.angle_rad)[sel][win])
    truth = np.rad2deg(g.theta)
    gate = min(sep_deg / 2, cfg.angle_gate_max_deg)
    sq: list[float] = []
    if est.size:
        d = np.abs(truth[:, None] - est[None, :])
        i, j = linear_sum_assignment(d)
        ok = d[i, j] <= gate
        sq = [float(x) for x in (truth[i[ok]] - est[j[ok]]) ** 2]
    return {
        "resolved": int(len(sq) == truth.size),
        "ospa_deg": ospa(truth, est, cfg.ospa_cutoff_deg),
        "sq_err_deg2": sq,
        "detection_rate": float(m["detection_rate"]),
        "false_points": int(m["false_points"]),
        "points_in_cell": int(est.size),
        "theta_deg": [float(x) for x in truth],
    }


def cell_seed(key: str) -> int:
    return int(hashlib.sha1(key.encode()).hexdigest()[:8], 16)


def run_pointcloud_cell(radar: RadarSystem, k: int, sep_deg: float, snr_db: float, cfg: StudyConfig,
                        key: str) -> dict[str, Any]:
    """``cfg.seeds`` trials of one cell (four per scan); raw trials, CRBs and the wall time."""
    t0 = time.perf_counter()
    seed = cell_seed(key)
    radar.rng = np.random.default_rng(seed)
    scene_rng = np.random.default_rng(seed + 1)
    crb_rng = np.random.default_rng(seed + 2)
    snr = 10 ** (snr_db / 10)
    rcs = snr / float(radar.config.unit_gain_snr(cfg.range_m, 1.0))
    trials: list[dict[str, Any]] = []
    crb_group: list[float] = []
    crb_single: list[float] = []
    while len(trials) < cfg.seeds:
        groups = make_groups(radar, k, sep_deg, cfg.range_m, cfg.centre_max_deg, scene_rng)
        xy = np.concatenate([g.xy for g in groups])
        n = len(xy)
        sc = Scatterers(xy, np.zeros((n, 2)), np.full(n, rcs), np.arange(n), np.ones(n, bool))
        cloud = radar.scan(sc)
        for g in groups[: cfg.seeds - len(trials)]:
            trials.append(evaluate_group(cloud, g, sep_deg, cfg))
            ant = radar.antennas[g.radar]
            snr_g = float(radar.config.unit_gain_snr(g.range_m, rcs))
            crb_group.extend(group_crb(ant, g.theta, snr_g, cfg.crb_phase_draws, crb_rng))
            crb_single.extend(np.atleast_1d(angle_crb(ant, g.theta, snr_g)))
    return {
        "trials": trials,
        "crb_group_deg": float(np.rad2deg(math.sqrt(np.mean(crb_group)))),
        "crb_single_deg": float(np.rad2deg(math.sqrt(np.mean(crb_single)))),
        "rcs_m2": rcs,
        "wall_s": time.perf_counter() - t0,
    }


def summarize_pointcloud(res: dict[str, Any]) -> dict[str, Any]:
    """Cell summary with 95 % intervals from the raw trials."""
    tr = res["trials"]
    n = len(tr)
    resolved = sum(t["resolved"] for t in tr)
    p, (plo, phi) = (resolved / n if n else float("nan")), wilson_interval(resolved, n)
    sq = np.array([e for t in tr for e in t["sq_err_deg2"]])
    mse, mlo, mhi = mean_interval(sq).mean_low_high()
    o, olo, ohi = mean_interval([t["ospa_deg"] for t in tr]).mean_low_high()
    d, dlo, dhi = np.clip(mean_interval([t["detection_rate"] for t in tr]).mean_low_high(), 0.0, 1.0).tolist()
    f, flo, fhi = mean_interval([t["false_points"] for t in tr]).mean_low_high()
    olo, flo = max(olo, 0.0), max(flo, 0.0)
    rmse = math.sqrt(mse) if np.isfinite(mse) else float("nan")
    return {
        "n": n,
        "resolution_prob": [p, plo, phi],
        "ospa_deg": [o, olo, ohi],
        "angle_rmse_deg": [rmse, math.sqrt(max(mlo, 0.0)) if np.isfinite(mlo) else float("nan"),
                           math.sqrt(mhi) if np.isfinite(mhi) else float("nan")],
        "n_matched": int(sq.size),
        "crb_group_deg": res["crb_group_deg"],
        "crb_single_deg": res["crb_single_deg"],
        "rmse_over_crb": rmse / res["crb_group_deg"] if res["crb_group_deg"] > 0 else float("nan"),
        "detection_rate": [d, dlo, dhi],
        "false_points": [f, flo, fhi],
        "points_in_cell": float(np.mean([t["points_in_cell"] for t in tr])),
        "rcs_m2": res["rcs_m2"],
        "wall_s": res["wall_s"],
    }


# --------------------------------------------------------------------------- SLAM level
def slam_scene(k: int, sep_deg: float, cfg: StudyConfig) -> tuple[np.ndarray, np.ndarray]:
    """Landmarks (5 K, 2) and poses (T, 3) of the paper's drive with each obstacle made a group of K.

    The ego starts at the origin heading +x at ``slam_speed_mps``; the obstacles sit at the
    paper's offsets from its start pose. Group members are spaced ``2 D tan(sep / 2)``
    across the line of sight from the middle of the drive (D: the obstacle's distance
    from there), so they share a range cell and are ``sep`` apart seen from there.
    """
    from rhs_env.envs import PAPER_OBSTACLES, PAPER_START

    t = np.arange(cfg.slam_cycles)
    poses = np.column_stack([t * cfg.slam_speed_mps * cfg.slam_dt_s, np.zeros(t.size), np.zeros(t.size)])
    centres = np.asarray(PAPER_OBSTACLES, float) - np.asarray(PAPER_START, float)
    mid = np.array([poses[-1, 0] / 2, 0.0])
    v = centres - mid
    dist = np.hypot(v[:, 0], v[:, 1])
    across = np.column_stack([-v[:, 1], v[:, 0]]) / dist[:, None]
    spacing = 2 * dist * math.tan(math.radians(sep_deg) / 2)
    offs = np.arange(k) - (k - 1) / 2
    lm = centres[:, None, :] + offs[None, :, None] * (spacing[:, None, None] * across[:, None, :])
    return lm.reshape(-1, 2), poses


def run_slam_unit(radar: RadarSystem, k: int, sep_deg: float, snr_db: float, seed: int, cfg: StudyConfig,
                  key: str) -> dict[str, Any]:
    """One seed of one SLAM cell: the clouds of the drive once, then SLAM per registration on them."""
    from slam.core.registration import DEFAULT_REGISTRATION, make_registration
    from slam.core.scenario import run_scenario
    from slam.gym.radar_cloud import RadarCloud

    t0 = time.perf_counter()
    s = cell_seed(key)
    radar.rng = np.random.default_rng(s)
    landmarks, poses = slam_scene(k, sep_deg, cfg)
    rcs = 10 ** (snr_db / 10) / float(radar.config.unit_gain_snr(cfg.range_m, 1.0))
    rc = RadarCloud(landmarks, poses, cfg.slam_dt_s, radar, rcs_m2=rcs)
    clouds = [rc(t, poses[t]) for t in range(len(poses))]
    t1 = time.perf_counter()
    out: dict[str, Any] = {"points_per_cycle": float(np.mean([len(c) for c in clouds])), "rcs_m2": rcs,
                           "radar_s": t1 - t0}
    for reg in cfg.slam_registrations:
        kind = DEFAULT_REGISTRATION if reg == "default" else reg
        registration = make_registration(kind, rng=np.random.default_rng(s + 1))
        res = run_scenario(landmarks, poses, lambda t, _p: clouds[t], registration, None,
                           np.random.default_rng(s + 2), dt=cfg.slam_dt_s, sensor_xy=radar.config.mounting.mounts()[0])
        out[reg] = {
            "registration": kind,
            "ate_m": float(res["ate_rmse_m"]),
            "heading_rmse_deg": float(np.rad2deg(res["heading_rmse_rad"])),
            "map_rmse_m": float("nan") if res["map_rmse_m"] is None else float(res["map_rmse_m"]),
            "map_matched": int(res["map_matched"]),
            "map_missed": int(res["map_missed"]),
            "map_spurious": int(res["map_spurious"]),
            "finite": bool(res["finite"]),
        }
    out["wall_s"] = time.perf_counter() - t0
    return out


def summarize_slam(units: list[dict[str, Any]], regs: tuple[str, ...]) -> dict[str, Any]:
    """Per registration: ATE, map RMSE, spurious and missed landmarks, mean and 95 % t-interval over seeds."""
    out: dict[str, Any] = {"n": len(units), "points_per_cycle": mean_interval([u["points_per_cycle"] for u in units]).mean_low_high(),
                           "wall_s": float(np.mean([u["wall_s"] for u in units]))}
    for reg in regs:
        rows = [u[reg] for u in units]
        out[reg] = {m: list(mean_interval([r[m] for r in rows]).mean_low_high())
                    for m in ("ate_m", "map_rmse_m", "map_spurious", "map_missed", "heading_rmse_deg")}
        out[reg]["registration"] = rows[0]["registration"] if rows else None
        out[reg]["map_failed"] = int(sum(not np.isfinite(r["map_rmse_m"]) for r in rows))
    return out


# --------------------------------------------------------------------------- units, cache, provenance
def _fingerprint(obj: Any) -> str:
    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


def slam_fingerprint() -> str:
    """The package's SLAM defaults (filter config, default registration) that a SLAM unit depends on."""
    from slam.core.rbpf import SlamConfig
    from slam.core.registration import DEFAULT_REGISTRATION

    return _fingerprint({"slam": asdict(SlamConfig()), "registration": DEFAULT_REGISTRATION})


def plan_units(cfg: StudyConfig, levels: tuple[str, ...]) -> list[dict[str, Any]]:
    """Every unit of work (a point-cloud cell, or one seed of a SLAM cell) with its cache key."""
    units: list[dict[str, Any]] = []
    pc_common = {f: getattr(cfg, f) for f in ("range_m", "seeds", "centre_max_deg", "range_gate_m",
                                               "angle_gate_max_deg", "ospa_cutoff_deg", "crb_phase_draws")}

    def add(level: str, system: tuple[str, int | None, float | None], **cell: Any) -> None:
        rc = radar_config(*system).flat_dict()  # the flat field names: keys (and seeds) as before the grouping
        extra = {"slam": slam_fingerprint(), "cycles": cfg.slam_cycles, "speed": cfg.slam_speed_mps,
                 "dt": cfg.slam_dt_s, "regs": cfg.slam_registrations, "range_m": cfg.range_m} \
            if level == "slam" else pc_common
        key = json.dumps({"level": level, **cell, "radar": _fingerprint(rc), **extra}, sort_keys=True, default=str)
        units.append({"level": level, "system": system, "key": key, **cell})

    # antennas innermost (and SLAM seeds outermost): a partial run already holds complete comparisons
    if "pointcloud" in levels:
        for k in cfg.group_sizes:
            for snr in sorted(cfg.snr_db, reverse=True):
                for s in cfg.separations_deg:
                    for a in cfg.antennas:
                        add("pointcloud", (a, None, cfg.grid_deg), antenna=a, k=k, sep_deg=s, snr_db=snr)
    if "elements" in levels:
        for m in cfg.elements:
            for s in cfg.elements_separations_deg:
                for snr in cfg.elements_snr_db:
                    for a in cfg.antennas:
                        add("elements", (a, m, cfg.elements_grid_deg), antenna=a, elements=m, k=cfg.group_sizes[0],
                            sep_deg=s, snr_db=snr)
    if "slam" in levels:
        cells = [(g, a) for g in cfg.slam_groups for a in cfg.slam_antennas]
        cells += [(g, a) for g in cfg.slam_extra_groups for a in cfg.slam_extra_antennas]
        for seed in range(cfg.slam_seeds):
            for snr in cfg.slam_snr_db:
                for (k, s), a in cells:
                    add("slam", (a, None, cfg.slam_grid_deg), antenna=a, k=k, sep_deg=s, snr_db=snr, seed=seed)
    return units


def load_cache(path: Path) -> dict[str, Any]:
    """Cached results by key (a JSON line per unit; a truncated last line from a killed run is skipped)."""
    out: dict[str, Any] = {}
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            out[rec["key"]] = rec["result"]
    return out


def run_config(cfg: StudyConfig, cache_dir: Path, report_only: bool) -> dict[str, Any]:
    """The full configuration recorded in the provenance: study, default radar, default SLAM, cache."""
    from slam.core.rbpf import SlamConfig
    from slam.core.registration import DEFAULT_REGISTRATION

    return {"study": asdict(cfg), "radar": RadarConfig().to_dict(), "slam": asdict(SlamConfig()),
            "registration": DEFAULT_REGISTRATION, "report_only": report_only, "cache_dir": cache_dir}  # fmt: skip


class Systems:
    """Radar systems by (antenna, elements, grid), built on first use; a timed scan of an empty scene each."""

    def __init__(self) -> None:
        self._sys: dict[tuple[Any, ...], RadarSystem] = {}
        self.scan_s: dict[tuple[Any, ...], float] = {}

    def get(self, system: tuple[str, int | None, float | None]) -> RadarSystem:
        if system not in self._sys:
            cfg = radar_config(*system)
            same = [s for s, r in self._sys.items() if r.config == cfg]  # e.g. M=60 given or defaulted
            if same:
                self._sys[system], self.scan_s[system] = self._sys[same[0]], self.scan_s[same[0]]
                return self._sys[system]
            radar = RadarSystem(cfg, np.random.default_rng(12345))
            t0 = time.perf_counter()
            radar.scan(Scatterers.empty())
            self.scan_s[system] = time.perf_counter() - t0
            self._sys[system] = radar
        return self._sys[system]


SLAM_STEP_GUESS_S = 0.03  # a priori seconds per SLAM cycle per registration (the ETA only)


def unit_cost(u: dict[str, Any], cfg: StudyConfig, systems: Systems) -> float:
    """A priori seconds of a unit: its scans at the timed scan speed (+ a guess for the SLAM steps)."""
    t = systems.scan_s[u["system"]]
    if u["level"] == "slam":
        return cfg.slam_cycles * (t + len(cfg.slam_registrations) * SLAM_STEP_GUESS_S)
    return math.ceil(cfg.seeds / 4) * (1.3 * t) + 0.002 * cfg.seeds


# --------------------------------------------------------------------------- aggregation
def _ratio_rows(cells: list[dict[str, Any]], raw: dict[tuple[Any, ...], dict[str, Any]], cfg: StudyConfig,
                group_keys: tuple[str, ...]) -> list[dict[str, Any]]:
    """Ratios antenna / phased of the group error (OSPA) and of the angle RMSE, with bootstrap intervals."""
    rng = np.random.default_rng(0)
    rows = []
    for c in cells:
        if c["antenna"] == "phased":
            continue
        gk = tuple(c[k] for k in group_keys)
        ref = raw.get(("phased",) + gk)
        own = raw.get((c["antenna"],) + gk)
        if ref is None or own is None:
            continue
        o = ratio_bootstrap([t["ospa_deg"] for t in own["trials"]], [t["ospa_deg"] for t in ref["trials"]], rng, cfg.bootstrap)
        sq_a = [e for t in own["trials"] for e in t["sq_err_deg2"]]
        sq_b = [e for t in ref["trials"] for e in t["sq_err_deg2"]]
        r2 = ratio_bootstrap(sq_a, sq_b, rng, cfg.bootstrap)  # MSE ratio -> RMSE ratio by sqrt
        rows.append({**{k: c[k] for k in ("antenna",) + group_keys},
                     "ospa_ratio": list(o),
                     "angle_rmse_ratio": [math.sqrt(x) if np.isfinite(x) and x >= 0 else float("nan") for x in r2],
                     "crb_ratio": own["crb_group_deg"] / ref["crb_group_deg"] if ref["crb_group_deg"] > 0 else None,
                     "crb_single_ratio": own["crb_single_deg"] / ref["crb_single_deg"]})
    return rows


def aggregate_pc(units: list[dict[str, Any]], cache: dict[str, Any], cfg: StudyConfig, level: str) -> dict | None:
    keys = ("k", "sep_deg", "snr_db") if level == "pointcloud" else ("elements", "k", "sep_deg", "snr_db")
    raw, cells = {}, []
    for u in units:
        if u["level"] != level or u["key"] not in cache:
            continue
        res = cache[u["key"]]
        raw[(u["antenna"],) + tuple(u[k] for k in keys)] = res
        cells.append({"antenna": u["antenna"], **{k: u[k] for k in keys}, **summarize_pointcloud(res)})
    if not cells:
        return None
    return {"cells": cells, "ratios": _ratio_rows(cells, raw, cfg, keys),
            "wall_s_per_cell": float(np.mean([c["wall_s"] for c in cells])),
            "cpu_s_per_cell": _mean_of(list(raw.values()), "cpu_s"), "n_cells": len(cells)}


def aggregate_slam(units: list[dict[str, Any]], cache: dict[str, Any], cfg: StudyConfig) -> dict | None:
    by_cell: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for u in units:
        if u["level"] == "slam" and u["key"] in cache:
            by_cell.setdefault((u["antenna"], u["k"], u["sep_deg"], u["snr_db"]), []).append(cache[u["key"]])
    if not by_cell:
        return None
    rng = np.random.default_rng(0)
    cells = [{"antenna": a, "k": k, "sep_deg": s, "snr_db": snr, **summarize_slam(v, cfg.slam_registrations)}
             for (a, k, s, snr), v in by_cell.items()]
    ratios = []
    for (a, k, s, snr), v in by_cell.items():
        ref = by_cell.get(("phased", k, s, snr))
        if a == "phased" or ref is None:
            continue
        row: dict[str, Any] = {"antenna": a, "k": k, "sep_deg": s, "snr_db": snr}
        for reg in cfg.slam_registrations:
            for m in ("ate_m", "map_rmse_m"):
                row[f"{m}_ratio_{reg}"] = list(ratio_bootstrap([x[reg][m] for x in v], [x[reg][m] for x in ref], rng,
                                                        cfg.bootstrap))
        ratios.append(row)
    units_done = [x for v in by_cell.values() for x in v]
    return {"cells": cells, "ratios": ratios, "wall_s_per_seed": float(np.mean([x["wall_s"] for x in units_done])),
            "radar_s_per_seed": float(np.mean([x["radar_s"] for x in units_done])),
            "cpu_s_per_seed": _mean_of(units_done, "cpu_s"), "n_units": len(units_done)}


def antenna_table(cfg: StudyConfig, systems: Systems, levels: tuple[str, ...]) -> dict[str, Any]:
    """Antenna properties on the study's grids (default M; and per M of the element sweep)."""
    out: dict[str, Any] = {"default": {}}
    for a in cfg.antennas:
        r = systems.get((a, None, cfg.grid_deg))
        out["default"][a] = antenna_properties(r.antennas[0], r.config.scan.sector_deg)
    if "elements" in levels:
        for m in cfg.elements:
            for a in ("rhs", "phased"):
                if a in cfg.antennas:
                    r = systems.get((a, m, cfg.elements_grid_deg))
                    out.setdefault(f"M{m}", {})[a] = antenna_properties(r.antennas[0], r.config.scan.sector_deg)
    return out


# --------------------------------------------------------------------------- driver
def run_unit(u: dict[str, Any], cfg: StudyConfig, systems: Systems) -> dict[str, Any]:
    """One unit; ``cpu_s`` (process CPU seconds) beside the wall time: on a shared machine only it plans."""
    radar = systems.get(u["system"])
    c0 = time.process_time()
    if u["level"] == "slam":
        res = run_slam_unit(radar, u["k"], u["sep_deg"], u["snr_db"], u["seed"], cfg, u["key"])
    else:
        res = run_pointcloud_cell(radar, u["k"], u["sep_deg"], u["snr_db"], cfg, u["key"])
    res["cpu_s"] = time.process_time() - c0
    return res


def _mean_of(rows: list[dict[str, Any]], key: str) -> float | None:
    v = [r[key] for r in rows if key in r]
    return float(np.mean(v)) if v else None


def compute(pending: list[dict[str, Any]], cfg: StudyConfig, systems: Systems, cache_dir: Path, stem: str,
            progress: bool, shard: str = "") -> None:
    """Run the pending units in order, appending each result to its level's cache file as it finishes."""
    from tqdm import tqdm

    for s in dict.fromkeys(u["system"] for u in pending):
        systems.get(s)  # builds (and times) every radar first: pattern libraries of a new M are built here
    costs = [unit_cost(u, cfg, systems) for u in pending]
    print(f"{len(pending)} units to run; estimated {sum(costs) / 60:.1f} min (from one timed scan per radar; "
          f"SLAM steps guessed at {SLAM_STEP_GUESS_S * 1e3:.0f} ms)", flush=True)
    bar = tqdm(total=round(sum(costs)), unit="s(est)", disable=not progress, smoothing=0.05,
               bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} est-s [{elapsed}<{remaining}]")
    cache_dir.mkdir(parents=True, exist_ok=True)
    for u, c in zip(pending, costs):
        bar.set_description(f"{u['level']} {u['antenna']} K={u['k']} {u['sep_deg']:g}deg {u['snr_db']:g}dB")
        res = run_unit(u, cfg, systems)
        with cache_file(cache_dir, stem, u["level"], shard).open("a") as fh:  # one writer per file
            fh.write(json.dumps({"key": u["key"], "result": res}) + "\n")
        bar.update(round(c))
    bar.close()


def cache_file(cache_dir: Path, stem: str, level: str, shard: str = "") -> Path:
    """The cache of one level (and shard): levels and shards run in parallel processes, one writer per file."""
    return cache_dir / f"{stem}_cache_{level}{shard}.jsonl"


def cache_files(cache_dir: Path, stem: str, level: str) -> list[Path]:
    return sorted(cache_dir.glob(f"{stem}_cache_{level}*.jsonl"))


def load_caches(cache_dir: Path, stem: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for lv in LEVELS:
        for f in cache_files(cache_dir, stem, lv):
            out.update(load_cache(f))
    return out


def build_results(cfg: StudyConfig, units: list[dict[str, Any]], cache: dict[str, Any], systems: Systems,
                  wall_s: float) -> dict[str, Any]:
    present = tuple(lv for lv in LEVELS if any(u["level"] == lv and u["key"] in cache for u in units))
    data: dict[str, Any] = {"levels": list(present), "antenna_properties": antenna_table(cfg, systems, present)}
    for lv in ("pointcloud", "elements"):
        if lv in present:
            data[lv] = aggregate_pc(units, cache, cfg, lv)
    if "slam" in present:
        data["slam"] = aggregate_slam(units, cache, cfg)
    data["timing"] = {"this_run_wall_s": wall_s, "load_average": list(os.getloadavg()),
                      "cpu_count": os.cpu_count(),
                      "note": "seconds on a shared machine (see load_average): rerun on a quiet one for planning"}
    return data


def finite_json(obj: Any) -> Any:
    """NaN / inf -> None and numpy scalars -> Python numbers, recursively (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): finite_json(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [finite_json(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def fingerprint() -> list[float]:
    """Small config: one point-cloud cell per antenna kind (pairs 6 deg apart at 10 dB): the raw trial metrics."""
    systems = Systems()
    out: list[float] = []
    for antenna in SMALL.antennas:
        cell = run_pointcloud_cell(systems.get((antenna, None, None)), 2, 6.0, 10.0, SMALL, f"fingerprint/{antenna}")
        for t in cell["trials"]:
            out += [float(t["resolved"]), t["ospa_deg"], t["detection_rate"], t["false_points"], *t["sq_err_deg2"]]
        out.append(cell["crb_group_deg"])
    return out


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", choices=LEVELS, help="run one level (the outputs include every cached level)")
    p.add_argument("--small", action="store_true", help="the small test configuration (seconds)")
    p.add_argument("--seeds", type=int, help="trials per point-cloud cell (default 24)")
    p.add_argument("--slam-seeds", type=int, help="seeds per SLAM cell (default 20)")
    p.add_argument("--out-dir", default=str(ROOT / "results"))
    p.add_argument("--cache-dir", help="cache folder (default OUT_DIR; files claim_study[_small]_cache_LEVEL.jsonl)")
    p.add_argument("--fresh", action="store_true", help="ignore (and replace) the cache")
    p.add_argument("--report-only", action="store_true", help="write the outputs from the cache, compute nothing")
    p.add_argument("--shard", default="0/1", help="I/N: run every N-th unit of the plan from the I-th (parallel processes)")
    p.add_argument("--no-progress", action="store_true")
    a = p.parse_args(argv)
    try:
        si, sn = (int(x) for x in a.shard.split("/"))
    except ValueError:
        p.error(f"--shard must be I/N, got {a.shard!r}")
    if not 0 <= si < sn:
        p.error(f"--shard I/N needs 0 <= I < N, got {a.shard!r}")
    cfg = SMALL if a.small else StudyConfig()
    if a.seeds is not None or a.slam_seeds is not None:
        cfg = dataclasses.replace(cfg, seeds=a.seeds or cfg.seeds, slam_seeds=a.slam_seeds or cfg.slam_seeds)
    out = Path(a.out_dir)
    stem = "claim_study_small" if a.small else "claim_study"
    cache_dir = Path(a.cache_dir) if a.cache_dir else out
    levels = (a.only,) if a.only else LEVELS
    if a.fresh:
        for lv in levels:
            for f in cache_files(cache_dir, stem, lv):
                f.unlink()
    units = plan_units(cfg, LEVELS)
    cache = load_caches(cache_dir, stem)
    selected = [u for u in units if u["level"] in levels][si::sn]  # a shard is fixed by the plan, not the cache
    pending = [u for u in selected if u["key"] not in cache]
    print(f"{len(units)} units in the study, {len(selected) - len(pending)} of the requested ones cached, "
          f"{len(pending)} to run", flush=True)
    systems = Systems()
    started, t0 = time.time(), time.perf_counter()
    if pending and not a.report_only:
        compute(pending, cfg, systems, cache_dir, stem, not a.no_progress, "" if sn == 1 else f"_shard{si}of{sn}")
    cache = load_caches(cache_dir, stem)
    data = finite_json(build_results(cfg, units, cache, systems, time.perf_counter() - t0))
    data["provenance"] = write_json(out / f"{stem}.json", data, __file__, run_config(cfg, cache_dir, a.report_only),
                                    started, fingerprint_fn=None if a.small else fingerprint, argv=argv)  # fmt: skip
    from rhs_studies.slam.claim_study_report import make_figures, write_markdown

    write_markdown(data, out / f"{stem}.md")
    make_figures(data, out, stem)
    print(f"wrote {out / stem}.json, .md and figures in {time.perf_counter() - t0:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
