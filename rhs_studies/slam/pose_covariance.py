"""Pose covariance per radar configuration: the calibrated model against the adaptive one and the drift densities.

``python scripts/pose_covariance.py [--seeds 12000 ...] [--cycles 150] [--configs default grid5 ...] [--out-dir results]``
(``--merge a/pose_covariance.json b/pose_covariance.json`` combines runs of disjoint configurations)

For each configuration (:data:`CONFIGS`: the default 1-degree env, ``grid_deg`` 5, the phased and random
antennas, the dense env, low SNR, the fast radar, each driven by IDM + MOBIL and, as ``<name>_policy``, by the
shipped policy; ``policy_env`` is the shipped policy in its own env, the 5-degree grid) and held-out seed, one drive
(``agents.evaluate.IDMMobilPolicy`` or the shipped policy: :data:`POLICIES`)
of ``--cycles`` cycles with ``pipeline={"pose_covariance": "calibrated"}``:
the env attaches the configuration's calibration (:mod:`slam.gym.pose_calibration`: shipped, cached, or fitted
at first use on the calibration seeds 13000-13039, which no evaluation uses). The covariance is report-only (the
filter's estimate does not depend on it), so each cycle scores the three models on the same estimate: the
calibrated one (``slam_pose_cov``), the adaptive one (its terms unscaled) and the drift densities (the pipeline's
``drift`` term plus the particles' variances: what ``pose_covariance="drift-constants"``, the default, reports).
3-dof NEES ``e^T P^-1 e`` with ``e`` the estimated minus the true pose (heading wrapped), floors and the loss's std
as in ``rhs_studies.slam.slam_accuracy.pose_nees`` (reimplemented here: studies do not import each other).

Reported per configuration and model (:func:`slam.core.pose_calibration.nees_coverage`): cycles below / inside /
above the 95 % chi-square band (3 dof), the median NEES, and the ANEES (mean NEES over the runs' cycles) with its
95 % interval (``chi2(3 n) / n`` for ``n`` cycles: the interval for independent cycles; successive cycles are
correlated, so it is narrower than the ANEES's real spread). Output: ``pose_covariance.json`` (every episode, the
calibrations, provenance) and ``pose_covariance.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from rhs_studies.kit.provenance import write_json
from slam.gym.pose_calibration import SHIPPED_CONFIGS

#: configuration name -> (env id, gym.make keyword arguments without the pipeline option): the configurations whose
#: calibrations the package ships, and the shipped policy's env (agents/data/shipped.json: its action setting does
#: not enter the calibration key, so it is calibrated as grid5)
#: the shipped policy (a byte copy of this experiment) and the action setting it drives with
SHIPPED_POLICY = "agents/data/rl/shield_flank_explore_lane_time.zip"
POLICY_ACTION = {"type": "DiscreteMetaAction", "target_speeds": [10, 15, 20, 25, 30]}
#: the configurations the shipped policy drives (name -> the configuration it drives in, with its action setting,
#: which does not enter the calibration key); ``policy_env`` is its own env, the 5-degree grid
POLICY_CONFIGS: dict[str, str] = {"policy_env": "grid5", **{f"{n}_policy": n for n in SHIPPED_CONFIGS if n != "grid5"}}
CONFIGS: dict[str, tuple[str, dict[str, Any]]] = {
    **SHIPPED_CONFIGS,
    **{name: (SHIPPED_CONFIGS[base][0], {"action": POLICY_ACTION, **SHIPPED_CONFIGS[base][1]})
       for name, base in POLICY_CONFIGS.items()},
}
#: the configurations' driver: IDM + MOBIL unless named here (the shipped policy)
POLICIES: dict[str, str] = dict.fromkeys(POLICY_CONFIGS, SHIPPED_POLICY)
MODELS = ("calibrated", "adaptive", "drift-constants")
#: held-out seeds (the densities were fitted on 1000-1009)
SEEDS = tuple(range(12000, 12040))
NEES_FLOOR = np.array([1e-3, 1e-3, 1e-4])  # std floors (m, m, rad), as slam_accuracy's


def chi2_band(dof: int, level: float = 0.95) -> tuple[float, float]:
    """The two-sided ``level`` interval of the chi-square distribution with ``dof`` degrees of freedom."""
    from scipy import stats

    return float(stats.chi2.ppf((1 - level) / 2, dof)), float(stats.chi2.ppf((1 + level) / 2, dof))


def nees(err: np.ndarray, cov: np.ndarray, std: np.ndarray) -> float:
    """3-dof NEES of ``err`` (3,) against ``cov`` (3, 3), its diagonal raised to ``max(std, NEES_FLOOR)^2``."""
    P = np.array(cov, dtype=float).reshape(3, 3)
    P[np.diag_indices(3)] = np.maximum(np.diag(P), np.maximum(np.square(np.asarray(std, float)), NEES_FLOOR**2))
    return float(err @ np.linalg.solve(P, err))


def _pipeline(env: Any) -> Any:
    """The env's :class:`slam.core.pipeline.SlamPipeline`."""
    e = env
    while not hasattr(e, "pipeline") or not hasattr(e.pipeline, "measured_drift"):
        e = e.env
    return e.pipeline


