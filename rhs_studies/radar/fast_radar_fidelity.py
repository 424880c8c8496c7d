"""Fast radar fidelity: the fast radar (``radar_model="fast"``) against the exact radar on the same scenes.

``python scripts/fast_radar_fidelity.py [--seeds 60] [--steps 40] [--slam-seeds 20] [--slam-steps 100]
[--out results/fast_radar_fidelity.json]`` (the page ``docs/results/fast-radar.md`` reads the Markdown beside it).

* **Radar** (scene seeds 200000 on, disjoint from the calibration's 100000-100099): along highway episodes (random
  meta-actions, mostly IDLE) every scene is scanned by both radars (the same scatterers; each its own generator)
  and both clouds are matched to the visible scatterers the same way
  (:func:`rhs_env.fast_radar_calibration.match_scan`). Compared:

  - detection probability per 5 dB bin of expected SNR, per scatterer class (moving, static): within 0.03
    absolute on every bin with >= :data:`MIN_TRIALS` pairs in both (the others are listed with their interval);
  - false points per scan, and ghosts in the ego's path (false points at 0 < x <= 40 m, |y| <= 2 m, vehicle
    frame) per scan: the fast mean inside the exact mean's 95 % interval (bootstrap over episodes);
  - per-point range, angle and Doppler errors of the detected pairs: two-sample Kolmogorov-Smirnov on 2,000 points
    drawn from each, p > 0.01;
  - the scan time, ms per 4-radar scan (median), exact and fast.

* **SLAM** (seeds 300000 on): ``rhs-highway-slam-v0`` with ``radar_model="exact"`` and ``"fast"`` on the same
  seeds, the same traffic (``sim="highway-env"`` for both) and the same actions (IDLE), the default SLAM; the
  position RMSE of each episode; the mean over the seeds within 15 %.

* **Throughput**: ``rhs-highway-slam-fast-v0`` (fast radar, compiled traffic), ``rhs-highway-slam-v0`` and
  highway-env's ``highway-fast-v0`` stepped round-robin in this process (IDLE), steps/s.

The shipped policy's return is not measured here (see the results page).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from rhs_studies.kit.provenance import write_json
from rhs_studies.kit.seeds import first

__all__ = ["fingerprint", "main", "markdown", "radar_fidelity", "slam_fidelity", "throughput"]

#: acceptance (module docstring)
PD_TOL, KS_P_MIN, SLAM_RMSE_TOL = 0.03, 0.01, 0.15
#: a P_d bin is compared when both radars measured at least this many pairs in it: below, the binomial spread of
#: the difference alone (two independent draws per pair, P_d ~ 0.7) reaches the 0.03 tolerance at 2 sigma
MIN_TRIALS = 1500
PD_BIN_DB = 5.0
KS_POINTS = 2000
#: ghosts: false points in the ego's lane ahead (vehicle frame)
GHOST_X_M, GHOST_Y_M = 40.0, 2.0
RADAR_FIRST_SEED, SLAM_FIRST_SEED = first("fast_radar_fidelity"), first("fast_radar_slam")


def _scan_pair(config: Any, seeds: list[int], steps: int) -> dict[str, Any]:
    """Both radars on every scene of the episodes: per scan records, per episode index, and scan times."""
    from rhs_env.fast_radar import FastRadarSystem
    from rhs_env.fast_radar_calibration import calibration_scenes, match_scan
    from rhs_env.radar import RadarSystem
    from rhs_env.scene import ScatterConfig, scene_scatterers

    exact = RadarSystem(config, np.random.default_rng(0))
    fast = FastRadarSystem(config, np.random.default_rng(0))
    scatter = ScatterConfig.make(None)
    out: dict[str, Any] = {"exact": [], "fast": [], "episode": [], "t_exact": [], "t_fast": []}
    for seed, t, env in calibration_scenes(seeds, steps):
        if t == 0:
            exact.rng, fast.rng = np.random.default_rng([seed, 11]), np.random.default_rng([seed, 13])
        sc, occ = scene_scatterers(env, env.unwrapped.vehicle, scatter, config.kernels)
        t0 = time.perf_counter()
        c_exact = exact.scan(sc, occ)
        t1 = time.perf_counter()
        c_fast = fast.scan(sc, occ)
        t2 = time.perf_counter()
        out["t_exact"].append(t1 - t0)
        out["t_fast"].append(t2 - t1)
        out["exact"].append(match_scan(exact, c_exact, sc, occ))
        out["fast"].append(match_scan(fast, c_fast, sc, occ))
        out["episode"].append(seed)
    return out


def _pd_bins(records: list, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(hits, trials) per class (0 moving, 1 static) and SNR bin."""
    snr = np.concatenate([r.snr_db for r in records]) if records else np.zeros(0)
    cls = np.concatenate([r.static for r in records]).astype(int) if records else np.zeros(0, int)
    det = np.concatenate([r.detected for r in records]) if records else np.zeros(0, bool)
    b = np.clip(np.digitize(snr, edges) - 1, 0, edges.size - 2)
    hits, trials = np.zeros((2, edges.size - 1)), np.zeros((2, edges.size - 1))
    np.add.at(trials, (cls, b), 1)
    np.add.at(hits, (cls, b), det)
    return hits, trials


