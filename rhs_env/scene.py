"""Static roadside landmarks and the scatterer view of a highway-env scene.

Frames
------
highway-env draws its world with the y axis pointing *down* the screen, and its
lanes are numbered from the top: lane 0 is the leftmost lane (the rewards call
the highest index the "right lane"). In the physical sense its ``(x, y)`` frame
is therefore left-handed: x forward along the road, y to the right. This
package works in right-handed frames only:

* **highway-env frame** (``*_he``): highway-env's own coordinates, used only to
  talk to highway-env (vehicle positions, lanes, rendering).
* **world frame**: ``(x, -y_he)``, headings ``-heading_he`` (counter-clockwise
  positive, y up / to the left of a vehicle driving along +x). The paper
  scenario's coordinates (``rhs-paper-v0``) live in this frame, and so do
  the ground-truth poses and landmark maps put into ``info``.
* **vehicle frame**: origin at the ego vehicle's centre, x forward, y left
  (docs/INTERFACES.md). Everything handed to the radar is in this frame.

Landmarks are kept as plain arrays on the environment (:class:`Landmarks`),
not as highway-env ``RoadObject`` s: they then never appear in the Kinematics
observation, never collide, never end an episode, and cost nothing in
highway-env's O(vehicles x objects) collision loop.

:func:`scene_scatterers` turns a scene into the radar's input: landmarks as
point scatterers, other vehicles (and solid highway-env obstacles) as a few
scattering points on the faces they show to the ego vehicle, the relative
velocity of every point in the (rotating) vehicle frame, and the box edges of
those objects as occluding segments. It is vectorized over objects.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from rhs_common.geometry import rotation, wrap_angle
from rhs_common.jit import KernelTable
from rhs_common.validation import (
    build,
    check_choice,
    check_int,
    check_range,
    check_types,
)
from rhs_env.scatterers import Occluders, Scatterers

__all__ = [
    "DENSE_LANDMARKS", "LANDMARK_SIDES", "LandmarkConfig", "Landmarks", "MAX_SCATTER_RANGE_M", "OBJECT_ID_OFFSET",
    "ScatterConfig", "VEHICLE_ID_OFFSET", "draw_disks", "ego_motion", "get_landmarks", "he_to_world_xy",
    "lane_coordinates", "off_lanes", "place_roadside_landmarks", "scatterers_to_dict", "scene_scatterers", "vehicle_to_he_xy", "world_pose",
    "world_surface_pixels", "world_to_he_xy",
]

#: object ids: landmarks are ``0 .. L-1``; other vehicles ``VEHICLE_ID_OFFSET + i``
#: (``i`` = index in ``road.vehicles``); solid road objects ``OBJECT_ID_OFFSET + j``
#: (``j`` = index in ``road.objects``). Ids are stable within an episode.
VEHICLE_ID_OFFSET = 1_000_000
OBJECT_ID_OFFSET = 2_000_000

LANDMARK_SIDES = ("both", "left", "right")
#: the farthest any object is handed to the radar, m (the bound of ``ScatterConfig.max_range_m``)
MAX_SCATTER_RANGE_M = 1000.0


# --------------------------------------------------------------------------- configs
def _check_off_or_range(name: str, value: Any, low: float, high: float) -> None:
    """``value`` is 0 (feature off) or in [low, high]."""
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool) and value == 0:
        return
    try:
        check_range(name, value, low, high)
    except ValueError:
        raise ValueError(f"{name} must be 0 (off) or in [{low:g}, {high:g}], got {value!r}") from None


@dataclass(frozen=True)
class LandmarkConfig:
    """Static roadside landmarks (posts, signs, barriers) placed along the road.

    Attributes:
        enabled: place landmarks at all.
        spacing_m: nominal distance between consecutive landmarks on one side [1, 1000] m.
            The right side is staggered by half a spacing.
        lateral_offset_m: distance of the landmarks from the road edge (the outer
            edge of the outermost lane), [0, 100] m.
        rcs_m2: radar cross-section of each landmark, (0, 1e4] m^2 (the paper's scene: 5 m^2).
        jitter_m: uniform longitudinal jitter +-jitter_m, [0, spacing_m / 2) m,
            so the landmark pattern is not periodic (periodic maps alias in SLAM).
        lateral_jitter_m: uniform lateral jitter, outward only, [0, 50] m (landmarks
            never move onto the road).
        sides: ``"both"`` | ``"left"`` | ``"right"`` side(s) of the road.
        pair_gap_m: 0 (single poles) or the along-road distance [0.5, 50] m between
            the two poles of a *pair*: every landmark gets a twin that far ahead, same
            offset, same RCS. Two poles g m apart seen from lateral distance d at
            longitudinal distance x subtend about ``g d / (x^2 + d^2)`` rad: 2 m pairs
            at 8 m lateral are 2-5 deg apart at 15-25 m, between one RHS beamwidth and
            one phased-array beamwidth.
        post_spacing_m: 0 (none) or the spacing [1, 100] m of guard-rail posts along
            the chosen side(s), with +-10 % uniform jitter of the spacing.
        post_offset_m: distance of the posts from the road edge, [0, 100] m.
        post_rcs_m2: radar cross-section of one post, (0, 1e4] m^2.
        gantry_spacing_m: 0 (none) or the spacing [10, 10000] m of sign gantries: two
            legs, one on each road edge at the same longitudinal position (both sides
            whatever ``sides`` says), ``lateral_offset_m`` from the edge.
        gantry_rcs_m2: radar cross-section of one gantry leg, (0, 1e4] m^2.

    The extra structures are placed after the poles, from the same ``rng``, so with
    their defaults (all off) a scene is identical to one without these fields.
    :data:`DENSE_LANDMARKS` is the preset of ``rhs-dense-v0``.
    """

    enabled: bool = True
    spacing_m: float = 20.0
    lateral_offset_m: float = 4.0
    rcs_m2: float = 5.0
    jitter_m: float = 4.0
    lateral_jitter_m: float = 2.0
    sides: str = "both"
    pair_gap_m: float = 0.0
    post_spacing_m: float = 0.0
    post_offset_m: float = 1.0
    post_rcs_m2: float = 0.5
    gantry_spacing_m: float = 0.0
    gantry_rcs_m2: float = 20.0

    def __post_init__(self) -> None:
        check_types(self)
        check_range("spacing_m", self.spacing_m, 1.0, 1000.0)
        check_range("lateral_offset_m", self.lateral_offset_m, 0.0, 100.0)
        check_range("rcs_m2", self.rcs_m2, 0.0, 1e4, low_open=True)
        check_range("jitter_m", self.jitter_m, 0.0, 500.0)
        if self.jitter_m >= self.spacing_m / 2:  # a bound set by another field: name both
            raise ValueError(f"jitter_m must be below spacing_m / 2 = {self.spacing_m / 2:g} "
                             f"(spacing_m={self.spacing_m:g}), got {self.jitter_m!r}")
        check_range("lateral_jitter_m", self.lateral_jitter_m, 0.0, 50.0)
        check_choice("sides", self.sides, LANDMARK_SIDES)
        _check_off_or_range("pair_gap_m", self.pair_gap_m, 0.5, 50.0)
        _check_off_or_range("post_spacing_m", self.post_spacing_m, 1.0, 100.0)
        check_range("post_offset_m", self.post_offset_m, 0.0, 100.0)
        check_range("post_rcs_m2", self.post_rcs_m2, 0.0, 1e4, low_open=True)
        _check_off_or_range("gantry_spacing_m", self.gantry_spacing_m, 10.0, 10000.0)
        check_range("gantry_rcs_m2", self.gantry_rcs_m2, 0.0, 1e4, low_open=True)

    @classmethod
    def make(cls, value: Any) -> LandmarkConfig:
        """``None`` (defaults), a ``LandmarkConfig`` or a dict of its fields (validated)."""
        return build(cls, value, "landmarks")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class ScatterConfig:
    """How a scene becomes scatterers.

    Attributes:
        max_range_m: only objects within this distance of the ego centre are
            returned (bounded work), (0, 1000] m. Keep it at or above the radar's range.
        vehicle_rcs_m2: total RCS of a vehicle, spread over its visible faces in
            proportion to their apparent (projected) width, (0, 1e4] m^2 (about 10 for a car).
        points_per_face: scattering points per visible face, [1, 16].
        include_obstacles: also treat solid highway-env road objects (``Obstacle``)
            as extended static scatterers.
    """

    max_range_m: float = 150.0
    vehicle_rcs_m2: float = 10.0
    points_per_face: int = 3
    include_obstacles: bool = True

    def __post_init__(self) -> None:
        check_types(self)
        check_range("max_range_m", self.max_range_m, 0.0, MAX_SCATTER_RANGE_M, low_open=True)
        check_range("vehicle_rcs_m2", self.vehicle_rcs_m2, 0.0, 1e4, low_open=True)
        check_int("points_per_face", self.points_per_face, 1, 16)

    @classmethod
    def make(cls, value: Any) -> ScatterConfig:
        """``None`` (defaults), a ``ScatterConfig`` or a dict of its fields (validated)."""
        return build(cls, value, "scatter")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


# --------------------------------------------------------------------------- frames
def he_to_world_xy(xy_he: np.ndarray) -> np.ndarray:
    """highway-env coordinates -> world frame (y flipped); works on (..., 2)."""
    out = np.array(xy_he, dtype=float, copy=True)
    out[..., 1] *= -1.0
    return out


world_to_he_xy = he_to_world_xy  # the flip is its own inverse


def world_pose(vehicle) -> np.ndarray:
    """(x, y, heading) of a highway-env vehicle in the world frame, heading wrapped to (-pi, pi]."""
    h = -float(vehicle.heading)
    h = wrap_angle(h)
    if h == -np.pi:
        h = np.pi
    return np.array([float(vehicle.position[0]), -float(vehicle.position[1]), h])


def vehicle_to_he_xy(points_xy: np.ndarray, vehicle) -> np.ndarray:
    """Vehicle-frame points (N, 2) of ``vehicle`` -> highway-env coordinates (N, 2)."""
    x, y, h = world_pose(vehicle)
    c, s = np.cos(h), np.sin(h)
    p = np.asarray(points_xy, dtype=float).reshape(-1, 2)
    wx = x + c * p[:, 0] - s * p[:, 1]
    wy = y + s * p[:, 0] + c * p[:, 1]
    return np.stack([wx, -wy], axis=1)


def _motion_arrays(objs: Sequence[Any]) -> dict[str, np.ndarray]:
    """World-frame state of highway-env objects, vectorized.

    Velocity is the bicycle model's centre velocity ``speed * dir(heading + beta)``
    with the side-slip ``beta = atan(tan(steering) / 2)`` and the yaw rate
    ``speed sin(beta) / (length / 2)`` (highway_env.vehicle.kinematics.Vehicle.step);
    objects without a steering action (obstacles) have ``beta = 0``.
    """
    n = len(objs)
    pos = np.array([o.position for o in objs], dtype=float).reshape(n, 2)
    heading = np.fromiter((o.heading for o in objs), float, n)
    speed = np.fromiter((o.speed for o in objs), float, n)
    steer = np.fromiter((float((getattr(o, "action", None) or {}).get("steering", 0.0)) for o in objs), float, n)
    length = np.fromiter((o.LENGTH for o in objs), float, n)
    width = np.fromiter((o.WIDTH for o in objs), float, n)
    beta = np.arctan(0.5 * np.tan(steer))
    vel_he = speed[:, None] * np.stack([np.cos(heading + beta), np.sin(heading + beta)], axis=1)
    yaw_rate_he = speed * np.sin(beta) / (length / 2)
    # to the world frame (y flipped: headings and rotation rates change sign)
    pos[:, 1] *= -1.0
    vel = vel_he * np.array([1.0, -1.0])
    return {
        "pos": pos,
        "heading": -heading,
        "vel": vel,
        "yaw_rate": -yaw_rate_he,
        "length": length,
        "width": width,
    }


def ego_motion(vehicle) -> tuple[np.ndarray, float]:
    """World-frame velocity (2,) and yaw rate (rad/s, counter-clockwise) of a vehicle."""
    m = _motion_arrays([vehicle])
    return m["vel"][0], float(m["yaw_rate"][0])


# --------------------------------------------------------------------------- landmarks
@dataclass
class Landmarks:
    """Static point landmarks of a scene, stored in highway-env coordinates.

    Attributes:
        xy_he: (L, 2) positions in highway-env coordinates (m).
        rcs: (L,) radar cross-sections (m^2).

    ``ids`` are the row indices (0..L-1). Lookups by distance use a sort on x, so
    :meth:`near` costs O(log L + k) for the k landmarks in the x window.
    """

    xy_he: np.ndarray
    rcs: np.ndarray

    def __post_init__(self) -> None:
        self.xy_he = np.asarray(self.xy_he, dtype=float).reshape(-1, 2)
        self.rcs = np.broadcast_to(np.asarray(self.rcs, dtype=float), (len(self.xy_he),)).copy()
        if not np.all(np.isfinite(self.xy_he)):
            raise ValueError("landmark positions must be finite")
        if np.any(self.rcs <= 0) or not np.all(np.isfinite(self.rcs)):
            raise ValueError("landmark rcs must be finite and > 0")
        self._order = np.argsort(self.xy_he[:, 0], kind="stable")
        self._sorted_x = self.xy_he[self._order, 0]

    def __len__(self) -> int:
        return len(self.xy_he)

    @property
    def ids(self) -> np.ndarray:
        return np.arange(len(self), dtype=np.int64)

    @property
    def xy_world(self) -> np.ndarray:
        """(L, 2) positions in the world frame (y up)."""
        return he_to_world_xy(self.xy_he)

    @classmethod
    def empty(cls) -> Landmarks:
        return cls(np.zeros((0, 2)), np.zeros(0))

    @classmethod
    def from_world(cls, xy_world: np.ndarray, rcs: float | np.ndarray) -> Landmarks:
        """Landmarks given in the world frame (y up), e.g. the paper's obstacle list."""
        xy = world_to_he_xy(np.asarray(xy_world, dtype=float).reshape(-1, 2))
        return cls(xy, np.broadcast_to(np.asarray(rcs, dtype=float), (len(xy),)).copy())

    def concat(self, other: Landmarks) -> Landmarks:
        return Landmarks(np.concatenate([self.xy_he, other.xy_he]), np.concatenate([self.rcs, other.rcs]))

    def near(self, center_he: np.ndarray, radius: float) -> np.ndarray:
        """Indices (sorted) of the landmarks within ``radius`` of ``center_he``."""
        if len(self) == 0:
            return np.zeros(0, dtype=np.int64)
        lo, hi = np.searchsorted(self._sorted_x, [center_he[0] - radius, center_he[0] + radius])
        cand = self._order[lo:hi]
        d2 = np.sum((self.xy_he[cand] - np.asarray(center_he, dtype=float)) ** 2, axis=1)
        return np.sort(cand[d2 <= radius * radius])


def _lane_points(lane, s: np.ndarray, lateral: np.ndarray) -> np.ndarray:
    """lane.position for arrays; vectorized for straight lanes, a loop otherwise."""
    from highway_env.road.lane import StraightLane

    if isinstance(lane, StraightLane):
        return (
            lane.start[None, :]
            + s[:, None] * lane.direction[None, :]
            + lateral[:, None] * lane.direction_lateral[None, :]
        )
    return np.array([lane.position(si, li) for si, li in zip(s, lateral)], dtype=float).reshape(-1, 2)


def place_roadside_landmarks(network, config: LandmarkConfig, rng: np.random.Generator) -> Landmarks:
    """Place landmarks along both edges of every road segment of a highway-env network.

    For each edge (from, to) of ``network.graph``, lane 0 is the leftmost lane and
    the last lane the rightmost (highway-env's convention). Left landmarks sit at
    longitudinal ``(k + 1/2) spacing``, right ones at ``(k + 1) spacing`` (staggered),
    each with uniform jitter +-``jitter_m`` along the road and ``[0, lateral_jitter_m]``
    outward, at ``lateral_offset_m`` beyond the outer lane edge; with ``pair_gap_m``
    each gets a twin ``pair_gap_m`` further along the road. Then (after all poles, so
    the poles' draws do not depend on them) the guard-rail posts and the sign gantries
    of :class:`LandmarkConfig`. All draws come from ``rng``.

    Any lane geometry works (``StraightLane``, ``SineLane``, ``CircularLane``, ...): the
    points are ``lane.position(s, lateral)``. The spacing runs on across connected edges
    (a ring of short arcs, a road cut into segments: the next edge starts where the
    previous one's spacing left off, along the lane centre), so short segments get
    their share. Landmarks that fall strictly inside a lane of the network (the inner
    side of a ramp beside the main road, a median between opposite lanes, the inside
    of a junction) are dropped (:func:`off_lanes`). A single straight segment (the
    highway scenes) is placed exactly as before either rule.
    """
    if not config.enabled:
        return Landmarks.empty()
    keys = [(a, b) for a, tos in network.graph.items() for b, lanes in tos.items() if lanes]
    edges = [network.graph[a][b] for a, b in keys]
    sides = [side for side in ("left", "right") if config.sides in ("both", side)]
    xy, rcs = [], []

    def add(lane, s, out, side, value):
        xy.append(_lane_points(lane, s, -out if side == "left" else out))
        rcs.append(np.full(len(s), float(value)))

    carry: dict[tuple[Any, Any, str], float] = {}  # (from, to, side) -> start of the spacing on that edge
    done: set[tuple[Any, Any]] = set()
    for (a, b), lanes in zip(keys, edges):
        done.add((a, b))
        for side in sides:
            lane = lanes[0] if side == "left" else lanes[-1]
            length = float(lane.length)
            start = carry.pop((a, b, side), 0.5 * config.spacing_m if side == "left" else config.spacing_m)
            s = np.arange(start, length, config.spacing_m)
            left_over = (float(s[-1]) + config.spacing_m if s.size else start) - length
            for c in network.graph.get(b, {}):
                if (b, c) not in done:
                    carry.setdefault((b, c, side), max(left_over, 0.0))
            if s.size == 0:
                continue
            s = np.clip(s + rng.uniform(-config.jitter_m, config.jitter_m, s.size), 0.0, length)
            out = _half_width(lane) + config.lateral_offset_m + rng.uniform(0.0, config.lateral_jitter_m, s.size)
            add(lane, s, out, side, config.rcs_m2)
            if config.pair_gap_m > 0:
                add(lane, np.clip(s + config.pair_gap_m, 0.0, length), out, side, config.rcs_m2)
    for lanes in edges:
        if config.post_spacing_m > 0:
            for side in sides:
                lane = lanes[0] if side == "left" else lanes[-1]
                s = np.arange(0.5 * config.post_spacing_m, float(lane.length), config.post_spacing_m)
                s = np.clip(s + config.post_spacing_m * rng.uniform(-0.1, 0.1, s.size), 0.0, float(lane.length))
                add(lane, s, np.full(s.size, _half_width(lane) + config.post_offset_m), side, config.post_rcs_m2)
        if config.gantry_spacing_m > 0:
            for side, lane in (("left", lanes[0]), ("right", lanes[-1])):
                s = np.arange(0.5 * config.gantry_spacing_m, float(lane.length), config.gantry_spacing_m)
                add(lane, s, np.full(s.size, _half_width(lane) + config.lateral_offset_m), side, config.gantry_rcs_m2)
    if not xy:
        return Landmarks.empty()
    points, values = np.concatenate(xy), np.concatenate(rcs)
    keep = off_lanes(network, points) if len(keys) > 1 else np.ones(len(points), dtype=bool)
    return Landmarks(points[keep], values[keep])


def lane_coordinates(lane: Any, xy_he: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``lane.local_coordinates`` of many points (N, 2) at once: (longitudinal, lateral) arrays.

    Vectorized for ``StraightLane``, ``SineLane`` and ``CircularLane`` (highway-env's formulas), a loop otherwise.

    Args:
        lane: a highway-env lane.
        xy_he: (N, 2) points in highway-env coordinates.

    Returns:
        (N,) longitudinal and (N,) lateral coordinates, m.
    """
    from highway_env.road.lane import CircularLane, SineLane, StraightLane

    p = np.asarray(xy_he, dtype=float).reshape(-1, 2)
    if isinstance(lane, StraightLane):
        d = p - lane.start
        s, lat = d @ lane.direction, d @ lane.direction_lateral
        if isinstance(lane, SineLane):
            lat = lat - lane.amplitude * np.sin(lane.pulsation * s + lane.phase)
        return s, lat
    if isinstance(lane, CircularLane):
        d = p - lane.center
        phi = np.arctan2(d[:, 1], d[:, 0])
        phi = lane.start_phase + (phi - lane.start_phase + np.pi) % (2 * np.pi) - np.pi
        return lane.direction * (phi - lane.start_phase) * lane.radius, lane.direction * (lane.radius - np.hypot(*d.T))
    coords = np.array([lane.local_coordinates(q) for q in p], dtype=float).reshape(-1, 2)
    return coords[:, 0], coords[:, 1]


def off_lanes(network: Any, xy_he: np.ndarray) -> np.ndarray:
    """(N,) bool: the points (highway-env frame) lying strictly inside no lane of ``network``.

    Inside a lane means ``0 <= s <= length`` and ``|lateral| < width / 2`` in its
    coordinates (:func:`lane_coordinates`): a point on a lane's edge line is off it.

    Args:
        network: a highway-env ``RoadNetwork``.
        xy_he: (N, 2) points in highway-env coordinates.

    Returns:
        The mask of the points off every lane.
    """
    p = np.asarray(xy_he, dtype=float).reshape(-1, 2)
    keep = np.ones(len(p), dtype=bool)
    for tos in network.graph.values():
        for lanes in tos.values():
            for lane in lanes:
                s, lat = lane_coordinates(lane, p)
                keep &= ~((s >= 0) & (s <= float(lane.length)) & (np.abs(lat) < _half_width(lane)))
    return keep


def _half_width(lane) -> float:
    return float(lane.width_at(0.0)) / 2


#: ``rhs-dense-v0``'s scene (where the antenna matters): paired poles every
#: 20 m (2 m apart, RCS 5 m^2), guard-rail posts every 2.5 m on both sides 1 m off the
#: road edge (RCS 0.5 m^2 each: small steel posts), sign gantries every 150 m (legs of
#: 20 m^2). Within the radar's 100 m reach that is ~160 posts, ~20 poles and a gantry or
#: two; consecutive posts seen from the car are 1-5 deg apart at 10-30 m.
DENSE_LANDMARKS = LandmarkConfig(
    spacing_m=20.0,
    jitter_m=3.0,
    pair_gap_m=2.0,
    post_spacing_m=2.5,
    post_offset_m=1.0,
    post_rcs_m2=0.5,
    gantry_spacing_m=150.0,
    gantry_rcs_m2=20.0,
)


def get_landmarks(env) -> Landmarks:
    """The landmarks of an env (``env.unwrapped.landmarks``), or none for plain highway-env envs."""
    lm = getattr(env.unwrapped, "landmarks", None)
    return lm if isinstance(lm, Landmarks) else Landmarks.empty()


# --------------------------------------------------------------------------- scatterers
# Box faces in the object's own frame (x forward, y left): outward normals, and the
# tangent (normal turned +90 deg) along which the face's points are spread.
_FACE_NORMALS = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
_FACE_TANGENTS = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [1.0, 0.0]])


def _cross_z(omega: np.ndarray, r: np.ndarray) -> np.ndarray:
    """omega (scalar per row, broadcastable) x r in 2-D: omega * (-r_y, r_x)."""
    return np.asarray(omega)[..., None] * np.stack([-r[..., 1], r[..., 0]], axis=-1)


def _nearby_objects(road, ego, radius: float, include_obstacles: bool) -> tuple[list, np.ndarray, np.ndarray]:
    """Other vehicles (and solid obstacles) whose box may reach within ``radius`` of the ego:
    the objects, their ids (``VEHICLE_ID_OFFSET + i`` / ``OBJECT_ID_OFFSET + j``) and static flags."""
    objs, ids, static = [], [], []
    for i, v in enumerate(road.vehicles if road is not None else ()):
        if v is not ego:
            objs.append(v)
            ids.append(VEHICLE_ID_OFFSET + i)
            static.append(False)
    if include_obstacles and road is not None:
        for j, o in enumerate(road.objects):
            if getattr(o, "solid", False) and getattr(o, "collidable", True):
                objs.append(o)
                ids.append(OBJECT_ID_OFFSET + j)
                static.append(True)
    if not objs:
        return [], np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool)
    pos_he = np.array([o.position for o in objs], dtype=float).reshape(-1, 2)
    diag = np.fromiter((np.hypot(o.LENGTH, o.WIDTH) for o in objs), float, len(objs))
    keep = np.linalg.norm(pos_he - np.asarray(ego.position, dtype=float), axis=1) <= radius + diag / 2
    return [o for o, k in zip(objs, keep) if k], np.asarray(ids, dtype=np.int64)[keep], np.asarray(static, bool)[keep]


def _face_scatterers(m: dict[str, np.ndarray], ids: np.ndarray, static: np.ndarray, ego_motion: dict[str, np.ndarray],
                     cfg: ScatterConfig, kernels: str = "numba") -> tuple[tuple[np.ndarray, ...], Occluders]:
    """Points on the visible faces of box objects of motion ``m`` (:func:`_motion_arrays`) and their four edges as
    occluders, vehicle frame: the points' fields ``(xy, velocity, rcs, object_id, is_static)`` of
    :class:`Scatterers` (checked once, by :func:`scene_scatterers`) and the :class:`Occluders`.

    A face is visible when its outward normal points toward the ego centre; the
    object's ``vehicle_rcs_m2`` is shared among the ``points_per_face`` points of its
    visible faces in proportion to their projected widths. Velocities of the rigid
    motion, seen from the rotating ego frame: ``R^T (v_obj - v_ego) + w_obj x (q - c) - w_ego x q``.
    ``kernels="numba"``: the same operations compiled (:func:`rhs_env.kernels.face_scatterers`), else numpy.
    """
    ego = tuple(ego_motion[k][0] for k in ("pos", "heading", "vel", "yaw_rate"))
    faces = _STAGES.choose(kernels).faces  # the compiled or the numpy faces
    return faces(m, len(ids), ids, static, ego, cfg)


#: the vehicles' faces in two implementations (:class:`rhs_common.jit.KernelTable`), chosen by the ``kernels`` of
#: :func:`scene_scatterers` (the radar's ``RadarConfig.kernels``)
_STAGES = KernelTable("rhs_env.scene")


@_STAGES.stage("faces", "numba")
def _faces_compiled(m: dict[str, np.ndarray], n_obj: int, ids: np.ndarray, static: np.ndarray, ego: tuple,
                    cfg: ScatterConfig) -> tuple[tuple[np.ndarray, ...], Occluders]:
    """:func:`_face_scatterers` of the ``n_obj`` boxes of motion ``m`` (:func:`_motion_arrays`) seen from ``ego``
    (position, heading, velocity, yaw rate), the same operations compiled (:func:`rhs_env.kernels.face_scatterers`)."""
    from rhs_env.kernels import face_scatterers

    e_pos, e_head, e_vel, e_rate = ego
    ego_row = np.array([e_pos[0], e_pos[1], e_head, e_vel[0], e_vel[1], e_rate], dtype=float)
    xy, vel, rcs, box, segments = face_scatterers(m["pos"], m["heading"], m["vel"], m["yaw_rate"], m["length"],
                                                  m["width"], ego_row, int(cfg.points_per_face), float(cfg.vehicle_rcs_m2))
    return (xy, vel, rcs, ids[box], static[box]), Occluders(segments=segments, object_id=np.repeat(ids, 4))


@_STAGES.stage("faces", "numpy")
def _faces_numpy(m: dict[str, np.ndarray], n_obj: int, ids: np.ndarray, static: np.ndarray, ego: tuple,
                 cfg: ScatterConfig) -> tuple[tuple[np.ndarray, ...], Occluders]:
    """:func:`_face_scatterers` of the ``n_obj`` boxes of motion ``m`` (:func:`_motion_arrays`) seen from ``ego``
    (position, heading, velocity, yaw rate) in numpy (the reference)."""
    e_pos, e_head, e_vel, e_rate = ego
    r_t = rotation(-e_head)  # world -> vehicle frame
    p = cfg.points_per_face
    c = (m["pos"] - e_pos) @ r_t.T  # (V, 2) centres in the vehicle frame
    rot = rotation(m["heading"] - e_head)  # (V, 2, 2) object -> vehicle frame
    half = np.stack([m["length"], m["width"], m["length"], m["width"]], 1) / 2  # (V, 4)
    face_len = np.stack([m["width"], m["length"], m["width"], m["length"]], 1)  # (V, 4)
    normals = np.einsum("vij,fj->vfi", rot, _FACE_NORMALS)  # (V, 4, 2)
    tangents = np.einsum("vij,fj->vfi", rot, _FACE_TANGENTS)
    mids = c[:, None, :] + normals * half[..., None]  # (V, 4, 2)
    dist = np.linalg.norm(mids, axis=-1)
    cos_inc = -np.sum(normals * mids, axis=-1) / np.maximum(dist, 1e-9)  # normal . (ego - mid)/|.|
    weight = np.where(cos_inc > 1e-9, face_len * cos_inc, 0.0)  # projected width of visible faces
    total = weight.sum(axis=1)  # (V,)
    share = np.divide(weight, total[:, None], out=np.zeros_like(weight), where=total[:, None] > 0)
    frac = (np.arange(p) + 0.5) / p - 0.5  # (P,) positions along a face, in face lengths
    pts = mids[:, :, None, :] + tangents[:, :, None, :] * (frac[None, None, :, None] * face_len[..., None, None])
    rcs = np.broadcast_to((cfg.vehicle_rcs_m2 * share / p)[..., None], (n_obj, 4, p))
    v_rel_c = (m["vel"] - e_vel) @ r_t.T  # (V, 2)
    vel = (
        v_rel_c[:, None, None, :]
        + _cross_z(m["yaw_rate"][:, None, None], pts - c[:, None, None, :])
        - _cross_z(np.asarray(e_rate), pts)
    )
    vis = np.broadcast_to((weight > 0)[..., None], (n_obj, 4, p))
    corners = mids - tangents * (face_len[..., None] / 2)  # start corner of each face
    ends = mids + tangents * (face_len[..., None] / 2)
    fields = (pts[vis], vel[vis], rcs[vis], np.broadcast_to(ids[:, None, None], (n_obj, 4, p))[vis],
              np.broadcast_to(static[:, None, None], (n_obj, 4, p))[vis])
    return fields, Occluders(segments=np.stack([corners, ends], axis=2).reshape(-1, 2, 2), object_id=np.repeat(ids, 4))


def scene_scatterers(
    env: Any,
    ego: Any = None,
    config: ScatterConfig | Mapping[str, Any] | None = None,
    kernels: str = "numba",
) -> tuple[Scatterers, Occluders]:
    """Scatterers and occluders of a highway-env scene in the ego vehicle frame.

    Args:
        env: a highway-env env (wrapped or not). Landmarks are taken from
            ``env.unwrapped.landmarks`` when it is a :class:`Landmarks` (the RHS envs).
        ego: the observing vehicle; default ``env.unwrapped.vehicle``.
        config: :class:`ScatterConfig` (or a dict of its fields).
        kernels: "numba" (the vehicles' faces compiled, :func:`rhs_env.kernels.face_scatterers`) or "numpy"
            (the reference); the radar's ``RadarConfig.kernels`` in the envs.

    Returns:
        ``(Scatterers, Occluders)`` (``rhs_env.scatterers``), everything in the
        vehicle frame (x forward, y left). Landmarks come first (sorted by id),
        then the extended objects (:func:`_face_scatterers`). Velocities are
        relative to the ego vehicle as seen in its rotating frame: ``R^T (v_point -
        v_ego) - w_ego x q``, with ``v_point = v_obj + w_obj x (p - c_obj)``; a
        static point's is minus the ego velocity (plus the rotation term when the ego turns).
    """
    cfg = ScatterConfig.make(config)
    base = env.unwrapped
    ego = base.vehicle if ego is None else ego
    if ego is None:
        raise ValueError("scene_scatterers needs an ego vehicle (env.unwrapped.vehicle is None)")
    objs, ids, static = _nearby_objects(base.road, ego, cfg.max_range_m, cfg.include_obstacles)
    motion = _motion_arrays([ego, *objs])  # the ego's row first, then the objects' (one vectorized pass)
    em = {k: v[:1] for k, v in motion.items()}
    r_t = rotation(-em["heading"][0])  # world -> vehicle frame

    lms = get_landmarks(base)  # static point landmarks
    idx = lms.near(np.asarray(ego.position, dtype=float), cfg.max_range_m)
    q_lm = (he_to_world_xy(lms.xy_he[idx]) - em["pos"][0]) @ r_t.T
    v_lm = np.broadcast_to(r_t @ (-em["vel"][0]), q_lm.shape) - _cross_z(em["yaw_rate"][0], q_lm)
    landmarks = (q_lm, v_lm, lms.rcs[idx], idx.astype(np.int64), np.ones(len(idx), dtype=bool))
    if not objs:
        return Scatterers(*landmarks), Occluders(segments=np.zeros((0, 2, 2)), object_id=np.zeros(0, dtype=np.int64))
    faces, occluders = _face_scatterers({k: v[1:] for k, v in motion.items()}, ids, static, em, cfg, kernels)
    return Scatterers(*(np.concatenate([a, b]) for a, b in zip(landmarks, faces))), occluders


def scatterers_to_dict(scatterers) -> dict[str, np.ndarray]:
    """Plain dict of a ``Scatterers``' arrays (for ``info``: picklable, comparable)."""
    return {
        "xy": np.array(scatterers.xy, dtype=float),
        "velocity": np.array(scatterers.velocity, dtype=float),
        "rcs": np.array(scatterers.rcs, dtype=float),
        "object_id": np.array(scatterers.object_id, dtype=np.int64),
        "is_static": np.array(scatterers.is_static, dtype=bool),
    }


# --------------------------------------------------------------------------- drawing
def world_surface_pixels(env, xy_he: np.ndarray) -> np.ndarray | None:
    """Pixel (column, row) of highway-env points on the env viewer's last frame; None without a viewer."""
    viewer = getattr(env.unwrapped, "viewer", None)
    surface = getattr(viewer, "sim_surface", None)
    if surface is None:
        return None
    xy = np.asarray(xy_he, dtype=float).reshape(-1, 2)
    return np.floor((xy - np.asarray(surface.origin, dtype=float)) * float(surface.scaling)).astype(np.int64)


def draw_disks(frame: np.ndarray, pixels: np.ndarray, color: Sequence[int] | np.ndarray, radius: int = 2) -> np.ndarray:
    """Draw filled disks in place on an (H, W, 3) uint8 frame; ``pixels`` (N, 2) = (column, row).

    ``color`` is one RGB triple or one per point (N, 3). Off-frame parts are clipped.
    """
    pixels = np.asarray(pixels, dtype=np.int64).reshape(-1, 2)
    if pixels.size == 0:
        return frame
    r = int(radius)
    dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
    disk = dx**2 + dy**2 <= r * r + r  # slightly fuller than a pure circle for small radii
    off = np.stack([dx[disk], dy[disk]], axis=1)  # (K, 2)
    allpx = pixels[:, None, :] + off[None, :, :]  # (N, K, 2)
    color = np.asarray(color, dtype=np.uint8)
    colors = np.broadcast_to(color if color.ndim == 2 else color[None, :], (len(pixels), 3))
    colors = np.broadcast_to(colors[:, None, :], allpx.shape[:2] + (3,))
    h, w = frame.shape[:2]
    ok = (allpx[..., 0] >= 0) & (allpx[..., 0] < w) & (allpx[..., 1] >= 0) & (allpx[..., 1] < h)
    frame[allpx[..., 1][ok], allpx[..., 0][ok]] = colors[ok]
    return frame
