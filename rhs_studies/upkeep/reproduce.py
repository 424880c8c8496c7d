"""Regenerate every file in ``results/`` and the pages that show them, or only some of them.

Each step runs one script (a subprocess, single-threaded BLAS) with the options that
made the published numbers, then ``scripts/write_results_pages.py`` copies the tables into
the documentation's results pages (``docs/results/``) and the README's headline table.
The run-time estimate comes from the ``provenance.wall_s`` each results file recorded
(``STEPS[*].guess_s`` where none is recorded yet); the progress bar advances in
estimated seconds.

    python scripts/reproduce.py --list                     # steps, their state and estimated time
    python scripts/reproduce.py                            # everything (hours: trains the CNN and the policies)
    python scripts/reproduce.py --only fig5b fig5c         # some steps
    python scripts/reproduce.py --only slam_accuracy_before   # 'before' records run only when named
    python scripts/reproduce.py --fingerprints-only --only fig5a --reason "SLAM proposal changed; full rerun at the end"

``--fingerprints-only`` reruns only the small-config fingerprints (seconds each) and,
with ``--reason``, records those that changed in ``results/fingerprints.json``. That
does not make the old numbers fresh: their results files keep the fingerprint of the
code that produced them, so they show as *unverified* (with the reason) on their pages
until the step is rerun. See ``rhs_studies/kit/provenance.py`` for the design.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from rhs_studies.kit.provenance import (
    RESULTS,
    ROOT,
    compute_fingerprint,
    fingerprint_matches,
    load_fingerprints,
    record_fingerprint,
    script_name,
    verification,
)
from rhs_studies.kit.subprocess_env import study_env

SCRIPTS = ROOT / "scripts"
#: studies whose module was renamed after results were recorded: ``scripts/<launcher>.py`` (the recorded command and
#: the key in fingerprints.json) runs ``rhs_studies.<module>``
RENAMED_STUDIES = {"rl_lane_test": "rl_lane_rule_trial"}


@dataclass(frozen=True)
class Step:
    """One script run: ``python scripts/<script> <args>`` writing ``results/<results>``."""

    name: str
    script: str
    args: tuple[str, ...] = ()
    results: tuple[str, ...] = ()
    guess_s: float = 600.0  # estimate (s, quiet 2-core machine) when no results file recorded a run time
    note: str = ""
    env: dict = field(default_factory=dict)
    #: why the script has no ``fingerprint()`` (timings, or a training run that takes minutes even when tiny)
    no_fingerprint: str = ""
    #: run only when named with ``--only`` (historical 'before' records of a change)
    on_request: bool = False
    #: another environment's Python, relative to the repository (an optional extra that conflicts with the base pins)
    python: str = ""


#: every results file and the step that writes it, in dependency order (libraries and weights first)
STEPS: tuple[Step, ...] = (
    Step("patterns_build", "build_patterns.py", ("--json", "results/patterns_build.json"),
         ("patterns_build.json",), 200, "rebuilds the shipped pattern libraries"),
    Step("patterns_sidelobe_limits", "pattern_sidelobe_limits.py",
         ("--caps", "-16.5", "-18", "-20", "--angles", "12.5", "13.5", "17.5", "18.5", "25.5", "36.5", "37.5", "38.5",
          "39.5", "40.5", "41.5", "42.5", "43.5", "44.5"), ("patterns_sidelobe_limits.json",), 1200,
         "the 14 one-degree grids worse than -20 dB, optimised under tighter caps"),
    Step("patterns_sdr_vs_fast", "compare_pattern_methods.py", (), ("patterns_sdr_vs_fast.json",), 260),
    Step("registration", "train_registration.py", ("--no-progress",), ("registration.json",), 400,
         "retrains the shipped CNN weights"),
    Step("fig5a", "fig5a_slam_rmse.py", ("--seeds", "20", "--powers", "30", "20", "10", "0", "-10", "--workers", "2",
                                   "--no-progress"),
         ("fig5a.json",), 900),
    Step("fig5b", "fig5b_pointcloud_vs_elements.py", ("--elements", "20", "40", "60", "80", "--grids", "1", "2", "5"),
         ("fig5b.json",), 1800),
    Step("fig5c", "fig5c_trajectory_map.py", ("--no-progress",), ("fig5c.json",), 60),
    Step("registration_in_loop", "registration_in_loop.py", ("--no-progress",), ("registration_in_loop.json",), 900),
    Step("radar_quality", "radar_quality.py", ("--out", "results/radar_quality_after.json"),
         ("radar_quality_after.json",), 300),
    Step("radar_profiles", "radar_profiles.py", ("--no-progress", "--out", "results/radar_profiles.json"),
         ("radar_profiles.json",), 900, "speed against quality of the processing settings"),
    Step("radar_quality_before", "radar_quality.py", ("--fidelity", "iq", "--out", "results/radar_quality_before.json"),
         ("radar_quality_before.json",), 600, on_request=True, no_fingerprint="the 'before' record of the radar change, kept "
         "for comparison: measured on the code before it; the command is its closest equivalent at HEAD"),
    Step("slam_accuracy", "slam_accuracy.py", ("--parts", "highway", "paper", "dense", "drivers", "--workers", "2"),
         ("slam_accuracy.json",), 7200, "the tuned drives, and the three drivers (IDM + MOBIL, the shipped policy, "
         "random actions) on both envs on 100 seeds held out from every tuning (1600-1699; ~35-50 min on 2 cores)"),
    Step("slam_accuracy_before", "slam_accuracy.py",
         ("--slam", '{"variant": "fastslam1", "association": "nearest", "measurement_noise": "fixed"}',
          "--out", "results/slam_accuracy_before", "--no-progress"),
         ("slam_accuracy_before.json",), 1800, on_request=True, no_fingerprint="the 'before' record of the SLAM change, "
         "kept for comparison: measured on the code before it; the command is the first-round model at HEAD"),
    Step("slam_roads", "slam_accuracy.py", ("--parts", "roads", "--out", "results/slam_roads", "--no-progress"),
         ("slam_roads.json",), 1800, "the SLAM on highway-env's merge, roundabout, intersection, exit and racetrack "
         "(IDM + MOBIL and random actions, 20 held-out seeds each, the 5-degree scan grid; ~25 min on 2 cores)",
         no_fingerprint="a part of scripts/slam_accuracy.py, whose code the slam_accuracy step fingerprints (one "
         "fingerprinted step per script); the roads' own figures are checked by tests/test_road_envs.py"),
    Step("train_policy", "train_policy.py", ("--no-progress", "--algo", "dagger", "--only", "slam", "truth",
                                             "truth_all_around", "slam_rhs", "slam_phased", "dense", "dense_phased"),
         ("train_policy.json",), 7200,
         "trains the DAgger policies (PPO: --algo ppo)", no_fingerprint="a record of training runs (timesteps, wall time); "
         "what the policies do is fingerprinted by the policies step"),
    Step("policies", "evaluate_policies.py", (), ("policies.json",), 220),
    Step("episode_video", "make_video.py", (), ("episode_video.json",), 60,
         no_fingerprint="an animation (results/episode.gif, the front page's video): pixels that no tolerance compares; "
         "the drive it shows is the shipped policy's, whose numbers the policies step guards"),
    Step("rl_finetune", "rl_finetune.py", ("--train",), ("rl_finetune.json",), 16000,
         "PPO fine-tune of the student with its controls and the lookahead teacher's student (trains the arms missing "
         "in runs/rl: ~10-20 min per 20k env steps, ~45 min per 80k arm, ~35 min for the lookahead's 48k), then 100 "
         "held-out seeds per policy (~4 min each on 2 cores)"),
    Step("rl_confirm", "rl_confirm.py", (), ("rl_confirm.json",), 2100,
         "the RL study's two exploring shield fine-tunes: the choice on fresh validation seeds, one test on fresh seeds"),
    Step("rl_lane_test", "rl_lane_test.py", (), ("rl_lane_test.json",), 2700,
         "the chosen fine-tune behind two stricter lane rules of the shield: the choice on validation seeds, one test "
         "on fresh seeds"),
    Step("teachers", "teachers.py", (), ("teachers.json",), 500,
         "the headway driver against the lookahead teachers on validation seeds (rhs-highway-v0)"),
    Step("crash_analysis", "crash_analysis.py", (), ("crash_analysis.json",), 700,
         "the shipped radar + SLAM student's crashes against the expert's labels"),
    Step("detection_curves", "detection_curves.py", (), ("detection_curves.json",), 600),
    Step("long_drive", "long_drive.py", (), ("long_drive.json",), 600,
         "3,000-cycle (10 min) highway SLAM drives, IDM + MOBIL at 15 m/s, seeds 1700-1702: NEES, KITTI drift, memory, "
         "step time against the cycle (~1 min per seed on a quiet core)"),
    Step("long_drive_calibrated", "long_drive.py", ("--pose-covariance", "calibrated"), ("long_drive_calibrated.json",),
         600, "the same drives with the calibrated pose covariance (fitted on 50-cycle drives)",
         no_fingerprint="the long_drive step's fingerprint covers the study; this step changes one env option"),
    Step("racetrack_loops", "racetrack_loops.py", (), ("racetrack_loops.json",),
         2400, "the racetrack over 5 laps with the loop closure off and on, then a keep_map episode (10 seeds)"),
    Step("bc_from_dataset", "bc_from_dataset.py",
         ("--datasets", "data", "--dataset-id", "rhs-slam/highway-slam-fast/shipped-v0", "--out", "runs/bc", "--labels",
          "decisions", "--like", "agents/data/shipped.zip", "--eval-env", "rhs-highway-slam-v0", "--eval-episodes", "30",
          "--eval-seed", "31000", "--seed-set", "bc_test", "--compare", "agents/data/shipped.zip", "--results",
          "results/bc_from_dataset.json"), ("bc_from_dataset.json",), 3600,
         "behaviour cloning of the shipped policy from a dataset recorded first with rhs-slam record "
         "(docs/usage/datasets.md has the recording command)",
         no_fingerprint="needs a Minari dataset recorded first (rhs-slam record, hours for 100k steps)", on_request=True),
    Step("campaign_select", "campaign.py", ("select", "--recipe", "ppo_scratch", "--seeds", "0", "1", "2"),
         ("campaign_select_ppo_scratch.json",), 600, "the checkpoint each PPO-from-scratch run is tested with: the "
         "chunks' best against the latest, on 50 validation seeds (writes campaign/ppo_scratch/seed<k>/chosen.zip)",
         no_fingerprint="a choice among the committed training checkpoints (minutes of driving per run)"),
    Step("campaign_curves", "campaign.py", ("curves", "--recipe", "ppo_scratch", "--seeds", "0", "1", "2"),
         ("campaign_ppo_scratch.json",), 60, "the training campaign's learning curves, read from its committed "
         "checkpoints (campaign/; the training itself: scripts/campaign.py train, a chunk at a time)",
         no_fingerprint="a record of training runs (env steps, returns, wall time), read from the committed state"),
    Step("campaign_curves_student", "campaign.py", ("curves", "--recipe", "ppo_student", "--seeds", "0", "1", "2"),
         ("campaign_ppo_student.json",), 60, "the imitation + RL recipe's learning curves (PPO from the DAgger "
         "student's weights), read from its committed checkpoints (campaign/ppo_student/)",
         no_fingerprint="a record of training runs (env steps, returns, wall time), read from the committed state"),
    Step("campaign_curves_student_safe", "campaign.py",
         ("curves", "--recipe", "ppo_student_safe", "--seeds", "0", "1", "2"), ("campaign_ppo_student_safe.json",), 60,
         "the learning curves of the imitation + RL recipe trained on a reward that prices the crash "
         "(ppo_student_safe), read from its committed checkpoints (campaign/ppo_student_safe/)",
         no_fingerprint="a record of training runs (env steps, returns, wall time), read from the committed state"),
    Step("shield_table_scripted", "shield_table.py",
         ("--arms", "idm", "headway", "constant:1", "constant:3", "--envs", "exact", "fast", "--seed", "21100",
          "--episodes", "100", "--out", "results/shield_table_scripted.json"), ("shield_table_scripted.json",), 2400,
         "the shield as a measured feature on the campaign's 100 test seeds (21100-21199): the scripted and trivial "
         "arms with and without it, exact and fast env (the campaign's runs join the table, --merge, when it ends)",
         no_fingerprint="100 episodes per arm, env and shield on the exact env; the table's arithmetic is tested"),
    Step("shield_table", "shield_table.py",
         ("--arms", "campaign:ppo_scratch:seed0", "campaign:ppo_scratch:seed1", "campaign:ppo_scratch:seed2",
          "--envs", "exact", "fast", "--seed", "21100", "--episodes", "100", "--merge",
          "results/shield_table_scripted.json", "--out", "results/shield_table.json"), ("shield_table.json",), 2400,
         "the campaign's test: each PPO-from-scratch run's chosen checkpoint on the 100 test seeds, with and without "
         "the shield, exact and fast env, beside the scripted arms (merged from shield_table_scripted.json)",
         no_fingerprint="100 episodes per arm, env and shield on the exact env; the table's arithmetic is tested"),
    Step("campaign_select_student", "campaign.py", ("select", "--recipe", "ppo_student", "--seeds", "0", "1", "2"),
         ("campaign_select_ppo_student.json",), 600, "the checkpoint each imitation + RL run is tested with: the "
         "chunks' best against the latest, on 50 validation seeds (writes campaign/ppo_student/seed<k>/chosen.zip)",
         no_fingerprint="a choice among the committed training checkpoints (minutes of driving per run)"),
    Step("shield_table_student_scripted", "shield_table.py",
         ("--recipe", "ppo_student", "--arms", "idm", "headway", "agents/data/dagger_rhs_highway_slam.zip",
          "agents/data/shipped.zip", "constant:1", "constant:3", "--envs", "exact", "fast", "--seed", "21100",
          "--episodes", "100", "--out", "results/shield_table_student_scripted.json"),
         ("shield_table_student_scripted.json",), 3600,
         "the imitation + RL recipe's env settings (5-degree scan) on the campaign's 100 test seeds: IDM + MOBIL, the "
         "headway driver, the DAgger student the recipe starts from, the shipped policy and the trivial policies "
         "(always IDLE, always FASTER), with and without the shield",
         no_fingerprint="100 episodes per arm, env and shield on the exact env; the table's arithmetic is tested"),
    Step("shield_table_student", "shield_table.py",
         ("--recipe", "ppo_student", "--arms", "campaign:ppo_student:seed0", "campaign:ppo_student:seed1",
          "campaign:ppo_student:seed2", "--envs", "exact", "fast", "--seed", "21100", "--episodes", "100",
          "--versus", "agents/data/dagger_rhs_highway_slam.zip", "--merge", "results/shield_table_student_scripted.json",
          "--out", "results/shield_table_student.json"), ("shield_table_student.json",), 2400,
         "the imitation + RL recipe's test: each run's chosen checkpoint on the 100 test seeds, with and without the "
         "shield, exact and fast env, each paired against the DAgger student it started from",
         no_fingerprint="100 episodes per arm, env and shield on the exact env; the table's arithmetic is tested"),
    Step("campaign_floor", "campaign_report.py", ("floor", "--steps", "150", "--ppo-steps", "640"),
         ("campaign_floor.json",), 300, "env steps per CPU second of the fast and exact SLAM envs and of the "
         "campaign's PPO, and the hours its target budget needs", no_fingerprint="timings"),
    Step("low_snr_slam", "low_snr_slam.py", ("--seeds", "100", "101", "102", "103", "104", "105", "106", "107"),
         ("low_snr_slam.json",), 900),
    Step("pose_calibration", "calibrate_pose_covariance.py", ("--spread", "4"), ("pose_calibration_spread.json",), 600,
         "the shipped pose-covariance calibrations (slam/data/pose_calibration/: 40 IDM + MOBIL drives of 50 cycles "
         "per configuration, seeds 13000-13039) and how fits on 10 of those drives vary and carry to the other 30",
         no_fingerprint="writes package data (the calibrations); what they make the covariance do is the "
         "pose_covariance step's measurement"),
    Step("pose_covariance", "pose_covariance.py",
         ("--configs", "default", "fast", "grid5", "policy_env", "dense", "phased", "random", "low_snr",
          "default_policy", "fast_policy", "dense_policy", "phased_policy", "random_policy", "low_snr_policy",
          "--seeds", *(str(s) for s in range(12000, 12040)),
          "--cycles", "50", "--workers", "2"),
         ("pose_covariance.json",), 2400,
         "NEES of the calibrated and adaptive pose covariances and of the drift densities, 7 configurations driven by "
         "IDM + MOBIL and by the shipped policy x 40 held-out seeds (each configuration calibrated at first use on "
         "seeds 13000-13039 unless shipped)",
         no_fingerprint="a calibration measurement of a report-only, opt-in covariance (pipeline option "
         "pose_covariance='calibrated'): no default path's numbers depend on it; its tests check it on a short drive"),
    Step("pose_covariance_150", "pose_covariance.py",
         ("--configs", "default", "fast", "grid5", "dense", "phased", "random", "low_snr",
          "--seeds", *(str(s) for s in range(12000, 12020)), "--cycles", "150", "--workers", "2",
          "--name", "pose_covariance_150"), ("pose_covariance_150.json",), 1800,
         "the same calibrations on drives three times as long as their calibration drives: 150 cycles, IDM + MOBIL, "
         "20 held-out seeds per configuration",
         no_fingerprint="the pose_covariance step's study at another drive length (the study has no fingerprint: "
         "a calibration measurement of a report-only, opt-in covariance)"),
    Step("claim_study", "claim_study.py", (), ("claim_study.json",), 3600,
         "point-cloud, element and SLAM levels; resumes from results/claim_study_cache_*.jsonl"),
    Step("ablations", "ablate_policy.py", ("--fresh",), ("ablations.json",), 4500,
         "short PPO and DAgger ablations (ablate_policy.REPRODUCE)",
         no_fingerprint="a record of training runs (minutes each even when tiny); "
         "the policies they make are evaluated on the same seeds as the policies step"),
    Step("traffic_alignment", "traffic_alignment.py", (), ("traffic_alignment.json",), 600,
         "the compiled traffic core against highway-env, 50 seeds x 200 steps per scene",
         no_fingerprint="an equivalence check of two implementations, not numbers of the code: its differences are "
         "rounding-level and vary by CPU; a short version runs in tests/test_traffic_core.py on every test run"),
    Step("fast_radar_calibration", "calibrate_fast_radar.py", (), (), 600,
         "rebuilds the fast radar's shipped table (rhs_env/data/fast_radar_<key>.npz) from the exact radar",
         no_fingerprint="writes package data (the fast radar's table), no results file; what the table makes the fast "
         "radar do is fingerprinted by the fast_radar_fidelity step"),
    Step("fast_radar_fidelity", "fast_radar_fidelity.py", ("--workers", "4"), ("fast_radar_fidelity.json",), 1500,
         "the fast radar against the exact one on the same scenes, the SLAM on 20 paired seeds, steps/s"),
    Step("benchmark_radar", "benchmark_radar.py", (), ("benchmark_radar.json",), 60, "timings",
         no_fingerprint="timings"),
    Step("benchmark", "benchmark.py", ("--out", "results/benchmark.json"), ("benchmark.json",), 900, "timings",
         no_fingerprint="timings"),
    Step("benchmark_rllib", "benchmark_rllib.py", (), ("benchmark_rllib.json",), 300,
         "timings; in the rllib environment (docs/usage/training.md: Ray RLlib)", no_fingerprint="timings",
         python=".venv-rllib/bin/python"),
    Step("kit_counts", "kit_counts.py", ("--rev", "8adb345"), ("kit_counts.json",), 30,
         "the research kit's counts (modules, lines, parsers, study-to-study imports, pools, kernels branches, "
         "duplicate pairs) before the kit (8adb345) and in this checkout",
         no_fingerprint="counts of the source tree, not numbers the code computes: they move with every commit to "
         "rhs_studies/; tests/test_kit_counts.py checks the rules they measure on this checkout"),
)
BY_NAME = {s.name: s for s in STEPS}


def step_for_result(result_name: str) -> Step | None:
    """The step that writes ``results/<result_name>`` (``fig5a.json`` or ``fig5a``)."""
    stem = Path(result_name).stem
    return next((s for s in STEPS if any(Path(r).stem == stem for r in s.results)), None)


def load_script(script: str):
    """The module of ``scripts/<script>``: :mod:`rhs_studies.<name>` for the studies the script launches, else the
    script file itself imported as a module (the scripts that are not yet in the kit)."""
    name = RENAMED_STUDIES.get(Path(script).stem, Path(script).stem)
    if importlib.util.find_spec(f"rhs_studies.{name}") is not None:
        return importlib.import_module(f"rhs_studies.{name}")
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / script)
    if spec is None or spec.loader is None:
        raise ImportError(f"{SCRIPTS / script} cannot be loaded as a module")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # dataclasses resolve their annotations through sys.modules
    spec.loader.exec_module(mod)
    return mod


def fingerprint_fn(step: Step):
    """The step's ``fingerprint()`` function, or None (timings have none)."""
    return getattr(load_script(step.script), "fingerprint", None)


