"""Data association for the RBPF SLAM (paper section VII-B), vectorized with numpy.

Three steps, all in SI units (m, m/s, rad):

1. **Moving-point filter** (:func:`static_mask`). A static scatterer at vehicle-frame
   position ``r`` seen by a sensor at ``s`` from a vehicle moving with velocity ``v``
   (vehicle frame) and yaw rate ``w`` has the relative velocity ``-(v + w z x r)`` and
   therefore the radial velocity (positive receding)

   ``vr_static = -(v + w z x r) . u``,   ``u = (r - s) / |r - s|``.

   With the sensor at the vehicle origin the rotation term vanishes (``z x r`` is
   normal to ``r``). Points whose measured radial velocity departs from ``vr_static``
   by more than a threshold are dynamic (other vehicles) and are kept out of the map
   and of the registration.

2. **Clustering** (:func:`cluster_points`). Points of one object (closer than a small
   radius, single-linkage) are merged into one observation at their
   amplitude-weighted centroid ``x_c = sum_i a_i x_i / sum_i a_i``.

3. **Position compensation and cluster match** (:func:`to_map_frame`,
   :func:`associate`). Observations are moved into the map frame with each
   particle's predicted pose ``p = (px, py, th)``:

   ``x_map = [px, py] + R(th) x_veh``,   ``R(th) = [[cos th, -sin th], [sin th, cos th]]``

   and matched to the nearest active landmark of that particle; farther than
   ``delta_m`` means a new landmark (paper: "Cluster Match"). Everything is batched
   over particles (P), observations (M) and landmarks (L) with a P x M x L distance
   tensor.

4. **Per-point covariance and Mahalanobis association** (:func:`point_covariance`,
   :func:`cluster_covariance`, :func:`mahalanobis_associate`). A point measured at
   range R and angle phi from its sensor at ``s`` has the vehicle-frame covariance
   ``Sigma = sigma_R^2 u u^T + (R sigma_phi)^2 u_perp u_perp^T`` (``u`` the line of
   sight); a cluster fuses its points in information form. Association gates on the
   Mahalanobis distance ``d^2 = nu^T C^-1 nu`` with the full innovation covariance
   ``C`` and enforces mutual exclusion (one observation per landmark and one
   landmark per observation, per particle) by rounds of mutual-nearest matching.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from rhs_common.jit import KernelTable

__all__ = [
    "NEW",
    "DROPPED",
    "static_mask",
    "bearing_sectors",
    "estimate_ego_velocity",
    "cluster_points",
    "to_map_frame",
    "associate",
    "point_covariance",
    "cluster_covariance",
    "sym2_inverse",
    "mahalanobis_associate",
]

#: association code: observation starts a new landmark in this particle
NEW = -1
#: association code: observation lost a conflict (another observation of the same
#: cycle is closer to the same landmark) and is ignored in this particle
DROPPED = -2
#: the RANSAC, the clusters' components and their fusion in two implementations (:class:`rhs_common.jit.KernelTable`),
#: chosen by the functions' ``kernels`` (the SLAM's ``SlamConfig.kernels``)
_STAGES = KernelTable("slam.core.association")


def static_mask(
    points: np.ndarray,
    ego_velocity_xy: np.ndarray | tuple[float, float] | None,
    threshold: float = 1.0,
    *,
    yaw_rate: float = 0.0,
    sensor_xy: np.ndarray | None = None,
) -> np.ndarray:
    """Boolean mask (N,) of points whose radial velocity fits a static scatterer.

    Parameters
    ----------
    points : (N, >=3) array, columns x, y (vehicle frame, m), radial velocity (m/s,
        positive receding).
    ego_velocity_xy : (2,) ego velocity over ground in the vehicle frame (m/s). ``None``
        means unknown: every point is kept.
    threshold : allowed |vr_measured - vr_static| (m/s).
    yaw_rate : ego yaw rate w (rad/s); only matters with ``sensor_xy``.
    sensor_xy : optional (N, 2) or (2,) sensor positions in the vehicle frame (m); the
        line of sight is taken from the sensor. Default: the vehicle origin.

    Model: ``vr_static = -(v + w z x r) . u`` with ``u = (r - s)/|r - s|``.
    """
    if threshold < 0:
        raise ValueError(f"threshold must be in [0, inf), got {threshold!r}")
    pts = np.asarray(points, dtype=float)
    n = pts.shape[0]
    if n == 0 or ego_velocity_xy is None:
        return np.ones(n, dtype=bool)
    v = np.asarray(ego_velocity_xy, dtype=float).reshape(2)
    r = pts[:, :2]
    s = np.zeros(2) if sensor_xy is None else np.asarray(sensor_xy, dtype=float)
    los = r - s
    norm = np.linalg.norm(los, axis=1, keepdims=True)
    u = los / np.maximum(norm, 1e-9)
    # velocity of the static point relative to the vehicle, vehicle frame
    rel = -(v[None, :] + yaw_rate * np.stack([-r[:, 1], r[:, 0]], axis=1))
    vr_static = np.sum(rel * u, axis=1)
    return np.abs(pts[:, 2] - vr_static) <= threshold


def bearing_sectors(bearing: np.ndarray, angular_bins: int) -> np.ndarray:
    """The sector (0 .. angular_bins - 1) of each bearing (rad, [-pi, pi)) among ``angular_bins`` equal ones from -pi:
    the Doppler fits' coverage score counts the sectors holding an inlier."""
    return np.floor((bearing + np.pi) / (2 * np.pi) * angular_bins).astype(int) % angular_bins


