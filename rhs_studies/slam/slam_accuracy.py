"""SLAM accuracy against its targets: highway, paper scene at 30 dBm, dense landmark pairs.

Writes ``results/slam_accuracy.json`` (per-seed figures, means with 95 % confidence
intervals, commit, command line, full SLAM config) and ``results/slam_accuracy.md``.

* **highway**: ``rhs-highway-slam-v0`` default (1-degree grid, traffic), ``--cycles``
  cycles (default 200, the target's run length), the ego driven by the constant
  meta-action SLOWER (``--highway-action``, default 4): the lowest target speed
  (20 m/s) and no lane change. It is the package's collision-free scripted driver
  (always-SLOWER: 0/30 collisions in ``results/policies.md``; all 200 cycles on the
  tuning seeds 0..4 and the evaluation seeds 100..104), needs no policy and no
  import from ``agents``. IDLE (the previous driver) crashes into traffic on every
  one of those ten seeds (after 19-162 cycles), so the run was not the 200 cycles
  the target asks; the IDM + MOBIL driver (``agents.evaluate.IDMMobilPolicy``) also
  drives collision-free but swaps the ego vehicle under the env.
  Metrics: position RMSE and final position error of the vehicle, the fraction of
  the landmarks seen so far that the map matched (``matched / (matched + missed)``,
  *seen* = within the radar's 100 m range at some cycle, as
  :class:`slam.gym.metrics_info.SlamMetricsInfo` counts them: field of view, traffic
  occlusion and detection ignored) and the fraction of map landmarks that match
  nothing (``spurious / (matched + spurious)``), Hungarian matching within 2 m.
  Also ``measured_matched_fraction``: the matched fraction among the landmarks the
  radar measured, a point within 1 m in >= 2 scans (:mod:`slam.core.metrics`);
  ``visible_matched_fraction``: among those in the radar's unoccluded view for at
  least 2 cycles; and per run the unmatched seen landmarks by the number of scans
  with a point within 1 m of them (``unmatched_by_scans``).
* **paper**: ``rhs-paper-v0`` (the Fig. 5c scene, 50 cycles) at 30 dBm: vehicle RMSE.
* **dense**: a scripted short straight drive (6 m/s, 40 cycles, 47 m) past pairs
  of landmarks 2-5 deg apart in one range cell (:func:`dense_scene`: pairs on both
  sides every ``--dense-spacing`` m, 20-35 m from the path, each pair's members
  across the line of sight from the middle of the drive, the geometry of the claim
  study's SLAM scene with more pairs), the RHS and the phased array on the same
  scene and seed: ATE (vehicle RMSE) of each and the ratio, map RMSE, spurious and
  missed landmarks; ``geometry`` (:func:`pair_geometry`) says how much of the drive
  the pairs spend in that regime (about half the (cycle, pair)s). The earlier scene
  (10 m/s past pairs 0.3-1.2 m apart along x, 8-14 m from a 118 m path) had them
  there for 10 % only: most of the drive saw each pair from far ahead or behind,
  < 2 deg apart or resolved in range by both antennas, and members closer than the
  SLAM's 1 m ``cluster_radius_m`` are one object whatever the antenna resolves.

Seeds: ``--seeds`` (default 100..104) are evaluation seeds, disjoint from the seeds
0..4 used while tuning the filter. ``--slam JSON`` overrides SlamConfig fields (for
the before/after comparison, e.g. ``'{"variant": "fastslam1", "association":
"nearest", "measurement_noise": "fixed"}'``). ``--quick`` is the small config of the
tests (few cycles, one seed, few particles).

Drivers part: ``--workers N`` spreads its (env, driver, seed) episodes over N processes, the same runs as one
process (each episode starts from its seed), with a progress line per episode (done / total, time left).

Example: ``python scripts/slam_accuracy.py --parts highway paper dense``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from agents.policies.decision import IDLE, SLOWER
from rhs_common.stats import mean_half_record as ci95
from rhs_studies.kit.provenance import numbers, write_json
from rhs_studies.kit.slam_metrics import (
    CFEAR_DRIFT_PCT,
    DRIFT_LENGTHS_M,
    DRO_DRIFT_PCT,
    NEES_FLOOR,  # noqa: F401  (re-exported: the tests read it here)
    nees_interval,
    pooled_drift,
    pose_nees,
    segment_drift,
)

POLICY_HZ = 5
TARGETS = {
    "highway": {"position_rmse_m": ("<=", 0.5), "final_error_m": ("<=", 1.0),
                "matched_fraction": (">=", 0.9), "spurious_fraction": ("<=", 0.1)},
    "paper": {"position_rmse_m": ("<=", 0.05)},
    "dense": {"rhs_ate_m": ("<=", 0.12), "ratio_rhs_phased": ("<=", 1.0 / 3.0)},
}

EXTRA = {"highway": ("measured_matched_fraction", "visible_matched_fraction", "cycles", "final_error_before_crash_m",
                     "map_rmse_m"), "paper": ("final_error_m",),
         "dense": ("phased_ate_m", "rhs_map_rmse_m", "phased_map_rmse_m", "rhs_spurious", "phased_spurious",
                   "rhs_missed", "phased_missed")}


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _visible_landmarks(env) -> np.ndarray:
    """Ids of the roadside landmarks the radar can see now (field of view, range, not occluded)."""
    from rhs_env.scene import scene_scatterers
    from rhs_env.wrappers import RadarObservation

    w = env
    while not isinstance(w, RadarObservation):
        w = w.env
    if w.radar is None:
        raise RuntimeError("the radar is built on reset: reset the env before asking what it sees")
    base = env.unwrapped
    sc, occ = scene_scatterers(base, base.vehicle, w.scatter_config)
    view = w.radar.in_view(sc, occ) & sc.is_static & (sc.object_id < 1_000_000)
    return np.unique(sc.object_id[view])


def _visible_matched_fraction(env, info: dict, visible: dict) -> float | None:
    """Matched fraction among the seen landmarks that were in the radar's unoccluded view >= 2 cycles."""
    from slam.core.metrics import matched_fraction

    ids = np.array(sorted(env.get_wrapper_attr("seen_ids")), dtype=int)
    keep = np.array([visible.get(int(i), 0) >= 2 for i in ids], dtype=bool)
    return matched_fraction(np.asarray(info["estimated_landmarks"]).reshape(-1, 2),
                            np.asarray(info["true_landmarks"]).reshape(-1, 2), keep, 2.0)


