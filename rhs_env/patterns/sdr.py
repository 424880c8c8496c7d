"""The paper's holographic pattern optimisation: alternating SDR for P2 (Tx) and P3/P4 (Rx).

Per grid i, from a random ``psi_R`` (paper section "Holographic Pattern Optimization
Algorithm"), alternate until delta changes by less than ``delta_t`` (relative):

* **P2 (Tx)**, Rx fixed with ``o(s) = |r(s)|^2 / ||psi_R||^2``::

      max delta  s.t.  ||psi_T||^2 = P_M = 1,
                       o(s_i) |t(s_i)|^2 - o(s_l) |t(s_l)|^2 >= delta   for l in D,
                       0 <= psi_T <= 1

  with ``|t(s)|^2 = psi^T B(s) psi``, ``B(s) = Re(conj(b(s)) b(s)^T)``. Semidefinite
  relaxation: lift ``X = psi psi^T`` and drop rank one::

      max delta  s.t.  tr X = 1,  o_i tr(B_i X) - o_l tr(B_l X) >= delta,
                       [[X, psi], [psi^T, 1]] >= 0 (PSD),  X_mm <= psi_m,  0 <= psi <= 1

  (``X_mm <= psi_m`` is the lifted ``psi_m^2 <= psi_m``, i.e. ``psi_m in [0, 1]``).
* **P3/P4 (Rx)**: P3 is scale invariant in ``psi_R`` (SNR normalised by the Rx noise
  ``||psi_R||^2 sigma^2``); P4 fixes ``||psi_R||^2 sigma^2 = 1`` and has the same
  optimum (paper). With ``sigma^2 = 1`` it is the same SDR with the roles swapped.

Each SDR is followed by Gaussian randomisation: samples ``xi ~ N(psi_hat, X - psi_hat psi_hat^T)``
(plus ``psi_hat`` and the principal eigenvector of X), projected to the feasible set
(clip to [0, 1], scale to ``||psi|| = 1``), keeping the best by the true delta. The
previous iterate is a candidate too, so delta never decreases. A random ``psi_R`` whose
first Tx SDR bound is below ``1e-3 M^2`` is redrawn (up to 10 draws).
Units: delta in the normalised two-way power units of :mod:`rhs_env.patterns.metrics`.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from rhs_common.validation import check_choice, check_int, check_range, check_types
from rhs_env.array_models import RHSConfig, ScanConfig
from rhs_env.parallel import parallel_map
from rhs_env.patterns.metrics import side_matrix, sidelobe_directions

__all__ = [
    "SDRSettings", "SDR_BASE_BYTES", "SDR_BYTES_PER_ENTRY", "SDR_MEMORY_SHARE", "SDR_SOLVERS", "build_sdr",
    "check_memory", "estimate_memory_bytes", "optimize_grid_sdr",
]

SDR_SOLVERS = ("CLARABEL", "SCS")


@dataclass(frozen=True)
class SDRSettings:
    """Settings of the SDR baseline (all change the result, all are hashed).

    Attributes:
        oversample: samples of D per main-lobe half-width (same meaning as the fast method), (0, 64].
        max_iter: maximum Tx+Rx alternations, [1, 200].
        delta_t: stop when |delta change| / |delta| < delta_t, (0, 1).
        randomizations: Gaussian randomisation samples per SDR, [0, 100000].
        seed: seed of the random psi_R initialisation and the randomisation (grid index is mixed in), >= 0.
        solver: cvxpy SDP solver, SCS (default: first-order, fast on the 61x61 lift) or CLARABEL.
    """

    oversample: float = 4.0
    max_iter: int = 10
    delta_t: float = 1e-2
    randomizations: int = 200
    seed: int = 0
    solver: str = "SCS"

    def __post_init__(self) -> None:
        check_types(self)
        check_range("oversample", self.oversample, 0.0, 64.0, low_open=True)
        check_int("max_iter", self.max_iter, 1, 200)
        check_range("delta_t", self.delta_t, 0.0, 1.0, low_open=True, high_open=True)
        check_int("randomizations", self.randomizations, 0, 100_000)
        check_int("seed", self.seed, 0, 2**63 - 1)
        check_choice("solver", self.solver, SDR_SOLVERS)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class _LiftedSDR:
    """The SDR ``max delta s.t. W vec(X) >= delta, tr X = 1, Z >= 0, X_mm <= psi_m, 0 <= psi <= 1``.

    ``W`` (L, M^2) is a cvxpy Parameter, so the problem is compiled once (DPP) and re-solved.
    """

    def __init__(self, m: int, l: int, solver: str) -> None:
        import cvxpy as cp

        self.cp = cp
        self.m = m
        self.Z = cp.Variable((m + 1, m + 1), PSD=True)
        self.X = self.Z[:m, :m]
        self.psi = self.Z[:m, m]
        self.delta = cp.Variable()
        self.W = cp.Parameter((l, m * m))
        cons = [
            self.Z[m, m] == 1,
            cp.trace(self.X) == 1,
            self.W @ cp.vec(self.X, order="F") >= self.delta,
            cp.diag(self.X) <= self.psi,
            self.psi >= 0,
            self.psi <= 1,
        ]
        self.problem = cp.Problem(cp.Maximize(self.delta), cons)
        self.solver = solver

    def solve(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        self.W.value = w
        try:
            self.problem.solve(solver=self.solver)
        except self.cp.error.SolverError:
            return None
        if self.problem.status not in ("optimal", "optimal_inaccurate") or self.Z.value is None:
            return None
        z = np.asarray(self.Z.value)
        return z[: self.m, : self.m], z[: self.m, self.m]


def _quad_forms(b: np.ndarray) -> np.ndarray:
    """vec(B_l) with ``B_l = Re(conj(b_l) b_l^T)``, shape (L, M^2) (column-major = row-major, symmetric)."""
    return np.real(np.conj(b)[:, :, None] * b[:, None, :]).reshape(b.shape[0], -1)


def _candidates(x_mat: np.ndarray, psi: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Gaussian randomisation around the SDR solution, projected to ``psi in [0, 1], ||psi|| = 1``; (N, M)."""
    cov = x_mat - np.outer(psi, psi)
    ev, evec = np.linalg.eigh(0.5 * (cov + cov.T))
    root = evec * np.sqrt(np.clip(ev, 0.0, None))
    ex, exv = np.linalg.eigh(0.5 * (x_mat + x_mat.T))
    principal = np.abs(exv[:, -1]) * np.sqrt(max(ex[-1], 0.0))
    cands = [psi[None], principal[None]]
    if n:
        cands.append(psi[None] + rng.standard_normal((n, psi.size)) @ root.T)
    c = np.clip(np.concatenate(cands), 0.0, 1.0)
    norm = np.linalg.norm(c, axis=1, keepdims=True)
    c = c[norm[:, 0] > 0] / norm[norm[:, 0] > 0]
    return c