def estimate_ego_velocity(
    points: np.ndarray,
    threshold: float = 0.5,
    rng: np.random.Generator | None = None,
    n_hypotheses: int = 64,
    min_inliers: int = 3,
    *,
    angular_bins: int = 24,
    prior: np.ndarray | None = None,
    max_change: float = np.inf,
    kernels: str = "numpy",
) -> np.ndarray | None:
    """Ego velocity (2,) in the vehicle frame (m/s) from the Doppler of static points.

    Static points obey ``vr_i = -(vx cos b_i + vy sin b_i)`` (sensor at the origin),
    a linear model in ``v``. RANSAC, vectorized over hypotheses: ``n_hypotheses``
    random point pairs each give ``v`` from a 2x2 solve. A hypothesis is scored
    first by the number of ``angular_bins`` bearing sectors holding one of its
    inliers (within ``threshold`` m/s), then by its inlier count: the static
    world surrounds the vehicle, while a platoon of vehicles moving together,
    which can outnumber the landmarks' points, occupies a few sectors only.
    With ``prior`` (2,), hypotheses farther than ``max_change`` (m/s) from it
    are rejected (bounded acceleration over a cycle). The winner is refined by
    least squares on its inliers. Returns ``None`` with fewer than
    ``min_inliers`` inliers or a degenerate geometry (one line of sight).
    ``kernels="numba"``: the same hypotheses (the same draws of ``rng``) scored
    and fitted in one compiled call (:func:`slam.core.kernels.doppler_ransac`).
    """
    pts = np.asarray(points, dtype=float)
    n = pts.shape[0] if pts.ndim == 2 else 0
    if n < max(2, min_inliers):
        return None
    rng = rng if rng is not None else np.random.default_rng(0)
    b = np.arctan2(pts[:, 1], pts[:, 0])
    A = -np.stack([np.cos(b), np.sin(b)], axis=1)  # vr = A v
    vr = pts[:, 2]
    i = rng.integers(0, n, n_hypotheses)
    j = rng.integers(0, n, n_hypotheses)
    sector = bearing_sectors(b, angular_bins)
    fit = _STAGES.choose(kernels).velocity_fit  # the compiled or the numpy RANSAC
    return fit(A, vr, i, j, sector, threshold, angular_bins, min_inliers, prior, max_change)