def _count_hits(env, obs: dict, hits: dict) -> None:
    """Add one to ``hits[id]`` for each landmark with a radar point of this scan within 1 m of it."""
    from rhs_common.geometry import apply_motion
    from rhs_env.scene import get_landmarks, world_pose
    from slam.core.metrics import MEASURED_GATE_M, landmark_hits

    base = env.unwrapped
    pose_w = world_pose(base.vehicle)
    pts = np.asarray(obs["points"], dtype=float)[np.asarray(obs["points_mask"]) > 0][:, :2]
    if not len(pts):
        return
    lms = get_landmarks(base)
    ids = lms.near(np.array([pose_w[0], -pose_w[1]]), 110.0)
    hit = landmark_hits(apply_motion(pts, pose_w), lms.xy_world[ids], MEASURED_GATE_M)
    for i in ids[hit]:
        hits[int(i)] = hits.get(int(i), 0) + 1


def _seen_breakdown(env, info: dict, visible: dict, hits: dict) -> dict[str, Any]:
    """The measured matched fraction and the unmatched seen landmarks by radar scans that hit them."""
    from slam.core.metrics import MEASURED_MIN_SCANS, map_metrics, matched_fraction

    ids = np.array(sorted(env.get_wrapper_attr("seen_ids")), dtype=int)
    est = np.asarray(info["estimated_landmarks"]).reshape(-1, 2)
    true = np.asarray(info["true_landmarks"]).reshape(-1, 2)
    scans = np.array([hits.get(int(i), 0) for i in ids], dtype=int)
    in_view = np.array([visible.get(int(i), 0) for i in ids], dtype=int)
    matched = np.zeros(len(ids), dtype=bool)
    matched[map_metrics(est, true, 2.0)["pairs"][:, 1]] = True
    un = ~matched
    return {
        "measured_matched_fraction": matched_fraction(est, true, scans >= MEASURED_MIN_SCANS, 2.0),
        "seen": int(len(ids)),
        "measured": int((scans >= MEASURED_MIN_SCANS).sum()),
        "unmatched_by_scans": {"0": int((un & (scans == 0)).sum()), "1": int((un & (scans == 1)).sum()),
                               ">=2": int((un & (scans >= 2)).sum())},
        "unmatched_never_in_view": int((un & (in_view == 0)).sum()),
        "unmatched_in_view_cycles": [int(v) for v in in_view[un]],
        "unmatched_scans": [int(v) for v in scans[un]],
    }


def _episode(env, seed: int, visibility: bool = False, action: int = IDLE) -> dict[str, Any]:
    """Episode at a constant meta-action; vehicle errors per step and the final map counts.

    With ``visibility`` also the landmarks' cycles in the radar's unoccluded view and the
    scans whose points measured them (:func:`_seen_breakdown`).
    """
    obs, _ = env.reset(seed=seed)
    err: list[float] = []
    done, info = False, {}
    visible: dict[int, int] = {}  # landmark id -> cycles in the radar's unoccluded view
    hits: dict[int, int] = {}  # landmark id -> scans with a point within 1 m of it
    if visibility:
        _count_hits(env, obs, hits)
    while not done:
        obs, _, term, trunc, info = env.step(action)
        err.append(float(info["position_error_m"]))
        done = term or trunc
        if visibility:
            for i in _visible_landmarks(env):
                visible[int(i)] = visible.get(int(i), 0) + 1
            _count_hits(env, obs, hits)
    m, miss, sp = int(info["map_matched"]), int(info["map_missed"]), int(info["map_spurious"])
    return {
        "visible_matched_fraction": _visible_matched_fraction(env, info, visible) if visibility else None,
        **(_seen_breakdown(env, info, visible, hits) if visibility else {}),
        "seed": seed,
        "cycles": len(err),
        "crashed": bool(info.get("crashed", False)),
        "position_rmse_m": float(np.sqrt(np.mean(np.square(err)))),
        "final_error_m": err[-1],
        # a highway-env collision stops the car within one step (no physical deceleration) and ends
        # the episode: the error of the last cycle before it
        "final_error_before_crash_m": err[-2] if info.get("crashed", False) and len(err) > 1 else err[-1],
        "matched": m, "missed": miss, "spurious": sp,
        "matched_fraction": m / max(m + miss, 1),
        "spurious_fraction": sp / max(m + sp, 1),
        "map_rmse_m": info.get("map_rmse_m"),
    }


def _slam_config(env) -> dict[str, Any]:
    try:
        return asdict(env.get_wrapper_attr("slam_config"))
    except AttributeError:
        return {}


def run_highway(args, slam: dict) -> dict[str, Any]:
    import gymnasium as gym

    import rhs_env  # noqa: F401

    kw: dict[str, Any] = {"duration": args.cycles / POLICY_HZ, "landmarks_in_info": True}
    if slam:
        kw["slam"] = slam
    env = gym.make("rhs-highway-slam-v0", **kw)
    runs = []
    for seed in args.seeds:
        t0 = time.perf_counter()
        runs.append({**_episode(env, seed, visibility=True, action=args.highway_action), "wall_s": time.perf_counter() - t0})
        _log(args, "highway", runs[-1])
    cfg = _slam_config(env)
    env.close()
    keys = ("position_rmse_m", "final_error_m", "matched_fraction", "spurious_fraction", "map_rmse_m",
            "visible_matched_fraction", "measured_matched_fraction", "cycles", "final_error_before_crash_m")
    return {"runs": runs, "summary": {k: ci95([r[k] for r in runs]) for k in keys}, "slam_config": cfg,
            "env_kwargs": kw, "action": args.highway_action}


def run_paper(args, slam: dict) -> dict[str, Any]:
    import gymnasium as gym

    import rhs_env  # noqa: F401

    kw: dict[str, Any] = {"radar": {"link": {"tx_power_dbm": 30.0}}, "duration": args.paper_cycles / POLICY_HZ}
    if slam:
        kw["slam"] = slam
    env = gym.make("rhs-paper-v0", **kw)
    runs = []
    for seed in args.seeds:
        runs.append(_episode(env, seed))
        _log(args, "paper", runs[-1])
    cfg = _slam_config(env)
    env.close()
    return {"runs": runs, "summary": {k: ci95([r[k] for r in runs]) for k in ("position_rmse_m", "final_error_m")},
            "slam_config": cfg, "env_kwargs": kw}


