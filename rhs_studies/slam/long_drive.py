"""A long drive: 3,000 cycles (10 minutes) of the highway SLAM env, no loop closure, per seed.

``python scripts/long_drive.py [--seeds 1700 1701 1702] [--cycles 3000] [--speed 15] [--out-dir results]``

``rhs-highway-slam-v0`` at its defaults (the exact radar, traffic, the default SLAM) but for the scan grid
(``--grid-deg``, default 5 degrees: the cheap configuration of the roads' results; the env's default is 1), the
episode's length set by the env's ``duration`` (``cycles / 5`` s), the ego driven by highway-env's IDM + MOBIL
(:class:`agents.evaluate.IDMMobilPolicy`) at a target speed of ``--speed`` m/s: highway-env's highway is one
straight road of 10 km, and 600 s at 15 m/s (9 km) stay on it (at the road's 30 m/s the car would leave the road,
and its landmarks, after about 330 s). Per cycle: the position error, the 3-dof NEES of ``info["slam_pose_cov"]``
(:func:`rhs_studies.kit.slam_metrics.pose_nees`), the wall time of ``env.step`` and of the SLAM's stages, the
landmark slots in use (of the filter's ``max_landmarks``), the landmarks in the estimate and in the archive, the
process's resident memory. Reported per seed and pooled:

* NEES inside its 95 % chi-square band (3 dof) over the whole drive (target >= 90 %);
* KITTI's translational drift (%) over 100-800 m segments (:func:`rhs_studies.kit.slam_metrics.segment_drift`;
  target <= 0.05 %), with the rotational drift (deg / 100 m) and the final position error;
* memory: the landmark slots' peak (bounded by ``max_landmarks``: the filter prunes landmarks not re-observed for
  ``prune_after_cycles``), the archive's size (16 bytes a landmark, capped at ``max_retired``), the RSS growth
  from cycle 100 to the end;
* step time against the cycle: the median over the first and the last 500 cycles, their ratio, and the slope of a
  least-squares line through the per-cycle times (ms per 1,000 cycles); ``results/long_drive_step_time.png`` plots
  the step time (100-cycle medians) against the cycle.

The times are wall-clock on a shared machine: their level depends on the load, the ratio and slope say whether they
grow with the drive's length.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rhs_studies.kit.provenance import write_json
from rhs_studies.kit.runner import Study, option, run_study
from rhs_studies.kit.slam_metrics import (
    CFEAR_DRIFT_PCT,
    DRIFT_LENGTHS_M,
    DRO_DRIFT_PCT,
    nees_interval,
    pooled_drift,
    pose_nees,
    segment_drift,
)

POLICY_HZ = 5
ENV_ID = "rhs-highway-slam-v0"
#: the targets of a long drive: NEES coverage, KITTI drift (%)
NEES_TARGET, DRIFT_TARGET_PCT = 0.90, 0.05
#: cycles per bin of the plot and of the memory samples
BIN = 100


@dataclass(frozen=True)
class Options:
    """The long drive's options (one flag each)."""

    seeds: tuple[int, ...] = option((1700, 1701, 1702), "episode seeds (held out: no tuning used them)")
    cycles: int = option(3000, "cycles per drive (5 Hz: 3000 = 10 minutes)")
    speed: float = option(15.0, "the IDM + MOBIL driver's target speed, m/s")
    grid_deg: float = option(5.0, "the radar's scan grid, deg (5: the roads' cheap configuration; the env's default is 1)")
    window: int = option(500, "cycles of the first / last window of the step-time ratio")
    pose_covariance: str = option("drift-constants", "the reported pose covariance (PipelineConfig.pose_covariance): "
                                  "drift-constants (the default), adaptive or calibrated")
    out_dir: Path = option(Path("results"), "where long_drive.json / .md / _step_time.png go")
    no_plot: bool = option(False, "skip the PNG")

    @property
    def result_name(self) -> str:
        """The results' file stem (:func:`result_stem` of the covariance model)."""
        return result_stem(self.pose_covariance)

    def __post_init__(self) -> None:
        if not self.seeds:
            raise ValueError("seeds: give at least one seed")
        if not 20 <= self.cycles <= 100_000:
            raise ValueError(f"cycles={self.cycles}: must lie in [20, 100000]")
        if not 1.0 <= self.speed <= 40.0:
            raise ValueError(f"speed={self.speed}: must lie in [1, 40] m/s")
        if not 0.1 <= self.grid_deg <= 10.0:
            raise ValueError(f"grid_deg={self.grid_deg}: must lie in [0.1, 10] deg")
        if not 5 <= self.window <= self.cycles // 2:
            raise ValueError(f"window={self.window}: must lie in [5, cycles / 2]")
        from slam.core.pipeline import POSE_COVARIANCE_MODELS

        if self.pose_covariance not in POSE_COVARIANCE_MODELS:
            raise ValueError(f"pose_covariance={self.pose_covariance!r}: must be one of {POSE_COVARIANCE_MODELS}")