@_STAGES.stage("velocity_fit", "numba")
def _velocity_fit_compiled(A, vr, i, j, sector, threshold, angular_bins, min_inliers, prior, max_change) -> np.ndarray | None:
    """The RANSAC of :func:`estimate_ego_velocity` on its point pairs ``(i, j)`` (rows of ``vr = A v``) in one
    compiled call (:func:`slam.core.kernels.doppler_ransac`): solve, gate by the prior, score by ``sector``
    coverage, refit."""
    from slam.core.kernels import doppler_ransac

    found, sol = doppler_ransac(A, vr, np.stack([i, j], axis=1), threshold, sector, angular_bins, min_inliers,
                                np.inf, np.zeros(2) if prior is None else np.asarray(prior, float)[:2],
                                int(prior is not None), float(max_change))
    return sol if found else None


@_STAGES.stage("velocity_fit", "numpy")
def _velocity_fit_numpy(A, vr, i, j, sector, threshold, angular_bins, min_inliers, prior, max_change) -> np.ndarray | None:
    """The RANSAC of :func:`estimate_ego_velocity` in numpy (the reference): each pair ``(i, j)`` solved (2 x 2),
    scored by the ``sector`` coverage of its inliers, then their count, gated by the prior; least squares on the
    winner's inliers."""
    n = len(vr)
    a1, a2 = A[i], A[j]
    det = a1[:, 0] * a2[:, 1] - a1[:, 1] * a2[:, 0]
    good = np.abs(det) > 1e-3
    if not good.any():
        return None
    a1, a2, det = a1[good], a2[good], det[good]
    r1, r2 = vr[i[good]], vr[j[good]]
    vx = (r1 * a2[:, 1] - r2 * a1[:, 1]) / det
    vy = (a1[:, 0] * r2 - a2[:, 0] * r1) / det
    V = np.stack([vx, vy], axis=1)  # (H, 2)
    res = np.abs(vr[None, :] - V @ A.T)  # (H, N)
    inliers = res <= threshold
    count = inliers.sum(axis=1)
    onehot = np.zeros((n, angular_bins))
    onehot[np.arange(n), sector] = 1.0
    coverage = ((inliers.astype(float) @ onehot) > 0).sum(axis=1)
    score = coverage * (n + 1) + count
    if prior is not None:
        score = np.where(np.hypot(*(V - np.asarray(prior, float)[:2]).T) <= max_change, score, -1)
        if score.max() < 0:
            return None
    best = int(np.argmax(score))
    inl = res[best] <= threshold
    if inl.sum() < min_inliers:
        return None
    sol, *_ = np.linalg.lstsq(A[inl], vr[inl], rcond=None)
    if np.linalg.matrix_rank(A[inl]) < 2:
        return None
    return sol