def dense_scene(seed: int, cycles: int, dt: float = 0.2, speed: float = 6.0, spacing: float = 12.0):
    """Short straight drive along x past landmark pairs 2-5 deg apart in one range cell.

    The drive: ``cycles`` poses at ``speed`` m/s from the origin heading +x (40 cycles:
    47 m, as the paper's Fig. 5c drive). Pair centres on both sides every ``spacing``
    m (+-2 m jitter) from 10 m before the start to 10 m past the end, 20-35 m from the
    path (uniform). Pair k: separation ``delta`` uniform in [2, 5] deg; its members are
    spaced ``2 D tan(delta / 2)`` across the line of sight from the middle of the drive
    (D: the centre's distance from there; 0.8-4.2 m apart), so from there they are
    ``delta`` apart at equal ranges. The drive is short next to D: the line of sight
    turns little and the pairs stay 2-5 deg apart in one range cell (c / 2B = 0.6 m)
    for about half of the (cycle, pair)s (:func:`pair_geometry`), where the RHS
    resolves them and the phased array (~3x wider beam) merges them. Members closer
    than the SLAM's 1 m ``cluster_radius_m`` are one object for either antenna.
    Returns landmarks (2 K, 2) (first members, then second members), poses (T, 3),
    the separations (deg).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(cycles)
    poses = np.stack([speed * dt * t, np.zeros(cycles), np.zeros(cycles)], axis=1)
    end = float(poses[-1, 0])
    xs = np.arange(-10.0, end + 10.0, spacing)
    xs = np.concatenate([xs, xs])
    side = np.concatenate([np.ones(xs.size // 2), -np.ones(xs.size // 2)])
    xs = xs + rng.uniform(-2.0, 2.0, xs.size)
    y = side * rng.uniform(20.0, 35.0, xs.size)
    delta = rng.uniform(2.0, 5.0, xs.size)
    centre = np.stack([xs, y], 1)
    v = centre - np.array([end / 2.0, 0.0])
    dist = np.hypot(v[:, 0], v[:, 1])
    across = np.stack([-v[:, 1], v[:, 0]], 1) / dist[:, None]
    half = (dist * np.tan(np.radians(delta) / 2.0))[:, None] * across
    return np.concatenate([centre - half, centre + half]), poses, delta


def pair_geometry(lm: np.ndarray, poses: np.ndarray, max_range_m: float = 100.0,
                  range_cell_m: float = 0.6) -> dict[str, float]:
    """How the pairs of :func:`dense_scene` look from the car over the drive.

    Over every (cycle, pair) with both members within ``max_range_m``: the fraction
    2-5 deg apart in angle, the fraction within one range cell (``|r1 - r2| <
    range_cell_m``), the fraction with both (the regime where the RHS resolves what the
    phased array merges), and that fraction among the pairs within 30 m.
    """
    k = len(lm) // 2
    a, b = lm[:k], lm[k:]
    sep, dr, rng_m = [], [], []
    for p in np.asarray(poses, dtype=float):
        ra, rb = np.hypot(*(a - p[:2]).T), np.hypot(*(b - p[:2]).T)
        d = np.arctan2(a[:, 1] - p[1], a[:, 0] - p[0]) - np.arctan2(b[:, 1] - p[1], b[:, 0] - p[0])
        ok = np.maximum(ra, rb) <= max_range_m
        sep.append(np.degrees(np.abs(np.angle(np.exp(1j * d))))[ok])
        dr.append(np.abs(ra - rb)[ok])
        rng_m.append(np.minimum(ra, rb)[ok])
    s, r, near = np.concatenate(sep), np.concatenate(dr), np.concatenate(rng_m) <= 30.0
    angle, cell = (s >= 2.0) & (s <= 5.0), r < range_cell_m
    both = angle & cell
    return {"angle_2_5_deg": float(angle.mean()), "same_range_cell": float(cell.mean()),
            "regime": float(both.mean()), "regime_within_30m": float(both[near].mean()) if near.any() else 0.0,
            "regime_pair_cycles": int(both.sum())}


def run_dense(args, slam: dict) -> dict[str, Any]:
    from rhs_env.radar import RadarConfig, RadarSystem
    from slam.core.rbpf import SlamConfig
    from slam.core.registration import make_registration
    from slam.core.scenario import run_scenario
    from slam.gym.radar_cloud import RadarCloud

    cfg = SlamConfig(**slam) if slam else SlamConfig()
    if args.particles:
        cfg = SlamConfig(**{**asdict(cfg), "n_particles": args.particles})
    runs = []
    for seed in args.seeds:
        lm, poses, delta = dense_scene(seed, args.dense_cycles, spacing=args.dense_spacing)
        row: dict[str, Any] = {"seed": seed, "separation_deg": [float(delta.min()), float(delta.max())],
                               "geometry": pair_geometry(lm, poses)}
        for ant in ("rhs", "phased"):
            rng = np.random.default_rng(seed)
            radar = RadarSystem(RadarConfig(antenna=ant), rng)
            res = run_scenario(lm, poses, RadarCloud(lm, poses, 0.2, radar), make_registration("icp", rng), cfg, rng,
                               dt=0.2)
            row[f"{ant}_ate_m"] = float(res["ate_rmse_m"])
            row[f"{ant}_map_rmse_m"] = None if res["map_rmse_m"] is None else float(res["map_rmse_m"])
            row[f"{ant}_spurious"] = int(res["map_spurious"])
            row[f"{ant}_missed"] = int(res["map_missed"])
        row["ratio_rhs_phased"] = row["rhs_ate_m"] / max(row["phased_ate_m"], 1e-12)
        runs.append(row)
        _log(args, "dense", row)
    keys = ("rhs_ate_m", "phased_ate_m", "ratio_rhs_phased", "rhs_map_rmse_m", "phased_map_rmse_m", "rhs_spurious",
            "phased_spurious", "rhs_missed", "phased_missed")
    return {"runs": runs, "summary": {k: ci95([r[k] for r in runs]) for k in keys}, "slam_config": asdict(cfg),
            "cycles": args.dense_cycles, "spacing_m": args.dense_spacing}


#: the drivers part: env id -> the learned driver (agents/data): on the highway the DAgger student continued 80k
#: (agents.evaluate.DAGGER_CONTINUED_POLICY, the shipped policy before the shielded 30 m/s student), on the dense
#: road its DAgger student; every driver on an env
#: runs with that policy's env kwargs (its radar grid and target speeds), so the drivers see one env
DRIVER_ENVS = {"rhs-highway-slam-v0": "rl/dagger_continue_80k.zip", "rhs-dense-v0": "antenna/dagger_rhs_highway_dense.zip"}
DRIVERS = ("idm", "policy", "random")
LOST_M = 5.0  # an error above this is a lost car
GOOD_M = 0.5  # below this the health signal must stay quiet
RECOVER_CYCLES = 10
RECOVERED_M = 1.0


def driver_episode(env, policy, seed: int, trace: list | None = None) -> dict[str, Any]:
    """One episode under ``policy`` until it ends; per-cycle errors, health, NEES and the loss events.

    A *loss* is a cycle where the health signal's ``slam_losses`` count rises; it is *recovered* when
    within ``RECOVER_CYCLES`` cycles the flag clears (relocalised or a new map) and the error in the
    current map is below ``RECOVERED_M``. Errors are in the current map (after a map break the truth
    is re-anchored at the break, :class:`slam.gym.metrics_info.SlamMetricsInfo`); ``episode_rmse_m`` is
    against the episode's start. ``trace``: a list that gets ``(estimated_pose, true_pose)`` (the current map's
    frame) of every cycle.
    """
    from rhs_common.geometry import wrap_angle

    if callable(getattr(policy, "reset", None)):
        policy.reset()
    obs, info = env.reset(seed=seed)
    err, err_ep, lost, nees, nees_diag, nees_particles, losses = [], [], [], [], [], [], []
    done = False
    crashed, last_losses = False, 0
    while not done:
        action, _ = policy.predict(obs, deterministic=True)
        a = np.asarray(action)
        obs, _, term, trunc, info = env.step(int(a) if a.ndim == 0 else action)
        done = term or trunc
        crashed = crashed or bool(info.get("crashed", False))
        e = np.asarray(info["estimated_pose"], dtype=float) - np.asarray(info["true_pose"], dtype=float)
        if trace is not None:
            trace.append((np.asarray(info["estimated_pose"], dtype=float), np.asarray(info["true_pose"], dtype=float)))
        err.append(float(info["position_error_m"]))
        err_ep.append(float(info["position_error_episode_m"]))
        lost.append(bool(info["slam_lost"]))
        std = np.asarray(info["slam_pose_std"], dtype=float)
        cov = info.get("slam_pose_cov")
        nees.append(pose_nees(e[:2], float(wrap_angle(e[2])), std, None if cov is None else np.asarray(cov, float)))
        nees_diag.append(pose_nees(e[:2], float(wrap_angle(e[2])), std))
        # the particles' spread alone (the observation's pose_std; while lost the loss's floor): no drift term
        alone = std if info["slam_lost"] else np.asarray(obs["pose_std"], dtype=float)
        nees_particles.append(pose_nees(e[:2], float(wrap_angle(e[2])), alone))
        if int(info["slam_losses"]) > last_losses:
            losses.append(len(err) - 1)
        last_losses = int(info["slam_losses"])
    e_arr, l_arr = np.asarray(err), np.asarray(lost)
    recovered = 0
    for t0 in losses:
        win = range(t0, min(t0 + RECOVER_CYCLES + 1, len(err)))
        recovered += any(not lost[t] and err[t] < RECOVERED_M for t in win)
    lo, hi = nees_interval()
    nees_arr = np.asarray(nees)
    return {
        "seed": seed, "cycles": len(err), "crashed": crashed,
        "position_rmse_m": float(np.sqrt(np.mean(e_arr**2))),
        "episode_rmse_m": float(np.sqrt(np.mean(np.square(err_ep)))),
        "max_error_m": float(e_arr.max()),
        "lost_episode": bool(e_arr.max() > LOST_M),
        "cycles_above_lost": int((e_arr > LOST_M).sum()),
        "cycles_above_lost_flagged": int(((e_arr > LOST_M) & l_arr).sum()),
        "cycles_below_good": int((e_arr < GOOD_M).sum()),
        "cycles_below_good_flagged": int(((e_arr < GOOD_M) & l_arr).sum()),
        "nees_cycles": len(nees), "nees_inside": int(((nees_arr >= lo) & (nees_arr <= hi)).sum()),
        "nees_below": int((nees_arr < lo).sum()), "nees_above": int((nees_arr > hi).sum()),
        "nees_diag_inside": int(((np.asarray(nees_diag) >= lo) & (np.asarray(nees_diag) <= hi)).sum()),
        "nees_particles_inside": int(((np.asarray(nees_particles) >= lo) & (np.asarray(nees_particles) <= hi)).sum()),
        "losses": len(losses), "losses_recovered": int(recovered),
        "relocalised": int(info.get("slam_relocalised", 0)), "map_breaks": int(info.get("slam_map_breaks", 0)),
    }


def _ratio(num: int, den: int) -> float | None:
    return num / den if den else None


def summarize_driver(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean, worst episode and lost fraction of the position RMSE; health hit / false-alarm rates; NEES coverage;
    losses recovered within ``RECOVER_CYCLES`` cycles."""
    tot = {k: sum(int(r[k]) for r in runs) for k in (
        "cycles_above_lost", "cycles_above_lost_flagged", "cycles_below_good", "cycles_below_good_flagged",
        "nees_cycles", "nees_inside", "nees_below", "nees_above", "losses", "losses_recovered", "map_breaks",
        "relocalised")}
    diag_inside = sum(int(r.get("nees_diag_inside", 0)) for r in runs)
    particles_inside = sum(int(r.get("nees_particles_inside", 0)) for r in runs)
    rmse = [r["position_rmse_m"] for r in runs]
    return {
        "episodes": len(runs),
        "position_rmse_m": ci95(rmse),
        "worst_rmse_m": float(max(rmse)) if rmse else None,
        "worst_seed": runs[int(np.argmax(rmse))]["seed"] if rmse else None,
        "lost_fraction": _ratio(sum(r["lost_episode"] for r in runs), len(runs)),
        "crashed_fraction": _ratio(sum(r["crashed"] for r in runs), len(runs)),
        "episode_rmse_m": ci95([r["episode_rmse_m"] for r in runs]),
        "cycles": int(sum(r["cycles"] for r in runs)),
        "health_hit_rate": _ratio(tot["cycles_above_lost_flagged"], tot["cycles_above_lost"]),
        "health_false_alarm_rate": _ratio(tot["cycles_below_good_flagged"], tot["cycles_below_good"]),
        "nees_coverage": _ratio(tot["nees_inside"], tot["nees_cycles"]),
        "nees_diag_coverage": _ratio(diag_inside, tot["nees_cycles"]),
        "nees_particles_coverage": _ratio(particles_inside, tot["nees_cycles"]),
        "nees_below_fraction": _ratio(tot["nees_below"], tot["nees_cycles"]),
        "nees_above_fraction": _ratio(tot["nees_above"], tot["nees_cycles"]),
        "recovered_fraction": _ratio(tot["losses_recovered"], tot["losses"]),
        **{k: tot[k] for k in ("cycles_above_lost", "cycles_below_good", "losses", "losses_recovered", "map_breaks",
                               "relocalised")},
    }