def _pd_diff_ci(runs: dict[str, Any], edges: np.ndarray, rng: np.random.Generator,
                n_boot: int = 1000) -> np.ndarray:
    """(2, 2, B) 95 % interval of P_d fast - P_d exact per class and bin, bootstrapping episodes (paired: the same
    scenes for both)."""
    episode = np.array(runs["episode"])
    ids = np.unique(episode)
    per = [(_pd_bins([r for r, e in zip(runs["exact"], episode, strict=True) if e == i], edges),
            _pd_bins([r for r, e in zip(runs["fast"], episode, strict=True) if e == i], edges)) for i in ids]
    he = np.stack([p[0][0] for p in per])
    te = np.stack([p[0][1] for p in per])
    hf = np.stack([p[1][0] for p in per])
    tf = np.stack([p[1][1] for p in per])
    pick = rng.integers(0, ids.size, (n_boot, ids.size))
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # bins no episode reached: NaN
        diff = hf[pick].sum(1) / tf[pick].sum(1) - he[pick].sum(1) / te[pick].sum(1)
        return np.stack([np.nanquantile(diff, 0.025, axis=0), np.nanquantile(diff, 0.975, axis=0)])


def _per_scan(records: list) -> dict[str, np.ndarray]:
    """False points and ghosts of each scan."""
    ghosts = [int(np.sum((r.false_xy[:, 0] > 0) & (r.false_xy[:, 0] <= GHOST_X_M)
                         & (np.abs(r.false_xy[:, 1]) <= GHOST_Y_M))) for r in records]
    return {"false": np.array([r.false_points.shape[0] for r in records], float), "ghosts": np.array(ghosts, float)}


def _episode_ci(values: np.ndarray, episode: np.ndarray, rng: np.random.Generator, n_boot: int = 2000) -> list[float]:
    """95 % interval of the per-scan mean, bootstrapping episodes (scans of one episode are not independent)."""
    ids = np.unique(episode)
    sums = np.array([values[episode == e].sum() for e in ids])
    counts = np.array([np.sum(episode == e) for e in ids])
    pick = rng.integers(0, ids.size, (n_boot, ids.size))
    means = sums[pick].sum(axis=1) / counts[pick].sum(axis=1)
    return [float(np.quantile(means, 0.025)), float(np.quantile(means, 0.975))]