def episode(env: Any, seed: int, cycles: int, driver: str = "idm") -> dict[str, Any]:
    """One drive of at most ``cycles`` cycles by ``driver`` (``agents.evaluate.load_policy``: ``idm`` or a
    policy zip); per-cycle NEES of the three models and the drift term."""
    from agents.evaluate import load_policy
    from rhs_common.geometry import wrap_angle

    policy = load_policy(driver, env, seed=seed)
    if callable(getattr(policy, "reset", None)):
        policy.reset()
    obs, info = env.reset(seed=seed)
    pipe = _pipeline(env)
    out: dict[str, list[float]] = {m: [] for m in MODELS}
    err_m: list[float] = []
    lost: list[bool] = []
    parts: list[list[float]] = []  # per cycle: error (3), particle variances (3), measured drift (9), scale,
    #                                heading, map-start term (9)
    for _ in range(cycles):
        action, _ = policy.predict(obs, deterministic=True)
        a = np.asarray(action)
        obs, _, term, trunc, info = env.step(int(a) if a.ndim == 0 else action)
        e = np.asarray(info["estimated_pose"], float) - np.asarray(info["true_pose"], float)
        e[2] = float(wrap_angle(e[2]))
        std_cal = np.asarray(info["slam_pose_std"], float)
        cov_cal = np.asarray(info["slam_pose_cov"], float)
        var = np.square(np.asarray(pipe.slam.last_estimate.pose_std, float))
        cov_const = np.diag(var) + pipe.drift.cov
        cov_adaptive = pipe.residual_scale * (np.diag(var) + pipe.measured_drift.cov)
        parts.append([*e, *var, *pipe.measured_drift.cov.ravel(), pipe.residual_scale, pipe.heading,
                      *pipe.map_start.cov.ravel()])
        std_const = np.sqrt(np.maximum(np.diag(cov_const), 0.0))
        std_adaptive = np.sqrt(np.maximum(np.diag(cov_adaptive), 0.0))
        if info["slam_lost"]:  # the loss's floor (honest_pose_std), the same for all three
            std_const = np.maximum(std_const, std_cal)
            std_adaptive = np.maximum(std_adaptive, std_cal)
        out["calibrated"].append(nees(e, cov_cal, std_cal))
        out["adaptive"].append(nees(e, cov_adaptive, std_adaptive))
        out["drift-constants"].append(nees(e, cov_const, std_const))
        err_m.append(float(info["position_error_m"]))
        lost.append(bool(info["slam_lost"]))
        if term or trunc:
            break
    return {"seed": seed, "cycles": len(err_m), "nees": out, "position_error_m": err_m, "lost": lost,
            "parts": [[float(f"{v:.4g}") for v in row] for row in parts]}  # 4 significant digits: a record


def summarize(runs: list[dict[str, Any]], model: str) -> dict[str, Any]:
    """Coverage below / inside / above the 95 % band, median NEES, ANEES and its 95 % interval over ``runs``
    (:func:`slam.core.pose_calibration.nees_coverage`)."""
    from slam.core.pose_calibration import nees_coverage

    x = np.concatenate([np.asarray(r["nees"][model], float) for r in runs]) if runs else np.zeros(0)
    return nees_coverage(x)


