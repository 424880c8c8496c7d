"""Traffic alignment: the compiled traffic core (``sim="compiled"``) against highway-env, seed by seed.

``python scripts/traffic_alignment.py [--seeds 50] [--steps 200] [--scenes highway dense paper paper-default]
[--out results/traffic_alignment.json]`` drives every scene with both sims for ``--steps`` uniformly
random meta-actions per seed (:func:`rhs_env.traffic.alignment.align_episode`) and writes the comparison
(JSON + a Markdown table beside it). The acceptance, per scene:

* the same lane changes, crashes and terminations (every vehicle's lane, target lane and crash flag, and
  ``terminated`` / ``truncated``, at every step) on at least 49 of 50 seeds;
* every vehicle's position within 1e-6 m and speed within 1e-6 m/s, and the rewards within 1e-9, wherever
  the discrete decisions agree.

It also times both sims on the same episodes (steps/s of the bare scene, the cheap base observation).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rhs_studies.kit.provenance import write_json

#: the acceptance (module docstring)
POSITION_TOL_M, SPEED_TOL_MPS, REWARD_TOL = 1e-6, 1e-6, 1e-9
#: seeds that must agree, as a share of those driven (49 of 50)
AGREE_SHARE = 0.98


def scene_summary(scene: str, seeds: int, steps: int,
                  on_episode: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """Every seed of ``scene`` and the summary against the acceptance (:func:`summarise`).

    Args:
        scene: a key of :data:`rhs_env.traffic.alignment.SCENES`.
        seeds: seeds 0 .. seeds - 1.
        steps: env steps per seed.
        on_episode: called with the summary of the seeds driven so far after each seed (a checkpoint).

    Returns:
        The summary of every seed.
    """
    from rhs_env.traffic.alignment import align_episode

    t0 = time.perf_counter()
    episodes = []
    for seed in range(seeds):
        episodes.append(align_episode(scene, seed, steps))
        if on_episode is not None and seed < seeds - 1:
            on_episode(summarise(scene, seeds, steps, episodes, time.perf_counter() - t0))
    return summarise(scene, seeds, steps, episodes, time.perf_counter() - t0)


def summarise(scene: str, seeds: int, steps: int, episodes: list[Any], wall: float) -> dict[str, Any]:
    """The summary of ``episodes`` (:class:`rhs_env.traffic.alignment.EpisodeAlignment`, the first seeds of
    ``seeds``); ``passes`` only once every seed was driven (``seeds_done`` says how many were)."""
    agree = [e for e in episodes if e.agrees and e.terminated_at == e.terminated_at_compiled]
    summary: dict[str, Any] = {
        "scene": scene,
        "seeds": seeds,
        "seeds_done": len(episodes),
        "steps": steps,
        "seeds_agreeing": len(agree),
        "max_position_diff_m": max(e.max_position_diff_m for e in episodes),
        "max_speed_diff_mps": max(e.max_speed_diff_mps for e in episodes),
        "max_reward_diff": max(e.max_reward_diff for e in episodes),
        "lane_changes": sum(e.lane_changes for e in episodes),
        "episodes_terminated": sum(1 for e in episodes if e.terminated_at),
        "crashed_vehicles": sum(e.crashed_vehicles for e in episodes),
        "wall_s": wall,
    }
    summary["passes"] = bool(
        len(episodes) == seeds and len(agree) >= AGREE_SHARE * seeds
        and summary["max_position_diff_m"] <= POSITION_TOL_M and summary["max_speed_diff_mps"] <= SPEED_TOL_MPS
        and summary["max_reward_diff"] <= REWARD_TOL)
    summary["episodes"] = [e.to_dict() for e in episodes]
    return summary


def within_tolerance(episode: dict[str, Any]) -> bool:
    """Whether an episode's positions, speeds and rewards are within the tolerances (before any discrete mismatch)."""
    return (episode["max_position_diff_m"] <= POSITION_TOL_M and episode["max_speed_diff_mps"] <= SPEED_TOL_MPS
            and episode["max_reward_diff"] <= REWARD_TOL)


def done(scene: dict[str, Any]) -> str:
    """The seeds driven, as ``"50"``, or ``"17 of 50"`` for a run that ended early."""
    n = scene.get("seeds_done", scene["seeds"])
    return str(n) if n == scene["seeds"] else f"{n} of {scene['seeds']}"