def radar_fidelity(seeds: list[int], steps: int, config: Any = None) -> dict[str, Any]:
    """The radar part of the module docstring on the episodes of ``seeds``."""
    from scipy import stats

    from rhs_env.radar import RadarConfig

    config = config or RadarConfig()
    runs = _scan_pair(config, seeds, steps)
    rng = np.random.default_rng(0)
    edges = np.arange(-10.0, 100.0 + PD_BIN_DB, PD_BIN_DB)
    he, te = _pd_bins(runs["exact"], edges)
    hf, tf = _pd_bins(runs["fast"], edges)
    pd_ci = _pd_diff_ci(runs, edges, rng)
    bins = []
    for c, name in ((0, "moving"), (1, "static")):
        for b in range(edges.size - 1):
            if te[c, b] == 0 and tf[c, b] == 0:
                continue
            row: dict[str, Any] = {"class": name, "snr_db": [float(edges[b]), float(edges[b + 1])], "trials_exact": int(te[c, b]),
                   "trials_fast": int(tf[c, b]), "pd_exact": float(he[c, b] / max(te[c, b], 1)),
                   "pd_fast": float(hf[c, b] / max(tf[c, b], 1))}
            row["compared"] = bool(te[c, b] >= MIN_TRIALS and tf[c, b] >= MIN_TRIALS)
            row["diff"] = row["pd_fast"] - row["pd_exact"]
            row["diff_ci95"] = [float(pd_ci[0, c, b]), float(pd_ci[1, c, b])]
            bins.append(row)
    compared = [r for r in bins if r["compared"]]
    pooled = {name: {"pd_exact": float(he[c].sum() / max(te[c].sum(), 1)),
                     "pd_fast": float(hf[c].sum() / max(tf[c].sum(), 1)), "pairs": int(te[c].sum())}
              for c, name in ((0, "moving"), (1, "static"))}
    episode = np.array(runs["episode"])
    scans: dict[str, Any] = {}
    pe, pf = _per_scan(runs["exact"]), _per_scan(runs["fast"])
    for key in ("false", "ghosts"):
        ci = _episode_ci(pe[key], episode, rng)
        mean_f = float(pf[key].mean())
        scans[key] = {"exact_mean": float(pe[key].mean()), "exact_ci95": ci, "fast_mean": mean_f,
                      "fast_ci95": _episode_ci(pf[key], episode, rng), "inside": bool(ci[0] <= mean_f <= ci[1])}
    ks: dict[str, dict[str, Any]] = {}
    err_e = np.concatenate([r.errors[r.detected] for r in runs["exact"]])
    err_f = np.concatenate([r.errors[r.detected] for r in runs["fast"]])
    for j, name in enumerate(("range_m", "angle_rad", "doppler_mps")):
        a = err_e[rng.choice(err_e.shape[0], min(KS_POINTS, err_e.shape[0]), replace=False), j]
        b = err_f[rng.choice(err_f.shape[0], min(KS_POINTS, err_f.shape[0]), replace=False), j]
        res = stats.ks_2samp(a, b)
        ks[name] = {"points": [int(a.size), int(b.size)], "statistic": float(res.statistic), "p": float(res.pvalue),
                    "exact_std": float(np.std(a)), "fast_std": float(np.std(b)),
                    "exact_median_abs": float(np.median(np.abs(a))), "fast_median_abs": float(np.median(np.abs(b)))}
    timing = {"exact_ms": float(1e3 * np.median(runs["t_exact"])), "fast_ms": float(1e3 * np.median(runs["t_fast"]))}
    timing["speedup"] = timing["exact_ms"] / timing["fast_ms"]
    passes = {
        "pd": bool(compared) and all(abs(r["diff"]) <= PD_TOL for r in compared),
        "false_points": scans["false"]["inside"],
        "ghosts": scans["ghosts"]["inside"],
        "ks": all(v["p"] > KS_P_MIN for v in ks.values()),
    }
    return {"seeds": [seeds[0], seeds[-1]], "episodes": len(seeds), "scans": len(runs["episode"]),
            "pairs_exact": int(te.sum()), "pairs_fast": int(tf.sum()),
            "pd_bins": bins, "pd_pooled": pooled, "min_trials": MIN_TRIALS,
            "pd_max_abs_diff": max((abs(r["diff"]) for r in compared), default=None),
            "per_scan": scans, "ks": ks, "scan_time": timing, "passes": passes}