def _calibration(name: str) -> dict[str, Any]:
    """The calibration the configuration's env attached (its factors, key, seeds, cycles)."""
    from slam.gym.pose_calibration import slam_wrapper

    env = _WORKER_ENVS.get(name)
    if env is None:  # the drives ran in worker processes: make one here (it finds the cached calibration)
        _task_env(name)
        env = _WORKER_ENVS[name]
    cal = slam_wrapper(env).pipeline.pose_calibration
    return {} if cal is None else {k: v for k, v in json.loads(cal.to_json()).items() if k != "setup"}


_WORKER_ENVS: dict[str, Any] = {}


def _task_env(name: str) -> None:
    """This process's env of the configuration ``name`` (the calibrated model: its calibration attached)."""
    import gymnasium as gym

    import rhs_env  # noqa: F401

    if name not in _WORKER_ENVS:
        env_id, kw = CONFIGS[name]
        _WORKER_ENVS[name] = gym.make(env_id, **kw, pipeline={"pose_covariance": "calibrated"})


def _prepare(name: str) -> None:
    """Make this process's env of ``name`` (its calibration found, or fitted at first use and cached)."""
    t0 = time.perf_counter()
    _task_env(name)
    print(f"{name}: env and calibration {time.perf_counter() - t0:.0f} s", flush=True)


def _task(task: tuple[str, int, int]) -> dict[str, Any]:
    """One (configuration, seed, cycles) drive on this process's env for the configuration."""
    name, seed, cycles = task
    driver = POLICIES.get(name, "idm")
    _task_env(name)
    t0 = time.perf_counter()
    out = episode(_WORKER_ENVS[name], seed, cycles, driver)
    print(f"{name} seed {seed}: {out['cycles']} cycles, {time.perf_counter() - t0:.0f} s", flush=True)
    return out


def run(configs: list[str], seeds: list[int], cycles: int, workers: int = 1) -> dict[str, Any]:
    """Every (configuration, seed) drive (over ``workers`` processes; an episode does not depend on which
    process ran it) and the summaries per configuration and model."""
    tasks = [(name, seed, cycles) for name in configs for seed in seeds]
    # each configuration's calibration found or fitted (and cached) once, before its drives
    if workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(workers) as pool:
            list(pool.map(_prepare, configs))
            runs = list(pool.map(_task, tasks))
    else:
        for name in configs:
            _prepare(name)
        runs = [_task(t) for t in tasks]
    res: dict[str, Any] = {"nees_band": chi2_band(3), "cycles": cycles, "seeds": seeds, "configs": {}}
    for name in configs:
        mine = [r for t, r in zip(tasks, runs) if t[0] == name]
        env_id, kw = CONFIGS[name]
        res["configs"][name] = {"env_id": env_id, "kwargs": kw, "policy": POLICIES.get(name, "idm"), "runs": mine,
                                "calibration": _calibration(name),
                                "summary": {m: summarize(mine, m) for m in MODELS}}
    return res


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def tail_concentration(config: dict[str, Any], band: tuple[float, float], model: str = "calibrated", worst: int = 3,
                       scales: tuple[float, ...] = (2.0, 4.0, 8.0)) -> dict[str, Any]:
    """How the cycles above the NEES band of one configuration's ``model`` spread over its drives.

    Returns the cycles above the band, those of the ``worst`` drives (most cycles above), the worst drives' seeds
    and median position errors (m), the other drives' median error, the fraction above without the worst drives,
    and, for each ``k`` of ``scales``, the fraction of the worst drives' cycles still above and of the others'
    below once every NEES is divided by ``k`` (every covariance ``k`` times wider).
    """
    lo, hi = band
    drives = [(np.asarray(r["nees"][model], float), np.asarray(r["position_error_m"], float), r["seed"])
              for r in config["runs"]]
    drives.sort(key=lambda d: -int(np.sum(d[0] > hi)))
    bad, rest = drives[:worst], drives[worst:]
    bad_n = np.concatenate([d[0] for d in bad]) if bad else np.zeros(0)
    rest_n = np.concatenate([d[0] for d in rest]) if rest else np.zeros(0)
    return {"above": int(sum(np.sum(d[0] > hi) for d in drives)), "cycles": int(sum(d[0].size for d in drives)),
            "worst_above": int(np.sum(bad_n > hi)), "worst_seeds": [int(d[2]) for d in bad],
            "worst_median_error_m": [float(np.median(d[1])) for d in bad],
            "others_median_error_m": float(np.median([np.median(d[1]) for d in rest])) if rest else None,
            "others_above": float(np.mean(rest_n > hi)) if rest_n.size else None,
            "scaled": [{"k": k, "worst_above": float(np.mean(bad_n / k > hi)), "others_below": float(np.mean(rest_n / k < lo))}
                       for k in scales]}


