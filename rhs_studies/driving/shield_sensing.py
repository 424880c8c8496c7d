"""What the radar shield can trust in a scan: Doppler errors, ghosts, and how the shield's leader estimate alarms.

Drives the DAgger student the shield was built for *without* it (:data:`agents.evaluate.DAGGER_CRUISE30_CLOSE_POLICY`,
``shield=False``; the shipped policy until its RL fine-tune replaced it) on
validation seeds (4050..: never used in training or in the held-out evaluations) and, at every env step, compares
the radar points with the simulator:

* **Doppler**: for points within 1.5 m of a vehicle's 5 m x 2 m box (vehicle frame), the error of the point's radial
  velocity against that vehicle's true relative radial velocity: median, and the share off by more than 3 m/s;
* **ghosts**: the share of scans with a point in the ego's path (``|Y| < path_half_width_m``, ``0 < X < 40`` m) farther
  than 1.5 m from every vehicle box;
* **front alarms**: the shield's front rule ``gap < d + T max(0, c)`` (:class:`agents.policies.shield.ShieldConfig`'s front gap
  and time gap) on the true leader in the ego's lane (bumper gap and closing speed from the simulator) against three
  radar estimates of the leader: the nearest single point with its own Doppler; the nearest two-point object with
  its median Doppler (:func:`agents.policies.shield.objects`); and the shield's tracked leader
  (:meth:`agents.policies.shield.RadarShield.leader`). Counted: steps where the radar alarms and the truth does not (spurious)
  and the reverse (missed), and the tracked closing speed's error quantiles for leaders within 40 m;
* **flanks**: per env step and side, whether a vehicle is beside the ego in the adjacent lane (its centre within
  ``alongside_m + 2.5`` m along the ego and one lane over, simulator) and how many radar points the shield's lane rule
  finds alongside there (``|X| <= alongside_m`` in that lane's band): with a car beside, the steps with 0, 1 and 2
  or more points (one point is the flank rule's case); with none, the steps with a point there anyway (ghosts).

    python scripts/shield_sensing.py                       # 10 episodes (2000 env steps), ~2 min on one core
    python scripts/shield_sensing.py --episodes 3 --seed 4050 --json /tmp/sensing.json

Prints a markdown table (the driving page's shield section quotes it); ``--json`` also writes the numbers.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from rhs_studies.kit.seeds import first

NEAR_BOX_M = 1.5  # a point this close to a vehicle's box belongs to it
HALF_LENGTH_M, HALF_WIDTH_M = 2.5, 1.0  # highway-env's 5 m x 2 m vehicles
PATH_RANGE_M = 40.0


def _vehicles_in_ego_frame(base) -> tuple[np.ndarray, np.ndarray]:
    """Other vehicles' centres (V, 2) in the vehicle frame (x forward, y left) and their true radial velocities."""
    ego = base.vehicle
    c, s = np.cos(ego.heading), np.sin(ego.heading)
    others = [v for v in base.road.vehicles if v is not ego]
    if not others:
        return np.zeros((0, 2)), np.zeros(0)
    d = np.array([v.position - ego.position for v in others])
    rel = np.array([v.velocity - ego.velocity for v in others])
    rot = np.array([[c, s], [s, -c]])  # highway-env (x, y right) -> vehicle frame (x forward, y left)
    centres, rel_v = d @ rot.T, rel @ rot.T
    radial = np.sum(centres * rel_v, axis=1) / np.maximum(np.linalg.norm(centres, axis=1), 1e-9)
    return centres, radial