def _slam_episode(model: str, seed: int, steps: int) -> dict[str, float]:
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids)

    env = gym.make("rhs-highway-slam-v0", radar_model=model)
    try:
        env.reset(seed=seed)
        err = []
        for _ in range(steps):
            _, _, term, trunc, info = env.step(1)
            err.append(info["position_error_m"])
            if term or trunc:
                break
    finally:
        env.close()
    e = np.asarray(err)
    return {"rmse_m": float(np.sqrt(np.mean(e ** 2))), "final_m": float(e[-1]), "steps": int(e.size)}


def slam_rows(seeds: list[int], steps: int) -> list[dict[str, Any]]:
    """Both radars' SLAM episodes on ``seeds`` (one row per seed)."""
    rows: list[dict[str, Any]] = []
    for seed in seeds:
        ex, fa = _slam_episode("exact", seed, steps), _slam_episode("fast", seed, steps)
        rows.append({"seed": seed, "exact": ex, "fast": fa})
        print(json.dumps(rows[-1]), flush=True)
    return rows


def slam_fidelity(seeds: list[int], steps: int, rows: list[dict[str, Any]] | None = None) -> dict[str, Any]:
    """The SLAM part of the module docstring (``rows``: :func:`slam_rows` already run, e.g. in workers)."""
    rows = slam_rows(seeds, steps) if rows is None else sorted(rows, key=lambda r: r["seed"])
    re_ = np.array([r["exact"]["rmse_m"] for r in rows])
    rf = np.array([r["fast"]["rmse_m"] for r in rows])
    rng = np.random.default_rng(1)
    pick = rng.integers(0, len(rows), (2000, len(rows)))
    ratio_boot = rf[pick].mean(axis=1) / re_[pick].mean(axis=1)
    ratio = float(rf.mean() / re_.mean())
    return {"seeds": [seeds[0], seeds[-1]], "episodes": rows, "steps": steps, "mean_rmse_exact_m": float(re_.mean()),
            "mean_rmse_fast_m": float(rf.mean()), "ratio": ratio,
            "ratio_ci95": [float(np.quantile(ratio_boot, 0.025)), float(np.quantile(ratio_boot, 0.975))],
            "passes": bool(abs(ratio - 1) <= SLAM_RMSE_TOL),
            "config": "rhs-highway-slam-v0 defaults (SLAM, registration), sim='highway-env', IDLE actions"}


def throughput(steps: int = 100, rounds: int = 3) -> dict[str, Any]:
    """Steps/s of the fast SLAM env, the exact SLAM env and highway-fast-v0, round-robin in this process."""
    import gymnasium as gym
    import highway_env  # noqa: F401  (registers highway-fast-v0)

    import rhs_env  # noqa: F401

    ids: dict[str, dict[str, Any]] = {"rhs-highway-slam-fast-v0": {}, "rhs-highway-slam-v0": {}, "highway-fast-v0": {}}
    envs = {k: gym.make(k, **v) for k, v in ids.items()}
    for env in envs.values():  # warm: kernels loaded, first scans done
        env.reset(seed=0)
        for _ in range(5):
            env.step(1)
    times = dict.fromkeys(envs, 0.0)
    counts = dict.fromkeys(envs, 0)
    for r in range(rounds):
        for k, env in envs.items():
            env.reset(seed=1000 + r)
            t0 = time.perf_counter()
            for _ in range(steps):
                _, _, term, trunc, _ = env.step(1)
                counts[k] += 1
                if term or trunc:
                    env.reset(seed=2000 + counts[k])
            times[k] += time.perf_counter() - t0
    for env in envs.values():
        env.close()
    sps = {k: counts[k] / times[k] for k in envs}
    return {"steps_per_s": sps, "steps": steps, "rounds": rounds,
            "fast_over_highway_fast": sps["rhs-highway-slam-fast-v0"] / sps["highway-fast-v0"],
            "exact_over_highway_fast": sps["rhs-highway-slam-v0"] / sps["highway-fast-v0"],
            "load_average": list(os.getloadavg()),
            "note": "IDLE actions; resets inside the timed loop counted in (episode ends); the ratios are what this "
                    "process measured round-robin, beside the other parts' workers"}