#: per worker process: the env of each (env id, env kwargs) and its driver, made once and reused
_WORKER_ENVS: dict[str, Any] = {}


def _driver_task(task: tuple[str, str, str, dict, int]) -> dict[str, Any]:
    """One (env, driver, seed) episode (:func:`driver_episode`) on this process's env for that env id and driver.

    Every episode starts from ``env.reset(seed)`` and a policy built for its seed (the SLAM's generator is drawn
    from the env's at reset), so an episode does not depend on which episodes the env ran before: any split
    of the seeds over processes gives the same runs.
    """
    import gymnasium as gym

    import rhs_env  # noqa: F401
    from agents.evaluate import load_policy

    env_id, driver, zip_path, kw, seed = task
    key = json.dumps([env_id, driver, kw], sort_keys=True)
    if key not in _WORKER_ENVS:
        _WORKER_ENVS[key] = gym.make(env_id, **kw)
    env = _WORKER_ENVS[key]
    policy = load_policy(zip_path if driver == "policy" else driver, env, seed=seed)
    t0 = time.perf_counter()
    return {**driver_episode(env, policy, seed), "wall_s": time.perf_counter() - t0}


def _close_worker_envs() -> None:
    while _WORKER_ENVS:
        _WORKER_ENVS.popitem()[1].close()