def recorded_seconds(step: Step) -> float | None:
    """Run time recorded by the step's last run (``provenance.wall_s``), or None."""
    for r in step.results:
        try:
            data = json.loads((RESULTS / r).read_text())
        except (OSError, ValueError):
            continue
        prov = (data.get("provenance") if isinstance(data, dict) else None) or {}
        if (prov.get("config") or {}).get("report_only"):
            continue  # written from a cache: its wall time is not the step's
        if prov.get("wall_s") is not None:
            return float(prov["wall_s"])
    return None


def estimate(step: Step) -> float:
    return recorded_seconds(step) or step.guess_s


def _hms(s: float) -> str:
    return f"{int(s // 3600)}h{int(s % 3600 // 60):02d}m" if s >= 3600 else f"{int(s // 60)}m{int(s % 60):02d}s"


def list_steps(steps: list[Step]) -> None:
    fps = load_fingerprints()
    for s in steps:
        state = "; ".join(f"{r}: {'verified' if ok else 'UNVERIFIED'} ({why})"
                          for r in s.results for ok, why in [verification(RESULTS / r, fps)])
        src = "recorded" if recorded_seconds(s) else "guess"
        print(f"{s.name:22s} ~{_hms(estimate(s)):>8s} ({src})  scripts/{s.script} {' '.join(s.args)}\n"
              f"{'':24s}{state}" + (f"  [{s.note}]" if s.note else ""))
    print(f"total estimate: {_hms(sum(estimate(s) for s in steps))}")