def _box_distance(points: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(P, V) distance of each point to each vehicle's axis-aligned box (vehicle frame), m (0 inside)."""
    dx = np.maximum(np.abs(points[:, None, 0] - centres[None, :, 0]) - HALF_LENGTH_M, 0.0)
    dy = np.maximum(np.abs(points[:, None, 1] - centres[None, :, 1]) - HALF_WIDTH_M, 0.0)
    return np.hypot(dx, dy)


def _unsafe(lead: tuple[float, float] | None, d: float, t: float) -> bool:
    return lead is not None and lead[0] < d + t * max(lead[1], 0.0)


def measure(seeds: list[int]) -> dict[str, Any]:
    """The statistics of the module docstring over full episodes on ``seeds``."""
    from agents.evaluate import DAGGER_CRUISE30_CLOSE_POLICY as STUDENT
    from agents.evaluate import load_policy, make_env, resolve_env
    from agents.policies.expert import bumper_gap
    from agents.policies.shield import RadarShield, ShieldedPolicy, nearest_object, road_offsets

    env_id, kwargs = resolve_env(STUDENT)
    env = make_env(env_id, kwargs)
    policy = load_policy(STUDENT, env)
    if isinstance(policy, ShieldedPolicy):
        policy = policy.model  # the student alone: the states it reaches without help
    cfg = RadarShield().config
    d, t = cfg.front_gap_m, cfg.front_time_s
    dop_err: list[np.ndarray] = []
    ghosts = steps = 0
    alarms = {name: {"spurious": 0, "missed": 0, "both": 0} for name in ("point", "object", "tracked")}
    closing_err: list[float] = []
    w = cfg.lane_width_m
    beside_points = [0, 0, 0]  # side-steps with a car beside the ego and 0 / 1 / 2+ points alongside
    empty_steps = empty_with_point = 0  # side-steps with no car beside, and those with a point alongside
    try:
        for seed in seeds:
            policy.reset()
            shield = RadarShield()
            obs, _ = env.reset(seed=seed)
            done = False
            while not done:
                base = env.unwrapped
                big_x, big_y, v_r, p_y = road_offsets(obs)
                points = np.asarray(obs["points"], float)[np.asarray(obs["points_mask"]) > 0][:, :2]
                centres, radial = _vehicles_in_ego_frame(base)
                dist = _box_distance(points, centres) if len(centres) else np.full((len(points), 0), np.inf)
                nearest = dist.argmin(axis=1) if dist.shape[1] else np.zeros(len(points), int)
                on_car = dist.min(axis=1) <= NEAR_BOX_M if dist.shape[1] else np.zeros(len(points), bool)
                dop_err.append(v_r[on_car] - radial[nearest[on_car]])
                offset = p_y - w * np.round(p_y / w)
                for side in (1.0, -1.0):  # left, right
                    lateral = (big_y + offset) * side
                    n = int(np.sum((lateral > w / 2) & (lateral < w / 2 + cfg.lane_band_m)
                                   & (np.abs(big_x) <= cfg.alongside_m)))
                    beside = np.any((np.abs(centres[:, 0]) <= cfg.alongside_m + HALF_LENGTH_M)
                                    & (centres[:, 1] * side > w / 2) & (centres[:, 1] * side < 1.5 * w))
                    if beside:
                        beside_points[min(n, 2)] += 1
                    else:
                        empty_steps += 1
                        empty_with_point += n > 0
                path = (big_x > 0) & (np.abs(big_y) < cfg.path_half_width_m)
                ghosts += bool(np.any(path & (big_x < PATH_RANGE_M) & ~on_car))
                ego = base.vehicle
                front, _ = base.road.neighbour_vehicles(ego, ego.lane_index)
                truth = None if front is None else (bumper_gap(ego, front), ego.speed - front.speed)
                x, c = big_x[path], -v_r[path]
                leads = {"point": nearest_object(x, c, 1, cfg.cluster_m, cfg.ego_half_length_m),
                         "object": nearest_object(x, c, cfg.min_points, cfg.cluster_m, cfg.ego_half_length_m),
                         "tracked": shield.leader(x, c)}
                for name, lead in leads.items():
                    r, u = _unsafe(lead, d, t), _unsafe(truth, d, t)
                    alarms[name]["spurious"] += r and not u
                    alarms[name]["missed"] += u and not r
                    alarms[name]["both"] += r and u
                tracked = leads["tracked"]
                if tracked is not None and truth is not None and truth[0] < PATH_RANGE_M and len(shield.track) >= 3:
                    closing_err.append(tracked[1] - truth[1])
                action, _ = policy.predict(obs, deterministic=True)
                obs, _, terminated, truncated, _ = env.step(int(np.asarray(action)))
                steps += 1
                done = terminated or truncated
    finally:
        env.close()
    err = np.concatenate(dop_err) if dop_err else np.zeros(0)
    q = np.percentile(closing_err, [5, 50, 95]).tolist() if closing_err else [None] * 3
    return {
        "seeds": seeds, "steps": steps, "policy": str(STUDENT), "shield_config": cfg.__dict__,
        "doppler": {"points_on_vehicles": int(err.size), "median_error_mps": float(np.median(err)) if err.size else None,
                    "share_off_by_3_mps": float(np.mean(np.abs(err) > 3.0)) if err.size else None},
        "ghost_scan_share": ghosts / max(steps, 1),
        "front_alarms": alarms,
        "tracked_closing_error_mps": {"p5": q[0], "median": q[1], "p95": q[2], "n": len(closing_err)},
        "flanks": {"beside_points": beside_points, "empty_steps": empty_steps, "empty_with_point": empty_with_point},
    }  # fmt: skip


def markdown(r: dict[str, Any]) -> str:
    dop, a, ce = r["doppler"], r["front_alarms"], r["tracked_closing_error_mps"]
    lines = [
        f"Seeds {r['seeds'][0]}-{r['seeds'][-1]} ({r['steps']} env steps), the shipped student without the shield.",
        "",
        "| quantity | measured |",
        "|---|---:|",
        f"| Doppler error of points on vehicles, median (m/s) | {dop['median_error_mps']:+.2f} |",
        f"| share of those points off by more than 3 m/s | {100 * dop['share_off_by_3_mps']:.1f} % |",
        f"| scans with a ghost point in the ego's path within {PATH_RANGE_M:g} m | {100 * r['ghost_scan_share']:.1f} % |",
    ]
    for name, label in (("point", "nearest single point"), ("object", "nearest two-point object"),
                        ("tracked", "tracked leader (the shield)")):
        lines.append(f"| front alarms from the {label}: spurious / missed / agreeing | "
                     f"{a[name]['spurious']} / {a[name]['missed']} / {a[name]['both']} |")
    if ce["n"]:
        lines.append(f"| tracked closing speed minus true, 5 / 50 / 95 % (m/s, {ce['n']} steps) | "
                     f"{ce['p5']:+.1f} / {ce['median']:+.1f} / {ce['p95']:+.1f} |")
    f = r.get("flanks")
    if f:
        b = f["beside_points"]
        lines += [f"| a car beside the ego one lane over: side-steps with 0 / 1 / 2+ points alongside | "
                  f"{b[0]} / {b[1]} / {b[2]} |",
                  f"| no car beside: side-steps with a point alongside (ghosts) | "
                  f"{f['empty_with_point']} of {f['empty_steps']} |"]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--seed", type=int, default=first("shield_validation", 50), help="first validation seed")
    ap.add_argument("--json", type=Path, default=None, help="also write the numbers here")
    args = ap.parse_args(argv)
    if not 1 <= args.episodes <= 10_000:
        ap.error("--episodes must be in [1, 10000]")
    result = measure(list(range(args.seed, args.seed + args.episodes)))
    print(markdown(result))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