def result_stem(pose_covariance: str) -> str:
    """The results' file stem: ``long_drive`` with the default covariance, ``long_drive_<model>`` otherwise."""
    return "long_drive" if pose_covariance == "drift-constants" else f"long_drive_{pose_covariance.replace('-', '_')}"


def rss_mb() -> float:
    """The process's resident set size, MB (``/proc/self/statm``; 0 where there is none)."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
    except (OSError, IndexError, ValueError):
        return 0.0
    import os

    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def _cycle_row(env: Any, info: dict[str, Any], obs: dict[str, Any], step_s: float) -> tuple[float, ...]:
    """One cycle: error (m), NEES, step time (s), SLAM stage time (s), slots used, landmarks, archived."""
    from rhs_common.geometry import wrap_angle

    e = np.asarray(info["estimated_pose"], dtype=float) - np.asarray(info["true_pose"], dtype=float)
    nees = pose_nees(e[:2], float(wrap_angle(e[2])), np.asarray(info["slam_pose_std"], float),
                     np.asarray(info["slam_pose_cov"], float))
    slam = env.get_wrapper_attr("pipeline").slam
    stages = env.get_wrapper_attr("stage_times")
    estimate = env.get_wrapper_attr("estimate")
    return (float(info["position_error_m"]), nees, step_s, float(sum(stages.values())), float(slam.slot_used.sum()),
            float(0 if estimate is None else len(estimate.landmarks)), float(len(slam.retired_xy)))


def drive(seed: int, o: Options) -> tuple[dict[str, Any], np.ndarray]:
    """One long drive; the per-seed figures and the per-cycle table (error, NEES, step s, SLAM s, slots,
    landmarks, archived, RSS MB)."""
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids)
    from agents.evaluate import load_policy

    model: dict[str, Any] = {} if o.pose_covariance == "drift-constants" else {"pipeline": {"pose_covariance": o.pose_covariance}}
    env = gym.make(ENV_ID, duration=o.cycles / POLICY_HZ, radar={"scan": {"grid_deg": o.grid_deg}}, **model)
    policy = load_policy(f"idm:{o.speed:g}", env, seed=seed)
    obs, info = env.reset(seed=seed)
    rows: list[tuple[float, ...]] = []
    est: list[np.ndarray] = []
    true: list[np.ndarray] = []
    rss, crashed, done = rss_mb(), False, False
    while not done:
        action, _ = policy.predict(obs, deterministic=True)
        t0 = time.perf_counter()
        obs, _, term, trunc, info = env.step(int(np.asarray(action)))
        dt = time.perf_counter() - t0
        done = term or trunc
        crashed = crashed or bool(info.get("crashed", False))
        if len(rows) % BIN == 0:
            rss = rss_mb()
        rows.append((*_cycle_row(env, info, obs, dt), rss))
        est.append(np.asarray(info["estimated_pose"], float))
        true.append(np.asarray(info["true_pose"], float))
    config = env.get_wrapper_attr("slam_config")
    env.close()
    return summarise(seed, np.asarray(rows), np.asarray(est), np.asarray(true), crashed, config, o), np.asarray(rows)


def flatness(times: np.ndarray, window: int) -> dict[str, float]:
    """Whether per-cycle times ``times`` (s) grow with the cycle: the medians of the first and last ``window``
    cycles (ms, the first 10 cycles' compilation left out), their ratio, and the least-squares slope of the time
    against the cycle (ms per 1,000 cycles) with the 100-cycle medians' spread."""
    t = np.asarray(times, dtype=float)[10:] * 1e3
    first, last = float(np.median(t[:window])), float(np.median(t[-window:]))
    k = np.arange(len(t), dtype=float)
    slope = float(np.polyfit(k, t, 1)[0]) * 1000 if len(t) > 2 else 0.0
    return {"first_ms": first, "last_ms": last, "last_over_first": last / first if first > 0 else float("nan"),
            "slope_ms_per_1000_cycles": slope, "median_ms": float(np.median(t))}


def summarise(seed: int, rows: np.ndarray, est: np.ndarray, true: np.ndarray, crashed: bool, config: Any,
              o: Options) -> dict[str, Any]:
    """The per-seed figures of a drive's per-cycle table (:func:`drive`)."""
    lo, hi = nees_interval()
    err, nees = rows[:, 0], rows[:, 1]
    path = float(np.hypot(*np.diff(true[:, :2], axis=0).T).sum()) if len(true) > 1 else 0.0
    drift = segment_drift(est, true, DRIFT_LENGTHS_M)
    pooled = pooled_drift([{"drift": drift}], DRIFT_LENGTHS_M)
    after = rows[min(BIN, len(rows) - 1):, 7]
    return {
        "seed": seed, "cycles": len(rows), "crashed": crashed, "path_m": path,
        "position_rmse_m": float(np.sqrt(np.mean(err**2))), "max_error_m": float(err.max()),
        "final_error_m": float(err[-1]), "final_error_pct_of_path": 100 * float(err[-1]) / path if path else None,
        "nees_inside": int(((nees >= lo) & (nees <= hi)).sum()), "nees_below": int((nees < lo).sum()),
        "nees_above": int((nees > hi).sum()), "nees_coverage": float(np.mean((nees >= lo) & (nees <= hi))),
        "drift": drift, "drift_translation_pct": pooled["translation_pct"],
        "drift_rotation_deg_per_100m": pooled["rotation_deg_per_100m"],
        "slots_max": int(rows[:, 4].max()), "slots_last": int(rows[-1, 4]), "max_landmarks": int(config.max_landmarks),
        "landmarks_max": int(rows[:, 5].max()), "archived_last": int(rows[-1, 6]),
        "max_retired": int(config.max_retired), "rss_mb_at_100": float(after[0]), "rss_mb_last": float(rows[-1, 7]),
        "rss_growth_mb": float(after.max() - after[0]),
        "step": flatness(rows[:, 2], o.window), "slam_step": flatness(rows[:, 3], o.window),
        "binned_step_ms": [float(np.median(rows[i:i + BIN, 2])) * 1e3 for i in range(0, len(rows), BIN)],
        "binned_slam_ms": [float(np.median(rows[i:i + BIN, 3])) * 1e3 for i in range(0, len(rows), BIN)],
        "binned_slots": [float(np.max(rows[i:i + BIN, 4])) for i in range(0, len(rows), BIN)],
    }


def pooled(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The seeds together: NEES coverage over every cycle, drift over every segment, the worst memory and timing
    figures, and the targets."""
    cycles = sum(r["cycles"] for r in runs)
    cov = sum(r["nees_inside"] for r in runs) / cycles
    drift = pooled_drift(runs, DRIFT_LENGTHS_M)
    ratio = [r["step"]["last_over_first"] for r in runs]
    return {
        "seeds": len(runs), "cycles": cycles, "nees_coverage": cov,
        "nees_below_fraction": sum(r["nees_below"] for r in runs) / cycles,
        "nees_above_fraction": sum(r["nees_above"] for r in runs) / cycles,
        "drift_translation_pct": drift["translation_pct"], "drift_rotation_deg_per_100m": drift["rotation_deg_per_100m"],
        "segments": drift["segments"], "final_error_m": [r["final_error_m"] for r in runs],
        "slots_max": max(r["slots_max"] for r in runs), "rss_growth_mb_max": max(r["rss_growth_mb"] for r in runs),
        "step_ratio": [min(ratio), max(ratio)],
        "slam_step_ratio": [min(r["slam_step"]["last_over_first"] for r in runs),
                            max(r["slam_step"]["last_over_first"] for r in runs)],
        "targets": {"nees_ge_90pct": bool(cov >= NEES_TARGET),
                    "drift_le_0_05pct": None if drift["translation_pct"] is None
                    else bool(drift["translation_pct"] <= DRIFT_TARGET_PCT),
                    "slots_bounded": all(r["slots_max"] <= r["max_landmarks"] for r in runs),
                    "step_time_flat": bool(max(r["slam_step"]["last_over_first"] for r in runs) <= 1.25)},
    }


def plot(runs: list[dict[str, Any]], path: Path) -> None:
    """Step time (100-cycle medians, ms) and landmark slots in use against the cycle, one line per seed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    for r in runs:
        k = np.arange(len(r["binned_step_ms"])) * BIN + BIN / 2
        ax.plot(k, r["binned_step_ms"], label=f"env.step, seed {r['seed']}")
        ax.plot(k, r["binned_slam_ms"], "--", label=f"SLAM stages, seed {r['seed']}")
        bx.plot(k, r["binned_slots"], label=f"seed {r['seed']}")
    ax.set_ylabel("step time, ms (100-cycle median)")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=7, ncol=2)
    bx.axhline(runs[0]["max_landmarks"], color="k", lw=0.8, ls=":", label="max_landmarks")
    bx.set_ylabel("landmark slots in use (max)")
    bx.set_xlabel("cycle (5 Hz)")
    bx.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _result(o: Options, runs: list[dict[str, Any]]) -> dict[str, Any]:
    return {"env": ENV_ID, "driver": f"idm:{o.speed:g}", "cycles": o.cycles, "grid_deg": o.grid_deg,
            "pose_covariance": o.pose_covariance, "runs": runs,
            "summary": pooled(runs), "seeds_done": [r["seed"] for r in runs], "nees_interval": nees_interval(),
            "dro_drift_pct": DRO_DRIFT_PCT, "cfear_drift_pct": list(CFEAR_DRIFT_PCT)}


def run(o: Options) -> dict[str, Any]:
    """Every seed's drive, the pooled figures and the plot. After each seed but the last, the seeds so far go to
    ``long_drive.json`` without a fingerprint (an interrupted run keeps them, marked unverified)."""
    runs: list[dict[str, Any]] = []
    started = time.time()
    for seed in o.seeds:
        if runs:
            write_json(Path(o.out_dir) / f"{o.result_name}.json", _result(o, runs), STUDY.launcher, o, started)
            (Path(o.out_dir) / f"{o.result_name}.md").write_text(markdown(_result(o, runs)))
            if not o.no_plot:
                plot(runs, Path(o.out_dir) / f"{o.result_name}_step_time.png")
        t0 = time.perf_counter()
        row, _ = drive(int(seed), o)
        runs.append({**row, "wall_s": time.perf_counter() - t0})
        print(f"seed {seed}: {row['cycles']} cycles, {row['path_m']:.0f} m, NEES {100 * row['nees_coverage']:.1f} %, "
              f"drift {row['drift_translation_pct']} %, final {row['final_error_m']:.2f} m, slots {row['slots_max']}, "
              f"step {row['step']['first_ms']:.0f} -> {row['step']['last_ms']:.0f} ms", file=sys.stderr, flush=True)
    if not o.no_plot:
        Path(o.out_dir).mkdir(parents=True, exist_ok=True)
        plot(runs, Path(o.out_dir) / f"{o.result_name}_step_time.png")
    return _result(o, runs)


def _yes(flag: bool | None) -> str:
    return "n/a" if flag is None else ("**met**" if flag else "**not met**")


def markdown(res: dict[str, Any]) -> str:
    """The page: targets, then one row per seed."""
    s, t = res["summary"], res["summary"]["targets"]
    lo, hi = res["nees_interval"]
    drift = s["drift_translation_pct"]
    lines = [
        f"`{res['env']}` at its defaults but a {res.get('grid_deg', 1):g}-degree scan grid, {res['cycles']} cycles "
        f"({res['cycles'] / POLICY_HZ / 60:.0f} min) per drive, "
        f"IDM + MOBIL at {res['driver'].split(':')[1]} m/s, no loop closure, {s['seeds']} seeds, the "
        f"`{res.get('pose_covariance', 'drift-constants')}` pose covariance. Simulated.", "",
        f"- NEES inside its 95 % band [{lo:.2f}, {hi:.2f}] on {100 * s['nees_coverage']:.1f} % of {s['cycles']} cycles "
        f"(below {100 * s['nees_below_fraction']:.1f} %, above {100 * s['nees_above_fraction']:.1f} %): target >= 90 % "
        f"{_yes(t['nees_ge_90pct'])};",
        f"- translational drift over 100-800 m segments {'n/a' if drift is None else f'{drift:.3f} %'} "
        f"({s['segments']} segments), rotational {s['drift_rotation_deg_per_100m']:.4f} deg / 100 m: target <= 0.05 % "
        f"{_yes(t['drift_le_0_05pct'])} (real-data radar odometry: DRO {res['dro_drift_pct']} %, CFEAR "
        f"{res['cfear_drift_pct'][0]}-{res['cfear_drift_pct'][1]} %);",
        f"- memory: at most {s['slots_max']} landmark slots in use (of {res['runs'][0]['max_landmarks']}: bounded "
        f"{_yes(t['slots_bounded'])}), resident memory grew by at most {s['rss_growth_mb_max']:.1f} MB after cycle 100;",
        f"- step time, median of the last 500 cycles over the first 500: env.step {s['step_ratio'][0]:.2f}-"
        f"{s['step_ratio'][1]:.2f}, the SLAM's stages {s['slam_step_ratio'][0]:.2f}-{s['slam_step_ratio'][1]:.2f} "
        f"(flat: <= 1.25 {_yes(t['step_time_flat'])}).", "",
        "| seed | cycles | path m | crashed | RMSE m | final error m | NEES inside | drift % | rot deg/100 m | "
        "slots max | archived | RSS +MB | step ms first/last | SLAM ms first/last | slope ms/1000 cyc |",
        "|---:|---:|---:|:-:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in res["runs"]:
        st, sl = r["step"], r["slam_step"]
        d = r["drift_translation_pct"]
        lines.append(
            f"| {r['seed']} | {r['cycles']} | {r['path_m']:.0f} | {'yes' if r['crashed'] else 'no'} | "
            f"{r['position_rmse_m']:.3f} | {r['final_error_m']:.3f} | {100 * r['nees_coverage']:.1f} % | "
            f"{'n/a' if d is None else f'{d:.3f}'} | {r['drift_rotation_deg_per_100m'] or 0:.4f} | {r['slots_max']} | "
            f"{r['archived_last']} | {r['rss_growth_mb']:.1f} | {st['first_ms']:.0f} / {st['last_ms']:.0f} | "
            f"{sl['first_ms']:.0f} / {sl['last_ms']:.0f} | {sl['slope_ms_per_1000_cycles']:+.2f} |")
    lines += ["", f"![step time against the cycle]({result_stem(res.get('pose_covariance', 'drift-constants'))}"
                  "_step_time.png)"]
    return "\n".join(lines) + "\n"


def fingerprint() -> list[float]:
    """Small config: one 40-cycle drive (seed 0): error, NEES coverage, slots, archive."""
    o = Options(seeds=(0,), cycles=40, window=5, no_plot=True)
    r, _ = drive(0, o)
    return [r["position_rmse_m"], r["final_error_m"], r["nees_coverage"], float(r["slots_max"]),
            float(r["archived_last"]), r["path_m"]]


STUDY = Study("", "scripts/long_drive.py", Options, run, markdown, fingerprint, __doc__)


def main(argv: list[str] | None = None) -> int:
    """Run the study (``python scripts/long_drive.py --help``)."""
    return run_study(STUDY, argv)


__all__ = ["Options", "STUDY", "drive", "result_stem", "flatness", "main", "markdown", "pooled", "run", "summarise"]

if __name__ == "__main__":
    sys.exit(main())