def fingerprint() -> list[float]:
    """Small config: both radars on one 4-step episode (seed 200000): points, detections, false points."""
    from rhs_env.radar import RadarConfig

    runs = _scan_pair(RadarConfig(), [RADAR_FIRST_SEED], 4)
    out: list[float] = []
    for key in ("exact", "fast"):
        for r in runs[key]:
            out += [float(r.detected.sum()), float(r.false_points.shape[0]), float(np.nansum(r.errors[:, 0]))]
    return out


def markdown(result: dict[str, Any]) -> str:
    """The results tables (``results/fast_radar_fidelity.md``)."""
    rad = result["radar"]
    lines = [f"Radar: {rad['episodes']} episodes, {rad['scans']} scans (scene seeds {rad['seeds'][0]}-"
             f"{rad['seeds'][1]}), {rad['pairs_exact']} visible (radar, scatterer) pairs.", "",
             "| check | exact | fast | acceptance | passes |", "|---|---|---|---|---|"]
    mx = rad["pd_max_abs_diff"]
    n_cmp = sum(r["compared"] for r in rad["pd_bins"])
    lines.append(f"| detection probability, max abs diff over {n_cmp} bins of 5 dB | | "
                 f"{mx if mx is None else f'{mx:.3f}'} | <= {PD_TOL} | {_yes(rad['passes']['pd'])} |")
    for key, name in (("false", "false points per scan"), ("ghosts", "ghosts in the ego's path (40 m) per scan")):
        s = rad["per_scan"][key]
        lines.append(f"| {name} | {s['exact_mean']:.3f} [{s['exact_ci95'][0]:.3f}, {s['exact_ci95'][1]:.3f}] "
                     f"| {s['fast_mean']:.3f} | inside the exact 95 % interval | {_yes(s['inside'])} |")
    for key, name in (("range_m", "range error (m)"), ("angle_rad", "angle error (rad)"),
                      ("doppler_mps", "Doppler error (m/s)")):
        k = rad["ks"][key]
        lines.append(f"| {name}: KS p on {k['points'][0]} + {k['points'][1]} points (std exact / fast "
                     f"{k['exact_std']:.3g} / {k['fast_std']:.3g}) | | p = {k['p']:.3f} | > {KS_P_MIN} "
                     f"| {_yes(k['p'] > KS_P_MIN)} |")
    t = rad["scan_time"]
    lines.append(f"| scan time, ms per 4-radar scan (median) | {t['exact_ms']:.2f} | {t['fast_ms']:.3f} "
                 f"| ({t['speedup']:.0f}x) | |")
    slam = result.get("slam")
    if slam:
        lines.append(f"| SLAM position RMSE, mean of {len(slam['episodes'])} paired seeds x {slam['steps']} steps (m) "
                     f"| {slam['mean_rmse_exact_m']:.3f} | {slam['mean_rmse_fast_m']:.3f} (ratio {slam['ratio']:.3f}, "
                     f"95 % [{slam['ratio_ci95'][0]:.3f}, {slam['ratio_ci95'][1]:.3f}]) | within {SLAM_RMSE_TOL:.0%} "
                     f"| {_yes(slam['passes'])} |")
    lines.append("| shipped policy's return | | not measured | within its paired interval | |")
    thr = result.get("throughput")
    if thr:
        lines += ["", "| env (same process, round-robin, IDLE) | steps/s |", "|---|---|"]
        for k, v in thr["steps_per_s"].items():
            lines.append(f"| {k} | {v:.1f} |")
        lines.append(f"| rhs-highway-slam-fast-v0 / highway-fast-v0 | {thr['fast_over_highway_fast']:.2f}x |")
        lines.append(f"| rhs-highway-slam-v0 / highway-fast-v0 | {thr['exact_over_highway_fast']:.2f}x |")
        lines.append("")
        lines.append(f"Load average during the throughput part: {thr['load_average'][0]:.1f} (1 min) on the 2-core "
                     "machine; the steps/s are low in absolute terms, the ratios are round-robin in one process.")
    lines += ["", f"Detection probability per 5 dB bin of expected SNR (compared: >= {rad['min_trials']} pairs; the "
              "interval bootstraps the episodes, paired):", "",
              "| class | SNR (dB) | pairs exact / fast | P_d exact | P_d fast | diff [95 %] | compared |",
              "|---|---|---|---|---|---|---|"]
    for r in rad["pd_bins"]:
        if r["trials_exact"] >= 100:
            lo, hi = r["diff_ci95"]
            lines.append(f"| {r['class']} | {r['snr_db'][0]:.0f}-{r['snr_db'][1]:.0f} | {r['trials_exact']} / "
                         f"{r['trials_fast']} | {r['pd_exact']:.3f} | {r['pd_fast']:.3f} | {r['diff']:+.3f} "
                         f"[{lo:+.3f}, {hi:+.3f}] | {'yes' if r['compared'] else 'no'} |")
    for name, v in rad["pd_pooled"].items():
        lines.append(f"| {name}, all SNR | | {v['pairs']} | {v['pd_exact']:.3f} | {v['pd_fast']:.3f} "
                     f"| {v['pd_fast'] - v['pd_exact']:+.3f} | |")
    return "\n".join(lines) + "\n"