def run_steps(steps: list[Step], progress: bool) -> int:
    from tqdm import tqdm

    env = study_env()
    total = sum(estimate(s) for s in steps)
    print(f"reproduce: {len(steps)} step(s), estimated {_hms(total)}", flush=True)
    failed = []
    with tqdm(total=round(total), unit="s", desc="reproduce (estimated s)", disable=not progress) as bar:
        for s in steps:
            bar.set_postfix_str(s.name)
            t0 = time.time()
            python = str(ROOT / s.python) if s.python else sys.executable
            if not Path(python).exists():
                failed.append(s.name)
                tqdm.write(f"reproduce: {s.name} needs {s.python} (see its note: {s.note}); skipped")
                continue
            cmd = [python, str(SCRIPTS / s.script), *s.args]
            proc = subprocess.run(cmd, cwd=ROOT, env={**env, **s.env}, check=False)
            bar.update(round(estimate(s)))
            if proc.returncode != 0:
                failed.append(s.name)
                tqdm.write(f"reproduce: {s.name} failed (exit {proc.returncode}) after {_hms(time.time() - t0)}")
    subprocess.run([sys.executable, str(SCRIPTS / "write_results_pages.py")], cwd=ROOT, check=False)
    if failed:
        print(f"reproduce: failed steps: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


def refresh_fingerprints(steps: list[Step], reason: str | None) -> int:
    """Recompute the fingerprints; with ``reason``, record the changed ones (their results become unverified)."""
    fps = load_fingerprints()
    changed = []
    for s in steps:
        fn = None if s.no_fingerprint else fingerprint_fn(s)
        if fn is None:
            continue
        fp = compute_fingerprint(fn)
        key = script_name(s.script)
        entry = fps.get(key)
        same, why = fingerprint_matches(entry, fp["values"]) if entry else (False, "none recorded")
        state = f"within tolerance ({why})" if same else f"CHANGED ({why})"
        print(f"{s.name:22s} {fp['seconds']:6.1f} s  {state}")
        if not same:
            changed.append(s.name)
            if reason:
                record_fingerprint(key, fp, list(s.results), f"refreshed without rerun: {reason}")
    if changed and not reason:
        print("fingerprints changed: rerun those steps (python scripts/reproduce.py --only "
              f"{' '.join(changed)}) or record the change with --reason", file=sys.stderr)
        return 1
    if changed:
        subprocess.run([sys.executable, str(SCRIPTS / "write_results_pages.py")], cwd=ROOT, check=False)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="+", choices=tuple(BY_NAME), help="run these steps only")
    ap.add_argument("--skip", nargs="+", choices=tuple(BY_NAME), default=[], help="leave these steps out")
    ap.add_argument("--list", action="store_true", help="list the steps, their state and estimated time")
    ap.add_argument("--fingerprints-only", action="store_true", help="recompute the small-config fingerprints only")
    ap.add_argument("--reason", default=None, help="with --fingerprints-only: record changed fingerprints, why")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    steps = [s for s in STEPS if (s.name in a.only if a.only else not s.on_request) and s.name not in a.skip]
    if a.list:
        list_steps(steps)
        return 0
    if a.fingerprints_only:
        return refresh_fingerprints(steps, a.reason)
    return run_steps(steps, not a.no_progress)


if __name__ == "__main__":
    sys.exit(main())