def cluster_points(
    points: np.ndarray, radius: float = 1.0, kernels: str = "numpy"
) -> tuple[np.ndarray, np.ndarray]:
    """Merge points of one object into single observations.

    Points closer than ``radius`` (m) are linked (single linkage, connected components
    of the radius graph from a cKDTree). Each cluster c becomes one observation:

    - position: amplitude-weighted centroid ``x_c = sum_i a_i x_i / sum_i a_i``
      (plain mean when every amplitude is zero),
    - radial velocity: amplitude-weighted mean,
    - amplitude: the largest amplitude of the cluster (strongest echo).

    Returns ``(observations (C, 4), labels (N,))`` with ``labels[i]`` the cluster of
    point i. ``radius <= 0`` disables clustering (one observation per point).
    ``kernels="numba"`` finds the components with :func:`slam.core.kernels.radius_components` (the same pairs and
    labels as the cKDTree and ``connected_components`` of the reference).
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 4)
    n = pts.shape[0]
    if n == 0:
        return np.zeros((0, 4)), np.zeros(0, dtype=int)
    if radius <= 0 or n == 1:
        return pts.copy(), np.arange(n)
    components = _STAGES.choose(kernels).components(pts, radius)
    if components is None:  # no pair within the radius
        return pts.copy(), np.arange(n)
    n_c, labels = components
    amp = np.maximum(pts[:, 3], 0.0)
    w = np.bincount(labels, weights=amp, minlength=n_c)
    cnt = np.bincount(labels, minlength=n_c).astype(float)
    # weights per point: amplitude, or 1 for all-zero-amplitude clusters
    zero = w[labels] <= 0
    wp = np.where(zero, 1.0, amp)
    wsum = np.where(w > 0, w, cnt)
    obs = np.empty((n_c, 4))
    for k in range(3):  # x, y, radial velocity (3 bincounts, not a loop over points)
        obs[:, k] = np.bincount(labels, weights=wp * pts[:, k], minlength=n_c) / wsum
    obs[:, 3] = -np.inf
    np.maximum.at(obs[:, 3], labels, pts[:, 3])
    return obs, labels


@_STAGES.stage("components", "numba")
def _components_compiled(pts: np.ndarray, radius: float) -> tuple[int, np.ndarray] | None:
    """The single-linkage clusters of :func:`cluster_points`, compiled (:func:`slam.core.kernels.radius_components`):
    ``(count, labels (N,))``, None when no two points are within ``radius``."""
    from slam.core.kernels import radius_components

    n_c, labels = radius_components(np.ascontiguousarray(pts[:, :2]), float(radius))
    return None if n_c == len(pts) else (n_c, labels)


@_STAGES.stage("components", "numpy")
def _components_numpy(pts: np.ndarray, radius: float) -> tuple[int, np.ndarray] | None:
    """The single-linkage clusters of :func:`cluster_points` in numpy (the reference): the connected components of the
    cKDTree's radius graph, ``(count, labels (N,))``, None when no two points are within ``radius``."""
    n = len(pts)
    pairs = cKDTree(pts[:, :2]).query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return None
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)