def _tail_lines(res: dict[str, Any]) -> list[str]:
    """The concentration of the calibrated model's upper tail, for the configurations whose goal it misses."""
    rows = [(name, tail_concentration(c, res["nees_band"])) for name, c in res["configs"].items()
            if c["summary"].get("calibrated", {}).get("cycles") and not c["summary"]["calibrated"]["goal_met"]
            and all("calibrated" in r["nees"] for r in c["runs"])]
    if not rows:
        return []
    lines = ["", "Where the calibrated model misses, its cycles above the band by drive (the 3 drives with the most "
             "of them; `k`: every covariance k times wider, the worst drives' cycles still above / the other drives' "
             "below):", "",
             "| configuration | above (cycles) | of them in the 3 worst drives | their median error (m) | the others' "
             "median error (m) | above without them | " + " | ".join(f"k = {s['k']:g}" for s in rows[0][1]["scaled"])
             + " |", "|---|---:|---:|---|---:|---:|" + "---|" * len(rows[0][1]["scaled"])]
    for name, t in rows:
        errs = " / ".join(f"{e:.3f}" for e in t["worst_median_error_m"])
        lines.append(f"| {name} | {t['above']} of {t['cycles']} | {t['worst_above']} (seeds "
                     f"{', '.join(str(x) for x in t['worst_seeds'])}) | {errs} | {t['others_median_error_m']:.3f} | "
                     f"{_pct(t['others_above'])} | " + " | ".join(f"{_pct(s['worst_above'])} / {_pct(s['others_below'])}"
                                                            for s in t["scaled"]) + " |")
    return lines


def heading_origin(config: dict[str, Any], band: tuple[float, float], at: int = 5, worst: int = 3) -> dict[str, Any] | None:
    """Where one configuration's pose error comes from: the heading error, turned into a cross-track error by the
    distance driven (:mod:`slam.core.drift`'s ``F``), against the heading variance the calibrated model reports.

    From the runs' per-cycle parts (:data:`slam.core.pose_calibration.ROW_COLUMNS` less ``lost``; the road runs
    along x, so the map frame's y error is the cross-track error):

    * ``r2`` / ``slope_m``: the least-squares line of each drive's last cross-track error on its mean heading error
      over the drive (``y_end ~ slope h_mean``; ``slope`` is a distance, m) and its R^2 over the drives;
    * ``spread_rad`` / ``reported_rad`` / ``ratio``: at cycle ``at`` (and at the last cycle, ``*_end``), the RMS over
      the drives of the heading error against the median heading std the calibrated model reports
      (:func:`slam.core.pose_calibration.calibrated_covariance` with the configuration's factors);
    * ``worst_z`` / ``others_z``: the median |heading error| / reported heading std over the first 10 cycles of the
      ``worst`` drives (most cycles above the NEES band) and the median of it over the other drives.

    None without a calibration or without complete drives.
    """
    from slam.core.pose_calibration import calibrated_covariance

    k = config.get("calibration") or {}
    runs = [r for r in config["runs"] if r.get("parts") and "calibrated" in r["nees"]]
    if not k or not runs:
        return None
    factors = np.array([k["particles"], k["along"], k["cross"], k["heading"], k.get("map_heading", 0.0)], float)
    last = min(len(r["parts"]) for r in runs) - 1
    at = min(at, last)
    h_err, h_std, y_end, h_mean, above = [], [], [], [], []
    for r in runs:
        P = np.asarray(r["parts"], float)
        std = np.sqrt([calibrated_covariance(row[3:6], row[6:15].reshape(3, 3), row[16], row[15], factors,
                                             row[17:26].reshape(3, 3) if len(row) >= 26 else None)[2, 2]
                       for row in P])
        h_err.append(P[:, 2])
        h_std.append(std)
        y_end.append(P[last, 1])
        h_mean.append(P[: last + 1, 2].mean())
        above.append(int(np.sum(np.asarray(r["nees"]["calibrated"]) > band[1])))
    y, h = np.asarray(y_end), np.asarray(h_mean)
    slope = float(h @ y / max(h @ h, 1e-30))
    r2 = float(np.corrcoef(h, y)[0, 1] ** 2) if len(runs) > 2 else float("nan")
    z = [float(np.median(np.abs(e[:10]) / np.maximum(sd[:10], 1e-12))) for e, sd in zip(h_err, h_std, strict=True)]
    order = np.argsort(above)[::-1]
    out: dict[str, Any] = {"drives": len(runs), "r2": r2, "slope_m": slope, "at": at,
                           "worst_z": [z[i] for i in order[:worst]], "others_z": float(np.median([z[i] for i in order[worst:]]))}
    for name, t in (("", at), ("_end", last)):
        spread = float(np.sqrt(np.mean([e[t] ** 2 for e in h_err])))
        reported = float(np.median([sd[t] for sd in h_std]))
        out.update({f"spread_rad{name}": spread, f"reported_rad{name}": reported, f"ratio{name}": spread / reported})
    return out


