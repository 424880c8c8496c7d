"""Speed against point-cloud quality of the radar's processing settings.

Each profile (``PROFILES``: radar kwargs over the default, exactly as ``gym.make(...,
radar=...)`` takes them) is measured two ways, on the default antenna and 1-degree grid:

* **speed**: wall time per stage of one four-radar scan of the typical highway scene
  (:func:`rhs_studies.kit.scenes.typical_scene`); the profiles take turns scan by scan, so
  load on the machine slows all of them alike, and each is reported as the median
  over ``--repeats`` rounds and as a ratio to the default's total;
* **quality**: :func:`radar_quality.evaluate` on the Fig. 5b scenes (detection rate,
  false points per scan, point / range / angle / Doppler RMSE, 95 % intervals), the
  same scenes and noise seeds for every profile, pooled over ``--noise-draws``
  noise realizations of each scene (the RMSEs rest on a few outlier points: one
  realization's value moves by more than its interval). A profile keeps the default's quality
  when every metric differs from the default's by less than the two-sample 95 %
  interval, ``|m - m_0| <= sqrt(h^2 + h_0^2)`` with ``h`` the metrics' 95 % half-widths.

What the speed target asks of the default path is the scan at a third of a highway-env step
with unchanged quality; this table says which settings buy how much of it, and at what
cost. The default stays the reference until a profile keeps the quality and the
results are rerun on it.

    OMP_NUM_THREADS=1 python scripts/radar_profiles.py [--repeats 15] [--scenes 100] [--noise-draws 3] [--out results/radar_profiles.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from rhs_studies.kit.provenance import numbers, write_json
from rhs_studies.kit.seeds import first

ROOT = Path(__file__).resolve().parents[2]

#: name -> radar kwargs over the default (the processing settings only: the scene and antenna stay)
PROFILES: dict[str, dict] = {
    "default": {},
    "newton1": {"estimation": {"newton_steps": 1}},
    "refine1": {"estimation": {"refine_passes": 1}},
    "refine0": {"estimation": {"refine_passes": 0}},
    "oversampling2": {"estimation": {"oversampling": 2}},
    "newton1_refine1": {"estimation": {"newton_steps": 1, "refine_passes": 1}},
    # the default until 2026-11: two fixed refinement passes (before the convergence stop)
    "fixed2": {"estimation": {"refine_passes": 2, "refine_tol": 0.0}},
    # half the candidates and one Newton step: the same Fig. 5b quality, a worse SLAM on tuning drives
    "oversampling2_newton1": {"estimation": {"oversampling": 2, "newton_steps": 1}},
    "iq": {"fidelity": "iq"},  # the reference synthesis path (the default is "range")
}
QUALITY = ("detection_rate", "false_points_per_scan", "point_rmse_m", "range_rmse_m", "angle_rmse_deg",
           "doppler_rmse_mps")


def radar_config(profile: dict, grid_deg: float):
    """The validated RadarConfig of a profile on ``grid_deg`` (the env's own kwargs path)."""
    from rhs_env.wrappers import make_radar_config

    return make_radar_config({"scan": {"grid_deg": grid_deg}, **profile})


def time_profiles(names: list[str], grid_deg: float, repeats: int, seed: int) -> dict[str, dict]:
    """Median ms per stage (and total) of one scan per profile; the profiles scan in turn, round by round."""
    from rhs_env.radar import RadarSystem
    from rhs_studies.kit.episodes import typical_scene

    radars = {n: RadarSystem(radar_config(PROFILES[n], grid_deg), np.random.default_rng(seed)) for n in names}
    scene, occ = typical_scene(np.random.default_rng(seed + 1))
    for r in radars.values():
        r.scan(scene, occ)  # warm-up: caches, buffers
    stages: dict[str, dict[str, list[float]]] = {n: {} for n in names}
    for _ in range(repeats):
        for n, r in radars.items():
            t0 = time.perf_counter()
            cloud = r.scan(scene, occ)
            stages[n].setdefault("total", []).append(time.perf_counter() - t0)
            for k, v in cloud.stage_times.items():
                stages[n].setdefault(k, []).append(v)
    return {n: {k: 1e3 * float(np.median(v)) for k, v in s.items()} for n, s in stages.items()}


def same_quality(metrics: dict, reference: dict) -> dict[str, bool]:
    """Per metric: within the two-sample 95 % interval of the reference's value."""
    out = {}
    for k in QUALITY:
        a, b = metrics[k], reference[k]
        va, vb = a.get("mean", a.get("rmse")), b.get("mean", b.get("rmse"))
        out[k] = bool(abs(va - vb) <= float(np.hypot(a["ci95"], b["ci95"])))
    return out


def verdict(metrics: dict, reference: dict, same: dict[str, bool]) -> str:
    """"same" (every metric within its interval), "better" (every one that differs is better: a higher
    detection rate, fewer false points, a lower RMSE) or "worse"."""
    if all(same.values()):
        return "same"
    better = []
    for k in QUALITY:
        if not same[k]:
            va = metrics[k].get("mean", metrics[k].get("rmse"))
            vb = reference[k].get("mean", reference[k].get("rmse"))
            better.append(va > vb if k == "detection_rate" else va < vb)
    return "better" if all(better) else "worse"


def study(names: list[str], grid_deg: float, repeats: int, scenes: int, seed: int, progress: bool = True,
          noise_draws: int = 1) -> dict:
    from tqdm.auto import tqdm

    from rhs_studies.radar.radar_quality import evaluate

    times = time_profiles(names, grid_deg, repeats, seed)
    quality = {n: evaluate(radar_config(PROFILES[n], grid_deg), scenes, seed, noise_draws)
               for n in tqdm(names, desc="quality", disable=not progress)}
    ref_t, ref_q = times["default"]["total"], quality["default"]
    rows = {}
    for n in names:
        same = same_quality(quality[n], ref_q)
        rows[n] = {"radar": PROFILES[n], "stage_ms": times[n], "speedup": ref_t / times[n]["total"],
                   "quality": quality[n], "same_quality": same, "keeps_quality": all(same.values()),
                   "quality_verdict": verdict(quality[n], ref_q, same)}
    return {"grid_deg": grid_deg, "repeats": repeats, "scenes": scenes, "seed": seed, "noise_draws": noise_draws,
            "profiles": rows}


def markdown(res: dict) -> str:
    def cell(r: dict, k: str) -> str:
        m = r["quality"][k]
        v = m.get("mean", m.get("rmse"))
        return f"{v:.3g} ± {m['ci95']:.2g}" + ("" if r["same_quality"][k] else " *")

    lines = [
        f"One four-radar scan of the typical highway scene (median of {res['repeats']} rounds, profiles in turn) and "
        f"the point-cloud quality on {res['scenes']} Fig. 5b scenes"
        + (f", each with {res['noise_draws']} noise realizations pooled" if res.get("noise_draws", 1) > 1 else "")
        + " (± 95 % half-widths), default antenna, "
        f"{res['grid_deg']:g}-degree grid. A metric marked * differs from the default's by more than the two-sample "
        "95 % interval; the last column says whether every metric is the default's (same), every one that differs "
        "is better, or one is worse.",
        "",
        "| profile | radar kwargs | scan (ms) | OMP (ms) | speed-up | detection rate | false points / scan | "
        "point RMSE (m) | angle RMSE (deg) | Doppler RMSE (m/s) | quality against the default |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for n, r in res["profiles"].items():
        lines.append(
            f"| {n} | `{json.dumps(r['radar'])}` | {r['stage_ms']['total']:.1f} | {r['stage_ms'].get('omp', 0):.1f} "
            f"| {r['speedup']:.2f} | {cell(r, 'detection_rate')} | {cell(r, 'false_points_per_scan')} "
            f"| {cell(r, 'point_rmse_m')} | {cell(r, 'angle_rmse_deg')} | {cell(r, 'doppler_rmse_mps')} "
            f"| {r['quality_verdict']} |"
        )
    return "\n".join(lines) + "\n"


def fingerprint() -> list[float | None]:
    """Quality of two profiles on two scenes of the 5-degree grid (no timings: they are not reproducible)."""
    from rhs_studies.radar.radar_quality import evaluate

    return numbers({n: evaluate(radar_config(PROFILES[n], 5.0), 2, 0, 2) for n in ("default", "newton1_refine1")})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("profiles", nargs="*", metavar="PROFILE", help=f"of {', '.join(PROFILES)} (default: all)")
    ap.add_argument("--grid-deg", type=float, default=1.0)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--scenes", type=int, default=100)
    ap.add_argument("--seed", type=int, default=first("scenes"))
    ap.add_argument("--noise-draws", type=int, default=3,
                    help="noise realizations of each scene, pooled in the quality metrics (default 3)")
    ap.add_argument("--out", default=None, help="JSON (and .md beside it), e.g. results/radar_profiles.json")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    unknown = [p for p in a.profiles if p not in PROFILES]
    if unknown:
        ap.error(f"unknown profiles {unknown}; choose from {', '.join(PROFILES)}")
    if a.repeats < 1 or a.scenes < 2 or a.noise_draws < 1:
        ap.error("--repeats and --noise-draws must be >= 1 and --scenes >= 2 (the intervals need two scenes)")
    names = ["default", *[p for p in (a.profiles or PROFILES) if p != "default"]]
    started = time.time()
    res = study(names, a.grid_deg, a.repeats, a.scenes, a.seed, progress=not a.no_progress, noise_draws=a.noise_draws)
    md = markdown(res)
    if a.out:
        write_json(a.out, res, __file__, vars(a), started, fingerprint, argv)
        Path(a.out).with_suffix(".md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