def to_map_frame(xy: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Vehicle-frame points (M, 2) -> map frame for each pose (P, 3): (P, M, 2).

    ``x_map = [px, py] + R(th) x_veh`` (position compensation, paper VII-B).
    A single pose (3,) gives (M, 2).
    """
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    poses = np.asarray(poses, dtype=float)
    single = poses.ndim == 1
    p = poses.reshape(-1, 3)
    c, s = np.cos(p[:, 2])[:, None], np.sin(p[:, 2])[:, None]
    x = p[:, 0:1] + c * xy[None, :, 0] - s * xy[None, :, 1]
    y = p[:, 1:2] + s * xy[None, :, 0] + c * xy[None, :, 1]
    out = np.stack([x, y], axis=-1)
    return out[0] if single else out


def associate(
    obs_map: np.ndarray,
    landmarks: np.ndarray,
    active: np.ndarray,
    delta_m: float = 2.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-landmark association per particle (paper "Cluster Match").

    Parameters
    ----------
    obs_map : (P, M, 2) observations in the map frame of each particle (m).
    landmarks : (P, L, 2) landmark means (m).
    active : (P, L) bool, which landmarks exist in each particle.
    delta_m : association gate (m): the nearest landmark farther than this means a
        new landmark.

    Returns
    -------
    idx : (P, M) int, the matched landmark index in ``[0, L)``, or :data:`NEW` (-1)
        for a new landmark, or :data:`DROPPED` (-2) when another observation of the
        same cycle is closer to the same landmark (each landmark takes at most one
        observation per cycle, so the batched EKF update has no write conflicts).
    dist : (P, M) distance to the matched landmark (m), ``inf`` for NEW/DROPPED.

    Cost: one P x M x L distance tensor; conflicts resolved with a P x M x M compare.
    """
    if delta_m <= 0:
        raise ValueError(f"delta_m must be in (0, inf), got {delta_m!r}")
    obs_map = np.asarray(obs_map, dtype=float)
    P, M = obs_map.shape[:2]
    L = landmarks.shape[1]
    if M == 0:
        return np.zeros((P, 0), dtype=int), np.zeros((P, 0))
    if L == 0 or not active.any():
        return np.full((P, M), NEW, dtype=int), np.full((P, M), np.inf)
    # squared distances, per coordinate in place (exact, no cancellation)
    d2 = obs_map[:, :, None, 0] - landmarks[:, None, :, 0]  # (P, M, L)
    dy = obs_map[:, :, None, 1] - landmarks[:, None, :, 1]
    d2 *= d2
    dy *= dy
    d2 += dy
    d2[~np.broadcast_to(active[:, None, :], d2.shape)] = np.inf
    idx = np.argmin(d2, axis=2)  # (P, M)
    best = np.take_along_axis(d2, idx[:, :, None], axis=2)[:, :, 0]
    ok = best <= delta_m * delta_m
    dist = np.where(ok, np.sqrt(np.where(ok, best, 0.0)), np.inf)
    idx = np.where(ok, idx, NEW)
    # conflicts: obs m loses if another obs k matched the same landmark and is closer
    # (ties broken by the lower observation index)
    if M > 1:
        same = (idx[:, :, None] == idx[:, None, :]) & ok[:, :, None] & ok[:, None, :]
        closer = (dist[:, None, :] < dist[:, :, None]) | (
            (dist[:, None, :] == dist[:, :, None])
            & (np.arange(M)[None, None, :] < np.arange(M)[None, :, None])
        )
        lose = np.any(same & closer, axis=2)
        idx = np.where(lose, DROPPED, idx)
        dist = np.where(lose, np.inf, dist)
    return idx, dist


def point_covariance(
    points: np.ndarray, sensor_xy: np.ndarray | None = None, floor_m: float = 0.0
) -> np.ndarray:
    """Vehicle-frame covariance (N, 2, 2) (m^2) of radar points with their own stds.

    ``points`` (N, 7) rows ``x, y, vr, amplitude, range std (m), angle std (rad), radar``;
    ``sensor_xy`` (S, 2) the radar positions in the vehicle frame indexed by the last
    column (``None``: every sensor at the vehicle origin). With ``u`` the unit line of
    sight from the sensor and ``R`` the range from it:

    ``Sigma = sigma_R^2 u u^T + (R sigma_phi)^2 u_perp u_perp^T + floor_m^2 I``.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] < 7:
        raise ValueError(f"points must have shape (N, 7), got {pts.shape}")
    if sensor_xy is None:
        s = np.zeros((len(pts), 2))
    else:
        sens = np.asarray(sensor_xy, dtype=float).reshape(-1, 2)
        s = sens[np.clip(pts[:, 6].astype(int), 0, len(sens) - 1)]
    d = pts[:, :2] - s
    r = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
    u = d / r[:, None]
    var_r = pts[:, 4] ** 2
    var_c = (r * pts[:, 5]) ** 2
    cov = np.empty((len(r), 2, 2))
    cov[:, 0, 0] = var_r * u[:, 0] ** 2 + var_c * u[:, 1] ** 2 + floor_m**2
    cov[:, 1, 1] = var_r * u[:, 1] ** 2 + var_c * u[:, 0] ** 2 + floor_m**2
    cov[:, 0, 1] = cov[:, 1, 0] = (var_r - var_c) * u[:, 0] * u[:, 1]
    return cov


def sym2_inverse(a: np.ndarray, b: np.ndarray, c: np.ndarray):
    """Inverse and determinant of symmetric 2 x 2 matrices ``[[a, b], [b, c]]`` (any shape).

    Returns ``(i00, i01, i11, det)``; the determinant is floored at 1e-300.
    """
    det = np.maximum(a * c - b * b, 1e-300)
    return c / det, -b / det, a / det, det


def cluster_covariance(
    points: np.ndarray, labels: np.ndarray, cov: np.ndarray, n_clusters: int, kernels: str = "numpy"
) -> tuple[np.ndarray, np.ndarray]:
    """Information fusion of the points of each cluster: positions (C, 2) and covariances (C, 2, 2).

    ``Sigma_c = (sum_i Sigma_i^-1)^-1``, ``x_c = Sigma_c sum_i Sigma_i^-1 x_i`` (independent errors
    of one scatterer). Adding the members' spread to ``Sigma_c`` (for clusters of distinct
    scatterers) was tried and measured worse on the dense-pair scene (RHS ATE 0.14 / 0.10 m ->
    0.24 / 0.19 m on tuning seeds 0 / 1), so it is not done. ``kernels="numba"``: the same sums in one compiled
    pass (:func:`slam.core.kernels.cluster_fusion`).
    """
    return _STAGES.choose(kernels).fusion(points, labels, cov, n_clusters)


@_STAGES.stage("fusion", "numba")
def _fusion_compiled(points: np.ndarray, labels: np.ndarray, cov: np.ndarray, n_clusters: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`cluster_covariance`'s information sums and inverses in one compiled pass
    (:func:`slam.core.kernels.cluster_fusion`)."""
    from slam.core.kernels import cluster_fusion

    return cluster_fusion(points, labels, cov, n_clusters)