def _heading_lines(res: dict[str, Any]) -> list[str]:
    """The heading's share of the pose error per configuration (:func:`heading_origin`)."""
    found = [(name, heading_origin(c, res["nees_band"])) for name, c in res["configs"].items()]
    rows = [(name, h) for name, h in found if h is not None]
    if not rows:
        return []
    at = rows[0][1]["at"]
    lines = ["", "Where the error comes from (`heading_origin`): the last cycle's cross-track error of each drive "
             "against its mean heading error (R^2 over the drives, and the fitted distance), and the heading error's "
             f"RMS over the drives against the calibrated model's median heading std, at cycle {at} and at the end; "
             "`z`: median |heading error| / reported std over the first 10 cycles, the 3 drives with the most cycles "
             "above the band and the others' median:", "",
             "| configuration | R^2 (cross-track ~ heading) | distance (m) | heading error RMS / reported std, "
             f"cycle {at} (mrad) | at the end (mrad) | z, 3 worst drives | z, the others |",
             "|---|---:|---:|---|---|---|---:|"]
    for name, h in rows:
        lines.append(f"| {name} | {h['r2']:.2f} | {h['slope_m']:.0f} | {1e3 * h['spread_rad']:.2f} / "
                     f"{1e3 * h['reported_rad']:.2f} ({h['ratio']:.2f} x) | {1e3 * h['spread_rad_end']:.2f} / "
                     f"{1e3 * h['reported_rad_end']:.2f} ({h['ratio_end']:.2f} x) | "
                     + " / ".join(f"{v:.1f}" for v in h["worst_z"]) + f" | {h['others_z']:.2f} |")
    return lines


def halves(config: dict[str, Any], model: str = "calibrated") -> list[dict[str, Any]]:
    """``model``'s coverage (:func:`summarize`) on the first and on the second half of one configuration's runs (in
    seed order): how much the figures move between two sets of drives of the same configuration."""
    runs = sorted(config["runs"], key=lambda r: r["seed"])
    half = len(runs) // 2
    return [{"seeds": [part[0]["seed"], part[-1]["seed"]], **summarize(part, model)}
            for part in (runs[:half], runs[half:]) if part and all(model in r["nees"] for r in part)]


