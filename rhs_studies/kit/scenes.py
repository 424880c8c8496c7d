"""The radar scenes the studies share, in the ego frame (m, m/s, m^2).

* :func:`typical_scene`: a highway scene, roadside landmarks and vehicles in four lanes
  with occluding boxes (the speed benchmarks and the detection and profile studies);
* :func:`landmark_scene`: static landmarks inside the four radars' sectors (Fig. 5b and
  the radar-quality study).
"""

from __future__ import annotations

import numpy as np

from rhs_env.radar import RadarSystem
from rhs_env.scatterers import Occluders, Scatterers


def typical_scene(rng: np.random.Generator, n_landmarks: int = 20, n_vehicles: int = 10,
                  ego_speed: float = 25.0) -> tuple[Scatterers, Occluders]:
    """Highway scene in the ego frame: landmarks at y = +-(9..12) m, vehicles in 4 lanes (4 m wide)."""
    half = n_landmarks // 2
    lx = np.concatenate([np.linspace(-55, 60, half), np.linspace(-50, 55, n_landmarks - half)])
    lx = lx + rng.uniform(-2, 2, lx.size)
    ly = np.concatenate([rng.uniform(9, 12, half), -rng.uniform(9, 12, n_landmarks - half)])
    l_xy = np.column_stack([lx, ly])
    l_vel = np.tile([-ego_speed, 0.0], (n_landmarks, 1))
    # vehicles in lanes y = -6, -2, 2, 6 (ego in lane y = -2 -> shifted so the ego lane is y = 0)
    lanes = np.array([-4.0, 4.0, 8.0, -8.0 + 4.0])
    vx = rng.uniform(-60, 70, n_vehicles)
    vx = np.where(np.abs(vx) < 8, vx + np.sign(vx + 1e-9) * 10, vx)
    vy = lanes[rng.integers(0, lanes.size, n_vehicles)]
    vrel = rng.uniform(-5, 5, n_vehicles)
    centers = np.column_stack([vx, vy])
    # face centres (front, left, rear, right) and outward normals, heading 0
    off = np.array([[2.5, 0], [0, 1.0], [-2.5, 0], [0, -1.0]])
    faces = centers[:, None, :] + off[None]  # (V, 4, 2)
    facing = np.einsum("vfd,fd->vf", faces, off) < 0  # the face looks at the ego (origin)
    vid = np.repeat(np.arange(n_vehicles), 4).reshape(n_vehicles, 4) + 1000
    nf = np.maximum(facing.sum(1, keepdims=True), 1)
    pts = faces[facing]
    rcs = np.broadcast_to(10.0 / nf, facing.shape)[facing]
    vel = np.column_stack([np.repeat(vrel, 4).reshape(n_vehicles, 4)[facing], np.zeros(pts.shape[0])])
    scat = Scatterers(
        np.vstack([l_xy, pts]), np.vstack([l_vel, vel]), np.concatenate([np.full(n_landmarks, 5.0), rcs]),
        np.concatenate([np.arange(n_landmarks), vid[facing]]),
        np.concatenate([np.ones(n_landmarks, bool), np.zeros(pts.shape[0], bool)]),
    )
    occ = Occluders.from_boxes(centers, np.zeros(n_vehicles), 5.0, 2.0, np.arange(n_vehicles) + 1000)
    return scat, occ


def landmark_scene(rng: np.random.Generator, radar: RadarSystem, n: int = 24, speed: float = 20.0) -> Scatterers:
    """Static landmarks 10-60 m from random radars, inside their sectors (+-42 deg)."""
    r = rng.integers(0, 4, n)
    rng_m = rng.uniform(10, 60, n)
    th = radar.boresights[r] + np.deg2rad(rng.uniform(-42, 42, n))
    xy = radar.positions[r] + rng_m[:, None] * np.column_stack([np.cos(th), np.sin(th)])
    return Scatterers(xy, np.tile([-speed, 0.0], (n, 1)), np.full(n, 5.0), np.arange(n), np.ones(n, bool))
