"""Compiled kernels of the SLAM (numba): the RBPF's association, proposal, landmark update and estimates, the ICP,
the Doppler fits.

Each kernel computes what the numpy reference computes (:func:`slam.core.association.mahalanobis_associate`
with the distances of :meth:`slam.core.rbpf.RBPFSlam._associate`; the FastSLAM 2.0 proposal terms and sums, the
landmarks' Kalman update, the particle-weighted estimates and the pruning of :class:`slam.core.rbpf.RBPFSlam`, bit
for bit; the clusters' information fusion of :func:`slam.core.association.cluster_covariance`; the fit of
:class:`slam.core.registration.ICPRegistration` with its ``cKDTree`` queries; the RANSAC Doppler ego-motion fits of
:func:`slam.core.association.estimate_ego_velocity` and :func:`slam.core.pipeline.doppler_ego_motion`, the same
hypotheses), with the same variable names and floating-point order, per particle or pair instead of on P x M x L
tensors. Where numpy reduces, the kernels add in numpy's order: ``np.sum`` of a contiguous run pairwise
(:func:`_pairwise_sum`), einsum's contiguous reductions on two accumulator lanes (:func:`_einsum_dot`,
:func:`_einsum_dot3`: numpy's x86-64 baseline, SSE, mul then add), its outer-axis sums in order: the filter's
existence and hit thresholds (``exist >= min_existence`` on sums of equal weights) sit exactly on such ties, so a
landmark appears or not by the last bit. What stays numpy: the transcendental functions (cos, sin, log, exp: numpy's
own SIMD code) and the per-particle 3 x 3 inverse, log-determinant and Cholesky factor of the proposal (LAPACK).
``SlamConfig(kernels="numpy")`` (``gym.make(..., slam={"kernels": "numpy"})``) selects the reference; the costs of
numba are listed in :mod:`rhs_env.kernels`.
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import njit, sort_small

__all__ = ["cluster_fusion", "doppler_ransac", "icp_fit", "icp_search", "landmark_update", "mahalanobis_association",
           "mahalanobis_association_at", "pose_moments", "proposal_information", "proposal_prior_information",
           "proposal_sample", "proposal_shift", "proposal_terms", "prune_slots", "radius_components",
           "slot_estimates"]

NEW = -1  # slam.association.NEW
DROPPED = -2  # slam.association.DROPPED


@njit
def mahalanobis_association(obs_map: np.ndarray, a00: np.ndarray, a01: np.ndarray, a11: np.ndarray,
                            mean: np.ndarray, cov: np.ndarray, active: np.ndarray, used: np.ndarray,
                            gate2: float, new_gate2: float, rounds: int) -> np.ndarray:
    """Gated mutual-nearest association per particle on the squared Mahalanobis distances (P, M) -> sub-index.

    For particle p, observation m (map frame ``obs_map[p, m]``, covariance ``A = [[a00, a01], [a01, a11]]``)
    and used landmark slot ``l = used[q]`` (mean mu, covariance Lambda):
    ``S = A + Lambda``, ``S^-1 = [[s11, -s01], [-s01, s00]] / max(det S, 1e-300)``, ``nu = z - mu``,

        d2 = i00 nx nx + 2 i01 nx ny + i11 ny ny     (inf for an inactive landmark).

    Then :func:`slam.core.association.mahalanobis_associate`: ``rounds`` rounds accepting the pairs that are each
    other's nearest among the free observations and landmarks within ``gate2``; a free observation
    is DROPPED when some landmark is within ``new_gate2``, else NEW. Returns idx (P, M) into ``used``.

    Only what decides the result is computed: a pair with ``|nu|^2 > 2 new_gate2 (s00 + s11)`` is beyond both
    gates (``d2 >= |nu|^2 / lambda_max(S)`` and ``lambda_max <= trace S``, with a factor 2 of margin for
    round-off) and is skipped; the rounds run on each observation's list of in-gate landmarks (in slot order,
    so the first of equal minima wins, as ``np.argmin``), with accepted rows and columns marked instead of
    overwritten. The same pairs and the same distances as the dense matrix of the numpy reference.
    """
    n_p, n_m = a00.shape
    n_l = used.size
    idx = np.full((n_p, n_m), NEW, np.int64)
    fin_q = np.empty((n_m, n_l), np.int64)  # per observation: its in-gate landmarks (sub-index), in order
    fin_c = np.empty((n_m, n_l))
    fin_n = np.empty(n_m, np.int64)
    near = np.empty(n_m, np.bool_)
    act = np.empty(n_l, np.int64)  # the particle's active landmarks (sub-index) and their means and covariances
    lm = np.empty((5, n_l))  # x, y, Lambda00, Lambda01, Lambda11 of those landmarks
    for p in range(n_p):
        n_act = _active_landmarks(p, used, active, mean, cov, act, lm)
        _in_gate_lists(p, obs_map, a00, a01, a11, act, lm, n_act, gate2, new_gate2, fin_q, fin_c, fin_n, near)
        _mutual_nearest_rounds(idx[p], fin_q, fin_c, fin_n, n_l, rounds)
        for m in range(n_m):
            if idx[p, m] == NEW and near[m]:
                idx[p, m] = DROPPED
    return idx


@njit
def mahalanobis_association_at(pose: np.ndarray, cth: np.ndarray, sth: np.ndarray, z: np.ndarray, b00: np.ndarray,
                               b01: np.ndarray, b11: np.ndarray, mean: np.ndarray, cov: np.ndarray, active: np.ndarray,
                               used: np.ndarray, gate2: float, new_gate2: float, rounds: int) -> np.ndarray:
    """:meth:`slam.core.rbpf.RBPFSlam._associate` from the particles' poses: :func:`mahalanobis_association` on the
    observations in each particle's map frame and their covariances there, and the landmark slots it picked.

    Particle p (pose ``pose[p]``, ``cth, sth`` its heading's cosine and sine from numpy), observation m (vehicle
    frame z, covariance with the pose terms ``B = [[b00, b01], [b01, b11]]``): ``x_map = (p_x + c z_x) - s z_y``,
    ``y_map = (p_y + s z_x) + c z_y`` (:func:`slam.core.association.to_map_frame`) and ``A = R B R^T``
    (:func:`slam.core.rbpf.rotate_sym2`), the same operations in the same order. Returns idx (P, M): the slot
    ``used[q]`` of a match, else NEW or DROPPED.
    """
    n_p, n_m = pose.shape[0], z.shape[0]
    obs_map = np.empty((n_p, n_m, 2))
    a00 = np.empty((n_p, n_m))
    a01 = np.empty((n_p, n_m))
    a11 = np.empty((n_p, n_m))
    for p in range(n_p):
        c, s = cth[p], sth[p]
        for m in range(n_m):
            obs_map[p, m, 0] = pose[p, 0] + c * z[m, 0] - s * z[m, 1]
            obs_map[p, m, 1] = pose[p, 1] + s * z[m, 0] + c * z[m, 1]
            a00[p, m], a01[p, m], a11[p, m] = _rotate_sym2(c, s, b00[m], b01[m], b11[m])
    idx = mahalanobis_association(obs_map, a00, a01, a11, mean, cov, active, used, gate2, new_gate2, rounds)
    for p in range(n_p):
        for m in range(n_m):
            if idx[p, m] >= 0:
                idx[p, m] = used[idx[p, m]]
    return idx


@njit
def _active_landmarks(p: int, used: np.ndarray, active: np.ndarray, mean: np.ndarray, cov: np.ndarray,
                      act: np.ndarray, lm: np.ndarray) -> int:
    """Particle ``p``'s active landmarks among ``used``: their sub-indices into ``act`` and their means and
    covariance entries into the rows of ``lm`` (x, y, Lambda00, Lambda01, Lambda11); returns how many."""
    n_act = 0
    for q in range(used.size):
        l = used[q]
        if active[p, l]:
            act[n_act] = q
            lm[0, n_act], lm[1, n_act] = mean[p, l, 0], mean[p, l, 1]
            lm[2, n_act], lm[3, n_act], lm[4, n_act] = cov[p, l, 0, 0], cov[p, l, 0, 1], cov[p, l, 1, 1]
            n_act += 1
    return n_act


@njit
def _in_gate_lists(p: int, obs_map: np.ndarray, a00: np.ndarray, a01: np.ndarray, a11: np.ndarray,
                   act: np.ndarray, lm: np.ndarray, n_act: int, gate2: float, new_gate2: float,
                   fin_q: np.ndarray, fin_c: np.ndarray, fin_n: np.ndarray, near: np.ndarray) -> None:
    """Per observation m of particle ``p``: the landmarks within ``gate2`` (sub-index ``fin_q[m, :fin_n[m]]``,
    distance ``fin_c``, in slot order) and whether any is within ``new_gate2`` (``near[m]``); the squared
    Mahalanobis distance ``d2 = nu^T S^-1 nu`` with ``S = A + Lambda``, skipped where ``|nu|^2`` puts the pair
    beyond both gates."""
    for m in range(a00.shape[1]):
        lowest = np.inf
        k = 0
        ox, oy = obs_map[p, m, 0], obs_map[p, m, 1]
        b00, b01, b11 = a00[p, m], a01[p, m], a11[p, m]
        for j in range(n_act):
            nx = ox - lm[0, j]
            ny = oy - lm[1, j]
            s00 = b00 + lm[2, j]
            s11 = b11 + lm[4, j]
            if nx * nx + ny * ny > 2.0 * new_gate2 * (s00 + s11):
                continue
            q = act[j]
            s01 = b01 + lm[3, j]
            det = max(s00 * s11 - s01 * s01, 1e-300)
            i00, i01, i11 = s11 / det, -s01 / det, s00 / det
            d2 = i00 * nx * nx + 2.0 * i01 * nx * ny + i11 * ny * ny
            lowest = min(lowest, d2)
            if d2 <= gate2:
                fin_q[m, k] = q
                fin_c[m, k] = d2
                k += 1
        fin_n[m] = k
        near[m] = lowest <= new_gate2


@njit
def _mutual_nearest_rounds(idx_p: np.ndarray, fin_q: np.ndarray, fin_c: np.ndarray, fin_n: np.ndarray, n_l: int,
                           rounds: int) -> None:
    """``rounds`` rounds accepting the (observation, landmark) pairs that are each other's nearest among the free
    ones, on the in-gate lists (first of equal minima wins, as ``np.argmin``); writes the accepted sub-indices
    into ``idx_p`` (the others stay as they are)."""
    n_m = fin_n.size
    row_dead = np.zeros(n_m, np.bool_)
    col_dead = np.zeros(n_l, np.bool_)
    best_l = np.empty(n_m, np.int64)
    best_c = np.empty(n_m)
    best_m = np.empty(n_l, np.int64)
    best_mc = np.empty(n_l)
    for _ in range(rounds):
        for q in range(n_l):
            best_mc[q] = np.inf
        for m in range(n_m):  # argmin over landmarks (first of equal minima, as np.argmin)
            best_l[m], best_c[m] = 0, np.inf
            if row_dead[m]:
                continue
            for j in range(fin_n[m]):
                q = fin_q[m, j]
                if not col_dead[q] and fin_c[m, j] < best_c[m]:
                    best_l[m], best_c[m] = q, fin_c[m, j]
            for j in range(fin_n[m]):  # argmin over observations, m in order (first of equal minima)
                q = fin_q[m, j]
                if not col_dead[q] and fin_c[m, j] < best_mc[q]:
                    best_m[q], best_mc[q] = m, fin_c[m, j]
        found = False
        for m in range(n_m):
            if np.isfinite(best_c[m]) and best_m[best_l[m]] == m:
                idx_p[m] = best_l[m]
                found = True
                row_dead[m] = True
                col_dead[best_l[m]] = True
        if not found:
            break


@njit
def _nearest(src: np.ndarray, prev: np.ndarray, motion: np.ndarray, upper_bound: float,
             d: np.ndarray, j: np.ndarray) -> None:
    """``cKDTree(prev).query(R(dth) src + t, k=1, distance_upper_bound=upper_bound)`` by brute force (small clouds).

    ``d_q = min_r sqrt((x_q - x_r)^2 + (y_q - y_r)^2)`` of the moved point and its index (the first of equal
    distances); ``(inf, len(prev))`` where no point is nearer than ``upper_bound``. Written into d, j.
    """
    c, s = np.cos(motion[2]), np.sin(motion[2])
    n_r = prev.shape[0]
    for q in range(src.shape[0]):
        mx = c * src[q, 0] - s * src[q, 1] + motion[0]
        my = s * src[q, 0] + c * src[q, 1] + motion[1]
        best = np.inf
        arg = n_r
        for r in range(n_r):
            dx = mx - prev[r, 0]
            dy = my - prev[r, 1]
            d2 = dx * dx + dy * dy
            if d2 < best:
                best, arg = d2, r
        dist = np.sqrt(best)
        if dist < upper_bound:
            d[q], j[q] = dist, arg
        else:
            d[q], j[q] = np.inf, n_r


@njit
def _median(x: np.ndarray) -> float:
    """``np.median`` of a short 1-D array: the middle of the sorted values, or the mean of the two middle ones."""
    v = x.copy()
    sort_small(v)  # tens of values
    h = v.size // 2
    return v[h] if v.size % 2 else (v[h - 1] + v[h]) / 2


@njit
def icp_fit(src: np.ndarray, prev: np.ndarray, guess: np.ndarray, amp_p: np.ndarray, amp_c: np.ndarray,
            use_amp: bool, max_iterations: int, max_gate_m: float, min_gate_m: float, outlier_factor: float,
            tol_m: float, tol_rad: float, min_pairs: int) -> tuple[np.ndarray, int, float, int]:
    """:meth:`slam.core.registration.ICPRegistration._fit` from one start, and the score of its result.

    Each iteration: the nearest previous point of every moved point (within ``max_gate_m``), the pairs
    within ``gate = max(min_gate_m, outlier_factor median(d))``, then the weighted 2-D Procrustes fit
    (weights ``w = sqrt(a_c a_p)`` or 1): with ``ws = w / sum w``, centroids ``mu_s = ws . src``,
    ``mu_d = ws . dst`` and centred ``a, b``, ``th = atan2(sum ws (a_x b_y - a_y b_x), sum ws (a_x b_x + a_y b_y))``,
    ``t = mu_d - R(th) mu_s``; stop when the update is below ``tol_m`` / ``tol_rad``.
    Returns the estimate (tx, ty, th), the pairs of the last fit, the RMS distance of the final
    neighbours and the number of points within ``min_gate_m`` of a previous point (the yaw search's score).
    """
    n = src.shape[0]
    d = np.empty(n)
    j = np.empty(n, np.int64)
    ok = np.empty(n, np.bool_)
    est = guess.copy()
    last_pairs = 0
    for _ in range(max_iterations):
        _nearest(src, prev, est, max_gate_m, d, j)
        finite = d[np.isfinite(d)]
        if finite.size < min_pairs:
            break
        gate = max(min_gate_m, outlier_factor * _median(finite))
        n_ok = 0
        for q in range(n):
            ok[q] = np.isfinite(d[q]) and d[q] <= gate
            n_ok += ok[q]
        if n_ok < min_pairs:
            break
        w = np.empty(n_ok)
        a = np.empty((n_ok, 2))
        b = np.empty((n_ok, 2))
        k = 0
        for q in range(n):
            if ok[q]:
                w[k] = np.sqrt(amp_c[q] * amp_p[j[q]]) if use_amp else 1.0
                a[k, 0], a[k, 1] = src[q, 0], src[q, 1]
                b[k, 0], b[k, 1] = prev[j[q], 0], prev[j[q], 1]
                k += 1
        ws = w / w.sum()
        mu_s = ws @ a
        mu_d = ws @ b
        sxy = 0.0
        sxx = 0.0
        for k in range(n_ok):
            ax, ay = a[k, 0] - mu_s[0], a[k, 1] - mu_s[1]
            bx, by = b[k, 0] - mu_d[0], b[k, 1] - mu_d[1]
            sxy += ws[k] * (ax * by - ay * bx)
            sxx += ws[k] * (ax * bx + ay * by)
        th = np.arctan2(sxy, sxx)
        c, s = np.cos(th), np.sin(th)
        new = np.array([mu_d[0] - (c * mu_s[0] - s * mu_s[1]), mu_d[1] - (s * mu_s[0] + c * mu_s[1]), th])
        step = np.abs(new - est)
        est = new
        last_pairs = n_ok
        if step[0] < tol_m and step[1] < tol_m and step[2] < tol_rad:
            break
    rmse = np.nan
    score = 0
    if last_pairs:
        _nearest(src, prev, est, max_gate_m, d, j)
        finite = d[np.isfinite(d)]
        if finite.size:
            rmse = np.sqrt(np.mean(finite ** 2))
        for q in range(n):
            score += d[q] <= min_gate_m
    return est, last_pairs, rmse, score


@njit
def proposal_information(pp: np.ndarray, H: np.ndarray, Si: np.ndarray, nu: np.ndarray, ok: np.ndarray,
                         n_particles: int) -> tuple[np.ndarray, np.ndarray]:
    """Information matrix and vector of the FastSLAM 2.0 pose proposal, summed per particle over its matched pairs.

    ``info_p = sum_{k of p, ok_k} H_k^T S_k^-1 H_k`` (P, 3, 3) and ``g_p = sum_{k of p, ok_k} H_k^T S_k^-1 nu_k`` (P, 3),
    H (K, 2, 3), Si = S^-1 (K, 2, 2), nu (K, 2), the pairs in the order of ``pp`` (the particle of each pair);
    :meth:`slam.core.rbpf.RBPFSlam._sample_proposal`'s einsums and ``np.add.at``, term by term.
    """
    info = np.zeros((n_particles, 3, 3))
    g = np.zeros((n_particles, 3))
    hts = np.empty((3, 2))
    for q in range(pp.size):
        p = pp[q]
        w = 1.0 if ok[q] else 0.0
        for a in range(3):
            for j in range(2):
                hts[a, j] = (H[q, 0, a] * Si[q, 0, j] + H[q, 1, a] * Si[q, 1, j]) * w
        for a in range(3):
            for b in range(3):
                info[p, a, b] += hts[a, 0] * H[q, 0, b] + hts[a, 1] * H[q, 1, b]
            g[p, a] += hts[a, 0] * nu[q, 0] + hts[a, 1] * nu[q, 1]
    return info, g


@njit
def icp_search(src: np.ndarray, prev: np.ndarray, guess: np.ndarray, offsets: np.ndarray, amp_p: np.ndarray,
               amp_c: np.ndarray, use_amp: bool, max_iterations: int, max_gate_m: float, min_gate_m: float,
               outlier_factor: float, tol_m: float, tol_rad: float,
               min_pairs: int) -> tuple[np.ndarray, int, float, bool]:
    """:meth:`slam.core.registration.ICPRegistration.estimate`'s heading search in one call.

    :func:`icp_fit` from every start ``guess + (0, 0, offset)``; among the fits with pairs, the best score
    ``(near, -rmse)`` (the points within ``min_gate_m`` of a previous point, then the lower RMS distance),
    compared as Python compares the tuples: ``near > near*`` or ``near == near*`` and ``-rmse > -rmse*``; the
    first of equal scores wins. Returns the winner's estimate, pairs and RMS distance, and whether any fit had
    pairs (else the estimate is the guess).
    """
    best = guess.copy()
    best_pairs, best_rmse, best_near = 0, np.nan, 0
    found = False
    start = np.empty(3)
    for o in offsets:
        start[0], start[1], start[2] = guess[0] + 0.0, guess[1] + 0.0, guess[2] + o
        est, pairs, rmse, near = icp_fit(src, prev, start, amp_p, amp_c, use_amp, max_iterations, max_gate_m,
                                         min_gate_m, outlier_factor, tol_m, tol_rad, min_pairs)
        if pairs and (not found or near > best_near or (near == best_near and -rmse > -best_rmse)):
            best, best_pairs, best_rmse, best_near, found = est, pairs, rmse, near, True
    return best, best_pairs, best_rmse, found


@njit
def _solve3(m: np.ndarray, b: np.ndarray, x: np.ndarray) -> float:
    """``x = m^-1 b`` (3 x 3, Gaussian elimination with partial pivoting, as LAPACK's getrf / getrs: multipliers
    by the pivot's reciprocal) and ``det(m)``; m and b are overwritten. Returns det (0 when singular, x unset)."""
    det = 1.0
    for k in range(3):
        p = k
        for i in range(k + 1, 3):
            if abs(m[i, k]) > abs(m[p, k]):
                p = i
        if m[p, k] == 0.0:
            return 0.0
        if p != k:
            det = -det
            for j in range(3):
                m[k, j], m[p, j] = m[p, j], m[k, j]
            b[k], b[p] = b[p], b[k]
        det *= m[k, k]
        inv = 1.0 / m[k, k]
        for i in range(k + 1, 3):
            f = m[i, k] * inv
            for j in range(k + 1, 3):
                m[i, j] -= f * m[k, j]
            b[i] -= f * b[k]
    for k in range(2, -1, -1):
        acc = b[k]
        for j in range(k + 1, 3):
            acc -= m[k, j] * x[j]
        x[k] = acc / m[k, k]
    return det


@njit
def _consensus(A: np.ndarray, vr: np.ndarray, x: np.ndarray, threshold: float, sector: np.ndarray,
               covered: np.ndarray) -> int:
    """RANSAC score ``coverage (N + 1) + count`` of the hypothesis x: its inliers ``|vr_i - A_i x| <= threshold``
    and the bearing sectors holding one (``covered`` (n_bins,) work space)."""
    n, k = A.shape
    count = 0
    for b in range(covered.size):
        covered[b] = False
    for q in range(n):
        fit = 0.0
        for c in range(k):
            fit += x[c] * A[q, c]
        if abs(vr[q] - fit) <= threshold:
            count += 1
            covered[sector[q]] = True
    score = count
    for b in range(covered.size):
        if covered[b]:
            score += n + 1
    return score


@njit
def doppler_ransac(A: np.ndarray, vr: np.ndarray, idx: np.ndarray, threshold: float, sector: np.ndarray,
                   n_bins: int, min_inliers: int, max_yaw_rate: float, prior: np.ndarray, prior_mode: int,
                   max_change: float) -> tuple[bool, np.ndarray]:
    """The RANSAC of the Doppler ego-motion fits (``vr = A x``, x = v (2,) or (vx, vy, w) (3,)) in one call.

    Each hypothesis h solves the rows ``idx[h]`` exactly (2 x 2: Cramer's rule as
    :func:`slam.core.association.estimate_ego_velocity`; 3 x 3: :func:`_solve3`) and is kept where
    ``|det| > 1e-3``, ``|w| <= max_yaw_rate`` (3 unknowns) and, with ``prior_mode`` 1, ``|v - prior| <= max_change``
    or, with 2, ``||v| - |prior|| <= max_change``. Score ``coverage (N + 1) + count`` of its inliers
    ``|vr_i - A_i x| <= threshold`` (coverage: the ``n_bins`` bearing sectors ``sector`` holding one); the first
    best hypothesis' inliers, when at least ``min_inliers`` and of full rank, give the least-squares x
    (:func:`_least_squares`, numpy's ``lstsq`` and ``matrix_rank`` to ~1e-15). Returns (found, x).
    """
    n, k = A.shape
    n_h = idx.shape[0]
    x = np.empty(k)
    best_x = np.zeros(k)
    best = -1
    m = np.empty((3, 3))
    b = np.empty(3)
    covered = np.zeros(n_bins, np.bool_)
    for h in range(n_h):
        if k == 2:
            i, j = idx[h, 0], idx[h, 1]
            det = A[i, 0] * A[j, 1] - A[i, 1] * A[j, 0]
            if not abs(det) > 1e-3:
                continue
            x[0] = (vr[i] * A[j, 1] - vr[j] * A[i, 1]) / det
            x[1] = (A[i, 0] * vr[j] - A[j, 0] * vr[i]) / det
        else:
            for r in range(3):
                b[r] = vr[idx[h, r]]
                for c in range(3):
                    m[r, c] = A[idx[h, r], c]
            if not abs(_solve3(m, b, x)) > 1e-3:
                continue
            if not abs(x[2]) <= max_yaw_rate:
                continue
        if prior_mode == 1 and not np.hypot(x[0] - prior[0], x[1] - prior[1]) <= max_change:
            continue
        if prior_mode == 2 and not abs(np.hypot(x[0], x[1]) - np.hypot(prior[0], prior[1])) <= max_change:
            continue
        score = _consensus(A, vr, x, threshold, sector, covered)
        if score > best:
            best = score
            for c in range(k):
                best_x[c] = x[c]
    if best < 0:
        return False, best_x
    keep = np.zeros(n, np.bool_)
    for q in range(n):
        fit = 0.0
        for c in range(k):
            fit += best_x[c] * A[q, c]
        keep[q] = abs(vr[q] - fit) <= threshold
    n_in = int(keep.sum())
    if n_in < min_inliers:
        return False, best_x
    a_in = np.empty((n_in, k))
    v_in = np.empty(n_in)
    r = 0
    for q in range(n):
        if keep[q]:
            for c in range(k):  # element by element: a row assignment would compile numpy's shape-error path
                a_in[r, c] = A[q, c]
            v_in[r] = vr[q]
            r += 1
    sol = np.zeros(k)
    full_rank = _least_squares(a_in, v_in, sol)
    return full_rank, sol


@njit
def _least_squares(a: np.ndarray, b: np.ndarray, x: np.ndarray) -> bool:
    """``x = argmin ||a x - b||`` for a (N, k), k <= 3 columns, by Householder QR (a and b overwritten); False (x unset)
    when a is rank-deficient: ``|R_jj| <= eps max(N, k) max_i |R_ii|`` (numpy's ``matrix_rank`` tolerance on R's
    diagonal instead of the singular values: the same verdict on exactly dependent columns, a line of sight shared by
    every point). A few dozen rows: the QR's ~1e-16 relative accuracy, without LAPACK's call (and its compile time)."""
    n, k = a.shape
    if n < k:
        return False
    for j in range(k):
        norm = 0.0
        for i in range(j, n):
            norm += a[i, j] * a[i, j]
        norm = np.sqrt(norm)
        if norm == 0.0:
            continue
        alpha = -norm if a[j, j] >= 0 else norm  # v = a_j - alpha e_j, no cancellation
        v0 = a[j, j] - alpha
        vnorm2 = v0 * v0 + (norm * norm - a[j, j] * a[j, j])
        a[j, j] = alpha
        if vnorm2 == 0.0:
            continue
        for c in range(j + 1, k):  # a_c -= 2 v (v . a_c) / (v . v)
            dot = v0 * a[j, c]
            for i in range(j + 1, n):
                dot += a[i, j] * a[i, c]
            f = 2.0 * dot / vnorm2
            a[j, c] -= f * v0
            for i in range(j + 1, n):
                a[i, c] -= f * a[i, j]
        dot = v0 * b[j]
        for i in range(j + 1, n):
            dot += a[i, j] * b[i]
        f = 2.0 * dot / vnorm2
        b[j] -= f * v0
        for i in range(j + 1, n):
            b[i] -= f * a[i, j]
    top = 0.0
    for j in range(k):
        top = max(top, abs(a[j, j]))
    tol = np.finfo(np.float64).eps * max(n, k) * top
    for j in range(k):
        if not abs(a[j, j]) > tol:
            return False
    for j in range(k - 1, -1, -1):  # R x = Q^T b
        acc = b[j]
        for c in range(j + 1, k):
            acc -= a[j, c] * x[c]
        x[j] = acc / a[j, j]
    return True


@njit
def _rotate_sym2(c: float, s: float, b00: float, b01: float, b11: float) -> tuple[float, float, float]:
    """:func:`slam.core.rbpf.rotate_sym2` for one matrix: ``R B R^T``, ``R = [[c, -s], [s, c]]``, term by term."""
    cc, ss, cs = c * c, s * s, c * s
    return cc * b00 - 2.0 * cs * b01 + ss * b11, cs * (b00 - b11) + (cc - ss) * b01, ss * b00 + 2.0 * cs * b01 + cc * b11


@njit
def landmark_update(pose: np.ndarray, cth: np.ndarray, sth: np.ndarray, z: np.ndarray, q: np.ndarray, mean: np.ndarray,
                    cov: np.ndarray, hits: np.ndarray, last_seen: np.ndarray, pp: np.ndarray, mm: np.ndarray,
                    ll: np.ndarray, cycle: int) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`slam.core.rbpf.RBPFSlam._landmark_update`'s Kalman update, pair by pair, in place.

    For pair k (particle ``p = pp[k]`` at ``pose[p]``, its observation ``z[mm[k]]`` (vehicle frame, covariance
    ``q[mm[k]]`` (2, 2)), landmark slot ``l = ll[k]``; ``cth[k], sth[k]`` the cosine and sine of the particle's
    heading, from numpy):
    ``nu = p_xy + R z - mu``, ``Q = R q R^T``, ``Lambda`` the landmark covariance (off-diagonal symmetrised),
    ``S = Lambda + Q``, ``K = Lambda S^-1``, ``mu += K nu``, ``Lambda <- Lambda - K Lambda`` (symmetrised), hits
    + 1, last seen at ``cycle``. Returns the Mahalanobis distance ``nu^T S^-1 nu`` and ``det S`` (floored at
    1e-300) per pair: numpy's own operations in numpy's order, the same values. The pairs (p, l) are distinct.
    """
    n = pp.size
    maha = np.empty(n)
    det_s = np.empty(n)
    for k in range(n):
        p, m, l = pp[k], mm[k], ll[k]
        c, s = cth[k], sth[k]
        z0, z1 = z[m, 0], z[m, 1]
        nu0 = pose[p, 0] + (c * z0 - s * z1) - mean[p, l, 0]
        nu1 = pose[p, 1] + (s * z0 + c * z1) - mean[p, l, 1]
        q00, q01, q11 = _rotate_sym2(c, s, q[m, 0, 0], q[m, 0, 1], q[m, 1, 1])
        l00, l01, l11 = cov[p, l, 0, 0], 0.5 * (cov[p, l, 0, 1] + cov[p, l, 1, 0]), cov[p, l, 1, 1]
        a, b, d = l00 + q00, l01 + q01, l11 + q11
        det = max(a * d - b * b, 1e-300)
        i00, i01, i11 = d / det, -b / det, a / det
        k00, k01 = l00 * i00 + l01 * i01, l00 * i01 + l01 * i11
        k10, k11 = l01 * i00 + l11 * i01, l01 * i01 + l11 * i11
        mean[p, l, 0] += k00 * nu0 + k01 * nu1
        mean[p, l, 1] += k10 * nu0 + k11 * nu1
        cov[p, l, 0, 0] = l00 - (k00 * l00 + k01 * l01)
        cov[p, l, 1, 1] = l11 - (k10 * l01 + k11 * l11)
        off = l01 - 0.5 * (k00 * l01 + k01 * l11 + k10 * l00 + k11 * l01)
        cov[p, l, 0, 1] = off
        cov[p, l, 1, 0] = off
        hits[p, l] += 1
        last_seen[p, l] = cycle
        maha[k] = i00 * nu0 ** 2 + 2.0 * i01 * nu0 * nu1 + i11 * nu1 ** 2
        det_s[k] = det
    return maha, det_s


@njit
def proposal_terms(pose: np.ndarray, cth: np.ndarray, sth: np.ndarray, z: np.ndarray, q: np.ndarray, mean: np.ndarray,
                   cov: np.ndarray, pp: np.ndarray, mm: np.ndarray,
                   ll: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:meth:`slam.core.rbpf.RBPFSlam._proposal_terms` pair by pair: H (K, 2, 3), S^-1 (K, 2, 2), nu (K, 2), det S (K,).

    Pair k: particle ``pp[k]``, observation ``mm[k]`` (``z``, ``q`` its vehicle-frame position and covariance),
    landmark slot ``ll[k]``. At the particle's predicted pose (``pose[pp[k]]``, ``cth[k], sth[k]`` its heading's
    cosine and sine from numpy):
    ``d = mu - p_xy``, ``h = R^T d``, ``nu = z - h``, ``S = R^T Lambda R + q``,
    ``H = [[-c, -s, h_y], [s, -c, -h_x]]``; numpy's operations in numpy's order (the same values).
    """
    n = pp.size
    H = np.zeros((n, 2, 3))
    Si = np.empty((n, 2, 2))
    nu = np.empty((n, 2))
    det_s = np.empty(n)
    for k in range(n):
        p, m, l = pp[k], mm[k], ll[k]
        c, s = cth[k], sth[k]
        d0, d1 = mean[p, l, 0] - pose[p, 0], mean[p, l, 1] - pose[p, 1]
        hx, hy = c * d0 + s * d1, -s * d0 + c * d1
        nu[k, 0], nu[k, 1] = z[m, 0] - hx, z[m, 1] - hy
        l00, l01, l11 = _rotate_sym2(c, -s, cov[p, l, 0, 0], cov[p, l, 0, 1], cov[p, l, 1, 1])
        a, b, dd = l00 + q[m, 0, 0], l01 + q[m, 0, 1], l11 + q[m, 1, 1]
        det = max(a * dd - b * b, 1e-300)
        Si[k, 0, 0], Si[k, 0, 1], Si[k, 1, 0], Si[k, 1, 1] = dd / det, -b / det, -b / det, a / det
        H[k, 0, 0], H[k, 0, 1], H[k, 0, 2] = -c, -s, hy
        H[k, 1, 0], H[k, 1, 1], H[k, 1, 2] = s, -c, -hx
        det_s[k] = det
    return H, Si, nu, det_s


@njit
def _root(parent: np.ndarray, i: int) -> int:
    """The root of ``i`` in the union-find forest ``parent``, halving the path on the way."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit
def radius_components(xy: np.ndarray, radius: float) -> tuple[int, np.ndarray]:
    """Connected components of the radius graph of ``xy`` (N, 2): points ``i, j`` linked when
    ``(x_i - x_j)^2 + (y_i - y_j)^2 <= radius^2`` (m^2), the pairs of ``cKDTree.query_pairs(radius)``.

    Components are numbered in the order of their first point, as ``scipy.sparse.csgraph.connected_components``
    numbers them. Every pair is tested (the clouds hold tens of points).

    Args:
        xy: (N, 2) positions, m.
        radius: link distance, m.

    Returns:
        ``(number of components, labels (N,))``.
    """
    n = xy.shape[0]
    parent = np.arange(n)
    r2 = radius * radius
    for i in range(n):
        for j in range(i + 1, n):
            dx = xy[i, 0] - xy[j, 0]
            dy = xy[i, 1] - xy[j, 1]
            if dx * dx + dy * dy <= r2:
                a, b = _root(parent, i), _root(parent, j)
                if a != b:
                    parent[max(a, b)] = min(a, b)
    labels = np.empty(n, np.int64)
    of_root = np.full(n, -1, np.int64)
    n_c = 0
    for i in range(n):
        r = _root(parent, i)
        if of_root[r] < 0:
            of_root[r] = n_c
            n_c += 1
        labels[i] = of_root[r]
    return n_c, labels


@njit
def _einsum_dot3(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float) -> float:
    """``sum_i a_i b_i`` over 3 terms as numpy's einsum reduces a contiguous axis of length 3 (``"pab,pb->pa"``):
    two accumulator lanes, the first holding terms 0 and 2, mul then add (the x86-64 baseline's SSE lanes),
    ``((a0 b0 + 0) + a2 b2) + (a1 b1 + 0)`` added to the zeroed output."""
    lane0 = a2 * b2 + (a0 * b0 + 0.0)
    lane1 = 0.0 * 0.0 + (a1 * b1 + 0.0)
    return (lane0 + lane1) + 0.0


@njit
def _einsum_quad2(r0: float, r1: float, s00: float, s01: float, s10: float, s11: float) -> float:
    """``r^T S r`` of one pair as numpy's einsum ``"ki,kij,kj->k"`` sums it: ``(r_i S_ij) r_j`` term by term,
    i, j in row-major order, into the zeroed output."""
    acc = 0.0 + (r0 * s00) * r0
    acc = acc + (r0 * s01) * r1
    acc = acc + (r1 * s10) * r0
    return acc + (r1 * s11) * r1


@njit
def proposal_prior_information(pp: np.ndarray, H: np.ndarray, Si: np.ndarray, nu: np.ndarray, ok: np.ndarray,
                               prior_var: np.ndarray, n_particles: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`proposal_information` plus the motion prior's information: ``Lambda_p = Sigma_p^-1 + sum_k H_k^T S_k^-1 H_k``
    (P, 3, 3) with ``Sigma_p = diag(prior_var)`` (prior_var (3,): ``np.diag(1 / prior_var)`` added entry by entry,
    zeros off the diagonal), and ``g_p = sum_k H_k^T S_k^-1 nu_k`` (P, 3)."""
    info, g = proposal_information(pp, H, Si, nu, ok, n_particles)
    for p in range(n_particles):
        for a in range(3):
            for b in range(3):
                info[p, a, b] += 1.0 / prior_var[a] if a == b else 0.0
    return info, g


@njit
def proposal_shift(cov: np.ndarray, g: np.ndarray, pp: np.ndarray, H: np.ndarray, Si: np.ndarray, nu: np.ndarray,
                   gate2: float, check: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The proposal's mean shift and its joint-compatibility test (:meth:`slam.core.rbpf.RBPFSlam._sample_proposal`).

    ``delta_p = Lambda_p^-1 g_p`` (P, 3) from ``cov = Lambda_p^-1`` (numpy's ``inv``), ``sym = (cov + cov^T) / 2``
    (the Cholesky factor's input); with ``check``, per pair k of particle ``p = pp[k]`` the residual at the
    corrected pose ``r_k = nu_k - H_k delta_p`` and ``bad_k = r_k^T S_k^-1 r_k > gate2``. The einsums' sums in
    their order (:func:`_einsum_dot3`, :func:`_einsum_quad2`). Returns (delta, sym, bad (K,) bool, number bad).
    """
    n_p = cov.shape[0]
    delta = np.empty((n_p, 3))
    sym = np.empty((n_p, 3, 3))
    for p in range(n_p):
        for a in range(3):
            delta[p, a] = _einsum_dot3(cov[p, a, 0], cov[p, a, 1], cov[p, a, 2], g[p, 0], g[p, 1], g[p, 2])
            for b in range(3):
                sym[p, a, b] = 0.5 * (cov[p, a, b] + cov[p, b, a])
    bad = np.zeros(pp.size, np.bool_)
    n_bad = 0
    if check:
        for k in range(pp.size):
            d = delta[pp[k]]
            r0 = nu[k, 0] - _einsum_dot3(H[k, 0, 0], H[k, 0, 1], H[k, 0, 2], d[0], d[1], d[2])
            r1 = nu[k, 1] - _einsum_dot3(H[k, 1, 0], H[k, 1, 1], H[k, 1, 2], d[0], d[1], d[2])
            if _einsum_quad2(r0, r1, Si[k, 0, 0], Si[k, 0, 1], Si[k, 1, 0], Si[k, 1, 1]) > gate2:
                bad[k] = True
                n_bad += 1
    return delta, sym, bad, n_bad


@njit
def proposal_sample(pp: np.ndarray, ok: np.ndarray, nu: np.ndarray, Si: np.ndarray, logdet: np.ndarray,
                    g: np.ndarray, delta: np.ndarray, logdet_post: np.ndarray, chol: np.ndarray, noise: np.ndarray,
                    pose: np.ndarray, log2pi: float) -> np.ndarray:
    """FastSLAM 2.0's importance weight and pose draw per particle; ``pose`` moved in place.

    With the pairs k of particle p that pass (``ok_k``): ``a_p = sum_k nu_k^T S_k^-1 nu_k``, ``n_p`` their number,
    ``sum_k log det S_k`` (``logdet``, numpy's log), in pair order as ``np.bincount`` sums; ``quad = a_p -
    g_p^T delta_p`` and

        log w_p = -quad / 2 - n_p log(2 pi) - (sum_k log det S_k + logdet_post_p) / 2,

    ``logdet_post = log det Sigma_p + log det Lambda_p`` (numpy's ``slogdet``); then
    ``p_xy,th += delta_p + L_p eps_p`` (``chol`` L, ``noise`` eps ~ N(0, I)). The einsums' sums in their order.
    Returns log w (P,), the heading not yet wrapped.
    """
    n_p = pose.shape[0]
    quad = np.zeros(n_p)
    n = np.zeros(n_p)
    sum_logdet = np.zeros(n_p)
    for k in range(pp.size):
        p = pp[k]
        w = 1.0 if ok[k] else 0.0
        quad[p] += w * _einsum_quad2(nu[k, 0], nu[k, 1], Si[k, 0, 0], Si[k, 0, 1], Si[k, 1, 0], Si[k, 1, 1])
        n[p] += w
        sum_logdet[p] += w * logdet[k]
    loglik = np.empty(n_p)
    for p in range(n_p):
        q = quad[p] - _einsum_dot3(g[p, 0], g[p, 1], g[p, 2], delta[p, 0], delta[p, 1], delta[p, 2])
        loglik[p] = -0.5 * q - n[p] * log2pi - 0.5 * (sum_logdet[p] + logdet_post[p])
        for a in range(3):
            step = _einsum_dot3(chol[p, a, 0], chol[p, a, 1], chol[p, a, 2], noise[p, 0], noise[p, 1], noise[p, 2])
            pose[p, a] = pose[p, a] + (delta[p, a] + step)
    return loglik


@njit
def _pairwise_block(a: np.ndarray, lo: int, n: int) -> float:
    """numpy's pairwise summation of ``a[lo:lo + n]`` for ``n <= 128``: under 8 values in order; else eight running
    sums ``r_j`` over the blocks of 8, ``((r_0 + r_1) + (r_2 + r_3)) + ((r_4 + r_5) + (r_6 + r_7))``, the rest in order."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r = a[lo:lo + 8].copy()
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] += a[lo + i + j]
        i += 8
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit
def _pairwise_sum(a: np.ndarray) -> float:
    """``sum(a)`` as numpy adds a contiguous run (``np.add.reduce``): :func:`_pairwise_block` up to 128 values, a longer
    run as the sum of its two halves (the first ``n // 2`` rounded down to a multiple of 8), each summed the same way;
    the recursion unrolled on an explicit stack (numba's cache does not keep recursive kernels)."""
    seg_lo = np.empty(64, np.int64)
    seg_n = np.empty(64, np.int64)
    right = np.zeros(64, np.bool_)  # the segment is its parent's second half
    left_sum = np.empty(64)
    seg_lo[0], seg_n[0] = 0, a.size
    depth = 0
    while True:
        n = seg_n[depth]
        if n > 128:  # descend into the first half
            half = n // 2 - (n // 2) % 8
            seg_lo[depth + 1], seg_n[depth + 1], right[depth + 1] = seg_lo[depth], half, False
            depth += 1
            continue
        val = _pairwise_block(a, seg_lo[depth], n)
        while depth > 0 and right[depth]:  # a second half: close its parent
            depth -= 1
            val = left_sum[depth] + val
        if depth == 0:
            return val
        left_sum[depth - 1] = val  # a first half: go on with its sibling
        parent = depth - 1
        half = seg_n[depth]
        seg_lo[depth], seg_n[depth], right[depth] = seg_lo[parent] + half, seg_n[parent] - half, True


@njit
def _einsum_dot(a: np.ndarray, b: np.ndarray) -> float:
    """``sum_i a_i b_i`` of two contiguous runs as numpy's einsum reduces one (``"ps,ps->s"`` along p): two
    accumulator lanes (even and odd i), mul then add, blocks of 8 taken last pair first, then pairs with a zero
    past the end; ``0 + (lane_0 + lane_1)`` (the x86-64 baseline's 2-lane SSE code)."""
    n = a.size
    lane0 = 0.0
    lane1 = 0.0
    i = 0
    while n - i >= 8:
        for j in range(3, -1, -1):
            lane0 = a[i + 2 * j] * b[i + 2 * j] + lane0
            lane1 = a[i + 2 * j + 1] * b[i + 2 * j + 1] + lane1
        i += 8
    while i < n:
        lane0 = a[i] * b[i] + lane0
        lane1 = (a[i + 1] * b[i + 1] if i + 1 < n else 0.0 * 0.0) + lane1
        i += 2
    return 0.0 + (lane0 + lane1)


@njit
def slot_estimates(w: np.ndarray, active: np.ndarray, mean: np.ndarray, cov: np.ndarray, hits: np.ndarray,
                   slots: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:meth:`slam.core.rbpf.RBPFSlam._slot_estimates`: the particle-weighted statistics of landmark ``slots``.

    With ``W_ps = w_p [p holds s]``, the existence ``E_s = sum_p W_ps`` and ``Wn = W / E`` (``/ 1`` where E = 0):
    ``mu_s = sum_p Wn_ps e_ps``, ``Sigma_s = sum_p Wn_ps Lambda_ps + sum_p Wn_ps (e_ps - mu_s)(e_ps - mu_s)^T``
    and the hits ``sum_p Wn_ps h_ps``. numpy's order: ``active[:, slots]`` holds each slot's particles contiguous, so
    E is a pairwise sum (:func:`_pairwise_sum`) and the hits einsum a contiguous reduction (:func:`_einsum_dot`);
    the mean and covariance einsums add the particles in order (``out = a b + out``, ``(Wn d_i) d_j``).
    Returns (mu (S, 2), cov (S, 2, 2), E (S,), hits (S,)).
    """
    n_p, n_s = w.size, slots.size
    exist = np.empty(n_s)
    h = np.empty(n_s)
    col = np.empty(n_p)
    wn = np.empty((n_s, n_p))
    for q in range(n_s):
        l = slots[q]
        for p in range(n_p):
            col[p] = w[p] * (1.0 if active[p, l] else 0.0)
        exist[q] = _pairwise_sum(col)
        e = exist[q] if exist[q] > 0 else 1.0
        for p in range(n_p):
            wn[q, p] = col[p] / e
            col[p] = float(hits[p, l])
        h[q] = _einsum_dot(wn[q], col)
    mu = np.zeros((n_s, 2))
    spread = np.zeros((n_s, 2, 2))
    own = np.zeros((n_s, 2, 2))
    for q in range(n_s):
        l = slots[q]
        for p in range(n_p):
            mu[q, 0] = wn[q, p] * mean[p, l, 0] + mu[q, 0]
            mu[q, 1] = wn[q, p] * mean[p, l, 1] + mu[q, 1]
        for p in range(n_p):
            v = wn[q, p]
            d0, d1 = mean[p, l, 0] - mu[q, 0], mean[p, l, 1] - mu[q, 1]
            for i in range(2):
                for j in range(2):
                    own[q, i, j] = v * cov[p, l, i, j] + own[q, i, j]
            spread[q, 0, 0] = (v * d0) * d0 + spread[q, 0, 0]
            spread[q, 0, 1] = (v * d0) * d1 + spread[q, 0, 1]
            spread[q, 1, 0] = (v * d1) * d0 + spread[q, 1, 0]
            spread[q, 1, 1] = (v * d1) * d1 + spread[q, 1, 1]
    return mu, own + spread, exist, h


@njit
def prune_slots(active: np.ndarray, last_seen: np.ndarray, hits: np.ndarray, used: np.ndarray, cycle: int,
                prune_after: int, min_hits: int, tentative_after: int) -> tuple[np.ndarray, np.ndarray, int]:
    """The landmarks :meth:`slam.core.rbpf.RBPFSlam._prune` keeps, the slots it empties and how many it drops.

    With ``age = cycle - last_seen`` (cycles), a held landmark is dropped when ``age > prune_after`` or
    (``hits < min_hits`` and ``age > tentative_after``). Only the slots in use are visited (a free slot is held by
    no particle).

    Args:
        active: (P, L) bool, the landmarks each particle holds.
        last_seen: (P, L) the cycle each was last updated.
        hits: (P, L) its update count.
        used: the slots in use, ascending.
        cycle: the current cycle.
        prune_after: cycles without an update before a landmark goes.
        min_hits: updates that confirm a landmark.
        tentative_after: cycles an unconfirmed landmark waits.

    Returns:
        ``(active & ~kill`` (P, L; ``active`` itself when nothing is dropped), the slots of ``used`` no particle
        holds afterwards (ascending), the number of dropped landmarks).
    """
    n_p = active.shape[0]
    n_kill = 0
    for p in range(n_p):
        for l in used:
            if active[p, l]:
                age = cycle - last_seen[p, l]
                n_kill += age > prune_after or (hits[p, l] < min_hits and age > tentative_after)
    if n_kill == 0:
        return active, np.empty(0, np.int64), 0
    after = active.copy()
    for p in range(n_p):
        for l in used:
            if active[p, l]:
                age = cycle - last_seen[p, l]
                if age > prune_after or (hits[p, l] < min_hits and age > tentative_after):
                    after[p, l] = False
    held = np.zeros(used.size, np.bool_)
    for p in range(n_p):
        for q in range(used.size):
            held[q] |= after[p, used[q]]
    return after, used[~held], n_kill


@njit
def pose_moments(w: np.ndarray, pose: np.ndarray, dth: np.ndarray) -> tuple[float, float, float, float, float]:
    """The weighted mean position and the variances of :meth:`slam.core.rbpf.RBPFSlam._estimate`.

    ``x = sum_p w_p x_p``, ``y = sum_p w_p y_p``, ``var_x = sum_p w_p (x_p - x)^2``, ``var_y`` alike and
    ``var_th = sum_p w_p dth_p^2`` (``dth`` the headings' wrapped offsets from their circular mean, from numpy),
    each product array summed as ``np.sum`` sums it (:func:`_pairwise_sum`). Returns (x, y, var_x, var_y, var_th).
    """
    n_p = w.size
    col = np.empty(n_p)
    for p in range(n_p):
        col[p] = w[p] * pose[p, 0]
    x = _pairwise_sum(col)
    for p in range(n_p):
        col[p] = w[p] * pose[p, 1]
    y = _pairwise_sum(col)
    for p in range(n_p):
        d = pose[p, 0] - x
        col[p] = w[p] * (d * d)
    var_x = _pairwise_sum(col)
    for p in range(n_p):
        d = pose[p, 1] - y
        col[p] = w[p] * (d * d)
    var_y = _pairwise_sum(col)
    for p in range(n_p):
        col[p] = w[p] * (dth[p] * dth[p])
    return x, y, var_x, var_y, _pairwise_sum(col)


@njit
def cluster_fusion(points: np.ndarray, labels: np.ndarray, cov: np.ndarray,
                   n_clusters: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`slam.core.association.cluster_covariance`: the information fusion of each cluster's points.

    Point i (position ``points[i, :2]``, covariance ``cov[i]``, cluster ``labels[i]``): ``I_i = Sigma_i^-1``
    (``[[s11, -s01], [-s01, s00]] / max(det, 1e-300)``); per cluster, in point order (``np.bincount``'s sums),
    ``J_c = sum_i I_i`` and ``b_c = sum_i I_i x_i``; ``Sigma_c = J_c^-1`` the same way, ``x_c = Sigma_c b_c``.
    Returns (x_c (C, 2), Sigma_c (C, 2, 2)).
    """
    info = np.zeros((n_clusters, 3))
    vec = np.zeros((n_clusters, 2))
    for i in range(labels.size):
        a, b, d = cov[i, 0, 0], cov[i, 0, 1], cov[i, 1, 1]
        det = max(a * d - b * b, 1e-300)
        i00, i01, i11 = d / det, -b / det, a / det
        x, y = points[i, 0], points[i, 1]
        c = labels[i]
        info[c, 0] += i00
        info[c, 1] += i01
        info[c, 2] += i11
        vec[c, 0] += i00 * x + i01 * y
        vec[c, 1] += i01 * x + i11 * y
    xy = np.empty((n_clusters, 2))
    out = np.empty((n_clusters, 2, 2))
    for c in range(n_clusters):
        a, b, d = info[c, 0], info[c, 1], info[c, 2]
        det = max(a * d - b * b, 1e-300)
        c00, c01, c11 = d / det, -b / det, a / det
        out[c, 0, 0], out[c, 1, 1], out[c, 0, 1], out[c, 1, 0] = c00, c11, c01, c01
        xy[c, 0] = c00 * vec[c, 0] + c01 * vec[c, 1]
        xy[c, 1] = c01 * vec[c, 0] + c11 * vec[c, 1]
    return xy, out
