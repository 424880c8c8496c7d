"""README section and figures of the claim study, written from ``results/claim_study.json`` only.

:func:`write_markdown` writes the section "Does the paper's claim hold?" (every number
read from the JSON that :mod:`claim_study` wrote); :func:`make_figures` the regime map
(ratio RHS / phased of the group error over separation x SNR), the resolution and
accuracy curves against the CRB, the SLAM bars and the element sweep.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

PAPER_RATIO = 1.0 / 3.0


def _v(x: Any) -> float:
    """A JSON number (None for NaN) or the first entry of a [value, lo, hi] list, as a float."""
    if isinstance(x, list):
        x = x[0] if x else None
    return float("nan") if x is None else float(x)


def _ci(x: list | None, fmt: str = "{:.2f}") -> str:
    """'v [lo, hi]' of a [value, lo, hi] list."""
    if not x or x[0] is None:
        return "n/a"
    if len(x) < 3 or x[1] is None or x[2] is None:
        return fmt.format(x[0])
    return f"{fmt.format(x[0])} [{fmt.format(x[1])}, {fmt.format(x[2])}]"


def _ranges(values: list[tuple[float, float]]) -> str:
    """'0.5-3, 8' style summary of runs (first, last) of sorted grid values (a one-value run as one value)."""
    return ", ".join(f"{a:g}" if a == b else f"{a:g}-{b:g}" for a, b in values) if values else "none"


def _runs(grid: list[float], chosen: set[float]) -> list[tuple[float, float]]:
    """Maximal runs of consecutive grid values that are in ``chosen``."""
    out: list[tuple[float, float]] = []
    start: float | None = None
    prev = 0.0  # the last grid value in ``chosen``; set before any run closes
    for g in grid:
        if g in chosen:
            start = g if start is None else start
            prev = g
        elif start is not None:
            out.append((start, prev))
            start = None
    if start is not None:
        out.append((start, prev))
    return out


def ratio_grid(data: dict, k: int, antenna: str = "rhs") -> tuple[list[float], list[float], np.ndarray, np.ndarray]:
    """Separations, SNRs and the (SNR x separation) arrays of the OSPA ratio and its upper bound."""
    rows = [r for r in data["pointcloud"]["ratios"] if r["k"] == k and r["antenna"] == antenna]
    seps = sorted({r["sep_deg"] for r in rows})
    snrs = sorted({r["snr_db"] for r in rows})
    val = np.full((len(snrs), len(seps)), np.nan)
    hi = np.full_like(val, np.nan)
    for r in rows:
        i, j = snrs.index(r["snr_db"]), seps.index(r["sep_deg"])
        val[i, j], hi[i, j] = _v(r["ospa_ratio"]), _v(r["ospa_ratio"][2:])
    return seps, snrs, val, hi


def _cell(data: dict, level: str, **sel: Any) -> dict | None:
    """The first cell of ``data[level]["cells"]`` whose entries equal ``sel``, else None."""
    for c in data.get(level, {}).get("cells", []):
        if all(c.get(k) == v for k, v in sel.items()):
            return c
    return None


def _cell_of(data: dict, level: str, **sel: Any) -> dict:
    """:func:`_cell` where the study wrote every cell of the grid: a missing one is a malformed result."""
    c = _cell(data, level, **sel)
    if c is None:
        raise LookupError(f"the claim study's {level} level has no cell {sel}")
    return c


def _antenna_section(data: dict) -> list[str]:
    props = data["antenna_properties"]["default"]
    md = ["**Why: the antennas** (default M, two-way patterns; CRB at 0 dB per-slot SNR, scale by "
          "10^(-SNR/20)):", "",
          "| antenna | elements | two-way peak gain (dB) | -3 dB beamwidth (deg) | swept echo energy (dB) "
          "| PSLR median / worst (dB) | angle CRB at 0 dB (deg) |", "|---|---:|---:|---:|---:|---:|---:|"]
    for a, p in props.items():
        md.append(f"| {a} | {p['elements']} | {p['peak_gain_db']:.1f} | {p['beamwidth_3db_deg']:.2f} "
                  f"| {p['swept_energy_db']:.1f} | {p['pslr_median_db']:.1f} / {p['pslr_worst_db']:.1f} "
                  f"| {p['crb_deg_at_0db']:.3f} |")
    return md


def _verdict_pointcloud(data: dict) -> list[str]:
    """Where the RHS wins by >= 3x, where it loses, and the accuracy against the CRB (from the JSON)."""
    pc = data["pointcloud"]
    md = []
    ks = sorted({r["k"] for r in pc["ratios"]})
    for k in ks:
        seps, snrs, val, hi = ratio_grid(data, k)
        n = int(np.isfinite(val).sum())
        cut = data["provenance"]["config"]["study"]["ospa_cutoff_deg"]
        lo_bound = np.full_like(val, np.nan)
        fail = np.zeros(val.shape, bool)
        for r in data["pointcloud"]["ratios"]:
            if r["k"] == k and r["antenna"] == "rhs":
                i, j = snrs.index(r["snr_db"]), seps.index(r["sep_deg"])
                lo_bound[i, j] = _v(r["ospa_ratio"][1:])
                a = _cell_of(data, "pointcloud", antenna="rhs", k=k, sep_deg=r["sep_deg"], snr_db=r["snr_db"])
                b = _cell_of(data, "pointcloud", antenna="phased", k=k, sep_deg=r["sep_deg"], snr_db=r["snr_db"])
                fail[i, j] = _v(a["ospa_deg"]) >= 0.8 * cut and _v(b["ospa_deg"]) >= 0.8 * cut
        win, sure = val <= PAPER_RATIO, hi <= PAPER_RATIO
        worse = (val > 1.0) & ~fail
        sure_worse = worse & (lo_bound > 1.0)
        name = {2: "pairs", 3: "triplets"}.get(k, f"groups of {k}")
        md.append(f"* **{name}**: RHS / phased group error <= 1/3 in {int(win.sum())} of {n} cells "
                  f"({int(sure.sum())} with the whole 95 % interval below 1/3); RHS worse (> 1) in "
                  f"{int(worse.sum())} ({int(sure_worse.sum())} with the whole interval above 1); both at the "
                  f"cut-off (neither detects nor resolves) in {int(fail.sum())}. By SNR (per-slot, unit gain), "
                  "separations (deg) where the RHS wins by >= 3x | where it is worse | where both fail:")
        for i, s in enumerate(snrs):
            parts = [_ranges(_runs(seps, {seps[j] for j in range(len(seps)) if m[i, j]})) for m in (win, worse, fail)]
            md.append(f"  * {s:g} dB: " + " | ".join(parts))
    return md


def classify(data: dict, k: int, antenna: str = "rhs") -> dict[str, dict[str, int]]:
    """Why each cell of the regime map went the way it did, counted for the wins (<= 1/3) and losses (> 1).

    win reasons: ``phased_merged`` (phased resolution probability < 0.5 while the antenna's >= 0.5),
    ``accuracy`` (both resolve, the antenna's angle error lower). loss reasons: ``detection`` (the
    antenna detects fewer targets, by > 0.1), ``ghosts`` (more points in the range cell than the
    phased array, by > 0.5 per group), ``other``; and ``both_fail`` (both at >= 80 % of the OSPA
    cut-off, whatever the ratio), counted with the losses.
    """
    cut = data["provenance"]["config"]["study"]["ospa_cutoff_deg"]
    out: dict[str, dict[str, int]] = {"win": {}, "loss": {}}
    for r in data["pointcloud"]["ratios"]:
        if r["k"] != k or r["antenna"] != antenna or r["ospa_ratio"][0] is None:
            continue
        a = _cell_of(data, "pointcloud", antenna=antenna, k=k, sep_deg=r["sep_deg"], snr_db=r["snr_db"])
        b = _cell_of(data, "pointcloud", antenna="phased", k=k, sep_deg=r["sep_deg"], snr_db=r["snr_db"])
        ratio = r["ospa_ratio"][0]
        if _v(a["ospa_deg"]) >= 0.8 * cut and _v(b["ospa_deg"]) >= 0.8 * cut:
            out["loss"]["both_fail"] = out["loss"].get("both_fail", 0) + 1
        elif ratio <= PAPER_RATIO:
            why = "phased_merged" if _v(b["resolution_prob"]) < 0.5 <= _v(a["resolution_prob"]) else "accuracy"
            out["win"][why] = out["win"].get(why, 0) + 1
        elif ratio > 1.0:
            if _v(a["detection_rate"]) < _v(b["detection_rate"]) - 0.1:
                why = "detection"
            elif a.get("points_in_cell", 0) > b.get("points_in_cell", 0) + 0.5:
                why = "ghosts"
            else:
                why = "other"
            out["loss"][why] = out["loss"].get(why, 0) + 1
    return out


def _reason_lines(data: dict) -> list[str]:
    words = {"phased_merged": "the phased array merged the group (P(resolved) < 0.5) and the RHS did not",
             "accuracy": "both resolved; the RHS located the targets more precisely",
             "detection": "the RHS detected fewer targets (summed-slot CFAR, SPEC 11)",
             "ghosts": "the RHS put more (ghost) points in the range cell",
             "both_fail": "both at the OSPA cut-off (neither resolves nor detects)", "other": "other"}
    md = []
    for k in sorted({r["k"] for r in data["pointcloud"]["ratios"]}):
        c = classify(data, k)
        for side, name in (("win", "wins by >= 3x"), ("loss", "is worse, or both fail")):
            if c[side]:
                md.append(f"  * K={k}, where the RHS {name}: " + "; ".join(
                    f"{words[w]}: {n}" for w, n in sorted(c[side].items(), key=lambda x: -x[1])))
    return ["* **Why, cell by cell:**"] + md if md else []


def _accuracy_lines(data: dict) -> list[str]:
    pc = data["pointcloud"]
    k = min(c["k"] for c in pc["cells"])
    seps = sorted({c["sep_deg"] for c in pc["cells"]})
    snrs = sorted({c["snr_db"] for c in pc["cells"]})
    bw = data["antenna_properties"]["default"].get("rhs", {}).get("beamwidth_3db_deg", 3.0)
    close = min(seps, key=lambda x: abs(x - 1.2 * bw))
    md = ["* **Accuracy against the CRB** (angle RMSE of the matched targets; CRB of the pair, "
          f"x = RMSE / CRB): {seps[-1]:g} deg apart every antenna can resolve the pair; {close:g} deg apart "
          "(~1.2 RHS beamwidths) is the RHS's resolution limit:"]
    for sep in dict.fromkeys((seps[-1], close)):
        for s in dict.fromkeys((snrs[-1], snrs[len(snrs) // 2])):
            parts = []
            for a in data["antenna_properties"]["default"]:
                c = _cell(data, "pointcloud", antenna=a, k=k, sep_deg=sep, snr_db=s)
                if c and c["angle_rmse_deg"][0] is not None:
                    parts.append(f"{a} {_v(c['angle_rmse_deg']):.3f} deg (CRB {c['crb_group_deg']:.4f}, "
                                 f"x{_v(c['rmse_over_crb']):.1f}; {c['points_in_cell']:.1f} points in the cell)")
            if parts:
                md.append(f"  * {sep:g} deg, {s:g} dB: " + "; ".join(parts))
    md.append("* **Resolution** (smallest separation resolved with probability >= 0.9) and **detection** "
              "(lowest SNR with detection rate >= 0.9, at the largest separation):")
    for a in data["antenna_properties"]["default"]:
        res = []
        for s in dict.fromkeys((snrs[-1], snrs[len(snrs) // 2])):
            ok = [c["sep_deg"] for c in pc["cells"] if c["antenna"] == a and c["k"] == k and c["snr_db"] == s
                  and _v(c["resolution_prob"]) >= 0.9]
            res.append(f"{min(ok):g} deg at {s:g} dB" if ok else f"none at {s:g} dB")
        det = [c["snr_db"] for c in pc["cells"] if c["antenna"] == a and c["k"] == k and c["sep_deg"] == seps[-1]
               and _v(c["detection_rate"]) >= 0.9]
        md.append(f"  * {a}: resolves {', '.join(res)}; detects down to "
                  f"{f'{min(det):g} dB' if det else 'no SNR of the grid'}")
    return md


def _slam_section(data: dict) -> list[str]:
    sl = data["slam"]
    regs = [k for k in sl["cells"][0] if isinstance(sl["cells"][0][k], dict)]
    ns = sorted({c["n"] for c in sl["cells"]})
    seeds = f"{ns[0]}" if len(ns) == 1 else f"{ns[0]}-{ns[-1]}"
    md = ["", f"**SLAM level** (the paper's drive with each obstacle a group of K landmarks; {seeds} "
          "seeds per cell; ATE and map RMSE in m, mean [95 % t-interval]; ratio: RHS / phased ATE, bootstrap "
          "interval):", "",
          "| antenna | K | sep (deg) | SNR (dB) | " + " | ".join(f"ATE {r}" for r in regs)
          + " | map RMSE | spurious | missed | ATE ratio vs phased |",
          "|---|---:|---:|---:|" + "---:|" * (len(regs) + 4)]
    ratios = {(r["antenna"], r["k"], r["sep_deg"], r["snr_db"]): r for r in sl["ratios"]}
    first = regs[0]
    verdict: dict[str, list[str]] = {"win": [], "lose": []}
    for (a, k, sep, snr), r in sorted(ratios.items()):
        x = r.get(f"ate_m_ratio_{first}") or [None]
        if a != "rhs" or x[0] is None:
            continue
        tag = f"K={k}, {sep:g} deg, {snr:g} dB: {_ci(x)}"
        if x[0] <= PAPER_RATIO:
            verdict["win"].append(tag)
        elif x[0] >= 1.0:
            verdict["lose"].append(tag)
    md[2:2] = ["", f"RHS / phased ATE ({first} registration) <= 1/3: " + ("; ".join(verdict["win"]) or "none")
               + ". >= 1: " + ("; ".join(verdict["lose"]) or "none") + ". The odometry arm (true motion) is the "
               "filter's own floor: the gap above it is the registration's, which the antenna's point cloud drives."]
    for c in sorted(sl["cells"], key=lambda c: (c["k"], c["sep_deg"], -c["snr_db"], c["antenna"])):
        r = ratios.get((c["antenna"], c["k"], c["sep_deg"], c["snr_db"]))
        ratio = _ci(r.get(f"ate_m_ratio_{first}")) if r else "-"
        md.append(f"| {c['antenna']} | {c['k']} | {c['sep_deg']:g} | {c['snr_db']:g} | "
                  + " | ".join(_ci(c[g]["ate_m"]) for g in regs)
                  + f" | {_ci(c[first]['map_rmse_m'])} | {_ci(c[first]['map_spurious'], '{:.1f}')} "
                    f"| {_ci(c[first]['map_missed'], '{:.1f}')} | {ratio} |")
    return md


def _elements_section(data: dict) -> list[str]:
    el = data["elements"]
    md = ["", "**Element sweep** (pairs, beam grid of the sweep; phased array at round(M / 6) elements; "
          "group error in deg; ratio RHS / phased, bootstrap interval):", "",
          "| M | phased elements | sep (deg) | SNR (dB) | RHS group error | phased group error | ratio |"
          " RHS RMSE / CRB |", "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    ratios = {(r["elements"], r["sep_deg"], r["snr_db"]): r for r in el["ratios"] if r["antenna"] == "rhs"}
    props = data["antenna_properties"]
    grid = data["provenance"]["config"]["study"]["elements_grid_deg"]
    narrow = {m: p["rhs"]["beamwidth_3db_deg"] for m in {r[0] for r in ratios}
              if (p := props.get(f"M{m}", {})).get("rhs") and p["rhs"]["beamwidth_3db_deg"] < grid}
    if narrow:
        md[1] += (f" Caveat: on this {grid:g}-degree grid the RHS beam is narrower than the grid spacing ("
                  + ", ".join(f"{bw:.1f} deg at M={m}" for m, bw in sorted(narrow.items()))
                  + "): a target between two beams loses gain and the dictionary is coarse, so this sweep "
                  "understates the RHS (compare the default-grid point-cloud level at M=60).")
    for (m, s, snr), r in sorted(ratios.items()):
        a = _cell_of(data, "elements", antenna="rhs", elements=m, sep_deg=s, snr_db=snr)
        b = _cell_of(data, "elements", antenna="phased", elements=m, sep_deg=s, snr_db=snr)
        pe = props.get(f"M{m}", {}).get("phased", {}).get("elements", "?")
        md.append(f"| {m} | {pe} | {s:g} | {snr:g} | {_ci(a['ospa_deg'], '{:.3f}')} | {_ci(b['ospa_deg'], '{:.3f}')} "
                  f"| {_ci(r['ospa_ratio'])} | {_v(a['rmse_over_crb']):.1f} |")
    return md


def write_markdown(data: dict, path: Path) -> None:
    """The README section "Does the paper's claim hold?" from the study's JSON."""
    prov = data["provenance"]
    cfg = prov["config"]["study"]
    md = [
          f"Measured by `{' '.join(prov['command'])}` at commit `{prov['commit'][:10]}`"
          f"{' (dirty tree)' if prov['dirty'] else ''}; `results/claim_study.json`. Point-cloud level: groups of "
          f"K targets in one range cell at {cfg['range_m']:g} m, {cfg['seeds']} trials per cell; SNR is the "
          "per-slot SNR at unit two-way gain (add each antenna's two-way gain for the SNR it sees). Group error: "
          f"OSPA distance (cut-off {cfg['ospa_cutoff_deg']:g} deg) between the true angles and the points in the "
          "range cell: accuracy, merged targets, misses and ghosts in one number. 95 % intervals: t (ddof=1) for "
          "means, Wilson for probabilities, bootstrap for ratios.", ""]
    if "pointcloud" in data:
        md += (["**Verdict (point cloud):**", ""] + _verdict_pointcloud(data) + _reason_lines(data)
               + _accuracy_lines(data))
        md += ["", "![regime map](results/claim_study_regime.png)", ""]
    md += _antenna_section(data) + why_lines(data)
    if "slam" in data:
        md += _slam_section(data)
    if "elements" in data:
        md += _elements_section(data)
    tm = data["timing"]
    cost = []
    for lv, unit in (("pointcloud", "cell"), ("elements", "cell"), ("slam", "seed")):
        if lv in data:
            cpu = data[lv].get(f"cpu_s_per_{unit}")
            cost.append(f"{lv} {data[lv][f'wall_s_per_{unit}']:.2f} s wall"
                        + (f", {cpu:.2f} s CPU" if cpu is not None else "") + f" per {unit}")
    md += ["", f"Cost: {'; '.join(cost)} (load average {tm['load_average'][0]:.1f} on {tm['cpu_count']} cores "
           "when written: shared-machine timings)."]
    path.write_text("\n".join(md) + "\n")


def why_lines(data: dict) -> list[str]:
    """The physics behind the verdict, as ratios of the antennas' properties (RHS vs phased)."""
    p = data["antenna_properties"]["default"]
    if "rhs" not in p or "phased" not in p:
        return []
    r, q = p["rhs"], p["phased"]
    return ["", f"Why: the RHS's beam is {q['beamwidth_3db_deg'] / r['beamwidth_3db_deg']:.1f}x narrower "
            f"({r['beamwidth_3db_deg']:.2f} vs {q['beamwidth_3db_deg']:.2f} deg) and its angle CRB "
            f"{q['crb_deg_at_0db'] / r['crb_deg_at_0db']:.1f}x lower: it resolves and locates targets in one range "
            "cell that the phased array merges. Its two-way peak gain is "
            f"{r['peak_gain_db'] - q['peak_gain_db']:+.1f} dB over the phased array's, but the narrow beam holds a "
            f"target for fewer slots: the echo energy summed over a sweep is {r['swept_energy_db'] - q['swept_energy_db']:+.1f}"
            " dB, so it has no detection advantage; its PSLR (median "
            f"{r['pslr_median_db']:.1f} dB, worst {r['pslr_worst_db']:.1f} dB) is higher than the phased array's "
            f"({q['pslr_median_db']:.1f} / {q['pslr_worst_db']:.1f} dB), so strong targets raise more sidelobe ghosts. "
            "Where no target shares a range cell inside the phased beam, the SLAM error is set by the filter and the "
            "registration, not by the angle precision: the ratio goes to 1."]


def make_figures(data: dict, out: Path, stem: str) -> None:
    """``{stem}_regime.png`` (+ resolution, SLAM and element figures when those levels are present)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if "pointcloud" in data and data["pointcloud"]["ratios"]:
        _regime_figure(plt, data, out / f"{stem}_regime.png")
        _resolution_figure(plt, data, out / f"{stem}_resolution.png")
    if "slam" in data:
        _slam_figure(plt, data, out / f"{stem}_slam.png")
    if "elements" in data:
        _elements_figure(plt, data, out / f"{stem}_elements.png")


def _regime_figure(plt: Any, data: dict, path: Path) -> None:
    ks = sorted({r["k"] for r in data["pointcloud"]["ratios"]})
    fig, axes = plt.subplots(1, len(ks), figsize=(6.5 * len(ks), 4.8), squeeze=False)
    for ax, k in zip(axes[0], ks):
        seps, snrs, val, _ = ratio_grid(data, k)
        im = ax.imshow(np.log10(val), origin="lower", cmap="RdBu_r", vmin=-2, vmax=2, aspect="auto")
        for i in range(len(snrs)):
            for j in range(len(seps)):
                if np.isfinite(val[i, j]):
                    txt = f"{val[i, j]:.2g}"
                    bold = val[i, j] <= PAPER_RATIO or val[i, j] >= 1
                    ax.text(j, i, txt, ha="center", va="center", fontsize=6,
                            fontweight="bold" if bold else "normal")
        ax.set_xticks(range(len(seps)), [f"{s:g}" for s in seps])
        ax.set_yticks(range(len(snrs)), [f"{s:g}" for s in snrs])
        ax.set_xlabel("separation within one range cell (deg)")
        ax.set_ylabel("per-slot SNR at unit gain (dB)")
        ax.set_title(f"group error RHS / phased, K={k} (blue: RHS better; 1/3 = paper)")
        fig.colorbar(im, ax=ax, label="log10 ratio")
    fig.tight_layout()
    fig.savefig(path, dpi=140)
    plt.close(fig)


def _resolution_figure(plt: Any, data: dict, path: Path) -> None:
    pc = data["pointcloud"]
    k = min(c["k"] for c in pc["cells"])
    seps = sorted({c["sep_deg"] for c in pc["cells"]})
    snrs = sorted({c["snr_db"] for c in pc["cells"]})
    ants = list(data["antenna_properties"]["default"])
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.5))
    colors = dict(zip(ants, plt.cm.tab10(np.arange(len(ants)))))
    for a in ants:
        for s, ls in zip(dict.fromkeys((snrs[-1], snrs[len(snrs) // 2])), ("-", "--")):
            cs = sorted([c for c in pc["cells"] if c["antenna"] == a and c["k"] == k and c["snr_db"] == s],
                        key=lambda c: c["sep_deg"])
            a1.plot([c["sep_deg"] for c in cs], [_v(c["resolution_prob"]) for c in cs], ls, marker="o",
                    color=colors[a], label=f"{a}, {s:g} dB")
        cs = sorted([c for c in pc["cells"] if c["antenna"] == a and c["k"] == k and c["sep_deg"] == seps[-1]],
                    key=lambda c: c["snr_db"])
        a2.plot([c["snr_db"] for c in cs], [_v(c["angle_rmse_deg"]) for c in cs], "o-", color=colors[a],
                label=f"{a} RMSE")
        a2.plot([c["snr_db"] for c in cs], [c["crb_group_deg"] for c in cs], ":", marker="x", color=colors[a],
                label=f"{a} CRB")
    a1.set_xscale("log")
    a1.xaxis.set_major_formatter(matplotlib_ticker().ScalarFormatter())
    a1.set_xlabel("separation (deg)")
    a1.set_ylabel("P(all K resolved)")
    a1.set_title(f"resolution, K={k}")
    a1.legend(fontsize=7)
    a2.set_yscale("log")
    a2.set_xlabel("per-slot SNR at unit gain (dB)")
    a2.set_ylabel("angle RMSE of matched targets (deg)")
    a2.set_title(f"accuracy vs CRB, K={k}, {seps[-1]:g} deg apart")
    a2.legend(fontsize=7, ncol=2)
    for ax in (a1, a2):
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=140)
    plt.close(fig)


def matplotlib_ticker() -> Any:
    import matplotlib.ticker

    return matplotlib.ticker


def _slam_figure(plt: Any, data: dict, path: Path) -> None:
    sl = data["slam"]
    regs = [k for k in sl["cells"][0] if isinstance(sl["cells"][0][k], dict)]
    cells = sorted(sl["cells"], key=lambda c: (c["k"], c["sep_deg"], -c["snr_db"], c["antenna"]))
    fig, ax = plt.subplots(figsize=(max(8, 0.5 * len(cells)), 4.5))
    x = np.arange(len(cells))
    w = 0.8 / len(regs)
    for n, g in enumerate(regs):
        m = np.array([_v(c[g]["ate_m"]) for c in cells])
        lo = np.array([_v(c[g]["ate_m"][1:]) for c in cells])
        hi = np.array([_v(c[g]["ate_m"][2:]) for c in cells])
        err = np.nan_to_num(np.vstack([m - lo, hi - m]))
        ax.bar(x + n * w, m, w, yerr=err, capsize=2, label=f"registration: {g}")
    ax.set_xticks(x + w * (len(regs) - 1) / 2,
                  [f"{c['antenna']}\nK={c['k']} {c['sep_deg']:g}°\n{c['snr_db']:g} dB" for c in cells], fontsize=6)
    ax.set_yscale("log")
    ax.set_ylabel("ATE (m)")
    ax.set_title("SLAM vehicle-position RMSE, 95 % t-intervals")
    ax.legend(fontsize=7)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=140)
    plt.close(fig)


def _elements_figure(plt: Any, data: dict, path: Path) -> None:
    rows = [r for r in data["elements"]["ratios"] if r["antenna"] == "rhs"]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for s in sorted({r["sep_deg"] for r in rows}):
        for snr, ls in zip(sorted({r["snr_db"] for r in rows}), ("--", "-", ":")):
            rr = sorted([r for r in rows if r["sep_deg"] == s and r["snr_db"] == snr], key=lambda r: r["elements"])
            ax.plot([r["elements"] for r in rr], [_v(r["ospa_ratio"]) for r in rr], ls, marker="o",
                    label=f"{s:g}° apart, {snr:g} dB")
    ax.axhline(PAPER_RATIO, color="k", lw=0.8, ls=":", label="paper: 1/3")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("RHS elements M (phased: round(M / 6))")
    ax.set_ylabel("group error RHS / phased")
    ax.legend(fontsize=6, ncol=2)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=140)
    plt.close(fig)