def markdown(result: dict[str, Any]) -> str:
    """The results table (``results/traffic_alignment.md``), and the episodes outside the tolerances."""
    lines = [
        "| scene | seeds x steps | seeds with the same decisions | seeds within the tolerances | max position diff (m) "
        "| max speed diff (m/s) | max reward diff | lane changes | episodes ended by a crash | vehicles crashed | passes |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    outside = []
    for s in result["scenes"]:
        within = sum(within_tolerance(e) for e in s["episodes"])
        outside += [(s["scene"], e) for e in s["episodes"] if not within_tolerance(e)]
        lines.append(
            f"| {s['scene']} | {done(s)} x {s['steps']} | {s['seeds_agreeing']} / {done(s)} "
            f"| {within} / {done(s)} | {s['max_position_diff_m']:.1e} | {s['max_speed_diff_mps']:.1e} "
            f"| {s['max_reward_diff']:.1e} | {s['lane_changes']} | {s['episodes_terminated']} | {s['crashed_vehicles']} "
            f"| {'yes' if s['passes'] else '**no**'} |")
    lines.append("")
    for scene, e in outside:
        lines.append(f"Outside the tolerances: {scene} seed {e['seed']}, position {e['max_position_diff_m']:.1e} m, "
                     f"speed {e['max_speed_diff_mps']:.1e} m/s (the same decisions at every step).")
    if outside:
        lines.append("")
    lines.append(f"Acceptance: the same lane changes, crashes and terminations on at least {AGREE_SHARE:.0%} of the "
                 f"seeds; positions within {POSITION_TOL_M:g} m, speeds within {SPEED_TOL_MPS:g} m/s and rewards "
                 f"within {REWARD_TOL:g} wherever the decisions agree. Uniformly random meta-actions, the same for "
                 "both sims; the episodes run on past the ego's crash (the traffic goes on).")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=50)
    p.add_argument("--steps", type=int, default=200)
    from rhs_env.traffic.alignment import SCENES

    p.add_argument("--scenes", nargs="*", default=list(SCENES), choices=list(SCENES),
                   help="scenes to drive (none: only merge the --add files)")
    p.add_argument("--out", default="results/traffic_alignment.json")
    p.add_argument("--add", nargs="*", default=[], metavar="JSON",
                   help="results of other runs of this script (other --scenes, the same --seeds and --steps) whose "
                        "scenes go into --out beside this run's (their provenance kept under 'parts')")
    a = p.parse_args(argv)
    if a.seeds < 1 or a.steps < 1:
        p.error(f"--seeds and --steps must be >= 1, got {a.seeds} and {a.steps}")
    started = time.time()
    parts = [json.loads(Path(f).read_text()) for f in a.add]
    for part in parts:
        config = part["provenance"]["config"]
        if (config["seeds"], config["steps"]) != (a.seeds, a.steps):
            p.error(f"--add: a run of {config['seeds']} seeds x {config['steps']} steps, not {a.seeds} x {a.steps}")
    added: list[dict[str, Any]] = []
    for s in (s for part in parts for s in part["scenes"]):  # each scene once: this run's, else the first part's
        if s["scene"] not in a.scenes and s["scene"] not in [t["scene"] for t in added]:
            added.append(s)
    scenes: list[dict[str, Any]] = []
    out = Path(a.out)
    if not a.scenes and not added:
        p.error("nothing to do: give --scenes, or --add files to merge")
    result: dict[str, Any] = {}

    def write(current: list[dict[str, Any]]) -> None:
        result.clear()
        result.update(scenes=current + added, passes=all(s["passes"] for s in current + added),
                      parts=[part["provenance"] for part in parts])
        write_json(out, result, __file__, a, started, argv=argv)  # no fingerprint: see rhs_studies.upkeep.reproduce
        out.with_suffix(".md").write_text(markdown(result))

    for scene in a.scenes:  # written after every seed: a long run keeps the seeds it finished
        scenes.append(scene_summary(scene, a.seeds, a.steps, lambda partial: write([*scenes, partial])))
        print(json.dumps({k: v for k, v in scenes[-1].items() if k != "episodes"}), flush=True)
        write(scenes)
    if not a.scenes:
        write(scenes)
    print(f"acceptance {'met' if result['passes'] else 'NOT met'} (results in {out.with_suffix('.md')})", flush=True)
    return 0  # a record of the comparison, as the benchmark's goals are (scripts/reproduce.py runs on)


if __name__ == "__main__":
    sys.exit(main())
