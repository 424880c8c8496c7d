"""Loop closure and persistent maps for the RBPF SLAM (:class:`slam.core.rbpf.RBPFSlam`).

The filter keeps at most ``max_landmarks`` landmarks in its particles; a landmark not re-observed for
``prune_after_cycles`` cycles leaves them for the archive (``retired_xy`` / ``retired_ids``, the weighted mean
only). Driving back past archived landmarks, the filter maps them again as new ones, in a frame that has drifted
since: duplicates, and a pose that never returns to the old map. :class:`LoopCloser` closes that loop:

0. every ``every_cycles`` cycles, an active landmark within ``merge_gate_m`` of an archived one (the filter mapped
   it again after pruning it) takes the archived landmark's id and the archive drops the twin;
1. then the archived landmarks within ``search_radius_m`` of the pose that no particle
   holds are the *old* map near the car, the active landmarks within that radius the *current* one;
2. :func:`rigid_match` finds the rigid transform ``T`` (rotation ``R(phi)``, translation ``t``) that puts the most
   current landmarks within ``match_gate_m`` of an old one: hypotheses from every pair of current landmarks and
   every pair of old ones of the same separation (within ``pair_tol_m``), each scored by its inliers, the best
   refined by least squares over its inliers (Kabsch / Umeyama in 2-D:
   ``phi = atan2(sum (a x b), sum (a . b))`` over the centred pairs, ``t = mean(b) - R mean(a)``);
3. the closure is *verified* when at least ``min_inliers`` landmarks, and ``min_fraction`` of the current ones
   that have an old one within ``search_radius_m``, agree with ``T``, their RMS residual is below
   ``match_gate_m / 2`` and ``T`` moves the car by at most ``max_correction_m`` (a larger jump is an alias of a
   repeating roadside);
4. a verified closure moves every particle's pose and every active landmark by ``T`` (covariances rotated),
   hands each matched active landmark the id of its old twin and removes the twin from the archive (one landmark,
   not two), and re-activates the old landmarks near the car that nothing matched (:func:`seed_landmarks`), so the
   filter's own association keeps them.

A persistent map (``reset(options={"keep_map": True})`` of :class:`slam.gym.wrappers.SlamObservation`): the map of
the previous episode goes into the new filter's archive, and :func:`relocalise` finds the new start pose in it
from the first cloud's points (the same rigid match, points against landmarks, without a bound on the shift).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from rhs_common.geometry import wrap_angle
from rhs_common.validation import check_bool, check_int, check_range, check_types

__all__ = ["LoopCloser", "LoopClosureConfig", "Match", "apply_transform", "duplicate_fraction", "relocalise",
           "rigid_match", "seed_landmarks", "transform_filter"]


@dataclass(frozen=True)
class LoopClosureConfig:
    """When and how a loop closes (:class:`LoopCloser`).

    ``enabled``; ``every_cycles`` [1, 1000]: the check's period; ``search_radius_m`` (0, 500]: the old and current
    landmarks considered around the car (the radar's reach); ``match_gate_m`` (0, 10]: a landmark agrees with a
    transform within this distance; ``pair_tol_m`` (0, 5]: two pairs of the same separation within this make a
    hypothesis; ``min_inliers`` [3, 1000] and ``min_fraction`` [0, 1]: the verification; ``max_correction_m``
    (0, 1e4]: the largest move of the car a closure may make; ``max_hypotheses`` [1, 10^6]: the scored hypotheses'
    cap; ``landmark_std_m`` (0, 10]: the position std a re-activated landmark starts with; ``merge_gate_m`` [0, 10]:
    an active landmark this close to an archived one is that landmark mapped again (merged at every check).
    """

    enabled: bool = True
    every_cycles: int = 5
    search_radius_m: float = 80.0
    match_gate_m: float = 0.7
    pair_tol_m: float = 0.3
    min_inliers: int = 4
    min_fraction: float = 0.5
    max_correction_m: float = 10.0
    max_hypotheses: int = 20_000
    landmark_std_m: float = 0.1
    merge_gate_m: float = 0.5

    def __post_init__(self) -> None:
        check_types(self)
        check_bool("loop_closure.enabled", self.enabled)
        check_int("loop_closure.every_cycles", self.every_cycles, 1, 1000)
        check_range("loop_closure.search_radius_m", self.search_radius_m, 0.0, 500.0, low_open=True)
        check_range("loop_closure.match_gate_m", self.match_gate_m, 0.0, 10.0, low_open=True)
        check_range("loop_closure.pair_tol_m", self.pair_tol_m, 0.0, 5.0, low_open=True)
        check_int("loop_closure.min_inliers", self.min_inliers, 3, 1000)
        check_range("loop_closure.min_fraction", self.min_fraction, 0.0, 1.0)
        check_range("loop_closure.max_correction_m", self.max_correction_m, 0.0, 1e4, low_open=True)
        check_int("loop_closure.max_hypotheses", self.max_hypotheses, 1, 1_000_000)
        check_range("loop_closure.landmark_std_m", self.landmark_std_m, 0.0, 10.0, low_open=True)
        check_range("loop_closure.merge_gate_m", self.merge_gate_m, 0.0, 10.0)


@dataclass(frozen=True)
class Match:
    """A rigid transform ``b = R(phi) a + t`` and the pairs ``(i, j)`` (source, target) that agree with it."""

    phi: float
    t: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    rms_m: float

    @property
    def inliers(self) -> int:
        return len(self.src)


def apply_transform(xy: np.ndarray, phi: float, t: np.ndarray) -> np.ndarray:
    """``R(phi) xy + t`` for (N, 2) points."""
    c, s = math.cos(phi), math.sin(phi)
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    return np.column_stack([c * xy[:, 0] - s * xy[:, 1] + t[0], s * xy[:, 0] + c * xy[:, 1] + t[1]])


def _kabsch(a: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
    """The least-squares rotation angle and translation with ``b ~ R a + t`` (2-D)."""
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    da, db = a - ma, b - mb
    phi = math.atan2(float(np.sum(da[:, 0] * db[:, 1] - da[:, 1] * db[:, 0])), float(np.sum(da * db)))
    return phi, mb - apply_transform(ma[None], phi, np.zeros(2))[0]


def _hypotheses(src: np.ndarray, dst: np.ndarray, tol: float, cap: int) -> tuple[np.ndarray, np.ndarray]:
    """Rotation angles and translations from pairs of ``src`` and pairs of ``dst`` of equal separation."""
    i, j = np.triu_indices(len(src), 1)
    k, l_ = np.triu_indices(len(dst), 1)
    da = np.hypot(*(src[j] - src[i]).T)
    db = np.hypot(*(dst[l_] - dst[k]).T)
    keep_a, keep_b = da > 2 * tol, db > 2 * tol
    i, j, da = i[keep_a], j[keep_a], da[keep_a]
    k, l_, db = k[keep_b], l_[keep_b], db[keep_b]
    order = np.argsort(db)
    db, k, l_ = db[order], k[order], l_[order]
    lo, hi = np.searchsorted(db, da - tol), np.searchsorted(db, da + tol)
    ia = np.repeat(np.arange(len(da)), hi - lo)
    if ia.size == 0:
        return np.zeros(0), np.zeros((0, 2))
    ib = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi, strict=True)])
    if ia.size > cap // 2:
        pick = np.random.default_rng(0).choice(ia.size, cap // 2, replace=False)
        ia, ib = ia[pick], ib[pick]
    p, q = src[i[ia]], src[j[ia]]
    phis, ts = [], []
    for u, v in ((k[ib], l_[ib]), (l_[ib], k[ib])):  # both orders of the target pair
        phi = np.arctan2(*(dst[v] - dst[u]).T[::-1]) - np.arctan2(*(q - p).T[::-1])
        c, s = np.cos(phi), np.sin(phi)
        t = dst[u] - np.column_stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1]])
        phis.append(phi)
        ts.append(t)
    return wrap_angle(np.concatenate(phis)), np.concatenate(ts)


def rigid_match(src: np.ndarray, dst: np.ndarray, gate: float, tol: float, cap: int = 20_000,
                allowed: Any = None) -> Match | None:
    """The rigid transform that puts the most of ``src`` (N, 2) within ``gate`` of ``dst`` (M, 2).

    Args:
        src: the point set to move (N, 2), m.
        dst: the point set it is matched to (M, 2), m.
        gate: inlier distance (m).
        tol: separation tolerance of a pair hypothesis (m).
        cap: at most this many hypotheses are scored.
        allowed: a function ``(phi (K,), t (K, 2)) -> bool (K,)`` that keeps the admissible hypotheses.

    Returns:
        The best hypothesis refined by least squares over its inliers (one re-scoring), or None without one.
    """
    src, dst = np.asarray(src, float).reshape(-1, 2), np.asarray(dst, float).reshape(-1, 2)
    if len(src) < 2 or len(dst) < 2:
        return None
    phis, ts = _hypotheses(src, dst, tol, cap)
    if allowed is not None and len(phis):
        ok = np.asarray(allowed(phis, ts), dtype=bool)
        phis, ts = phis[ok], ts[ok]
    if len(phis) == 0:
        return None
    tree = cKDTree(dst)
    c, s = np.cos(phis)[:, None], np.sin(phis)[:, None]
    best, score = 0, -1
    for a in range(0, len(phis), 2000):  # (K, N) in chunks
        sl = slice(a, a + 2000)
        x = c[sl] * src[None, :, 0] - s[sl] * src[None, :, 1] + ts[sl, None, 0]
        y = s[sl] * src[None, :, 0] + c[sl] * src[None, :, 1] + ts[sl, None, 1]
        d, _ = tree.query(np.stack([x, y], -1).reshape(-1, 2), k=1, distance_upper_bound=gate)
        counts = (d.reshape(x.shape) <= gate).sum(axis=1)
        k = int(np.argmax(counts))
        if counts[k] > score:
            best, score = a + k, int(counts[k])
    phi, t = float(phis[best]), ts[best]
    for _ in range(2):  # refine on the inliers, re-score
        d, idx = tree.query(apply_transform(src, phi, t), k=1, distance_upper_bound=gate)
        inl = np.flatnonzero(d <= gate)
        if len(inl) < 2:
            return None
        phi, t = _kabsch(src[inl], dst[idx[inl]])
    d, idx = tree.query(apply_transform(src, phi, t), k=1, distance_upper_bound=gate)
    inl = np.flatnonzero(d <= gate)
    if len(inl) < 2:
        return None
    return Match(phi, np.asarray(t, float), inl, idx[inl], float(np.sqrt(np.mean(d[inl] ** 2))))


def transform_filter(slam: Any, phi: float, t: np.ndarray) -> None:
    """Move the RBPF's whole state by the rigid transform ``(phi, t)``: every particle's pose
    ``(R p_xy + t, theta + phi)``, every landmark mean ``R mu + t`` and covariance ``R Lambda R^T``."""
    c, s = math.cos(phi), math.sin(phi)
    R = np.array([[c, -s], [s, c]])
    slam.pose[:, :2] = slam.pose[:, :2] @ R.T + t
    slam.pose[:, 2] = wrap_angle(slam.pose[:, 2] + phi)
    slam.mean[:] = slam.mean @ R.T + t
    slam.cov[:] = np.einsum("ij,pljk,mk->plim", R, slam.cov, R)


def seed_landmarks(slam: Any, xy: np.ndarray, ids: np.ndarray, std_m: float) -> int:
    """Put landmarks ``xy`` (K, 2, map frame) with ids ``ids`` into free slots of every particle, confirmed
    (``min_hits`` updates), seen this cycle, with covariance ``std_m^2 I``; as many as there are free slots.
    Returns how many were seeded."""
    free = np.flatnonzero(~slam.slot_used)[: len(xy)]
    n = len(free)
    if n == 0:
        return 0
    slam.slot_used[free] = True
    slam.slot_id[free] = np.asarray(ids, dtype=np.int64)[:n]
    slam.mean[:, free] = np.asarray(xy, float)[:n][None]
    slam.cov[:, free] = (std_m**2) * np.eye(2)
    slam.active[:, free] = True
    slam.hits[:, free] = max(int(slam.config.min_hits), int(slam.config.retire_min_hits))
    slam.last_seen[:, free] = max(int(slam.cycle), 0)
    return n


def _drop_archived(slam: Any, ids: np.ndarray) -> None:
    keep = ~np.isin(slam.retired_ids, ids)
    slam.retired_xy, slam.retired_ids = slam.retired_xy[keep], slam.retired_ids[keep]


class LoopCloser:
    """Closes loops against the archived map (module docstring); one per pipeline."""

    def __init__(self, config: LoopClosureConfig | None = None) -> None:
        self.config = config if config is not None else LoopClosureConfig()
        self.closures = 0  # verified closures that moved the state
        self.merged = 0  # active landmarks merged with their archived twins
        self.reactivated = 0  # archived landmarks put back into the particles
        self.last_correction_m = 0.0

    def reset(self) -> None:
        self.closures = self.merged = self.reactivated = 0
        self.last_correction_m = 0.0

    def check(self, slam: Any, est: Any, cycle: int) -> bool:
        """One check after the cycle's update (``est``: its estimate); True when the state moved or merged."""
        c = self.config
        if not c.enabled or cycle % c.every_cycles or len(slam.retired_xy) == 0:
            return False
        merged = self._merge_twins(slam, est)
        if len(slam.retired_xy) < c.min_inliers:
            return merged
        return self._close(slam, est) or merged

    def _merge_twins(self, slam: Any, est: Any) -> bool:
        """Merge each active landmark with the archived landmark within ``merge_gate_m`` of it (nearest first,
        one each): the filter mapped it again after it was pruned; it takes the archived id, the archive drops
        the twin. Roadside landmarks stand metres apart, so a twin that close is the same landmark."""
        c = self.config
        cur = np.asarray(est.landmarks, float).reshape(-1, 2)
        held = np.isin(slam.retired_ids, est.landmark_ids)
        old = np.flatnonzero(~held)
        if len(cur) == 0 or len(old) == 0:
            return False
        d, j = cKDTree(slam.retired_xy[old]).query(cur, k=1, distance_upper_bound=c.merge_gate_m)
        pairs = sorted((float(d[i]), i, int(j[i])) for i in np.flatnonzero(d <= c.merge_gate_m))
        slot_of_id = {int(i): k for k, i in enumerate(slam.slot_id) if slam.slot_used[k]}
        taken: set[int] = set()
        twins = []
        for _, i, k in pairs:
            s = slot_of_id.get(int(est.landmark_ids[i]))
            if k in taken or s is None:
                continue
            taken.add(k)
            slam.slot_id[s] = int(slam.retired_ids[old[k]])
            twins.append(int(slam.retired_ids[old[k]]))
        if not twins:
            return False
        _drop_archived(slam, np.asarray(twins, dtype=np.int64))
        self.merged += len(twins)
        return True

    def _close(self, slam: Any, est: Any) -> bool:
        """The verified rigid closure of the module docstring's steps 1-4."""
        c = self.config
        pose = np.asarray(est.pose, float)
        old_d = np.hypot(*(slam.retired_xy - pose[:2]).T)
        held = np.isin(slam.retired_ids, est.landmark_ids)
        near_old = np.flatnonzero((old_d <= c.search_radius_m) & ~held)
        cur = np.flatnonzero(np.hypot(*(np.asarray(est.landmarks).reshape(-1, 2) - pose[:2]).T) <= c.search_radius_m)
        if len(near_old) < c.min_inliers or len(cur) < c.min_inliers:
            return False
        old_xy, cur_xy = slam.retired_xy[near_old], np.asarray(est.landmarks)[cur]

        def allowed(phis: np.ndarray, ts: np.ndarray) -> np.ndarray:
            cph, sph = np.cos(phis), np.sin(phis)
            moved = np.column_stack([cph * pose[0] - sph * pose[1], sph * pose[0] + cph * pose[1]]) + ts
            return np.hypot(*(moved - pose[:2]).T) <= c.max_correction_m

        m = rigid_match(cur_xy, old_xy, c.match_gate_m, c.pair_tol_m, c.max_hypotheses, allowed)
        if m is None or m.inliers < c.min_inliers or m.rms_m > c.match_gate_m / 2:
            return False
        if m.inliers < c.min_fraction * min(len(cur_xy), len(old_xy)):
            return False
        moved_pose = apply_transform(pose[None, :2], m.phi, m.t)[0]
        self.last_correction_m = float(np.hypot(*(moved_pose - pose[:2])))
        transform_filter(slam, m.phi, m.t)
        self.closures += 1
        # the matched active landmarks take their archived twins' ids; the twins leave the archive
        slot_of_id = {int(i): k for k, i in enumerate(slam.slot_id) if slam.slot_used[k]}
        twins = slam.retired_ids[near_old[m.dst]]
        for cur_id, old_id in zip(np.asarray(est.landmark_ids)[cur[m.src]], twins, strict=True):
            k = slot_of_id.get(int(cur_id))
            if k is not None:
                slam.slot_id[k] = int(old_id)
        # the old landmarks near the car that nothing matched come back into the particles
        rest = np.setdiff1d(near_old, near_old[m.dst])
        back = seed_landmarks(slam, slam.retired_xy[rest], slam.retired_ids[rest], c.landmark_std_m)
        _drop_archived(slam, np.concatenate([twins, slam.retired_ids[rest[:back]]]))
        self.merged += len(twins)
        self.reactivated += back
        return True


def relocalise(points_xy: np.ndarray, map_xy: np.ndarray, gate: float = 0.7, tol: float = 0.3,
               min_inliers: int = 5, min_fraction: float = 0.3) -> Match | None:
    """The pose of a vehicle in a map: the rigid transform from its cloud's points ``points_xy`` (N, 2, vehicle
    frame) to the map's landmarks ``map_xy`` (M, 2) that :func:`rigid_match` finds with at least ``min_inliers``
    points, and ``min_fraction`` of them, within ``gate`` (m); its ``(t, phi)`` is the vehicle's pose
    ``(x, y, heading)`` in the map frame. None when no transform is verified."""
    m = rigid_match(points_xy, map_xy, gate, tol)
    if m is None or m.inliers < max(min_inliers, int(math.ceil(min_fraction * len(points_xy)))):
        return None
    return m


def duplicate_fraction(est_xy: np.ndarray, true_xy: np.ndarray, gate: float = 2.0) -> float | None:
    """The fraction of the map's landmarks ``est_xy`` that duplicate another: each estimate goes to its nearest
    true landmark within ``gate`` (m); beyond the nearest estimate of a true landmark, every other estimate
    assigned to it is a duplicate. None for an empty map."""
    est_xy = np.asarray(est_xy, float).reshape(-1, 2)
    if len(est_xy) == 0:
        return None
    d, idx = cKDTree(np.asarray(true_xy, float).reshape(-1, 2)).query(est_xy, k=1, distance_upper_bound=gate)
    hit = idx[d <= gate]
    return float((len(hit) - len(np.unique(hit))) / len(est_xy))
