"""Tables and paired intervals of the driving studies: a policy's row (return, collisions, speed), paired return
differences over common seeds, and their Markdown.

Every driving study's table has the same five columns (policy, return with its 95 % t interval, collisions with a
Wilson interval, mean speed, a paired difference against a reference row); these functions write them, so a page
renders the same numbers the same way whichever study drove them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from rhs_common.stats import mean_interval, paired_difference, wilson_interval

#: the fields of an episode the driving studies' results keep (:func:`slim_runs`)
SLIM = ("seed", "return", "crashed", "mean_speed")
#: the table's header, the paired column named by the caller
HEADER = "| policy | return (95 % CI) | collisions [Wilson 95 %] | speed m/s | {paired} (paired, 95 % CI) |"
RULE = "|---|---|---|---|---|"


def paired(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> dict[str, float]:
    """Paired return difference a - b of two policies' episodes over their common seeds (t interval).

    Args:
        a: episodes (``seed``, ``return``) of one policy.
        b: episodes of the reference.

    Returns:
        ``mean``, ``low``, ``high`` (95 %) and ``n`` (common seeds).
    """
    by_b = {r["seed"]: r["return"] for r in b}
    common = [r for r in a if r["seed"] in by_b]
    d = paired_difference([r["return"] for r in common], [by_b[r["seed"]] for r in common])
    return {"mean": d.mean, "low": d.low, "high": d.high, "n": len(common)}


def paired_text(d: Mapping[str, float]) -> str:
    """A paired difference (:func:`paired`) as mean [low, high].

    >>> paired_text({"mean": 3.14, "low": 1.5, "high": 4.72})
    '+3.1 [+1.5, +4.7]'
    """
    return f"{d['mean']:+.1f} [{d['low']:+.1f}, {d['high']:+.1f}]"


def row_summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean return (t interval), collisions (Wilson interval), mean speed of one policy's episodes."""
    returns = [r["return"] for r in runs]
    crashes = sum(bool(r["crashed"]) for r in runs)
    ret = mean_interval(returns)
    low, high = wilson_interval(crashes, len(runs))
    speed = mean_interval([r["mean_speed"] for r in runs])
    return {"episodes": len(runs), "return": {"mean": ret.mean, "half": ret.half_width, "min": float(np.min(returns))},
            "collisions": crashes, "collision_rate": crashes / len(runs), "collision_interval": [low, high],
            "mean_speed_mps": {"mean": speed.mean, "half": speed.half_width}}


def table_row(label: str, s: Mapping[str, Any], gain: Mapping[str, float] | None) -> str:
    """One row of a results table: the policy's ``label``, its :func:`row_summary` ``s`` and its paired difference
    ``gain`` (None: blank)."""
    lo, hi = s["collision_interval"]
    diff = "" if gain is None else paired_text(gain)
    return (f"| {label} | {s['return']['mean']:.1f} +- {s['return']['half']:.1f} | "
            f"{s['collisions']}/{s['episodes']} [{100 * lo:.0f}-{100 * hi:.0f} %] | "
            f"{s['mean_speed_mps']['mean']:.1f} | {diff} |")


def met_text(met: Mapping[str, bool]) -> str:
    """``{"collisions": True, "speed": False}`` as ``collisions met, speed not met``."""
    return ", ".join(f"{k} {'met' if ok else 'not met'}" for k, ok in met.items())


def targets_line(tg: Mapping[str, Any], judged: str) -> str:
    """A fine-tune's targets (:func:`rhs_studies.kit.driving.targets`) on the test seeds, judged on ``judged``."""
    return (f"Targets judged on {judged}: {tg['return_vs_idm']:.3f}x IDM + MOBIL, "
            f"{100 * tg['collision_rate']:.0f} % collisions, {tg['mean_speed_mps']:.1f} m/s, "
            f"{paired_text(tg['gain_over_student'])} over the shield student, "
            f"{paired_text(tg['gain_over_control'])} over the DAgger control; targets: {met_text(tg['met'])}.")


def slim_runs(runs: Mapping[str, list[dict]], fields: tuple[str, ...] = SLIM) -> dict[str, list[dict]]:
    """Each row's episodes with only ``fields`` (those the results keep)."""
    return {k: [{f: e.get(f) for f in fields} for e in r] for k, r in runs.items()}


def mean_return(runs: list[dict[str, Any]]) -> float:
    """The mean return of a row's episodes."""
    return float(np.mean([e["return"] for e in runs]))


def collisions(runs: list[dict[str, Any]]) -> int:
    """The episodes of a row that ended in a collision."""
    return sum(bool(e["crashed"]) for e in runs)


def snr_at(pd: list[float], snr_db: np.ndarray, level: float) -> float | None:
    """SNR (dB) where a Pd curve first reaches ``level`` (linear interpolation), None if never."""
    p = np.maximum.accumulate(np.asarray(pd, float))
    if p[-1] < level:
        return None
    k = int(np.argmax(p >= level))
    if k == 0:
        return float(snr_db[0])
    return float(np.interp(level, [p[k - 1], p[k]], [snr_db[k - 1], snr_db[k]]))


__all__ = ["HEADER", "RULE", "SLIM", "collisions", "mean_return", "met_text", "paired", "paired_text", "row_summary",
           "slim_runs", "snr_at", "table_row", "targets_line"]