def _nested_update(base: dict, over: dict) -> dict:
    """``base`` with ``over`` merged in group by group: ``{"scan": {"grid_deg": 5}}`` updated by
    ``{"scan": {"sector_deg": 60}}`` keeps the grid (a plain ``{**base, **over}`` would drop it)."""
    out = dict(base)
    for k, v in over.items():
        out[k] = _nested_update(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def run_drivers(args, slam: dict) -> dict[str, Any]:
    """Every driver of ``--drivers`` on every env of ``--driver-envs`` over ``--driver-seeds``, until each episode
    ends; the episodes spread over ``--workers`` processes (the same runs as one process, :func:`_driver_task`),
    with a progress line per episode (done / total, elapsed, estimated time left) unless ``--no-progress``."""
    from agents.evaluate import DATA_DIR, policy_metadata

    tasks, combos = [], []
    for env_id in args.driver_envs:
        zip_path = DATA_DIR / DRIVER_ENVS[env_id]
        kw = {**policy_metadata(zip_path).get("env_kwargs", {}), "duration": args.driver_cycles / POLICY_HZ}
        if slam:
            kw["slam"] = slam
        if args.radar:
            kw["radar"] = _nested_update(kw.get("radar", {}), args.radar)
        for driver in args.drivers:
            combos.append((env_id, driver, zip_path, kw))
            tasks += [(env_id, driver, str(zip_path), kw, int(seed)) for seed in args.driver_seeds]
    started = time.perf_counter()
    results: list[dict[str, Any]] = []

    def progress(row: dict[str, Any], task: tuple) -> None:
        results.append(row)
        if not args.no_progress:
            done, elapsed = len(results), time.perf_counter() - started
            print(f"[drivers {done}/{len(tasks)} {elapsed:.0f} s, ~{elapsed / done * (len(tasks) - done):.0f} s left] "
                  f"{task[0]} {task[1]} seed {row['seed']}: {row['cycles']} cycles, RMSE "
                  f"{row['position_rmse_m']:.3f} m, max {row['max_error_m']:.2f} m", file=sys.stderr, flush=True)

    if args.workers > 1:
        import multiprocessing as mp

        with mp.get_context("spawn").Pool(args.workers) as pool:
            for task, row in zip(tasks, pool.imap(_driver_task, tasks), strict=True):
                progress(row, task)
    else:
        try:
            for k, task in enumerate(tasks):
                if k and task[:2] != tasks[k - 1][:2]:  # the next env and driver: one env open at a time
                    _close_worker_envs()
                progress(_driver_task(task), task)
        finally:
            _close_worker_envs()
    out: dict[str, Any] = {}
    n = len(args.driver_seeds)
    for i, (env_id, driver, zip_path, kw) in enumerate(combos):
        runs = results[i * n:(i + 1) * n]
        out[f"{env_id}/{driver}"] = {"env": env_id, "driver": driver, "env_kwargs": kw,
                                     "policy": str(zip_path.relative_to(DATA_DIR.parent.parent)) if driver == "policy"
                                     else driver, "runs": runs, "summary": summarize_driver(runs)}
    return {"combos": out, "seeds": list(args.driver_seeds), "lost_m": LOST_M, "good_m": GOOD_M,
            "nees_interval": nees_interval(), "recover_cycles": RECOVER_CYCLES, "recovered_m": RECOVERED_M}


#: the roads part: highway-env's other roads (rhs_env.road_envs), ids rhs-<road>-slam-v0
ROADS = ("merge", "roundabout", "intersection", "exit", "racetrack")
#: the roads part's drivers: highway-env's IDM + MOBIL in the ego's seat (agents.evaluate.IDMMobilPolicy, at the
#: road's top target speed; on the racetrack, whose continuous action has none, at its 10 m/s speed limit) and
#: uniformly random actions. No policy was trained on these roads.
ROAD_DRIVERS = ("idm", "random")
ROAD_IDM = {"racetrack": "idm:10"}
#: the roads part's radar: a 5-degree scan grid (the default is 1 degree), the cheap configuration
ROAD_RADAR = {"scan": {"grid_deg": 5}}
#: the roads part's episode bound, cycles: every road ends before it (merge ~60, roundabout 55, intersection 65,
#: exit 90 cycles) except the racetrack (300 s = 1500 cycles): 300 cycles = 60 s, about 600 m
ROAD_CYCLES = 300
#: KITTI's segment lengths (m); where an episode is shorter, :data:`SHORT_DRIFT_LENGTHS_M`
SHORT_DRIFT_LENGTHS_M = (25.0, 50.0)


class ZeroActionDriver:
    """IDM + MOBIL in the ego's seat (:class:`agents.evaluate.IDMMobilPolicy`, which ignores its actions) on an env
    with a ``Box`` action space (the racetrack's steering): it passes the zero action the env's step asks for (the
    driver's swap, :func:`rhs_env.idm_driver.swap_ego_for_idm`, gives highway-env's plain ``Vehicle`` ego the lane
    and route an ``IDMVehicle`` is made from)."""

    def __init__(self, driver: Any, env: Any):
        self.driver = driver
        self.zero = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)

    def reset(self) -> None:
        if callable(getattr(self.driver, "reset", None)):
            self.driver.reset()

    def predict(self, obs: Any, deterministic: bool = True) -> tuple[np.ndarray, None]:
        self.driver.predict(obs, deterministic)
        return self.zero, None


