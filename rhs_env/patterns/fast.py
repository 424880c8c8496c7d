"""Fast exact-convex holographic pattern optimisation (alternating SOCPs).

Per grid i (paper P1, normalised units, see :mod:`rhs_env.patterns.metrics`)::

    max_{psi_T, psi_R >= 0}  delta = |h(s_i)|^2 - max_{l in D} |h(s_l)|^2,
    |h(s)|^2 = |t(s)|^2 |r(s)|^2 / (||psi_T||^2 ||psi_R||^2)

The Tx power is fixed (``||psi_T||^2 = P``) and the Rx noise is proportional to
``||psi_R||^2``, so both sides are scale invariant: the box ``psi in [0, 1]``
reduces to ``psi >= 0`` and every pattern is rescaled to ``max psi = 1`` at the end.

**Half-step (side X, other side Y fixed, ||psi_Y|| = 1).** With
``o(s) = |y(s)|^2`` and weights ``w_l = o(s_l) / o(s_i)``::

    delta = o(s_i) ( |x_i|^2 - max_l w_l |x_l|^2 ),  x_l = b_l^T psi  (linear in psi)

Fix the main-lobe phase ``phi = angle(x_i(psi_cur))``. Because
``Re(e^{-j phi} x_i) <= |x_i|`` with equality at ``psi_cur`` (a minorizer), the SOCP::

    G(rho) = max  c^T psi,   c = Re(e^{-j phi} b_i)
             s.t. ||psi||_2 <= 1,  psi >= 0,
                  sqrt(w_l) |b_l^T psi| <= rho          for l in D       (sidelobes)
                  sqrt(w_k) |b_k^T psi| <= c^T psi      for k in K       (main lobe peaks at s_i)

is convex, ``G`` is concave and nondecreasing in ``rho`` with
``G'(rho) = sum_l z_l`` (the dual of the sidelobe cones' heads), and
``delta(rho) = G(rho)^2 - rho^2`` is maximised over the scalar rho by a
safeguarded secant / regula falsi search on ``delta'(rho)/2 = G G' - rho``, which
stops once no rho can beat the best delta by more than ``0.1 tol`` (relative): the
tangents of the concave G bound delta everywhere (:func:`_half_step`). Evaluating at the
current sidelobe level ``rho_cur`` reproduces ``psi_cur``'s delta, so every
half-step is monotone. The set K (``theta_i +- 0.9 grid``, and points across
the main lobe) keeps the two-way peak at the grid centre; the result is checked on
a fine grid and re-solved with ``+- 0.45 grid`` if it points more than half a grid off.

**Global search.** The alternation is a local method: the phase-fixed SOCP is local
in ``phi``, and which side moves first decides which local optimum it reaches. So the
first ``sweep_iters`` alternations try ``phase_sweep`` equally spaced phases per
half-step (keeping the best), every start (the closed-form cosine holograms, plus
optional random amplitudes) is run with the Tx and with the Rx half-step first, and
only the best of these candidates after the sweep continues to convergence.

The phase sweep screens each phase with ``sweep_evals`` SOCPs (a short rho search from
the current sidelobe level) and runs the full search only on the best screened phase.

**Active set.** Most sidelobe directions are far below rho, so each SOCP starts with the
directions within ``active_db`` of the current peak and adds any direction its solution
violates (re-solving), which keeps the cones few without changing the optimum; directions
added at a low rho are dropped again at a higher one (:class:`_SideSOCP`).

**Sidelobe cap.** P1's delta is a difference of powers, so on some grids its optimum
has a high PSLR. With ``max_sidelobe_db`` the rho search is limited to
``rho <= kappa G(rho)`` (``kappa = 10^(cap/20)``; ``rho / G`` increases with rho since G
is concave with G(0) >= 0), i.e. two-way sidelobes on D at most ``cap`` dB below the
main lobe; iterates are ranked by delta, halved when the cap is missed
(:func:`_score`). Where the cap is unreachable the plain delta step is taken.
D samples the sidelobe region at ``hw / oversample``; with ``cap_refine`` the converged
pattern is checked on the report's fine grid, the sidelobe peaks that break the cap are
added to D (an exchange method for the semi-infinite constraint) and the alternation
continues, so the cap holds on the fine grid where it is reachable.

The SOCPs are solved with Clarabel directly (the problem data change with
``phi`` and ``w`` every half-step, and only ``b`` changes with ``rho``, which
Clarabel updates in place without re-factorising the symbolic structure).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

import clarabel
import numpy as np
import scipy.sparse as sp

from rhs_common.validation import check_bool, check_int, check_range, check_types
from rhs_env.array_models import RHSConfig, ScanConfig, hologram_pattern
from rhs_env.parallel import parallel_map
from rhs_env.patterns.metrics import (
    FINE_GRID_POINTS,
    mainlobe_checks,
    pointing_error_deg,
    side_matrix,
    sidelobe_directions,
)


@dataclass(frozen=True)
class FastSettings:
    """Settings of the alternating-SOCP method (all change the result, all are hashed).

    Attributes:
        oversample: samples of D per main-lobe half-width ``lambda/(M d)`` (in sin theta), (0, 64].
        max_iter: maximum Tx+Rx alternations, [1, 1000].
        tol: stop when delta improves by less than ``tol`` (relative) over one alternation, (0, 1).
        rho_evals: most SOCP solves per half-step in the scalar rho search, [1, 50].
        pointing: constrain the two-way main lobe to peak at the grid centre (set K).
        max_sidelobe_db: cap on the two-way sidelobe level on D relative to the main lobe,
            ``max_l |h(s_l)|^2 / |h(s_i)|^2 <= 10^(cap/10)``, dB in [-80, 0] (0: sidelobes only below the main lobe).
        phase_sweep: main-lobe phases phi tried per half-step (equally spaced from the
            current one) during the first ``sweep_iters`` alternations, [1, 64]; the
            phase-fixed SOCP is local in phi, the sweep makes the first steps global in phi.
        sweep_iters: alternations that use the phase sweep, [0, 1000].
        starts: initial points: the cosine holograms plus ``starts - 1`` random amplitude
            pairs, each screened for ``max(sweep_iters, 1)`` alternations; the best one is
            continued to convergence, [1, 100].
        seed: seed of the random starts (the grid angle is mixed in), >= 0.
        pointing_check: the set K holds ``theta_i +- pointing_check * grid`` (plus points across
            the main lobe), [0.05, 1]. The result is verified on a fine grid to point within
            half a grid; if it does not, the grid is re-optimised with 0.45 (strict bound).
        warm_start: :func:`build_fast` runs a second pass in which every grid also starts from
            its neighbours' first-pass solutions (adjacent grids have similar optima) and keeps
            the better result.
        both_orders: screen every start twice, with the Tx and with the Rx half-step first
            (the two orders converge to different local optima); the best of all screened
            candidates is continued.
        active_db: sidelobe directions whose weighted level is within ``active_db`` dB of the
            current peak start in each half-step SOCP; directions that the solution violates
            are added and the SOCP re-solved, so every constraint on D holds (the active set
            only makes the SOCPs smaller), dB in [-80, 0].
        sweep_evals: rho evaluations per phase in the phase-sweep half-steps, [1, 50]; when below
            ``rho_evals`` every phase is screened with ``sweep_evals`` SOCPs and only the best
            screened phase gets the full ``rho_evals`` search.
        cap_refine: rounds of the fine-grid cap check, [0, 20]: after convergence the two-way
            pattern is evaluated on the fine grid of the PSLR report
            (``metrics.FINE_GRID_POINTS``); its sidelobe peaks above the cap join D and the
            alternation continues. With 0 the cap holds on D only (sampled at ``hw / oversample``,
            between whose samples a two-way sidelobe can rise about 1 dB above it).
        socp_tol: relative duality-gap tolerance of the half-step SOCPs (Clarabel ``tol_gap_rel``;
            ``tol_gap_abs`` is ``socp_tol / 100``), [1e-10, 1e-3].
    """

    oversample: float = 4.0
    max_iter: int = 100
    tol: float = 1e-5
    rho_evals: int = 8
    pointing: bool = True
    max_sidelobe_db: float = -16.5
    phase_sweep: int = 8
    sweep_iters: int = 1
    starts: int = 1
    seed: int = 0
    pointing_check: float = 0.9
    warm_start: bool = False
    both_orders: bool = True
    active_db: float = -6.0
    sweep_evals: int = 2
    cap_refine: int = 3
    socp_tol: float = 1e-5

    def __post_init__(self) -> None:
        check_types(self)
        check_range("oversample", self.oversample, 0.0, 64.0, low_open=True)
        check_int("max_iter", self.max_iter, 1, 1000)
        check_range("tol", self.tol, 0.0, 1.0, low_open=True, high_open=True)
        check_int("rho_evals", self.rho_evals, 1, 50)
        check_int("phase_sweep", self.phase_sweep, 1, 64)
        check_int("sweep_iters", self.sweep_iters, 0, 1000)
        check_int("starts", self.starts, 1, 100)
        check_int("seed", self.seed, 0, 2**63 - 1)
        check_range("max_sidelobe_db", self.max_sidelobe_db, -80.0, 0.0)
        check_range("pointing_check", self.pointing_check, 0.05, 1.0)
        check_range("active_db", self.active_db, -80.0, 0.0)
        check_int("sweep_evals", self.sweep_evals, 1, 50)
        check_int("cap_refine", self.cap_refine, 0, 20)
        check_range("socp_tol", self.socp_tol, 1e-10, 1e-3)
        for name in ("pointing", "warm_start", "both_orders"):
            check_bool(name, getattr(self, name))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _csc(a: np.ndarray) -> sp.csc_matrix:
    """``scipy.sparse.csc_matrix(a)`` of a dense ``a`` (zeros dropped, sorted indices), built directly."""
    nz = a.T != 0  # column-major scan of a
    indptr = np.zeros(a.shape[1] + 1, dtype=np.int32)
    np.cumsum(nz.sum(axis=1), out=indptr[1:])
    return sp.csc_matrix((a.T[nz], np.nonzero(nz)[1].astype(np.int32), indptr), shape=a.shape)


PRUNE = 8  # fewest directions dropped from the active set for a rebuild


class _SideSOCP:
    """The half-step SOCP of one side for fixed phase and weights; ``solve(rho)`` re-uses the solver.

    Active set: only the sidelobe directions in ``active`` enter the SOCP; after each solve
    the full set D is checked and violated directions are added (and the SOCP re-solved),
    so the returned optimum satisfies every constraint on D. Directions added at a low rho
    stay slack at a higher one but make every later solve dearer (the KKT system fills in
    with the dense rows): before each solve the set goes back to ``active`` plus the directions
    whose level at the last solution is at least ``keep * rho``, when that drops ``PRUNE`` or more.
    """

    def __init__(self, b_i: np.ndarray, b_d: np.ndarray, w_d: np.ndarray, b_k: np.ndarray, w_k: np.ndarray,
                 phi: float, active: np.ndarray | None = None, tol: float = 1e-6, keep: float = 0.5) -> None:
        self.c = np.real(np.exp(-1j * phi) * b_i)
        self.sd = np.sqrt(w_d)[:, None] * b_d
        self.sk = np.sqrt(w_k)[:, None] * b_k
        self.active = np.ones(b_d.shape[0], bool) if active is None else active.copy()
        self.base, self.keep = self.active.copy(), keep
        self.level: np.ndarray | None = None  # |sqrt(w_l) b_l^T psi| on D at the last solution
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        settings.tol_gap_rel = tol
        settings.tol_gap_abs = tol / 100.0
        settings.presolve_enable = False
        self.settings = settings
        self.solver: Any = None

    def _build(self, rho: float) -> None:
        """Set up the SOCP over the active sidelobe directions (and a fresh solver) at ``rho``."""
        m = self.c.size
        sd = self.sd[self.active]
        L, K = sd.shape[0], self.sk.shape[0]
        # A, written dense (at most a few hundred rows of m) and stored sparse (its zeros dropped):
        # rows 0..m-1: -psi <= 0 (psi >= 0); m..2m: the cone (1, psi) (||psi|| <= 1), head row zero;
        # then (head, Re, Im) per sidelobe direction (head row zero, b_head = rho) and per main-lobe
        # point (head -c: sqrt(w_k) |b_k^T psi| <= c^T psi)
        a = np.zeros((2 * m + 1 + 3 * (L + K), m))
        a[np.arange(m), np.arange(m)] = -1.0
        a[m + 1 + np.arange(m), np.arange(m)] = -1.0
        side = a[2 * m + 1 : 2 * m + 1 + 3 * L].reshape(L, 3, m)
        side[:, 1, :], side[:, 2, :] = -sd.real, -sd.imag
        main = a[2 * m + 1 + 3 * L :].reshape(K, 3, m)
        main[:, 0, :], main[:, 1, :], main[:, 2, :] = -self.c, -self.sk.real, -self.sk.imag
        cones: list[Any] = [clarabel.NonnegativeConeT(m), clarabel.SecondOrderConeT(m + 1)]
        cones += [clarabel.SecondOrderConeT(3)] * (L + K)
        self.b = np.zeros(a.shape[0])
        self.b[m] = 1.0
        self.head = 2 * m + 1 + 3 * np.arange(L)
        b = self.b.copy()
        b[self.head] = rho
        self.solver = clarabel.DefaultSolver(sp.csc_matrix((m, m)), -self.c, _csc(a), b, cones, self.settings)

    def solve(self, rho: float) -> tuple[float, float, np.ndarray, float] | None:
        """Return (G(rho), G'(rho), psi, max_l sqrt(w_l) |b_l^T psi| on D) or None when the solver fails.

        Only ``b`` depends on rho, so a solver is updated in place; a direction added to the
        active set rebuilds it.
        """
        if self.level is not None:
            want = self.base | (self.level >= self.keep * rho)
            if self.active.sum() - want.sum() >= PRUNE:
                self.active, self.solver = want, None
        while True:
            if self.solver is None:
                self._build(rho)
            else:
                b = self.b.copy()
                b[self.head] = rho
                self.solver.update(b=b)
            sol = self.solver.solve()
            if str(sol.status) not in ("Solved", "AlmostSolved"):
                return None
            x = np.maximum(np.asarray(sol.x), 0.0)
            level = np.abs(self.sd @ x)
            viol = (level > rho * (1 + 1e-5)) & ~self.active
            if not viol.any():
                break
            self.active |= viol
            self.solver = None
        self.level = level
        z = np.asarray(sol.z)
        return float(self.c @ x), float(np.sum(z[self.head])), x, float(level.max(initial=0.0))


UNCAPPED_WEIGHT = 0.5


def _score(delta: float, capped: bool) -> float:
    """Rank of a candidate: delta, times ``UNCAPPED_WEIGHT`` when it misses the sidelobe cap.

    The cap is relative (sidelobes vs main lobe), so a pattern weak everywhere can meet it;
    a plain (cap met, delta) ordering once kept such a pattern (M = 16 at 0 deg: delta 6e-5
    against 18.0). With the weight, meeting the cap wins unless it costs over half of delta.
    """
    return delta if capped else UNCAPPED_WEIGHT * delta


Point = tuple[float, float, float]  # (rho, G G' - rho, kappa G - rho)


FLAT = 1e-6  # G'(rho) rho / G(rho) below which G counts as flat (no sidelobe dual is positive)


def _regula_falsi(lo: Point, hi: Point) -> float:
    """The next rho once the root of ``F = min(f_opt, f_cap)`` is bracketed (``F(lo) > 0 >= F(hi)``).

    The root of F is the smaller root of its two terms, so each term that is negative at ``hi``
    (positive at ``lo``) gets the regula falsi step ``r_hi - f(r_hi) (r_hi - r_lo) / (f(r_hi) - f(r_lo))``
    and the smallest one is taken: F itself is kinked where the terms cross, and G G' jumps
    where G has a kink, where the secant through the last two points steps out of the bracket.
    """
    steps = [hi[0] - fh * (hi[0] - lo[0]) / (fh - fl) for fl, fh in zip(lo[1:], hi[1:]) if fh <= 0 < fl]
    return min(steps) if steps else 0.5 * (lo[0] + hi[0])


def _delta_bound(rho: float, g: float, dg: float) -> float:
    """``max_r (a + G' r)^2 - r^2`` with ``a = G - G' rho`` (inf for ``G' >= 1``): a bound on delta(r) for every r."""
    a = g - dg * rho
    return a * a / (1.0 - dg * dg) if dg < 1.0 else np.inf


def _first_rho(rho: float, g: float, dg: float, kappa: float) -> float:
    """The first step from ``rho0``: the root of F for the linearised model ``G(r) ~ G0 + G'(r - rho0)``."""
    if g * dg - rho <= kappa * g - rho:  # stationary point of (G0 + G'(r - rho0))^2 - r^2
        return dg * (g - dg * rho) / (1 - dg * dg) if dg < 1 else 2 * rho
    return kappa * (g - dg * rho) / (1 - kappa * dg) if kappa * dg < 1 else 2 * rho  # r = kappa (G0 + G'(r - rho0))


def _half_step(sv: _SideSOCP, rho0: float, evals: int, kappa: float, gain_tol: float = 0.0) -> np.ndarray | None:
    """Maximise delta(rho) = G(rho)^2 - rho^2 subject to the sidelobe cap rho <= kappa G(rho).

    The optimum is the root of ``F(rho) = min(G G' - rho, kappa G - rho)`` (both
    terms are positive for small rho and negative for large rho: ``delta'/2`` and
    the cap slack), found by a safeguarded search that starts at ``rho0`` with a step from the
    linearised model (:func:`_first_rho`, at least ``rho0 / 4``), extrapolates by the secant until the root is
    bracketed and then takes regula falsi steps (:func:`_regula_falsi`), or bisects the bracket
    when the last two steps moved the same end (F far from linear: a kink or a jump). Steps
    leaving the bracket ``(lo, hi)`` (``(lo, 4 rho)`` before a negative F) bisect it.

    Where ``G'(rho) = 0`` (no sidelobe constraint binds: ``G(rho) = max G``) the solution ``x``
    is also feasible, with the same objective, at its own sidelobe level ``r_x <= rho``, so
    ``G(r) = G(rho)`` for ``r >= r_x``, ``F(r_x) = -r_x`` and ``x`` scores ``G^2 - r_x^2``: the
    evaluation counts at ``r_x`` (otherwise regula falsi from the flat side, where
    ``F = -rho``, creeps towards the kink of G).

    Every evaluation bounds delta everywhere: G is concave, so ``G(r) <= a + G' r`` with
    ``a = G - G' rho``, and ``max_r (a + G' r)^2 - r^2 = a^2 / (1 - G'^2)`` for ``G' < 1``
    (:func:`_delta_bound`). The search stops once the best cap-feasible delta is within
    ``gain_tol`` (relative) of the smallest such bound: no rho can improve it by more.
    Returns the psi of the best cap-feasible evaluation, else None.
    """
    best_d, best_x, bound = -np.inf, None, np.inf
    lo: Point | None = None  # bracket ends (rho, f_opt, f_cap): F(lo) > 0 >= F(hi)
    hi: Point | None = None
    kept = 0  # > 0: the last steps moved lo (that many in a row), < 0: hi
    pts: list[tuple[float, float]] = []
    rho = rho0
    for _ in range(evals):
        out = sv.solve(rho)
        if out is None:
            break
        g, dg, x, level = out
        if dg * rho <= FLAT * g:  # G is flat from rho on, and from x's own sidelobe level on
            rho = min(rho, level)
        d = g * g - rho * rho
        if rho <= kappa * g * (1 + 1e-9) and d > best_d:
            best_d, best_x = d, x
        bound = min(bound, _delta_bound(rho, g, dg))
        if best_x is not None and bound - best_d <= gain_tol * abs(best_d):
            break
        pt = (rho, g * dg - rho, kappa * g - rho)
        f = min(pt[1], pt[2])
        if f > 0:
            lo, kept = pt, max(kept, 0) + 1
            if kept > 1 and hi is not None:
                hi = (hi[0], 0.5 * hi[1], 0.5 * hi[2])
        else:
            hi, kept = pt, min(kept, 0) - 1
            if kept < -1 and lo is not None:
                lo = (lo[0], 0.5 * lo[1], 0.5 * lo[2])
        pts.append((rho, f))
        if len(pts) == 1:  # at most a factor 4 down (G' ~ 0 where G is flat would send it to ~0)
            nxt = max(_first_rho(rho, g, dg, kappa), 0.25 * rho)
        elif lo is not None and hi is not None:
            nxt = _regula_falsi(lo, hi)
        else:  # secant; aimed 0.1 % below the root while no F > 0 is seen (the cap may never be met from above)
            (r1, f1), (r2, f2) = pts[-2], pts[-1]
            nxt = r2 - f2 * (r2 - r1) / (f2 - f1) if f2 != f1 else 0.5 * (r1 + r2)
            nxt *= 1.0 - 1e-3 if lo is None else 1.0
        low = lo[0] if lo is not None else 0.0
        upper = hi[0] if hi is not None else 4.0 * max(rho, 1e-12)
        if not np.isfinite(nxt) or not (low < nxt < upper):
            nxt = 0.5 * (low + upper)
        if abs(nxt - rho) <= 1e-4 * max(rho, 1e-12):
            break
        rho = nxt
    return best_x


def optimize_grid_fast(
    config: RHSConfig,
    angle_deg: float,
    grid_deg: float,
    settings: FastSettings | None = None,
    inits: list[tuple[np.ndarray, np.ndarray]] | None = None,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Optimise the Tx and Rx amplitudes of one grid; returns (tx_psi, rx_psi, info), psi in [0, 1], max 1.

    ``inits``: (tx, rx) warm starts used instead of the holograms / random starts (no phase
    sweep). ``info``: ``delta`` (P1 objective on D, normalised), ``capped`` (sidelobe cap met
    on D), ``iterations``, ``history`` (delta per alternation), ``start_deltas`` (delta of every
    screened candidate, start-major, Tx-first then Rx-first), ``order`` (``"tx"`` or ``"rx"``: the
    side that moves first in the kept candidate), ``pointing_check`` (the one used),
    ``refined`` (directions added to D by the fine-grid cap check).
    """
    settings = settings or FastSettings()
    near = settings.pointing_check
    out = _optimize(config, angle_deg, grid_deg, settings, inits, near)
    if settings.pointing and near > 0.45 and abs(pointing_error_deg(config, out[0], out[1], angle_deg)) > grid_deg / 2:
        strict = _optimize(config, angle_deg, grid_deg, settings, inits, 0.45)
        out = strict if abs(pointing_error_deg(config, strict[0], strict[1], angle_deg)) <= grid_deg / 2 else out
    return out


Psi = dict[str, np.ndarray]
Merit = tuple[float, float, bool]


class _Grid:
    """The data of one grid's problem: the sets D and K, the side matrices, the cap, the merit.

    ``mats[side] = (b_i, B_D, B_K)`` (rows ``b(s)^T`` of :func:`side_matrix` at ``s_i``, D and K).
    """

    def __init__(self, config: RHSConfig, angle_deg: float, grid_deg: float, settings: FastSettings,
                 near: float) -> None:
        self.config, self.angle_deg, self.settings = config, angle_deg, settings
        self.si = np.array([np.sin(np.deg2rad(angle_deg))])
        self.s_k = mainlobe_checks(config, angle_deg, grid_deg, near) if settings.pointing else np.zeros(0)
        self.feeds = {"tx": config.tx_feed, "rx": config.rx_feed}
        self.kappa = 10.0 ** (settings.max_sidelobe_db / 20.0)
        self._fine: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.set_directions(sidelobe_directions(config, angle_deg, settings.oversample))

    def set_directions(self, s_d: np.ndarray) -> None:
        """Use ``s_d`` (sin theta) as the sidelobe set D."""
        self.s_d = np.asarray(s_d, dtype=float)
        self.mats = {
            side: (side_matrix(self.config, self.si, f)[0], side_matrix(self.config, self.s_d, f),
                   side_matrix(self.config, self.s_k, f))
            for side, f in self.feeds.items()
        }
        s = np.concatenate([self.si, self.s_d])
        self.merit_mats = (side_matrix(self.config, s, self.config.tx_feed), side_matrix(self.config, s, self.config.rx_feed))

    def fine_mats(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, Tx and Rx side matrices at ``[s_i, s]``) of the report's fine grid outside the main lobe (computed once)."""
        if self._fine is None:
            s = np.linspace(-1.0, 1.0, FINE_GRID_POINTS)
            s = s[np.abs(s - self.si[0]) > self.config.mainlobe_halfwidth]
            si_s = np.concatenate([self.si, s])
            self._fine = (s, side_matrix(self.config, si_s, self.config.tx_feed),
                          side_matrix(self.config, si_s, self.config.rx_feed))
        return self._fine

    def merit(self, p: Psi) -> Merit:
        """(score, delta, sidelobe cap met on D); candidates are compared by score (:func:`_score`)."""
        pw = _two_way_power(p["tx"], p["rx"], *self.merit_mats)
        capped = bool(pw[1:].max() <= self.kappa**2 * pw[0] * (1 + 1e-6))
        delta = float(pw[0] - pw[1:].max())
        return _score(delta, capped), delta, capped


def _two_way_power(tx: np.ndarray, rx: np.ndarray, bt: np.ndarray, br: np.ndarray) -> np.ndarray:
    """:func:`rhs_env.patterns.metrics.two_way_power` with the side matrices given: ``|bt tx|^2 |br rx|^2 / (||tx||^2 ||rx||^2)``."""
    t = np.einsum("...m,km->...k", tx, bt)
    r = np.einsum("...m,km->...k", rx, br)
    return np.abs(t) ** 2 * np.abs(r) ** 2 / (np.sum(tx**2, axis=-1)[..., None] * np.sum(rx**2, axis=-1)[..., None])


GAIN_TOL = 0.1  # a half-step's rho search stops within GAIN_TOL * settings.tol (relative) of its delta bound


def _search(g: _Grid, sv: _SideSOCP, rho0: float, evals: int) -> np.ndarray | None:
    """:func:`_half_step` under the cap, else (cap unreachable from here) the plain delta step."""
    x = _half_step(sv, rho0, evals, g.kappa, GAIN_TOL * g.settings.tol)
    if x is None and g.kappa < 1.0:
        x = _half_step(sv, rho0, evals, np.inf, GAIN_TOL * g.settings.tol)
    return x if x is not None and np.any(x > 0) else None


def _side_step(g: _Grid, psi: Psi, cur: Merit, side: str, other: str, nphi: int) -> tuple[Psi, Merit]:
    """One half-step of ``side`` (``other`` fixed) over ``nphi`` main-lobe phases; keeps the best by merit.

    With ``nphi > 1`` (phase sweep) every phase is screened with ``sweep_evals`` rho
    evaluations and only the best screened phase gets the full ``rho_evals`` search.
    """
    st = g.settings
    b_i, b_d, b_k = g.mats[side]
    o_i_vec, o_d_mat, o_k_mat = g.mats[other]
    o_i = abs(o_i_vec @ psi[other]) ** 2
    if o_i <= 0:
        return psi, cur
    w_d = np.abs(o_d_mat @ psi[other]) ** 2 / o_i
    w_k = np.abs(o_k_mat @ psi[other]) ** 2 / o_i if g.s_k.size else np.zeros(0)
    phi0 = float(np.angle(b_i @ psi[side]))
    level = w_d * np.abs(b_d @ psi[side]) ** 2  # weighted sidelobe power on D
    rho0 = float(np.sqrt(level.max()))
    active = level >= level.max() * 10.0 ** (st.active_db / 10.0)
    evals = st.rho_evals if nphi == 1 else min(st.sweep_evals, st.rho_evals)
    screened: list[tuple[Merit, _SideSOCP]] = []
    for phi in phi0 + 2 * np.pi * np.arange(nphi) / nphi:
        sv = _SideSOCP(b_i, b_d, w_d, b_k, w_k, float(phi), active, st.socp_tol, 10.0 ** (st.active_db / 20.0))
        x = _search(g, sv, rho0, evals)
        if x is None:
            continue
        cand = {**psi, side: x / np.linalg.norm(x)}
        m = g.merit(cand)
        screened.append((m, sv))
        if m >= cur:
            psi, cur = cand, m
    if screened and evals < st.rho_evals:  # full rho search on the best screened phase
        sv = max(screened, key=lambda r: r[0])[1]
        x = _search(g, sv, rho0, st.rho_evals)
        if x is not None:
            cand = {**psi, side: x / np.linalg.norm(x)}
            m = g.merit(cand)
            if m >= cur:
                psi, cur = cand, m
    return psi, cur


def _alternate(g: _Grid, psi: Psi, first: int, last: int, order: tuple[str, str], sweep_iters: int
               ) -> tuple[Psi, Merit, list[float], int]:
    """Alternations ``first..last`` (1-based; the first ``sweep_iters`` sweep phi) from ``psi``,
    each a half-step of ``order[0]`` then of ``order[1]``; returns (psi, merit, delta history, last it)."""
    cur = g.merit(psi)
    history = [cur[1]]
    it = first - 1
    for it in range(first, last + 1):
        start = cur
        nphi = g.settings.phase_sweep if it <= sweep_iters else 1
        for side, other in (order, order[::-1]):
            psi, cur = _side_step(g, psi, cur, side, other, nphi)
        history.append(cur[1])
        if it > sweep_iters and cur[2] == start[2] and (
            cur[1] - start[1] <= g.settings.tol * max(abs(cur[1]), 1e-12)
        ):
            break
    return psi, cur, history, it


def _initial_points(g: _Grid, warm: list[tuple[np.ndarray, np.ndarray]] | None) -> list[Psi]:
    """The starts (unit norm): ``warm`` pairs, else the cosine holograms plus ``starts - 1`` seeded
    random amplitude pairs (the grid angle is mixed into the seed)."""
    if warm:
        inits = [{"tx": np.asarray(t, dtype=float), "rx": np.asarray(r, dtype=float)} for t, r in warm]
    else:
        cfg, st = g.config, g.settings
        rng = np.random.default_rng([st.seed, round(g.angle_deg * 1e6) % (2**32)])
        inits = [{side: hologram_pattern(cfg, np.array([g.angle_deg]), f)[0] for side, f in g.feeds.items()}]
        for _ in range(st.starts - 1):
            inits.append({side: rng.uniform(0.0, 1.0, cfg.elements) for side in g.feeds})
    return [{k: v / np.linalg.norm(v) for k, v in p.items()} for p in inits]


def _fine_sidelobes(g: _Grid, psi: Psi) -> tuple[np.ndarray, np.ndarray, float]:
    """Two-way power on the fine grid of :func:`pattern_report` (``FINE_GRID_POINTS`` in sin theta)
    outside the main lobe: (s, |h(s)|^2, |h(s_i)|^2)."""
    s, bt, br = g.fine_mats()
    p = _two_way_power(psi["tx"], psi["rx"], bt, br)
    return s, p[1:], float(p[0])


def _fine_violations(g: _Grid, psi: Psi) -> np.ndarray:
    """sin(theta) of the local maxima of the fine-grid sidelobes that exceed the cap relative to ``|h(s_i)|^2``."""
    s, p, p0 = _fine_sidelobes(g, psi)
    peak = np.r_[True, p[1:] >= p[:-1]] & np.r_[p[:-1] >= p[1:], True]
    return s[peak & (p > g.kappa**2 * p0 * (1 + 1e-9))]


def _fine_key(g: _Grid, psi: Psi) -> tuple[bool, float]:
    """Rank of a cap-refinement iterate on the fine grid: meeting the cap first; among those that
    meet it the larger delta, among those that miss it the lower peak sidelobe (so a round never
    makes the reported PSLR worse)."""
    _, p, p0 = _fine_sidelobes(g, psi)
    met = bool(p.max() <= g.kappa**2 * p0 * (1 + 1e-9))
    return met, (p0 - float(p.max())) if met else -float(p.max()) / p0


def _refine_cap(g: _Grid, psi: Psi, history: list[float], order: tuple[str, str]
                ) -> tuple[Psi, Merit, list[float], int]:
    """Up to ``cap_refine`` rounds: add the fine-grid sidelobe peaks that break the cap to D and continue
    the alternation. Returns the kept iterate (best :func:`_fine_key`: the cap, delta and PSLR on the
    fine grid), its merit on the final D, the history and
    the number of added directions."""
    kept = [psi]
    refined = 0
    for _ in range(g.settings.cap_refine if g.kappa < 1.0 else 0):
        extra = _fine_violations(g, psi)
        if extra.size == 0:
            break
        refined += extra.size
        g.set_directions(np.unique(np.r_[g.s_d, extra]))
        psi, _, more, _ = _alternate(g, psi, 1, g.settings.max_iter, order, 0)
        history = history + more[1:]
        kept.append(psi)
    psi = max(kept, key=lambda p: _fine_key(g, p)) if len(kept) > 1 else psi
    return psi, g.merit(psi), history, refined


def _optimize(
    config: RHSConfig,
    angle_deg: float,
    grid_deg: float,
    settings: FastSettings,
    warm: list[tuple[np.ndarray, np.ndarray]] | None,
    near: float,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Screen every start with each half-step order, continue the best to convergence, then (with
    ``cap_refine``) add the fine-grid sidelobe peaks that break the cap to D and continue again."""
    g = _Grid(config, angle_deg, grid_deg, settings, near)
    sweep_iters = 0 if warm else settings.sweep_iters
    orders = [("tx", "rx"), ("rx", "tx")] if settings.both_orders else [("tx", "rx")]
    screen = min(max(sweep_iters, 1), settings.max_iter)
    runs = [(*_alternate(g, p0, 1, screen, order, sweep_iters), order)
            for p0 in _initial_points(g, warm) for order in orders]
    psi, cur, history, it, order = max(runs, key=lambda r: r[1])
    if it < settings.max_iter:
        psi, cur, more, it = _alternate(g, psi, it + 1, settings.max_iter, order, sweep_iters)
        history = history + more[1:]
    psi, cur, history, refined = _refine_cap(g, psi, history, order)
    tx = psi["tx"] / psi["tx"].max()
    rx = psi["rx"] / psi["rx"].max()
    return tx, rx, {"delta": cur[1], "capped": cur[2], "iterations": it, "history": history,
                    "start_deltas": [r[1][1] for r in runs], "pointing_check": near, "order": order[0],
                    "refined": refined}


def _mirror_index(config: RHSConfig, angles: np.ndarray) -> np.ndarray | None:
    """For mirror-symmetric feeds (``tx_feed + rx_feed = M - 1``): ``idx[k]`` = the grid whose
    solution grid k mirrors (``-angles[k]``), or None when the feeds or the grid set are not symmetric.

    Reversing the element order swaps the feeds and maps s to -s, so
    ``(tx, rx)`` optimal at theta gives ``(rx[::-1], tx[::-1])`` optimal at -theta (same delta,
    PSLR and mirrored pointing error); only the grids with theta >= 0 are optimised.
    """
    if config.tx_feed + config.rx_feed != config.elements - 1:
        return None
    idx = np.arange(angles.size)
    for k, a in enumerate(angles):
        if a < 0:
            j = np.flatnonzero(np.abs(angles + a) <= 1e-9)
            if j.size == 0:
                return None
            idx[k] = j[0]
    return idx


def _better(a: tuple[np.ndarray, np.ndarray, dict[str, Any]], b: tuple[np.ndarray, np.ndarray, dict[str, Any]]) -> bool:
    """Is result ``a`` better than ``b`` by :func:`_score`?"""
    return _score(a[2]["delta"], a[2]["capped"]) > _score(b[2]["delta"], b[2]["capped"])


def build_fast(
    config: RHSConfig,
    scan: ScanConfig,
    settings: FastSettings | None = None,
    workers: int = 2,
    progress: Any = None,
    angles_deg: Iterable[float] | None = None,
) -> tuple[np.ndarray, np.ndarray, list[dict[str, Any]]]:
    """Optimise every grid of ``scan`` (or the given subset ``angles_deg``); returns (tx (I,M), rx (I,M), infos).

    With mirror-symmetric feeds only the grids with theta >= 0 are optimised and the others
    are their mirror images (:func:`_mirror_index`). With ``settings.warm_start`` a second
    pass restarts every optimised grid from its neighbours' first-pass solutions (in angle
    order) and keeps the better result.
    """
    settings = settings or FastSettings()
    angles = scan.angles_deg if angles_deg is None else np.asarray(list(angles_deg), dtype=float)
    mirror = _mirror_index(config, angles)
    solve = np.unique(mirror) if mirror is not None else np.arange(angles.size)
    solve = solve[np.argsort(angles[solve])]
    bar_total = getattr(progress, "total", None)
    if progress is not None and bar_total is not None:
        progress.total = solve.size * (2 if settings.warm_start and solve.size > 1 else 1)
        progress.refresh()
    res = parallel_map(
        optimize_grid_fast, [(config, float(angles[k]), scan.grid_deg, settings) for k in solve], workers, progress
    )
    if settings.warm_start and solve.size > 1:
        args = []
        for n, k in enumerate(solve):
            nb = [res[m][:2] for m in (n - 1, n + 1) if 0 <= m < solve.size]
            args.append((config, float(angles[k]), scan.grid_deg, settings, nb))
        res2 = parallel_map(optimize_grid_fast, args, workers, progress)
        for n, r in enumerate(res2):
            if _better(r, res[n]):
                res[n] = (r[0], r[1], {**r[2], "warm_started": True})
    by_grid = {int(k): r for k, r in zip(solve, res)}
    tx, rx, infos = [], [], []
    for k in range(angles.size):
        src = int(mirror[k]) if mirror is not None else k
        t, r, info = by_grid[src]
        if src != k:
            t, r, info = r[::-1].copy(), t[::-1].copy(), {**info, "mirror_of": float(angles[src])}
        tx.append(t)
        rx.append(r)
        infos.append(info)
    return np.stack(tx), np.stack(rx), infos


__all__ = ["FastSettings", "build_fast", "optimize_grid_fast"]