@_STAGES.stage("fusion", "numpy")
def _fusion_numpy(points: np.ndarray, labels: np.ndarray, cov: np.ndarray, n_clusters: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`cluster_covariance` in numpy (the reference): the members' information and information-weighted
    positions summed per cluster (bincount), inverted (:func:`sym2_inverse`)."""
    i00, i01, i11, _ = sym2_inverse(cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1])
    x, y = points[:, 0], points[:, 1]
    info = [np.bincount(labels, weights=w, minlength=n_clusters) for w in (i00, i01, i11)]
    vec = [
        np.bincount(labels, weights=i00 * x + i01 * y, minlength=n_clusters),
        np.bincount(labels, weights=i01 * x + i11 * y, minlength=n_clusters),
    ]
    c00, c01, c11, _ = sym2_inverse(*info)
    out = np.empty((n_clusters, 2, 2))
    out[:, 0, 0], out[:, 1, 1] = c00, c11
    out[:, 0, 1] = out[:, 1, 0] = c01
    xy = np.stack([c00 * vec[0] + c01 * vec[1], c01 * vec[0] + c11 * vec[1]], axis=1)
    return xy, out


def mahalanobis_associate(
    d2: np.ndarray, gate2: float, new_gate2: float, rounds: int = 3
) -> np.ndarray:
    """Gated association with mutual exclusion from squared Mahalanobis distances ``d2`` (P, M, L).

    Per particle, each round accepts the pairs (m, l) that are each other's nearest
    among the still free observations and landmarks within ``gate2``; ``rounds``
    rounds approximate the global nearest neighbour. An observation left without a
    landmark is :data:`NEW` when every landmark is farther than ``new_gate2``
    (``>= gate2``), else :data:`DROPPED` (its landmark went to a closer observation,
    or it is ambiguous). Inactive landmarks must carry ``inf``.

    Returns idx (P, M): landmark index, NEW or DROPPED.
    """
    P, M, L = d2.shape
    idx = np.full((P, M), NEW, dtype=np.int64)
    if M == 0 or L == 0:
        return idx
    near = d2.min(axis=2) <= new_gate2  # (P, M): some landmark close enough to forbid a new one
    cost = np.where(d2 <= gate2, d2, np.inf)
    for _ in range(rounds):
        best_l = np.argmin(cost, axis=2)  # (P, M)
        best_c = np.take_along_axis(cost, best_l[:, :, None], axis=2)[:, :, 0]
        best_m = np.argmin(cost, axis=1)  # (P, L)
        mutual = np.isfinite(best_c) & (np.take_along_axis(best_m, best_l, axis=1) == np.arange(M)[None, :])
        if not mutual.any():
            break
        idx = np.where(mutual, best_l, idx)
        pp, mm = np.nonzero(mutual)
        cost[pp, mm, :] = np.inf
        cost[pp, :, best_l[pp, mm]] = np.inf
    return np.where((idx == NEW) & near, DROPPED, idx)
