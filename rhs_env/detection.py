"""Beam-matched detection: CFAR on the echo energy over each beam's footprint of slots.

Why not the slot sum. A swept-beam radar sees a target in the few slots whose
two-way beam covers it (~3-4 of the 90 slots for the 60-element RHS, ~8 for the
phased array of the same cost). The slot-summed profile ``P[k] = sum_{i,c}
|Y[i, c, k]|^2`` (the paper's detector, :func:`rhs_env.radar.RadarSystem.process`
with ``detection.statistic="summed"``) adds the noise of every other slot: a Gamma(I C)
statistic, I C = 360, for the energy of ~12 cells. Per range bin k the detector
here tests every angle hypothesis j against its own footprint instead.

Statistic. Per radar r, bin k, slot i: the chirps are combined non-coherently,
``E[i, k] = sum_c |Y[i, c, k]|^2``, and for hypothesis j with footprint F_j (a set
of n_j slots)

    T_j(k) = sum_{i in F_j} E[i, k]                       (one matrix product per radar: F^T E)

Under noise alone T_j / sigma_Y^2 ~ Gamma(L_j), ``L_j = n_j C`` (independent
cells; sigma_Y^2 = sigma_n^2 sum w^2 per cell of the windowed FFT); with a target
of total energy E_s in the footprint, 2 T_j / sigma_Y^2 is non-central
chi-square with 2 L_j degrees of freedom and non-centrality 2 E_s / sigma_Y^2.

Why non-coherent. The coherent GLRT ``max_theta |h(theta)^H iota|^2 / ||h||^2``
needs the slot vector iota to be phase-coherent over the target's dwell, but the
Doppler phase runs on across the slots: ``omega C`` ~ 2 rad per slot for a 25 m/s
radial speed (``omega = 4 pi v T_c / lambda``), so iota needs a Doppler search
(~24 hypotheses for a 12-chirp dwell, 72 for the phased array's 36): ~100x the
cost of this matrix product and more hypotheses to pay for in the threshold. The
non-coherent sum of the ~12 cells of an RHS footprint loses ~1-2 dB against the
coherent matched filter (``scripts/detection_curves.py`` measures it); the OMP
stage then estimates angle and Doppler coherently at the detected bins.

Footprints. For each dictionary candidate theta (inside the scan sector), with
``g_i = |h_i(theta)|^2`` in decreasing order, the footprint is the n slots with the
largest g that maximise the deflection of the energy detector at low SNR,
``sum_{m <= n} g_(m) / sqrt(n)`` (captured energy over the noise standard
deviation); candidates with the same slot set are one hypothesis, ordered by angle.

Threshold. A cell raises a detection when ANY hypothesis exceeds, so the design
``P_fa`` (per range cell and radar) is shared among the J correlated hypotheses.
Per hypothesis the false-alarm probability is p_1, and the union follows Hunter's
bound along the chain of hypotheses ordered by angle:

    P(U_j A_j) <= sum_j P(A_j) - sum_j P(A_j A_{j+1}) = J p_1 - sum_j q_j = N_eff p_1,

(exactly the expected number of runs of consecutive exceedances, tight at small
P_fa where the exceedances of one noise spike form one run). With S the shared
slots of F_j and F_{j+1} (Gamma(s C)), X, Y the others (Gamma(a C), Gamma(b C)),

    q_j = P(S + X > tau_j, S + Y > tau_{j+1}) = int f_S(u) S_X(tau_j - u) S_Y(tau_{j+1} - u) du,

``tau_j = Gamma^{-1}(1 - p_1; L_j)``, by quadrature; p_1 solves ``N_eff(p_1) p_1 = P_fa``
(fixed point). CFAR per hypothesis along range (as the summed detector:
ordered statistic of rank ``detection.rank`` x 2 ``detection.train`` training cells, or the
cell average; the training cells are :func:`training_step` unpadded bins apart (2
for the Hann window, whose adjacent bins are correlated: spaced one bin the
measured P_fa was 1.3x the design for the RHS); at the ends of the profile the window is
one-sided, always 2 ``detection.train`` cells), multiplier from
:func:`os_alpha_fast` (= :func:`rhs_env.point_cloud.os_cfar_alpha`) / :func:`cfar_alpha` for Gamma(L_j) cells
at p_1; the noise estimate is clipped to [floor_j, floor_j 10^(cap/10)] with
``floor_j = L_j sigma_Y^2`` the calibrated noise mean. Per hypothesis, the
training cells hold only the echoes of that beam, so a vehicle at another angle
no longer raises a landmark's threshold. ``detection.mode="fixed"``: ``tau_j =
10^(detection.fixed_threshold_db / 10) floor_j``.

Peaks: local maxima along range of T_j above the threshold (only these cells
need the CFAR statistic: the threshold is never below ``alpha_j floor_j``); a
peak weaker than ``detection.sidelobe_margin_db`` above the window sidelobe of a stronger
detected bin of the same radar, read on the peak's own hypothesis, is dropped; the detected (radar, bin)
pairs are the union over hypotheses, less those inside the window main lobe of a
stronger pair (any hypothesis) and weaker than its leak plus the margin: the
same target peaks one bin apart in different hypotheses, and the OMP at the
stronger bin fits every target within the main lobe (as with the summed profile).
"""