def drive_intervals(config: dict[str, Any], model: str = "calibrated", draws: int = 2000, level: float = 0.95,
                    seed: int = 0) -> dict[str, list[float]]:
    """Percentile intervals of ``model``'s fractions below / inside / above the band over one configuration's
    drives: the drives resampled with replacement (``draws`` times, a fixed ``seed``), each keeping all its cycles.
    Successive cycles of a drive are correlated, so the drive, not the cycle, is the independent unit."""
    lo, hi = chi2_band(3)
    per = [np.asarray(r["nees"][model], float) for r in config["runs"] if model in r["nees"]]
    if len(per) < 2:
        return {}
    counts = np.array([[np.sum(x < lo), np.sum((x >= lo) & (x <= hi)), np.sum(x > hi), x.size] for x in per], float)
    pick = np.random.default_rng(seed).integers(0, len(per), size=(draws, len(per)))
    sums = counts[pick].sum(axis=1)  # (draws, 4)
    fr = sums[:, :3] / sums[:, 3:4]
    q = np.quantile(fr, [(1 - level) / 2, (1 + level) / 2], axis=0)
    return {k: [float(q[0, i]), float(q[1, i])] for i, k in enumerate(("below", "inside", "above"))}


def _halves_lines(res: dict[str, Any]) -> list[str]:
    """The calibrated model's coverage with its intervals over drives (:func:`drive_intervals`) and on each half of
    the seeds (:func:`halves`), when there are at least 2 runs."""
    rows = [(name, c, halves(c)) for name, c in res["configs"].items() if len(c["runs"]) >= 2]
    rows = [(name, c, h) for name, c, h in rows if len(h) == 2]
    if not rows:
        return []
    (a, b) = rows[0][2]
    lines = ["", "The calibrated model's coverage with 95 % intervals over drives (the drives resampled, each with all "
             "its cycles: successive cycles are correlated), and on each half of the held-out seeds (below / inside / "
             "above; goal met or not):", "",
             f"| configuration | inside [95 %] | above [95 %] | seeds {a['seeds'][0]}-{a['seeds'][1]} | seeds "
             f"{b['seeds'][0]}-{b['seeds'][1]} |", "|---|---|---|---|---|"]
    for name, c, h in rows:
        ci = drive_intervals(c)
        s = c["summary"]["calibrated"]
        lines.append(f"| {name} | {_pct(s['inside'])} [{_pct(ci['inside'][0])}, {_pct(ci['inside'][1])}] | "
                     f"{_pct(s['above'])} [{_pct(ci['above'][0])}, {_pct(ci['above'][1])}] | " + " | ".join(
            f"{_pct(x['below'])} / {_pct(x['inside'])} / {_pct(x['above'])} ({'met' if x['goal_met'] else 'not met'})"
            for x in h) + " |")
    return lines