def _road_task(task: tuple) -> dict[str, Any]:
    """One roads-part episode ``(road, driver, env kwargs, seed)`` in this process (its env kept per road)."""
    import gymnasium as gym

    import rhs_env  # noqa: F401
    from agents.evaluate import load_policy
    from rhs_common.geometry import wrap_angle

    road, driver, kw, seed = task
    env_id = f"rhs-{road}-slam-v0"
    key = json.dumps([env_id, kw], sort_keys=True)
    if key not in _WORKER_ENVS:
        _close_worker_envs()
        _WORKER_ENVS[key] = gym.make(env_id, **kw)
    env = _WORKER_ENVS[key]
    name = ROAD_IDM.get(road, "idm") if driver == "idm" else driver
    policy = load_policy(name, env, seed=seed)
    if driver == "idm" and isinstance(env.action_space, gym.spaces.Box):
        policy = ZeroActionDriver(policy, env)
    trace: list = []
    t0 = time.perf_counter()
    row = driver_episode(env, policy, seed, trace)
    est, true = (np.array([p[k] for p in trace]) for k in (0, 1))
    path = float(np.hypot(*np.diff(true[:, :2], axis=0).T).sum()) if len(true) > 1 else 0.0
    heading = np.degrees(wrap_angle(est[:, 2] - true[:, 2]))
    return {**row, "wall_s": time.perf_counter() - t0, "path_m": path,
            "heading_rmse_deg": float(np.sqrt(np.mean(heading**2))), "max_heading_error_deg": float(np.abs(heading).max()),
            "drift": segment_drift(est, true, SHORT_DRIFT_LENGTHS_M + DRIFT_LENGTHS_M)}