from __future__ import annotations

import functools

import numpy as np
from scipy import special, stats

from rhs_common.jit import KernelTable
from rhs_env.point_cloud import AngleDictionary, cfar_alpha
from rhs_env.radar_config import DETECTORS, RadarConfig

__all__ = ["DETECTORS", "FootprintDetector", "beam_footprints", "os_alpha_fast", "training_step", "union_false_alarm"]



def beam_footprints(dic: AngleDictionary, sector_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Footprints (I, J) bool and their centre angles (J,) rad, J distinct slot sets ordered by angle.

    For each candidate theta with ``|theta| <= sector / 2``: the n slots of largest
    ``g_i = |h_i(theta)|^2`` with ``n = argmax_n sum_{m <= n} g_(m) / sqrt(n)``.
    """
    half = np.deg2rad(sector_deg) / 2 + 1e-9
    cand = np.flatnonzero(np.abs(dic.candidates) <= half)
    g = np.abs(dic.H[:, cand]) ** 2  # (I, Ic)
    n_s = g.shape[0]
    order = np.argsort(-g, axis=0, kind="stable")
    deflection = np.cumsum(np.take_along_axis(g, order, 0), axis=0) / np.sqrt(np.arange(1, n_s + 1))[:, None]
    n = np.argmax(deflection, axis=0) + 1  # (Ic,)
    rank = np.empty_like(order)
    np.put_along_axis(rank, order, np.arange(n_s)[:, None].repeat(order.shape[1], 1), 0)
    foot = rank < n[None, :]  # (I, Ic)
    uniq, inv = np.unique(foot.T, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    centre = np.bincount(inv, dic.candidates[cand]) / np.bincount(inv)
    o = np.argsort(centre)
    return np.ascontiguousarray(uniq[o].T), centre[o]


def _pair_exceedance(s: np.ndarray, a: np.ndarray, b: np.ndarray, t1: np.ndarray, t2: np.ndarray,
                     points: int = 501) -> np.ndarray:
    """``P(S + X > t1, S + Y > t2)`` for S ~ Gamma(s), X ~ Gamma(a), Y ~ Gamma(b) independent (shape 0: zero).

    ``= int_lo^m f_S(u) S_X(t1 - u) S_Y(t2 - u) du + S_S(m)``, ``m = max(t1, t2)``
    (beyond m both survival functions are 1), ``lo = t1`` where a = 0 (and t2
    where b = 0): trapezoid rule on ``points`` nodes, vectorised over the pairs.
    """
    s, a, b, t1, t2 = (np.asarray(v, float) for v in (s, a, b, t1, t2))
    lo = np.maximum(np.where(a == 0, t1, 0.0), np.where(b == 0, t2, 0.0))
    hi = np.maximum(t1, t2)
    u = lo[:, None] + (hi - lo)[:, None] * np.linspace(0.0, 1.0, points)[None, :]  # (P, n)

    def sf(shape: np.ndarray, x: np.ndarray) -> np.ndarray:
        pos = np.maximum(shape, 1e-12)[:, None]
        return np.where(x < 0, 1.0, np.where(shape[:, None] > 0, special.gammaincc(pos, np.maximum(x, 0.0)), 0.0))

    with np.errstate(divide="ignore", invalid="ignore"):
        a_s = np.maximum(s, 1e-12)[:, None]
        f = np.exp(special.xlogy(a_s - 1.0, u) - u - special.gammaln(a_s))
        inner = np.trapezoid(f * sf(a, t1[:, None] - u) * sf(b, t2[:, None] - u), u, axis=1)
    shared = np.where(hi > lo, inner, 0.0) + stats.gamma.sf(np.maximum(hi, lo), np.maximum(s, 1e-12))
    indep = stats.gamma.sf(t1, np.maximum(a, 1e-12)) * stats.gamma.sf(t2, np.maximum(b, 1e-12))
    return np.where(s > 0, shared, indep)


def union_false_alarm(looks: np.ndarray, shared: np.ndarray, p1: float) -> float:
    """Hunter's bound on ``P(any T_j > tau_j)``, each ``T_j ~ Gamma(looks_j)`` exceeding w.p. p1.

    ``shared[j]``: looks common to hypotheses j and j+1 (the chain ordered by angle).
    Returns ``J p1 - sum_j P(T_j > tau_j, T_{j+1} > tau_{j+1})``.
    """
    looks = np.asarray(looks, float)
    tau = stats.gamma.isf(p1, looks)
    if looks.size < 2:
        return float(p1 * looks.size)
    s = np.asarray(shared, float)
    # the pairs repeat (same shared / own looks): integrate each distinct pair once
    key = np.stack([s, looks[:-1], looks[1:]], 1)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    t_of = dict(zip(looks.tolist(), tau.tolist()))
    t1 = np.array([t_of[v] for v in uniq[:, 1]])
    t2 = np.array([t_of[v] for v in uniq[:, 2]])
    q = _pair_exceedance(uniq[:, 0], uniq[:, 1] - uniq[:, 0], uniq[:, 2] - uniq[:, 0], t1, t2)
    return float(looks.size * p1 - q[inv.reshape(-1)].sum())


@functools.lru_cache(maxsize=64)
def _per_hypothesis_pfa(looks: tuple[int, ...], shared: tuple[int, ...], pfa: float) -> tuple[float, float]:
    """p_1 with ``N_eff(p_1) p_1 = pfa`` (fixed point, N_eff = union / p_1); returns (p_1, N_eff)."""
    lk, sh = np.array(looks, float), np.array(shared, float)
    p1, n_eff = pfa / len(looks), float(len(looks))
    for _ in range(8):
        n_eff = max(union_false_alarm(lk, sh, p1) / p1, 1.0)
        p_new = pfa / n_eff
        if abs(p_new - p1) < 1e-4 * p1:
            p1 = p_new
            break
        p1 = p_new
    return p1, n_eff


def os_alpha_fast(pfa: float, looks: int | np.ndarray, train_cells: int, rank: int,
                  floor: float | np.ndarray = 0.0, nodes: int = 401) -> float | np.ndarray:
    """OS-CFAR multiplier as :func:`rhs_env.point_cloud.os_cfar_alpha`, by a fixed quadrature (milliseconds).

    Test cell X and N = ``train_cells`` training cells Gamma(looks) i.i.d. (unit
    scale); the rank-th smallest training cell is ``F^{-1}(B)``, ``B ~ Beta(rank,
    N - rank + 1)``, clipped from below at ``floor`` (noise units, as the detector
    clips its estimate at the calibrated noise mean):

        P_fa(alpha) = int_0^1 S_X(alpha max(F^{-1}(b), floor)) f_B(b) db,

    on a grid uniform in ``t = logit(b)``, ``t in [-40, 40]`` (``db = b (1 - b) dt``:
    the low tail of B, where the noise estimate is small, is resolved); alpha by
    bisection on log alpha (P_fa decreases with alpha). Vectorised over ``looks``
    (and ``floor``): returns an array of the broadcast shape, a float for scalars.
    """
    lk, fl = np.broadcast_arrays(np.asarray(looks, float), np.asarray(floor, float))
    shape = lk.shape
    lk, fl = lk.reshape(-1, 1), fl.reshape(-1, 1)
    t = np.linspace(-40.0, 40.0, nodes)
    b = 1.0 / (1.0 + np.exp(-t))
    small = b < 0.5
    y = np.where(small, special.gammaincinv(lk, np.where(small, b, 0.5)),
                 special.gammainccinv(lk, np.where(small, 0.5, 1.0 - b)))
    y = np.maximum(y, fl)  # (L, nodes)
    with np.errstate(divide="ignore"):
        w = np.exp(stats.beta.logpdf(b, rank, train_cells - rank + 1) + np.log(b) + np.log1p(-b))
    w /= np.trapezoid(w, t)
    lo, hi = np.full((lk.size, 1), -2.0), np.full((lk.size, 1), 8.0)  # log alpha, bisected to 1e-11
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        pf = np.trapezoid(special.gammaincc(lk, np.exp(mid) * y) * w, t, axis=1)[:, None]
        above = pf > pfa
        lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
    alpha = np.exp(0.5 * (lo + hi)).reshape(shape)
    return float(alpha) if alpha.ndim == 0 else alpha


@functools.lru_cache(maxsize=64)
def _alphas_unique(method: str, p1: float, looks: tuple[int, ...], train_cells: int, rank: int,
                   fixed_db: float) -> tuple[float, ...]:
    if method == "os":  # the estimate is clipped at the noise mean, ``looks`` in noise units
        return tuple(np.atleast_1d(os_alpha_fast(p1, np.array(looks), train_cells, rank, floor=np.array(looks))))
    if method == "ca":
        return tuple(cfar_alpha(p1, v, train_cells) for v in looks)
    return (10 ** (fixed_db / 10),) * len(looks)


def _alphas(method: str, p1: float, looks: tuple[int, ...], train_cells: int, rank: int,
            fixed_db: float) -> np.ndarray:
    """CFAR multiplier per hypothesis (os / ca at the per-hypothesis P_fa p1, or the fixed factor)."""
    uniq, inv = np.unique(np.array(looks), return_inverse=True)
    vals = _alphas_unique(method, p1, tuple(int(v) for v in uniq), train_cells, rank, fixed_db)
    return np.asarray(vals)[inv.reshape(-1)]


def training_step(window: np.ndarray, max_corr: float = 0.05) -> int:
    """Smallest spacing m (unpadded bins) at which the window leaves noise powers nearly independent.

    For white noise, the FFT cells k and k + m (unpadded) of the windowed data have
    correlation ``rho(m) = sum_n w_n^2 exp(-j 2 pi m n / N) / sum_n w_n^2``, and their
    powers ``|rho(m)|^2``: 0.44 at m = 1 and 0.028 at m = 2 for the Hann window, 0 at
    m = 1 for the boxcar. Returns the first m with ``|rho(m)|^2 < max_corr``: the CFAR
    training cells are taken that far apart, so the design's i.i.d. assumption holds.
    """
    w2 = np.asarray(window, float) ** 2
    rho2 = np.abs(np.fft.fft(w2)) ** 2 / np.sum(w2) ** 2
    return int(np.argmax(rho2[1:] < max_corr) + 1)


class FootprintDetector:
    """The beam-footprint CFAR detector of one antenna (see the module docstring for the equations).

    Args:
        dic: the antenna's :class:`AngleDictionary`.
        config: a :class:`rhs_env.radar_config.RadarConfig` (``detection``, ``waveform.chirps_per_slot`` and
            ``zero_pad``, ``scan.sector_deg``).
        noise_cell_var: sigma_Y^2, noise variance of one cell Y[i, c, k] of the windowed FFT (W).
        leak: the window's power-leak envelope over padded bins (:func:`window_leak_envelope`).
        window: the range window w (N,).
    """

    def __init__(self, dic: AngleDictionary, config: RadarConfig, noise_cell_var: float, leak: np.ndarray,
                 window: np.ndarray) -> None:
        cfg = config
        self.footprints, self.centres = beam_footprints(dic, cfg.scan.sector_deg)  # (I, J), (J,)
        c = cfg.waveform.chirps_per_slot
        self.looks = self.footprints.sum(0) * c  # L_j
        shared = (self.footprints[:, :-1] & self.footprints[:, 1:]).sum(0) * c
        self.pfa = cfg.detection.pfa
        self.p1, self.n_eff = _per_hypothesis_pfa(tuple(int(v) for v in self.looks),
                                                  tuple(int(v) for v in shared), float(cfg.detection.pfa))
        self.method = cfg.detection.method if cfg.detection.mode == "cfar" else "fixed"
        self.rank = max(1, round(cfg.detection.rank * 2 * cfg.detection.train))
        self.alpha = _alphas(self.method, self.p1, tuple(int(v) for v in self.looks), 2 * cfg.detection.train,
                             self.rank, float(cfg.detection.fixed_threshold_db))
        self.floor = self.looks * float(noise_cell_var)  # noise mean of T_j, W
        self.cap = self.floor * 10 ** (cfg.detection.cap_db / 10)
        self._f = np.ascontiguousarray(self.footprints.T, dtype=np.float32)  # (J, I)
        # the same footprints as slot lists for the compiled statistic: S_j = slots[starts[j]:starts[j + 1]]
        self._slots = np.flatnonzero(self.footprints.T).astype(np.int64) % self.footprints.shape[0]
        self._starts = np.concatenate([[0], np.cumsum(self.footprints.sum(0))]).astype(np.int64)
        g, t = cfg.detection.guard, cfg.detection.train
        self.train_step = training_step(window)
        near, far = np.arange(g + 1, g + t + 1), np.arange(g + t + 1, g + 2 * t + 1)
        # training offsets in order of preference: both sides, then further out (used at the ends of the profile)
        self._offsets = cfg.waveform.zero_pad * self.train_step * np.concatenate([-near, near, -far, far])
        self._train = 2 * t
        self._tables: dict[int, np.ndarray] = {}
        self._leak = np.asarray(leak, float)
        resp = np.abs(np.fft.fft(np.asarray(window, float), cfg.waveform.zero_pad * window.size)) ** 2
        self._null = int(np.argmax(np.diff(resp[: resp.size // 2]) > 0))  # first null of the main lobe, padded bins
        self._margin = 10 ** (cfg.detection.sidelobe_margin_db / 10)
        self.kernels = getattr(cfg, "kernels", "numpy")
        self._impl = _STAGES.choose(self.kernels)  # the compiled or the numpy statistic and detector

    def _training_cells(self, n: int) -> np.ndarray:
        """(n, 2 train) training-cell indices of each of n cells (cached per profile length).

        The first 2 ``detection.train`` offsets inside the profile, in the order both sides
        then further out: a symmetric window inside, one-sided at the ends.
        """
        tab = self._tables.get(n)
        if tab is None:
            idx = np.arange(n)[:, None] + self._offsets[None, :]
            pick = np.argsort((idx < 0) | (idx >= n), axis=1, kind="stable")[:, : self._train]
            tab = self._tables[n] = np.clip(np.take_along_axis(idx, pick, 1), 0, n - 1)
        return tab

    @property
    def hypotheses(self) -> int:
        return self._f.shape[0]

    def statistic(self, spec: np.ndarray) -> np.ndarray:
        """T (R, J, K) float32: footprint energies of spectra ``spec`` (R, I, C, K) (one matmul ``F^T E``).

        ``E = sum_c re^2 + sum_c im^2``: one einsum over the interleaved (re, im) float32 view
        (the same sums over c as two einsums on the strided real and imaginary parts, in half the time).
        With ``kernels="numba"`` and complex64 spectra contiguous along the bins (e.g. the in-range bins of a
        longer profile): :func:`rhs_env.kernels.footprint_statistic`
        (each footprint's few slots summed instead of the dense product; within 1-2 float32 ulp).
        """
        return np.asarray(self._impl.statistic(self, spec))

    def _statistic_numpy(self, spec: np.ndarray) -> np.ndarray:
        """:meth:`statistic` in numpy (the reference)."""
        if spec.dtype == np.complex64 and spec.strides[-1] == spec.itemsize:
            f = spec.view(np.float32)  # (R, I, C, 2 K): re, im interleaved
            p = np.einsum("ricb,ricb->rib", f, f)
            e = p[..., 0::2] + p[..., 1::2]
        else:
            e = np.einsum("ricb,ricb->rib", spec.real, spec.real)
            e += np.einsum("ricb,ricb->rib", spec.imag, spec.imag)
        return np.matmul(self._f, e)

    def threshold(self, stat: np.ndarray, r: np.ndarray, j: np.ndarray, k: np.ndarray) -> np.ndarray:
        """CFAR thresholds (D,) at the cells (r, j, k) of ``stat`` (R, J, K): ``alpha_j clip(Z, floor_j, cap_j)``."""
        a, lo = self.alpha[j], self.floor[j]
        if self.method == "fixed":
            return a * lo
        idx = self._training_cells(stat.shape[-1])[k]
        vals = stat[r[:, None], j[:, None], idx].astype(float)
        if self.method == "os":
            z = np.partition(vals, self.rank - 1, axis=1)[:, self.rank - 1]
        else:
            z = vals.mean(1)
        return a * np.clip(z, lo, self.cap[j])

    def exceedance(self, stat: np.ndarray) -> np.ndarray:
        """(R, K) bool: some hypothesis exceeds its threshold (no peak picking): the cells the design P_fa counts."""
        r, j, k = np.indices(stat.shape).reshape(3, -1)
        hit = stat.reshape(-1) > self.threshold(stat, r, j, k)
        return np.asarray(hit.reshape(stat.shape).any(axis=1), dtype=bool)

    def detect(self, spec: np.ndarray, in_range: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Detected (radar, bin) pairs of spectra (R, I, C, K); ``in_range`` (K,) bool bins allowed.

        Returns rd, kd (sorted by radar then bin, as ``np.nonzero``) and the peak
        statistic ``max_j T_j / floor_j`` of each pair (noise-mean units). With the config's
        ``kernels="numba"`` everything after the statistic runs compiled
        (:func:`rhs_env.kernels.footprint_detections`, the same steps).
        """
        stat = self.statistic(spec)
        rd, kd, strength = self._impl.detect(self, stat, in_range)
        return rd, kd, strength

    def _detect_numpy(self, stat: np.ndarray, in_range: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`detect` after the statistic, in numpy (the reference)."""
        t = stat[:, :, 1:-1]
        lo = (self.alpha * self.floor).astype(np.float32)[None, :, None]  # no threshold is lower
        peak = np.zeros(stat.shape, bool)
        peak[:, :, 1:-1] = (t > stat[:, :, :-2]) & (t >= stat[:, :, 2:]) & (t > lo)
        peak &= in_range[None, None, :]
        r, j, k = np.nonzero(peak)
        val = stat[r, j, k].astype(float)
        keep = val > self.threshold(stat, r, j, k)
        r, j, k, val = r[keep], j[keep], k[keep], val[keep]
        if r.size > 1:  # window sidelobe, on this hypothesis' line, of a stronger detected bin of the same radar
            n_r = stat.shape[0]
            bins = [np.unique(k[r == q]) for q in range(n_r)]
            src = np.full((n_r, max(b.size for b in bins)), -1)
            for q, b in enumerate(bins):
                src[q, : b.size] = b
            sk = src[r]  # (D, m) the detected bins of each detection's radar (-1: none)
            sv = np.where(sk >= 0, stat[r[:, None], j[:, None], np.maximum(sk, 0)], 0.0).astype(float)
            dk = np.minimum(np.abs(k[:, None] - sk), self._leak.size - 1)
            leak = np.where(sv > val[:, None], sv * self._leak[dk], 0.0).max(axis=1)
            keep = val >= self._margin * leak
            r, j, k, val = r[keep], j[keep], k[keep], val[keep]
        n = stat.shape[-1]
        key, inv = np.unique(r * n + k, return_inverse=True)
        strength = np.zeros(key.size)
        np.maximum.at(strength, inv.reshape(-1), val / self.floor[j])
        rd, kd = key // n, key % n
        if rd.size > 1:  # inside the window main lobe of a stronger bin (any hypothesis): its OMP takes both
            dk = np.abs(kd[:, None] - kd[None, :])
            near = (rd[:, None] == rd[None, :]) & (dk < self._null) & (strength[None, :] > strength[:, None])
            leak = np.where(near, strength[None, :] * self._leak[np.minimum(dk, self._leak.size - 1)], 0.0)
            keep = strength >= self._margin * leak.max(axis=1)
            rd, kd, strength = rd[keep], kd[keep], strength[keep]
        return rd, kd, strength


#: the detector's stages, compiled (:mod:`rhs_env.kernels.detection`) or numpy, chosen by the config's ``kernels``
_STAGES = KernelTable("rhs_env.detection")
_STAGES.stage("statistic", "numpy")(FootprintDetector._statistic_numpy)
_STAGES.stage("detect", "numpy")(FootprintDetector._detect_numpy)


@_STAGES.stage("statistic", "numba")
def _statistic_numba(det: FootprintDetector, spec: np.ndarray) -> np.ndarray:
    """:meth:`FootprintDetector.statistic` compiled (:func:`rhs_env.kernels.footprint_statistic`) for complex64 spectra
    (R, I, C, K) contiguous along the bins; numpy for any other."""
    if spec.dtype != np.complex64 or spec.ndim != 4 or spec.strides[-1] != spec.itemsize:
        return det._statistic_numpy(spec)
    from rhs_env.kernels import footprint_statistic

    return np.asarray(footprint_statistic(spec.view(np.float32), det._slots, det._starts))


@_STAGES.stage("detect", "numba")
def _detect_numba(det: FootprintDetector, stat: np.ndarray,
                  in_range: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:meth:`FootprintDetector.detect` after the statistic, compiled (:func:`rhs_env.kernels.footprint_detections`)."""
    from rhs_env.kernels import footprint_detections

    method = {"os": 0, "ca": 1}.get(det.method, 2)
    rd, kd, strength = footprint_detections(stat, np.ascontiguousarray(in_range, dtype=bool), det.alpha, det.floor,
                                            det.cap, det._training_cells(stat.shape[-1]), method, det.rank, det._leak,
                                            det._margin, det._null)
    return rd, kd, strength