def optimize_grid_sdr(
    config: RHSConfig, angle_deg: float, grid_index: int = 0, settings: SDRSettings | None = None
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Paper method on one grid; returns (tx_psi, rx_psi, info) with psi in [0, 1], max psi = 1.

    ``info``: ``delta`` (P1 objective on D), ``iterations``, ``history``, ``relaxation_delta``
    (the last SDR upper bounds, per side).
    """
    settings = settings or SDRSettings()
    rng = np.random.default_rng([settings.seed, grid_index])
    si = np.array([np.sin(np.deg2rad(angle_deg))])
    s_d = sidelobe_directions(config, angle_deg, settings.oversample)
    s_all = np.concatenate([si, s_d])
    m = config.elements
    b = {"tx": side_matrix(config, s_all, config.tx_feed), "rx": side_matrix(config, s_all, config.rx_feed)}
    quad = {k: _quad_forms(v) for k, v in b.items()}  # (1 + L, M^2)
    sdr = _LiftedSDR(m, s_d.size, settings.solver)

    def power(side: str, p: np.ndarray) -> np.ndarray:
        """|x(s)|^2 / ||psi||^2 on [s_i, D] for one or many psi (..., M) -> (..., 1 + L)."""
        p = np.atleast_2d(p)
        return np.abs(p @ b[side].T) ** 2 / np.sum(p**2, axis=1, keepdims=True)

    # random psi_R (paper); a draw whose first Tx SDR bound is below 1e-3 M^2 (the random
    # Rx pattern is about as weak toward s_i as toward some sidelobe, so the alternation
    # stalls at delta ~ 0) is redrawn, up to 10 draws, keeping the draw with the best bound
    best_bound, best_psi = -np.inf, None
    for _ in range(10):
        draw = {"rx": rng.uniform(0.0, 1.0, m), "tx": np.full(m, 1.0)}
        draw = {k: v / np.linalg.norm(v) for k, v in draw.items()}
        o = power("rx", draw["rx"])[0]
        w0 = o[0] * quad["tx"][0][None, :] - o[1:, None] * quad["tx"][1:]
        res = sdr.solve(w0)
        bound = float(np.min(w0 @ res[0].reshape(-1))) if res is not None else -np.inf
        if bound > best_bound:
            best_bound, best_psi = bound, draw
        if bound > 1e-3 * m * m:
            break
    psi = best_psi if best_psi is not None else draw
    cur = -np.inf
    history: list[float] = []
    bounds: dict[str, float] = {}
    it = 0
    first = True
    for it in range(1, settings.max_iter + 1):  # noqa: B007 (it is reported after the loop)
        prev = cur
        for side, other in (("tx", "rx"), ("rx", "tx")):
            o = power(other, psi[other])[0]  # (1 + L,)
            w = o[0] * quad[side][0][None, :] - o[1:, None] * quad[side][1:]
            res = sdr.solve(w)
            if res is None:
                continue
            x_mat, p_hat = res
            bounds[side] = float(np.min(w @ x_mat.reshape(-1)))
            cands = _candidates(x_mat, p_hat, settings.randomizations, rng)
            if not first:
                cands = np.concatenate([psi[side][None], cands])
            pw = power(side, cands) * o[None, :]
            d = pw[:, 0] - pw[:, 1:].max(axis=1)
            k = int(np.argmax(d))
            psi = dict(psi)
            psi[side] = cands[k]
            cur = float(d[k])
            first = False
        history.append(cur)
        if np.isfinite(prev) and abs(cur - prev) < settings.delta_t * max(abs(prev), 1e-12):
            break
    tx = psi["tx"] / psi["tx"].max()
    rx = psi["rx"] / psi["rx"].max()
    return tx, rx, {"delta": cur, "iterations": it, "history": history, "relaxation_delta": bounds}


#: memory one SDR grid holds per entry of its lifted constraints ((1 + L) M^2 of them), bytes: the quadratic forms, the
#: parameter and cvxpy's compiled problem (measured 275 B at M = 24 -> 48 on top of ~100 MiB for cvxpy itself)
SDR_BYTES_PER_ENTRY = 256
SDR_BASE_BYTES = 100 * 2**20
#: share of the machine's memory the SDR workers of a build may hold together
SDR_MEMORY_SHARE = 0.5


def estimate_memory_bytes(config: RHSConfig, scan: ScanConfig, settings: SDRSettings | None = None) -> int:
    """Memory (bytes) one SDR worker holds for the largest grid of ``scan``: ``SDR_BASE_BYTES`` plus
    ``SDR_BYTES_PER_ENTRY`` per entry of the ``(1 + L, M^2)`` lifted constraints (L sidelobe directions)."""
    settings = settings or SDRSettings()
    l_max = max(sidelobe_directions(config, float(a), settings.oversample).size for a in scan.angles_deg)
    return SDR_BASE_BYTES + SDR_BYTES_PER_ENTRY * (1 + l_max) * config.elements**2


def _physical_memory() -> int | None:
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):  # (not on every platform)
        return None


def _size(n: float) -> str:
    for unit, scale in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n / 2**20:.2f} MiB"


def check_memory(config: RHSConfig, scan: ScanConfig, settings: SDRSettings | None = None, workers: int = 2) -> None:
    """Refuse, before anything is allocated, an SDR build whose workers would need more than ``SDR_MEMORY_SHARE``
    of this machine's memory (``ValueError`` naming the elements, the estimate and the limit)."""
    total = _physical_memory()
    if total is None:
        return
    need = estimate_memory_bytes(config, scan, settings)
    limit = SDR_MEMORY_SHARE * total
    if need * workers > limit:
        raise ValueError(
            f"method sdr with elements={config.elements}: each of the {workers} workers needs about {_size(need)} "
            f"(the lifted (M+1)^2 semidefinite problem of one grid), {_size(need * workers)} in all, above the limit "
            f"of {_size(limit)} ({SDR_MEMORY_SHARE:.0%} of this machine's {_size(total)}); use the fast method, fewer "
            f"elements or fewer workers")


def build_sdr(
    config: RHSConfig,
    scan: ScanConfig,
    settings: SDRSettings | None = None,
    workers: int = 2,
    progress: Any = None,
    angles_deg: Iterable[float] | None = None,
) -> tuple[np.ndarray, np.ndarray, list[dict[str, Any]]]:
    """Run the SDR baseline on every grid (or the subset ``angles_deg``); returns (tx, rx, infos).

    The grid index mixed into the seed is the index in ``scan.angles_deg`` so a subset
    reproduces the same grids of a full build.
    """
    settings = settings or SDRSettings()
    check_memory(config, scan, settings, workers)
    full = scan.angles_deg
    angles = full if angles_deg is None else np.asarray(list(angles_deg), dtype=float)
    idx = [int(np.argmin(np.abs(full - a))) for a in angles]
    res = parallel_map(
        optimize_grid_sdr, [(config, float(a), k, settings) for a, k in zip(angles, idx)], workers, progress
    )
    return np.stack([r[0] for r in res]), np.stack([r[1] for r in res]), [r[2] for r in res]