def road_targets(driver: str, summary: dict[str, Any], runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The per-road targets: worst-episode position RMSE <= 1 m (the scripted driver only), no cycle above
    :data:`LOST_M` without the loss flag, NEES inside its 95 % band on >= 90 % of the cycles."""
    silent = sum(int(r["cycles_above_lost"]) - int(r["cycles_above_lost_flagged"]) for r in runs)
    cov = summary["nees_coverage"]
    return {"worst_rmse_le_1m": bool(summary["worst_rmse_m"] <= 1.0) if driver == "idm" else None,
            "silent_lost_cycles": silent, "no_silent_loss": silent == 0,
            "nees_ge_90pct": None if cov is None else bool(cov >= 0.9)}


def run_roads(args, slam: dict) -> dict[str, Any]:
    """Every driver of ``--road-drivers`` on every road of ``--roads`` over ``--road-seeds`` (each episode until it
    ends, at most ``--road-cycles``), on the cheap radar :data:`ROAD_RADAR` (``--radar`` merged over it)."""
    tasks, combos = [], []
    for road in args.roads:
        kw: dict[str, Any] = {"radar": _nested_update(ROAD_RADAR, args.radar), **_duration_kw(road, args.road_cycles)}
        if slam:
            kw["slam"] = slam
        for driver in args.road_drivers:
            combos.append((road, driver, kw))
            tasks += [(road, driver, kw, int(seed)) for seed in args.road_seeds]
    started = time.perf_counter()
    results: list[dict[str, Any]] = []
    for task in tasks:
        row = _road_task(task)
        results.append(row)
        if not args.no_progress:
            done, elapsed = len(results), time.perf_counter() - started
            print(f"[roads {done}/{len(tasks)} {elapsed:.0f} s, ~{elapsed / done * (len(tasks) - done):.0f} s left] "
                  f"{task[0]} {task[1]} seed {row['seed']}: {row['cycles']} cycles, {row['path_m']:.0f} m, RMSE "
                  f"{row['position_rmse_m']:.3f} m, max {row['max_error_m']:.2f} m, heading "
                  f"{row['heading_rmse_deg']:.2f} deg", file=sys.stderr, flush=True)
    _close_worker_envs()
    out: dict[str, Any] = {}
    n = len(args.road_seeds)
    for i, (road, driver, kw) in enumerate(combos):
        runs = results[i * n:(i + 1) * n]
        summary = {**summarize_driver(runs), "heading_rmse_deg": ci95([r["heading_rmse_deg"] for r in runs]),
                   "path_m": ci95([r["path_m"] for r in runs]),
                   "drift_kitti": pooled_drift(runs, DRIFT_LENGTHS_M), "drift_short": pooled_drift(runs, SHORT_DRIFT_LENGTHS_M)}
        out[f"{road}/{driver}"] = {"road": road, "env": f"rhs-{road}-slam-v0", "driver": driver,
                                   "policy": ROAD_IDM.get(road, "idm") if driver == "idm" else driver,
                                   "env_kwargs": kw, "max_cycles": args.road_cycles, "runs": runs, "summary": summary,
                                   "targets": road_targets(driver, summary, runs)}
    return {"combos": out, "seeds": list(args.road_seeds), "lost_m": LOST_M, "good_m": GOOD_M,
            "nees_interval": nees_interval(), "radar": _nested_update(ROAD_RADAR, args.radar),
            "dro_drift_pct": DRO_DRIFT_PCT, "cfear_drift_pct": list(CFEAR_DRIFT_PCT)}


def _duration_kw(road: str, cycles: int) -> dict[str, Any]:
    """The ``duration`` that bounds an episode of ``road`` at ``cycles`` cycles, where the road has a time limit
    longer than that (the merge has none: it ends past x = 370 m)."""
    from rhs_env.road_envs import ROAD_ENVS

    default = ROAD_ENVS[road].default_config().get("duration")
    return {"duration": cycles / POLICY_HZ} if default is not None and default * POLICY_HZ > cycles else {}


def roads_markdown(res: dict[str, Any]) -> list[str]:
    """The per-road table: targets, heading RMSE, drift over KITTI's lengths beside the real-data anchors."""
    lo, hi = res["nees_interval"]
    seeds = res["seeds"]
    grid = res["radar"].get("scan", {}).get("grid_deg")
    lines = [f"\n## Roads (seeds {seeds[0]}..{seeds[-1]}, {len(seeds)} per road and driver, each episode until it "
             "ends)\n",
             f"Simulated: highway-env's roads, traffic and rewards with roadside landmarks (`rhs-<road>-slam-v0`), the "
             f"exact radar on a cheap {grid:g}-degree scan grid (the default is 1 degree), the default SLAM. "
             "Drivers: `idm` = highway-env's IDM + MOBIL in the ego's seat (following the road's route; on the "
             "racetrack at its 10 m/s speed limit, steering by the lane controller), `random` = uniformly random "
             "actions. No policy has been trained on these roads. Worst RMSE target (<= 1 m) for the scripted "
             f"driver. Silent: cycles with an error above {res['lost_m']:g} m where `slam_lost` is not set (target "
             f"0). NEES: 3-dof against `slam_pose_cov`, inside [{lo:.3f}, {hi:.2f}] (target >= 90 % of cycles). "
             "Drift: KITTI's translational error over 100-800 m segments where an episode is that long, else (in "
             "brackets) over 25-50 m segments.\n",
             "| road | driver | cycles | path (m) | RMSE mean (m) | worst (m) | target | crashed | silent | "
             "NEES inside | heading RMSE (deg) | drift (%) | drift (deg/100 m) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for combo in res["combos"].values():
        sm, tg = combo["summary"], combo["targets"]
        dk = sm["drift_kitti"] if sm["drift_kitti"]["segments"] else sm["drift_short"]
        br = (lambda x: x) if sm["drift_kitti"]["segments"] else (lambda x: f"({x})")
        drift_t = "n/a" if dk["translation_pct"] is None else br(f"{dk['translation_pct']:.2f}")
        drift_r = "n/a" if dk["rotation_deg_per_100m"] is None else br(f"{dk['rotation_deg_per_100m']:.2f}")
        met = {True: "met", False: "**not met**", None: "-"}[tg["worst_rmse_le_1m"]]
        lines.append(f"| {combo['road']} | {combo['driver']} | {sm['cycles']} | {_fmt(sm['path_m'])} | "
                     f"{_fmt(sm['position_rmse_m'])} | {sm['worst_rmse_m']:.3f} (seed {sm['worst_seed']}) | {met} | "
                     f"{_pct(sm['crashed_fraction'])} | {tg['silent_lost_cycles']} | {_pct(sm['nees_coverage'])} | "
                     f"{_fmt(sm['heading_rmse_deg'])} | {drift_t} | {drift_r} |")
    lines.append(f"\nReal-data radar odometry for scale (not the same test: real sensors, real roads, km-long "
                 f"drives): DRO {res['dro_drift_pct']:g} % (Boreas), CFEAR {res['cfear_drift_pct'][0]:g}-"
                 f"{res['cfear_drift_pct'][1]:g} % translational drift. The figures above are simulated.")
    return lines


def _log(args, part: str, row: dict) -> None:
    if not args.no_progress:
        short = {k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()
                 if not isinstance(v, (list, dict))}
        print(f"[{part}] {short}", file=sys.stderr, flush=True)


def _fmt(s: dict) -> str:
    if s.get("mean") is None:
        return "n/a"
    return f"{s['mean']:.3f}" + (f" +- {s['ci95']:.3f}" if s.get("ci95") is not None else "")


def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.1f} %"


def drivers_markdown(res: dict) -> list[str]:
    """The drivers table: per env and driver, the mean / worst RMSE, lost episodes, health rates, NEES, recovery."""
    lo, hi = res["nees_interval"]
    lines = [f"\n## Drivers (seeds {res['seeds'][0]}..{res['seeds'][-1]}, {len(res['seeds'])} per row, each episode until "
             "it ends)\n",
             f"Lost episode: position error above {res['lost_m']:g} m in some cycle. Health hit rate: cycles with an "
             f"error above {res['lost_m']:g} m where `slam_lost` is set; false alarms: cycles with an error below "
             f"{res['good_m']:g} m where it is set. NEES: 3-dof against `slam_pose_cov` (the particles plus the "
             f"shared map drift), inside [{lo:.3f}, {hi:.2f}] (95 %). Recovered: the flag clears with the error "
             f"below {res['recovered_m']:g} m within "
             f"{res['recover_cycles']} cycles of a loss. Errors in the current map (a map break re-anchors the truth).\n",
             "| env | driver | RMSE mean (m) | worst (m) | lost episodes | crashed | hit rate | false alarms | "
             "NEES inside | losses (recovered) | map breaks |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for combo in res["combos"].values():
        sm = combo["summary"]
        lines.append(f"| {combo['env']} | {combo['driver']} | {_fmt(sm['position_rmse_m'])} | {sm['worst_rmse_m']:.3f} "
                     f"(seed {sm['worst_seed']}) | {_pct(sm['lost_fraction'])} | {_pct(sm['crashed_fraction'])} | "
                     f"{_pct(sm['health_hit_rate'])} of {sm['cycles_above_lost']} | {_pct(sm['health_false_alarm_rate'])} "
                     f"of {sm['cycles_below_good']} | {_pct(sm['nees_coverage'])} | {sm['losses']} "
                     f"({_pct(sm['recovered_fraction'])}) | {sm['map_breaks']} |")
    pooled = [r for c in res["combos"].values() if c["driver"] in ("idm", "policy") for r in c["runs"]]
    n = sum(int(r["nees_cycles"]) for r in pooled)
    if n:
        inside = sum(int(r["nees_inside"]) for r in pooled) / n
        diag = sum(int(r.get("nees_diag_inside", 0)) for r in pooled) / n
        alone = sum(int(r.get("nees_particles_inside", 0)) for r in pooled) / n
        lines.append(f"\nNEES inside, pooled over the IDM and policy runs: {_pct(inside)} of {n} cycles "
                     f"({_pct(diag)} against the diagonal of `slam_pose_std`; {_pct(alone)} against the particles' "
                     "spread alone, without the drift).")
    return lines


def markdown(doc: dict) -> str:
    lines = [f"# SLAM accuracy against its targets\n\nCommand: `{doc['command']}`  \nCommit: `{doc['commit']}`  \n"
             f"Seeds: {doc['seeds']} (evaluation seeds; the filter was tuned on 0..4). Mean +- 95 % CI over seeds.\n",
             "| scene | metric | value | target | met |", "|---|---|---|---|---|"]
    for part, res in doc["parts"].items():
        if part in ("drivers", "roads"):
            continue
        for key, (op, val) in TARGETS[part].items():
            s = res["summary"][key]
            met = None if s["mean"] is None else (s["mean"] <= val if op == "<=" else s["mean"] >= val)
            lines.append(f"| {part} | {key} | {_fmt(s)} | {op} {val:.3g} | {'yes' if met else 'no'} |")
        for key in EXTRA.get(part, ()):
            if key in res["summary"]:
                lines.append(f"| {part} | {key} | {_fmt(res['summary'][key])} | - | - |")
    drivers, roads = doc["parts"].get("drivers"), doc["parts"].get("roads")
    if roads and set(doc["parts"]) == {"roads"}:  # the per-road page alone
        return "\n".join([f"# SLAM accuracy on highway-env's roads\n\nCommand: `{doc['command']}`  \nCommit: "
                          f"`{doc['commit']}`\n", *roads_markdown(roads)[1:]]) + "\n"
    return "\n".join(lines + _notes(doc) + (drivers_markdown(drivers) if drivers else [])
                     + (roads_markdown(roads) if roads else [])) + "\n"


def _notes(doc: dict) -> list[str]:
    """What the highway run drove and counted, and how the dense pairs looked from the car."""
    out: list[str] = []
    hw = doc["parts"].get("highway")
    if hw:
        runs = hw["runs"]
        crashed = sum(bool(r["crashed"]) for r in runs)
        by = {k: sum(r.get("unmatched_by_scans", {}).get(k, 0) for r in runs) for k in ("0", "1", ">=2")}
        hidden = sum(r.get("unmatched_never_in_view", 0) for r in runs)
        out.append(f"\nHighway: constant meta-action {hw.get('action', IDLE)} (4 = SLOWER, 20 m/s, no lane change; "
                   f"IDLE crashed into traffic on each of the seeds 0..4 and 100..104), {crashed} of {len(runs)} runs crashed. "
                   "`matched_fraction` counts every landmark that has been within the radar's 100 m range; "
                   "`measured_matched_fraction` only those the radar measured (a point within "
                   "1 m in >= 2 scans, `slam.metrics`); `visible_matched_fraction` those in its unoccluded view "
                   f">= 2 cycles. Unmatched seen landmarks, all seeds, by scans with a point within 1 m: "
                   f"0: {by['0']}, 1: {by['1']}, >= 2: {by['>=2']} ({hidden} never in the unoccluded view).")
    dense = doc["parts"].get("dense")
    if dense:
        geo = [r["geometry"] for r in dense["runs"] if "geometry" in r]
        if geo:
            m = {k: float(np.mean([g[k] for g in geo])) for k in ("angle_2_5_deg", "same_range_cell", "regime",
                                                                   "regime_within_30m")}
            out.append(f"\nDense: pairs on both sides every {dense.get('spacing_m', 12.0):g} m; over the (cycle, pair)s within "
                       f"100 m, {m['angle_2_5_deg']:.0%} are 2-5 deg apart, {m['same_range_cell']:.0%} in one "
                       f"range cell (0.6 m), {m['regime']:.0%} both ({m['regime_within_30m']:.0%} of those within "
                       "30 m); elsewhere the pair is outside 2-5 deg or resolved in range by both antennas.")
    return out


def parse_args(argv: list[str] | None) -> tuple[argparse.Namespace, dict]:
    """The options and the SlamConfig overrides (``--quick`` applied)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--parts", nargs="+", choices=("highway", "paper", "dense", "drivers", "roads"),
                   default=["highway", "paper", "dense"])
    p.add_argument("--drivers", nargs="+", choices=DRIVERS, default=list(DRIVERS),
                   help="drivers part: highway-env's IDM + MOBIL, the DAgger student continued 80k (dense road: its DAgger student), "
                        "uniformly random actions")
    p.add_argument("--driver-envs", nargs="+", choices=tuple(DRIVER_ENVS), default=list(DRIVER_ENVS))
    p.add_argument("--driver-seeds", type=int, nargs="+", default=list(range(1600, 1700)),
                   help="drivers part: seeds held out from every tuning (default 1600..1699, 100 per env and driver; "
                        "1000..1029 tuned the drift and the health threshold, 2000..2099 the Doppler turn fit, "
                        "1100..1199 to 1400..1499 were held out once and then diagnosed; 1500..1599 measured a "
                        "radar setting that was not adopted)")
    p.add_argument("--driver-cycles", type=int, default=200, help="drivers part: episode length bound (cycles)")
    p.add_argument("--roads", nargs="+", choices=ROADS, default=list(ROADS),
                   help="roads part (--parts roads): highway-env's roads, ids rhs-<road>-slam-v0 (default all five)")
    p.add_argument("--road-drivers", nargs="+", choices=ROAD_DRIVERS, default=list(ROAD_DRIVERS),
                   help="roads part: highway-env's IDM + MOBIL in the ego's seat, uniformly random actions")
    p.add_argument("--road-seeds", type=int, nargs="+", default=list(range(3000, 3020)),
                   help="roads part: held-out seeds (default 3000..3019, 20 per road and driver; no tuning used them)")
    p.add_argument("--road-cycles", type=int, default=ROAD_CYCLES,
                   help=f"roads part: episode length bound (cycles, default {ROAD_CYCLES}: only the racetrack's is longer)")
    p.add_argument("--workers", type=int, default=1,
                   help="drivers part: processes the episodes spread over (the same runs as 1; default 1)")
    p.add_argument("--seeds", type=int, nargs="+", default=[100, 101, 102, 103, 104])
    p.add_argument("--cycles", type=int, default=200, help="highway cycles")
    p.add_argument("--highway-action", type=int, default=SLOWER,
                   help="highway: the constant meta-action (4 SLOWER, default; 1 IDLE crashes on most seeds)")
    p.add_argument("--paper-cycles", type=int, default=50)
    p.add_argument("--dense-cycles", type=int, default=40)
    p.add_argument("--dense-spacing", type=float, default=12.0, help="dense: distance between pairs along the path (m)")
    p.add_argument("--particles", type=int, default=0, help="dense: particles (0: SlamConfig default)")
    p.add_argument("--slam", default="", help="JSON dict of SlamConfig overrides")
    p.add_argument("--radar", default="", help="drivers part: JSON dict of radar overrides, as gym.make(..., radar=...) "
                   "takes them, over the policy's env kwargs (e.g. '{\"estimation\": {\"refine_tol\": 0.01}}')")
    p.add_argument("--out", default="results/slam_accuracy", help="output path without extension")
    p.add_argument("--quick", action="store_true", help="small config for the tests: 1 seed, few cycles")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    if args.workers < 1:
        p.error(f"--workers must be >= 1, got {args.workers}")
    slam = json.loads(args.slam) if args.slam else {}
    args.radar = json.loads(args.radar) if args.radar else {}
    if not isinstance(args.radar, dict):
        p.error(f"--radar must be a JSON object of radar overrides, got {args.radar!r}")
    if args.quick:
        args.seeds, args.cycles, args.paper_cycles, args.dense_cycles = args.seeds[:1], 10, 6, 8
        args.driver_seeds, args.driver_cycles = args.driver_seeds[:1], 10
        args.road_seeds, args.road_cycles = args.road_seeds[:1], 10
        slam = {"n_particles": 10, **slam}
    return args, slam


def fingerprint() -> list[float | None]:
    """The paper part and the dense part's RHS values of the quick config (seed 100, 10 particles): seconds.

    The dense part's phased-array run is left out: with 10 particles it loses the car, and a
    lost track turns last-digit differences between machines into other numbers (the
    tolerance of ``scripts/fingerprint_tolerance.py`` cannot bound a chaotic run).
    """
    args, slam = parse_args(["--quick", "--no-progress"])
    dense = {k: v for k, v in run_dense(args, slam)["summary"].items() if k.startswith("rhs_")}
    return numbers([run_paper(args, slam)["summary"], dense])


def main(argv: list[str] | None = None) -> int:
    started = time.time()
    args, slam = parse_args(argv)
    runners = {"highway": run_highway, "paper": run_paper, "dense": run_dense, "drivers": run_drivers,
               "roads": run_roads}
    doc = {"command": " ".join([Path(sys.argv[0]).name, *(argv if argv is not None else sys.argv[1:])]),
           "commit": _commit(), "seeds": args.seeds, "slam_overrides": slam, "radar_overrides": args.radar, "parts": {}}
    for part in args.parts:
        doc["parts"][part] = runners[part](args, slam)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json(out.with_suffix(".json"), doc, __file__, {**vars(args), "slam_overrides": slam}, started,
               fingerprint, argv)
    out.with_suffix(".md").write_text(markdown(doc))
    print(markdown(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