def markdown(res: dict[str, Any]) -> str:
    """The results table: per configuration and model, coverage below / inside / above, median NEES, ANEES;
    then each configuration's calibration (factors, calibration seeds)."""
    lo, hi = res["nees_band"]
    seeds = res["seeds"]
    lines = [
        "# Pose covariance per radar configuration", "",
        f"IDM + MOBIL drives (`policy_env`: the shipped policy) of up to {res['cycles']} cycles, held-out seeds {seeds[0]}-{seeds[-1]} "
        f"({len(seeds)} per configuration). 3-dof NEES of the estimated minus the true pose against the "
        f"reported covariance; 95 % band [{lo:.3f}, {hi:.2f}]. `calibrated`: `pipeline={{\"pose_covariance\": "
        "\"calibrated\"}` (the adaptive model's terms scaled by the configuration's own calibration, fitted on "
        "other seeds); `adaptive`: the drift's increment measured each cycle, unscaled; `drift-constants`: the "
        "default (densities per metre fitted on the 5-degree grid). Goal: inside >= 90 %, neither tail above 7 %, "
        "ANEES inside its interval (the interval assumes independent cycles).", "",
        "| configuration | model | cycles | below | inside | above | median NEES | ANEES [95 % interval] | coverage goal |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, c in res["configs"].items():
        for m in MODELS:
            s = c["summary"].get(m, {})
            if not s.get("cycles"):
                continue
            a_lo, a_hi = s["anees_interval"]
            lines.append(f"| {name} | {m} | {s['cycles']} | {_pct(s['below'])} | {_pct(s['inside'])} | "
                         f"{_pct(s['above'])} | {s['median']:.2f} | {s['anees']:.2f} [{a_lo:.2f}, {a_hi:.2f}]"
                         f"{'' if s['anees_inside'] else ' (outside)'} | {'met' if s['goal_met'] else 'not met'} |")
    lines += _halves_lines(res)
    lines += _tail_lines(res)
    lines += _heading_lines(res)
    lines += ["", "Calibrations (`k_p`, `k_along`, `k_cross`, `k_heading`, and the map-start heading std `sqrt(k_map)`; "
              "the model: `slam.core.pose_calibration`):", "",
              "| configuration | key | k_p | k_along | k_cross | k_heading | sqrt(k_map) (mrad) | calibration seeds | "
              "cycles per drive |", "|---|---|---|---|---|---|---|---|---|"]
    for name, c in res["configs"].items():
        k = c.get("calibration") or {}
        if k:
            cs = k.get("seeds", [])
            lines.append(f"| {name} | `{k['key']}` | {k['particles']:.3g} | {k['along']:.3g} | {k['cross']:.3g} | "
                         f"{k['heading']:.3g} | {1e3 * math.sqrt(k.get('map_heading', 0.0)):.3g} | {cs[0]}-{cs[-1]} | "
                         f"{k['cycles']} |" if cs else f"| {name} | - |")
    return "\n".join(lines) + "\n"


def _merge(paths: list[str], out: Path, argv: list[str] | None, name: str = "pose_covariance") -> int:
    """Write one results file from several runs' (disjoint configurations, the same seeds and cycles); a merged
    file among them brings the provenance of each run it was made of."""
    from rhs_common.output_files import write_text_atomic

    parts = [json.loads(Path(q).read_text()) for q in paths]
    first = parts[0]
    if any(r["seeds"] != first["seeds"] or r["cycles"] != first["cycles"] for r in parts):
        raise SystemExit("--merge: the runs differ in seeds or cycles")
    res: dict[str, Any] = {"nees_band": first["nees_band"], "cycles": first["cycles"], "seeds": first["seeds"],
                           "configs": {}, "runs_provenance": [p for r in parts for p in r.get("runs_provenance", [r["provenance"]])]}
    for r in parts:
        res["configs"].update(r["configs"])
    out.mkdir(parents=True, exist_ok=True)
    config = {"merged": [str(q) for q in paths], "configs": list(res["configs"])}
    res["provenance"] = write_json(out / f"{name}.json", res, __file__, config, time.time(), argv=argv)
    write_text_atomic(out / f"{name}.md", markdown(res))
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    p.add_argument("--seeds", nargs="+", type=int, default=list(SEEDS))
    p.add_argument("--cycles", type=int, default=150, help="cycles per drive (default 150)")
    p.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    p.add_argument("--out-dir", default="results")
    p.add_argument("--name", default="pose_covariance", help="the results files' stem (default pose_covariance)")
    p.add_argument("--merge", nargs="+", metavar="JSON", help="combine the configurations of earlier runs' "
                   "pose_covariance.json (same seeds and cycles; each run's provenance kept) instead of driving")
    a = p.parse_args(argv)
    if a.merge:
        return _merge(a.merge, Path(a.out_dir), argv, a.name)
    if a.cycles < 1:
        p.error(f"--cycles must be >= 1, got {a.cycles}")
    if a.workers < 1:
        p.error(f"--workers must be >= 1, got {a.workers}")
    started = time.time()
    res = run(a.configs, a.seeds, a.cycles, a.workers)
    out = Path(a.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    config = {"configs": a.configs, "seeds": a.seeds, "cycles": a.cycles}
    res["provenance"] = write_json(out / f"{a.name}.json", res, __file__, config, started, argv=argv)
    (out / f"{a.name}.md").write_text(markdown(res))
    print(json.dumps({k: {m: {kk: v for kk, v in c["summary"][m].items() if kk != "anees_interval"}
                          for m in MODELS} for k, c in res["configs"].items()}, indent=1))
    return 0 if all(math.isfinite(c["summary"]["adaptive"].get("anees", 0.0)) for c in res["configs"].values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
