"""Train the CNN registration on point clouds of this simulator and compare it with ICP.

1. Drives ``rhs-highway-radar-v0`` (traffic, roadside landmarks, the default RHS
   radar) with random lane/speed actions, and the paper's road with random sparse
   obstacle layouts, and records consecutive clouds and the true motion between them. As in
   :class:`slam.core.pipeline.SlamPipeline`, the ego velocity comes from the clouds' Doppler and moving
   points are removed.
2. Each pair gets ``priors_per_pair`` motion priors = truth + Gaussian error
   (``prior_std_m``, ``prior_std_rad``): the network learns the residual.
3. Trains the paper's CNN with the paper's loss; held-out pairs come from
   separate episodes (other seeds).
4. Reports translation and rotation RMSE of the prior alone, the CNN and ICP on
   the held-out pairs (same priors), writes the weights and
   ``results/registration.json`` / ``results/registration.md``.

    python scripts/train_registration.py                       # the shipped weights
    python scripts/train_registration.py --small --out /tmp/w.pt   # a quick run (tests)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rhs_common.geometry import wrap_angle
from rhs_studies.kit.provenance import write_json
from rhs_studies.kit.seeds import first

if TYPE_CHECKING:
    from rhs_env.wrappers import RadarObservation
    from slam.core.cnn_registration import GridMapConfig

ROOT = Path(__file__).resolve().parents[2]


def paper_like_env(rng: np.random.Generator, radar: dict | None) -> RadarObservation:
    """The paper's scene with a random sparse obstacle layout and ego speed (radar observation)."""
    from rhs_env.envs import RHSPaperEnv
    from rhs_env.registration import with_cheap_base_observation
    from rhs_env.wrappers import RadarObservation

    n = int(rng.integers(4, 11))
    side = rng.choice([10.0, 65.0], n) + rng.uniform(-8, 8, n)
    obstacles = np.column_stack([rng.uniform(-10, 90, n), side]).tolist()
    speed = float(rng.uniform(4.0, 9.0))
    env = RHSPaperEnv(**with_cheap_base_observation({"obstacles": obstacles, "ego_speed": speed}))
    return RadarObservation(env, radar=radar)


def collect_pairs(episodes: int, steps: int, seed: int, env_kwargs: dict, progress: bool = True,
                  scene: str = "highway") -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Consecutive static clouds and true motions from ``episodes`` episodes of ``steps`` steps.

    ``scene``: ``highway`` (rhs-highway-radar-v0, traffic and roadside landmarks) or
    ``paper`` (the paper's road with a random sparse obstacle layout per episode).
    """
    import gymnasium as gym
    from tqdm.auto import tqdm

    import rhs_env  # noqa: F401  (registers the ids)
    from rhs_env.scene import world_pose
    from slam.core.association import estimate_ego_velocity, static_mask
    from slam.core.registration import relative_motion

    rng = np.random.default_rng(seed)
    prev_list: list[np.ndarray] = []
    cur_list: list[np.ndarray] = []
    motions: list[np.ndarray] = []
    bar = tqdm(total=episodes * steps, desc=f"collect clouds ({scene})", unit="step", disable=not progress)
    env: Any = gym.make("rhs-highway-radar-v0", **env_kwargs) if scene == "highway" else None
    for ep in range(episodes):
        if scene == "paper":
            env = paper_like_env(rng, env_kwargs.get("radar"))
        obs, _ = env.reset(seed=seed + ep)
        env.action_space.seed(seed + ep)
        prev_pts, prev_pose = None, world_pose(env.unwrapped.vehicle)
        for _ in range(steps):
            pts = obs["points"][obs["points_mask"] > 0].astype(float)
            v = estimate_ego_velocity(pts, 0.5, rng)
            static = pts[static_mask(pts, v, 1.0)] if v is not None else pts
            pose = world_pose(env.unwrapped.vehicle)
            if prev_pts is not None and len(prev_pts) >= 3 and len(static) >= 3:
                prev_list.append(prev_pts)
                cur_list.append(static)
                motions.append(relative_motion(prev_pose, pose))
            prev_pts, prev_pose = static, pose
            action = rng.choice([1, 1, 1, 0, 2, 3, 4])  # mostly IDLE, some lane changes / speed changes
            obs, _, terminated, truncated, _ = env.step(int(action))
            bar.update(1)
            if terminated or truncated:
                break
    bar.close()
    env.close()
    return prev_list, cur_list, np.asarray(motions)


def make_dataset(prev_list: list[np.ndarray], cur_list: list[np.ndarray], motions: np.ndarray, priors_per_pair: int,
                 prior_std: np.ndarray, grid: GridMapConfig, rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """CNN inputs (grid maps of each pair under ``priors_per_pair`` noisy priors), residual targets, the
    priors and the index of each sample's pair."""
    from slam.core.cnn_registration import pair_input
    from slam.core.registration import relative_motion

    xs, ys, priors, index = [], [], [], []
    for k, (p, c, m) in enumerate(zip(prev_list, cur_list, motions)):
        for _ in range(priors_per_pair):
            prior = m + rng.normal(0.0, prior_std)
            xs.append(pair_input(p, c, prior, grid))
            # residual: the motion b with prior (+) b = m
            ys.append(relative_motion(prior, m))
            priors.append(prior)
            index.append(k)
    return np.asarray(xs, np.float32), np.asarray(ys), np.asarray(priors), np.asarray(index)


def motion_errors(est: np.ndarray, truth: np.ndarray) -> dict:
    d = est - truth
    rot = wrap_angle(d[:, 2])
    return {
        "translation_rmse_m": float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2))),
        "rotation_rmse_deg": float(np.degrees(np.sqrt(np.mean(rot**2)))),
        "translation_median_m": float(np.median(np.hypot(d[:, 0], d[:, 1]))),
    }


