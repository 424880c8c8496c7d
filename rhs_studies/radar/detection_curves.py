"""Detection curves: Pd against SNR at a fixed P_fa, RHS and phased array, slot-summed and footprint detectors.

``python scripts/detection_curves.py [--trials 60] [--pfa 1e-6] [--quick] [--out-dir results]``
writes ``detection_curves.json`` (commit, command line, config, curves), ``.md``
(table) and ``.png``.

Simulation (detection stage only, the OMP stage is not involved): each sweep puts
one static point target on every radar (range ``--range`` m, angle uniform in
+-40 deg, so no other radar sees it) with the RCS that gives the requested
per-slot SNR at unit two-way gain ``snr_1 = |s|^2 / sigma_iota^2``
(:meth:`RadarConfig.unit_gain_snr`; the x axis, the same echo for both antennas);
the same spectra go to both detectors. A target is detected when its radar
reports a bin within ``zero_pad + 1`` padded bins of its beat bin.

Theory, averaged over the same angles (``E = snr_1 sum_i |h_i(theta)|^2``, the
sweep's echo energy over the noise of one cell, ``sigma_Y^2``):

* matched filter (angle and Doppler known, coherent over the sweep, Swerling 0):
  ``Pd = Q_1(sqrt(2 E), sqrt(2 ln(1 / P_fa)))`` = ``ncx2.sf(2 ln(1/P_fa); 2, 2 E)``;
* footprint energy detector, known noise, the best hypothesis j at the per-hypothesis
  P_fa p_1 of :class:`rhs_env.detection.FootprintDetector`:
  ``ncx2.sf(2 tau_j; 2 L_j, 2 E_j)``, ``tau_j = Gamma^{-1}(1 - p_1; L_j)``, E_j the energy in F_j;
* slot-summed energy detector, known noise: ``ncx2.sf(2 Gamma^{-1}(1 - P_fa; I C); 2 I C, 2 E)``.

It also measures the false-alarm rate of both detectors on noise-only scans at
``--pfa-check`` (the fraction of (radar, range cell) above threshold before peak
picking) and the detector's time per scan against the summed one on the
benchmark's highway scene (same process, ratio of medians).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import scipy.fft as sfft
from scipy import stats

from rhs_env.point_cloud import os_cfar_threshold
from rhs_env.radar import DetectionConfig, RadarConfig, RadarSystem
from rhs_env.scatterers import Scatterers
from rhs_studies.kit.provenance import write_json
from rhs_studies.kit.seeds import first
from rhs_studies.kit.tables import snr_at

DETECTORS = ("summed", "footprint")
ANTENNAS = ("rhs", "phased")


def spectra(radar: RadarSystem, scatterers: Scatterers) -> np.ndarray:
    """Range spectra (4, I, C, Kb) of one sweep, as :meth:`RadarSystem.process` computes them."""
    cfg = radar.config
    y = radar.synthesize(scatterers)
    n = cfg.waveform.zero_pad * cfg.waveform.samples
    return sfft.fft(y * radar.range_fft.window, n=n, axis=-1, workers=1)[..., : radar.range_fft.bin_hi]


def make_radars(antenna: str, pfa: float, max_range: float, seed: int) -> dict[str, RadarSystem]:
    """One RadarSystem per detector (same antenna and rng seed; synthesis uses the first one's rng)."""
    return {d: RadarSystem(RadarConfig(antenna=antenna, detection=DetectionConfig(statistic=d, pfa=pfa), max_range_m=max_range),
                           np.random.default_rng(seed)) for d in DETECTORS}


def simulate_pd(radars: dict[str, RadarSystem], snr_db: np.ndarray, trials: int, range_m: float,
                rng: np.random.Generator) -> dict[str, list[float]]:
    """Measured Pd per detector and SNR (4 targets per sweep, one per radar)."""
    synth = radars["summed"]
    cfg = synth.config
    wf = cfg.waveform
    bins_per_m = 2 * wf.slope / 299_792_458.0 * wf.zero_pad * wf.samples / wf.sample_rate_hz
    tol = wf.zero_pad + 1
    sweeps = int(np.ceil(trials / 4))
    pd: dict[str, list[float]] = {d: [] for d in radars}
    for x in snr_db:
        rcs = 10 ** (x / 10) / cfg.unit_gain_snr(range_m, 1.0)
        hits = dict.fromkeys(radars, 0)
        for _ in range(sweeps):
            th = np.deg2rad(rng.uniform(-40, 40, 4)) + synth.boresights
            xy = synth.positions + range_m * np.column_stack([np.cos(th), np.sin(th)])
            spec = spectra(synth, Scatterers.static_points(xy, rcs))
            for d, radar in radars.items():
                rd, kd = radar.detector.detect(spec)
                near = np.abs(kd[None, :] - range_m * bins_per_m) <= tol
                hits[d] += int(np.sum(np.any((rd[None, :] == np.arange(4)[:, None]) & near, axis=1)))
        for d in radars:
            pd[d].append(hits[d] / (4 * sweeps))
    return pd


def theory_pd(radar: RadarSystem, snr_db: np.ndarray, pfa: float) -> dict[str, list[float]]:
    """Theoretical Pd (module docstring), averaged over angles uniform in +-40 deg."""
    cfg = radar.config
    det = radar.detector.footprint_detectors[0] if radar.detector.footprint_detectors else None
    dic = radar.dictionaries[0]
    theta = np.deg2rad(np.linspace(-40, 40, 161))
    g = np.abs(dic.atoms(theta)[0]) ** 2  # (I, T)
    e_unit = g.sum(0)  # sweep energy per unit snr_1
    looks_all = cfg.scan.slots * cfg.waveform.chirps_per_slot
    out: dict[str, list[float]] = {"matched_filter": [], "summed_known_noise": [], "footprint_known_noise": []}
    for x in snr_db:
        e = 10 ** (x / 10) * e_unit
        out["matched_filter"].append(float(np.mean(stats.ncx2.sf(2 * np.log(1 / pfa), 2, 2 * e))))
        t_sum = stats.gamma.isf(pfa, looks_all)
        out["summed_known_noise"].append(float(np.mean(stats.ncx2.sf(2 * t_sum, 2 * looks_all, 2 * e))))
        if det is not None:
            e_j = 10 ** (x / 10) * (det.footprints.T.astype(float) @ g)  # (J, T)
            tau = stats.gamma.isf(det.p1, det.looks)[:, None]
            pj = stats.ncx2.sf(2 * tau, 2 * det.looks[:, None], 2 * e_j)
            out["footprint_known_noise"].append(float(np.mean(pj.max(axis=0))))
    return out


def measure_pfa(radars: dict[str, RadarSystem], scans: int) -> dict[str, dict]:
    """Fraction of (radar, range cell) above threshold on noise-only sweeps, before peak picking."""
    synth = radars["summed"]
    cfg = synth.config
    fp = radars["footprint"].detector.footprint_detectors[0]
    cap = synth.detector.noise_mean * 10 ** (cfg.detection.cap_db / 10)
    hits = dict.fromkeys(radars, 0)
    cells = 0
    for _ in range(scans):
        spec = spectra(synth, Scatterers.empty())
        prof = np.sum(np.abs(spec) ** 2, axis=(1, 2))
        thr = os_cfar_threshold(prof, cfg.detection.guard, cfg.detection.train, cfg.waveform.zero_pad, synth.detector.alpha,
                                synth.detector.rank, floor=synth.detector.noise_mean, cap=cap)
        hits["summed"] += int(np.sum(prof > thr))
        hits["footprint"] += int(fp.exceedance(fp.statistic(spec)).sum())
        cells += prof.size
    res = {}
    for d, h in hits.items():
        lo, hi = stats.beta.ppf([0.025, 0.975], h + 0.5, cells - h + 0.5)  # Jeffreys 95 % interval
        res[d] = {"design": cfg.detection.pfa, "measured": h / cells, "hits": h, "cells": cells, "ci95": [lo, hi]}
    return res


def time_detectors(antenna: str, repeats: int, seed: int = 0) -> dict:
    """Median time (ms) of the detection stage (``RangeDetector.detect``) and of a full scan, both detectors."""
    from rhs_studies.kit.episodes import typical_scene

    scene, occ = typical_scene(np.random.default_rng(seed + 1))
    radars = {d: RadarSystem(RadarConfig(antenna=antenna, detection=DetectionConfig(statistic=d)), np.random.default_rng(seed))
              for d in DETECTORS}
    spec = spectra(radars["summed"], scene)
    det_ms: dict[str, list[float]] = {d: [] for d in DETECTORS}
    scan_ms: dict[str, list[float]] = {d: [] for d in DETECTORS}
    points = {}
    for _ in range(repeats):
        for d, radar in radars.items():  # interleaved, so load changes hit both alike
            t0 = time.perf_counter()
            radar.detector.detect(spec)
            det_ms[d].append(1e3 * (time.perf_counter() - t0))
            cloud = radar.scan(scene, occ)
            scan_ms[d].append(1e3 * cloud.stage_times["total"])
            points[d] = len(cloud)
    med = {d: float(np.median(det_ms[d])) for d in DETECTORS}
    med_scan = {d: float(np.median(scan_ms[d])) for d in DETECTORS}
    return {"detect_ms_median": med, "scan_ms_median": med_scan,
            "detect_ratio_footprint_over_summed": med["footprint"] / med["summed"],
            "scan_ratio_footprint_over_summed": med_scan["footprint"] / med_scan["summed"],
            "points_last_scan": points, "repeats": repeats}


def write_outputs(res: dict, out_dir: Path) -> None:
    """JSON, markdown table and figure."""
    out_dir.mkdir(parents=True, exist_ok=True)
    started = res.pop("_started")
    res["provenance"] = write_json(out_dir / "detection_curves.json", res, __file__, res["config"], started, fingerprint,
                                   res.pop("_argv"))
    snr = np.array(res["snr_db"])
    lines = [f"Pd against the per-slot SNR at unit two-way gain, P_fa = {res['config']['pfa']:g} per range cell "
             f"({res['config']['trials']} targets per point; `{' '.join(res['provenance']['command'])}`, commit "
             f"{res['provenance']['commit'][:10]}). SNR (dB) needed for Pd = 0.5 / 0.9:", "",
             "| antenna | curve | Pd=0.5 | Pd=0.9 |", "|---|---|---|---|"]
    for ant in ANTENNAS:
        curves = {**{f"measured {d}": res["measured"][ant][d] for d in DETECTORS},
                  **{f"theory {k}": v for k, v in res["theory"][ant].items()}}
        for name, pd in curves.items():
            cells = [snr_at(pd, snr, lv) for lv in (0.5, 0.9)]
            lines.append(f"| {ant} | {name} | " + " | ".join("-" if c is None else f"{c:.1f}" for c in cells) + " |")
    lines += ["", f"False-alarm rate on noise-only scans (design {res['config']['pfa_check']:g}):", "",
              "| antenna | detector | measured | 95 % interval | cells |", "|---|---|---|---|---|"]
    for ant in ANTENNAS:
        for d in DETECTORS:
            m = res["pfa_check"][ant][d]
            lines.append(f"| {ant} | {d} | {m['measured']:.3g} | [{m['ci95'][0]:.3g}, {m['ci95'][1]:.3g}] | "
                         f"{m['cells']} |")
    t = res["timing"]
    lines += ["", f"Detection stage, median per four-radar scan (highway scene, {t['repeats']} repeats): summed "
              f"{t['detect_ms_median']['summed']:.2f} ms, footprint {t['detect_ms_median']['footprint']:.2f} ms "
              f"(ratio {t['detect_ratio_footprint_over_summed']:.2f}); whole scan ratio "
              f"{t['scan_ratio_footprint_over_summed']:.2f}. Shared machine: ratios only."]
    (out_dir / "detection_curves.md").write_text("\n".join(lines) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for ax, ant in zip(axes, ANTENNAS):
        th = res["theory"][ant]
        ax.plot(snr, th["matched_filter"], "k-", label="theory: matched filter (known angle, Doppler)")
        ax.plot(snr, th["footprint_known_noise"], "C0--", label="theory: footprint, known noise")
        ax.plot(snr, th["summed_known_noise"], "C1--", label="theory: slot sum, known noise")
        ax.plot(snr, res["measured"][ant]["footprint"], "C0o-", label="measured: footprint CFAR")
        ax.plot(snr, res["measured"][ant]["summed"], "C1s-", label="measured: slot-summed CFAR")
        ax.set_title(f"{ant}: P_fa = {res['config']['pfa']:g} per cell")
        ax.set_xlabel("per-slot SNR at unit two-way gain (dB)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("Pd")
    axes[0].legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(out_dir / "detection_curves.png", dpi=120)


def fingerprint() -> list[float]:
    """Small config: RHS, Pfa 1e-3, 30 m, Pd of both detectors at three SNRs over 4 trials (fixed seeds)."""
    radars = make_radars("rhs", 1e-3, 40.0, 0)
    pd = simulate_pd(radars, np.array([-14.0, -8.0, -2.0]), 4, 30.0, np.random.default_rng(1))
    return [float(v) for d in sorted(pd) for v in pd[d]]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=80, help="targets per SNR point and curve")
    p.add_argument("--pfa", type=float, default=1e-6, help="design P_fa of the curves (RadarConfig.detection.pfa)")
    p.add_argument("--pfa-check", type=float, default=1e-3, help="design P_fa of the noise-only check")
    p.add_argument("--pfa-scans", type=int, default=40, help="noise-only sweeps of the check")
    p.add_argument("--range", type=float, default=40.0, help="target range, m")
    p.add_argument("--max-range", type=float, default=60.0, help="RadarConfig.max_range_m (fewer bins: faster)")
    p.add_argument("--snr-min", type=float, default=-24.0)
    p.add_argument("--snr-max", type=float, default=-4.0)
    p.add_argument("--snr-step", type=float, default=1.5)
    p.add_argument("--timing-repeats", type=int, default=15)
    p.add_argument("--seed", type=int, default=first("scenes"))
    p.add_argument("--quick", action="store_true", help="few trials and points (a smoke run)")
    p.add_argument("--out-dir", default="results")
    a = p.parse_args(argv)
    if a.quick:
        a.trials, a.pfa_scans, a.snr_step, a.timing_repeats = 8, 4, 5.0, 2
    snr = np.arange(a.snr_min, a.snr_max + 1e-9, a.snr_step)
    rng = np.random.default_rng(a.seed)
    res = {"_started": time.time(), "_argv": argv, "config": {**vars(a), "radar": RadarConfig().to_dict()},
           "snr_db": snr.tolist(), "measured": {}, "theory": {}, "pfa_check": {}}
    for ant in ANTENNAS:
        t0 = time.perf_counter()
        radars = make_radars(ant, a.pfa, a.max_range, a.seed)
        res["measured"][ant] = simulate_pd(radars, snr, a.trials, a.range, rng)
        res["theory"][ant] = theory_pd(radars["footprint"], snr, a.pfa)
        fp = radars["footprint"].detector.footprint_detectors[0]
        res.setdefault("footprints", {})[ant] = {"hypotheses": fp.hypotheses, "looks": np.bincount(fp.looks).tolist(),
                                                 "p1": fp.p1, "n_eff": fp.n_eff}
        res["pfa_check"][ant] = measure_pfa(make_radars(ant, a.pfa_check, a.max_range, a.seed + 1), a.pfa_scans)
        print(f"{ant}: {time.perf_counter() - t0:.0f} s", flush=True)
    res["timing"] = time_detectors("rhs", a.timing_repeats, a.seed)
    write_outputs(res, Path(a.out_dir))
    print((Path(a.out_dir) / "detection_curves.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