def _yes(ok: bool) -> str:
    return "yes" if ok else "**no**"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=60, help="radar episodes")
    p.add_argument("--steps", type=int, default=40)
    p.add_argument("--slam-seeds", type=int, default=20)
    p.add_argument("--slam-steps", type=int, default=100)
    p.add_argument("--throughput-steps", type=int, default=100)
    p.add_argument("--workers", type=int, default=1,
                   help="processes for the parts (radar, SLAM halves, throughput); the numbers do not depend on it")
    p.add_argument("--out", default="results/fast_radar_fidelity.json")
    a = p.parse_args(argv)
    if min(a.seeds, a.steps) < 1 or min(a.slam_seeds, a.slam_steps, a.throughput_steps) < 0:
        p.error("--seeds and --steps must be >= 1; the SLAM and throughput counts >= 0 (0 skips the part)")
    started = time.time()
    radar_seeds = list(range(RADAR_FIRST_SEED, RADAR_FIRST_SEED + a.seeds))
    slam_seeds = list(range(SLAM_FIRST_SEED, SLAM_FIRST_SEED + a.slam_seeds)) if a.slam_steps else []
    result: dict[str, Any] = {}
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=max(1, a.workers)) as pool:
        jobs = {"radar": pool.submit(radar_fidelity, radar_seeds, a.steps)}
        half = (len(slam_seeds) + 1) // 2
        slam_jobs = [pool.submit(slam_rows, chunk, a.slam_steps) for chunk in (slam_seeds[:half], slam_seeds[half:])
                     if chunk]
        if a.throughput_steps:
            jobs["throughput"] = pool.submit(throughput, a.throughput_steps)
        result["radar"] = jobs["radar"].result()
        print(json.dumps({k: result["radar"][k] for k in ("scans", "pd_max_abs_diff", "per_scan", "ks", "scan_time",
                                                           "passes")}), flush=True)
        if slam_jobs:
            rows = [r for j in slam_jobs for r in j.result()]
            result["slam"] = slam_fidelity(slam_seeds, a.slam_steps, rows)
        if "throughput" in jobs:
            result["throughput"] = jobs["throughput"].result()
    result["policy_return"] = "not measured"
    result["passes"] = all(result["radar"]["passes"].values()) and result.get("slam", {}).get("passes", True)
    out = Path(a.out)
    final = a.seeds == 60 and a.steps == 40 and a.slam_seeds == 20 and a.slam_steps == 100
    write_json(out, result, __file__, a, started, fingerprint_fn=fingerprint if final else None, argv=argv)
    out.with_suffix(".md").write_text(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