def fingerprint() -> list[float]:
    """The pipeline on a tiny config, seconds: 1 highway episode of 5 steps (5-degree grid), its
    dataset, one training epoch into a temporary file, and the held-out comparison (shipped CNN,
    freshly trained CNN, ICP) on the same pairs."""
    import tempfile

    from slam.core.cnn_registration import (
        CNNRegistration,
        CNNTrainConfig,
        GridMapConfig,
        train_cnn,
    )
    from slam.core.registration import ICPRegistration

    raw = collect_pairs(1, 5, 0, {"radar": {"scan": {"grid_deg": 5.0}}, "vehicles_count": 5}, progress=False)
    grid, rng = GridMapConfig(), np.random.default_rng(0)
    x, y, priors, idx = make_dataset(*raw, 1, np.array([0.5, 0.5, 0.02]), grid, rng)
    prev, cur = [raw[0][k] for k in idx], [raw[1][k] for k in idx]
    out = [*np.ravel(priors)]
    with tempfile.TemporaryDirectory() as tmp:
        weights = str(Path(tmp) / "cnn.pt")
        train_cnn(x, y, grid, CNNTrainConfig(epochs=1, seed=0), x, y, out=weights, progress=False)
        out += [*np.ravel(CNNRegistration(weights).estimate_batch(prev, cur, priors))]
    out += [*np.ravel(CNNRegistration().estimate_batch(prev, cur, priors))]
    icp = ICPRegistration(constant_velocity=False)
    out += [*np.ravel([icp.estimate(p, c, prior=pr) for p, c, pr in zip(prev, cur, priors)])]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=12)
    ap.add_argument("--val-episodes", type=int, default=3)
    ap.add_argument("--paper-episodes", type=int, default=8, help="episodes on random sparse paper-like layouts")
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--priors-per-pair", type=int, default=4)
    ap.add_argument("--prior-std-m", type=float, default=0.5)
    ap.add_argument("--prior-std-rad", type=float, default=0.02)
    ap.add_argument("--epochs", type=int, default=40)
    ap.add_argument("--seed", type=int, default=first("scenes"))
    ap.add_argument("--grid-deg", type=float, default=1.0, help="radar beam grid (deg)")
    ap.add_argument("--small", action="store_true", help="tiny config for tests (2+1 episodes, 8 steps, 2 epochs)")
    ap.add_argument("--out", default=str(ROOT / "slam" / "data" / "registration_cnn.pt"))
    ap.add_argument("--results", default=str(ROOT / "results"), help="directory for registration.json/.md")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    started = time.time()
    if args.small:
        args.episodes, args.val_episodes, args.steps, args.epochs, args.priors_per_pair = 2, 1, 8, 2, 2
        args.paper_episodes = 1

    from slam.core.cnn_registration import (
        CNNRegistration,
        CNNTrainConfig,
        GridMapConfig,
        train_cnn,
    )
    from slam.core.registration import ICPRegistration

    progress = not args.no_progress
    env_kwargs = {"radar": {"scan": {"grid_deg": args.grid_deg}}, "vehicles_count": 20}
    t0 = time.perf_counter()
    def both(episodes: int, paper_episodes: int, seed: int) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
        a = collect_pairs(episodes, args.steps, seed, env_kwargs, progress)
        b = collect_pairs(paper_episodes, args.steps, seed + 500, env_kwargs, progress, scene="paper")
        return a[0] + b[0], a[1] + b[1], np.concatenate([a[2].reshape(-1, 3), b[2].reshape(-1, 3)])

    train_raw = both(args.episodes, args.paper_episodes, args.seed)
    val_raw = both(args.val_episodes, max(1, args.paper_episodes // 4), args.seed + 1000)
    t_collect = time.perf_counter() - t0
    if len(train_raw[2]) == 0 or len(val_raw[2]) == 0:
        print("no usable cloud pairs were collected", file=sys.stderr)
        return 1
    grid = GridMapConfig()
    prior_std = np.array([args.prior_std_m, args.prior_std_m, args.prior_std_rad])
    rng = np.random.default_rng(args.seed)
    x, y, _, _ = make_dataset(*train_raw, args.priors_per_pair, prior_std, grid, rng)
    vx, vy, vpriors, vidx = make_dataset(*val_raw, 1, prior_std, grid, rng)
    cfg = CNNTrainConfig(epochs=args.epochs, seed=args.seed)
    t1 = time.perf_counter()
    train_cnn(x, y, grid, cfg, vx, vy, out=args.out, progress=progress)
    t_train = time.perf_counter() - t1

    # held-out comparison: prior alone, CNN, ICP, all from the same priors
    truth = val_raw[2][vidx]
    cnn = CNNRegistration(args.out)
    prev_v = [val_raw[0][k] for k in vidx]
    cur_v = [val_raw[1][k] for k in vidx]
    est_cnn = cnn.estimate_batch(prev_v, cur_v, vpriors)
    icp = ICPRegistration(constant_velocity=False)
    est_icp = np.stack([icp.estimate(p, c, prior=pr) for p, c, pr in zip(prev_v, cur_v, vpriors)])
    report = {
        "pairs_train": int(len(train_raw[2])),
        "pairs_heldout": int(len(truth)),
        "samples_train": int(len(x)),
        "prior_std": prior_std.tolist(),
        "epochs": args.epochs,
        "collect_time_s": round(t_collect, 1),
        "train_time_s": round(t_train, 1),
        "weights": str(args.out),
        "weights_kib": round(Path(args.out).stat().st_size / 1024, 1),
        "prior_only": motion_errors(vpriors, truth),
        "cnn": motion_errors(est_cnn, truth),
        "icp": motion_errors(est_icp, truth),
    }
    res_dir = Path(args.results)
    res_dir.mkdir(parents=True, exist_ok=True)
    write_json(res_dir / "registration.json", report, __file__, args, started, fingerprint, argv)
    rows = [("prior alone (truth + noise)", report["prior_only"]), ("CNN (paper)", report["cnn"]), ("ICP", report["icp"])]
    md = [
        f"Held-out pairs: {report['pairs_heldout']} (separate episodes); training samples: {report['samples_train']} "
        f"({report['pairs_train']} pairs x {args.priors_per_pair} priors); prior error std "
        f"{args.prior_std_m} m / {args.prior_std_rad} rad; training {report['train_time_s']} s on this CPU; "
        f"weights {report['weights_kib']} KiB.",
        "",
        "| method | translation RMSE (m) | median translation error (m) | rotation RMSE (deg) |",
        "|---|---|---|---|",
    ]
    md += [
        f"| {name} | {m['translation_rmse_m']:.3f} | {m['translation_median_m']:.3f} | {m['rotation_rmse_deg']:.3f} |"
        for name, m in rows
    ]
    (res_dir / "registration.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
