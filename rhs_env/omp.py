"""The OMP over the angle dictionary (numpy, the reference): step 3 of :mod:`rhs_env.point_cloud`'s chain.

At a detected bin the data over slots and chirps obey ``Y[i, c] = sum_k s_k h_i(theta_k) exp(j omega_k t_ic) +
noise`` with ``H[i, j] = h_i(theta_j)`` (:class:`AngleDictionary`: the two-way gain of slot i toward candidate j and
its analytic angle derivatives), ``t_ic = i C + c`` the chirp time over the sweep and ``omega = 4 pi v T_c /
lambda`` the chirp-to-chirp Doppler phase. :func:`omp_doppler` (paper Algorithm 1, loop condition corrected to
"l <= L_max AND ||r||^2 >= delta_r") finds, on the residual, a coarse Doppler from the chirp pairs, the best
candidate of ``|h_j^H rho| / ||h_j||`` for the Doppler-compensated slot vector (a joint angle x Doppler grid when
the Doppler uncertainty matters over the target's dwell), the fine Doppler over the whole sweep, the angle below the
candidate spacing (parabola, then Newton steps), least squares for all amplitudes and a cyclic re-refinement of
every atom against its own partial residual (:func:`joint_refine`, as in Newtonized OMP); it stops at
:func:`residual_threshold`, below a fraction of the data power, at a weak new atom or after L_max atoms.
:func:`omp_angles` is the angle-only OMP of one snapshot per detection.

Its compiled twin is :mod:`rhs_env.kernels.omp` (the whole OMP in one call) on the stages of
:mod:`rhs_env.kernels.omp_stages` and :mod:`rhs_env.kernels.atoms`; the dictionary's ``kernels`` field
(:meth:`AngleDictionary.use_kernels`) chooses them. Every name here is importable from :mod:`rhs_env.point_cloud`
too.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.fft as sfft
from scipy import stats

from rhs_common.jit import KernelTable
from rhs_common.linalg import batched_lstsq
from rhs_env.array_models import ArrayAntenna, steering

__all__ = [
    "AngleDictionary", "DopplerOMPResult", "OMPResult", "atom_norms", "joint_refine", "omp_angles", "omp_doppler",
    "parabolic_offset", "residual_threshold", "warm_refinement_kernels",
]


#: the OMP's stages that have a compiled twin (:mod:`rhs_env.kernels`), chosen by the dictionary's ``kernels``
#: (:meth:`AngleDictionary.use_kernels`) or a ``kernels`` argument; each numba function computes what its numpy one
#: does, or calls it where its kernel does not apply (no Taylor table, a wide search)
_STAGES = KernelTable("rhs_env.omp")


def parabolic_offset(ym: np.ndarray, y0: np.ndarray, yp: np.ndarray) -> np.ndarray:
    """Vertex offset in [-0.5, 0.5] of the parabola through (-1, ym), (0, y0), (1, yp)."""
    den = ym - 2.0 * y0 + yp
    d = np.divide(0.5 * (ym - yp), den, out=np.zeros(np.shape(den)), where=den < 0)  # 0 where not concave
    return np.minimum(np.maximum(d, -0.5), 0.5)


# --------------------------------------------------------------------------- angle
class AngleDictionary:
    """The OMP dictionary H of one antenna and its analytic angle derivatives.

    ``h_i(theta) = r_i(theta) t_i(theta)`` with the power-normalised one-way gains
    ``t_i = sum_m w_T,im a_m / ||w_T,i||``, ``a_m = exp(j 2 pi x_m sin theta)``
    (x in wavelengths). Derivatives use ``da_m/dtheta = j 2 pi x_m cos(theta) a_m``
    and ``d2a_m/dtheta2 = [(j 2 pi x_m cos theta)^2 - j 2 pi x_m sin theta] a_m``.

    Candidates: ``theta_j = lo + j * step``, j = 0..I_c-1, covering the scan sector
    plus ``margin`` candidates each side, ``step = min(grid / oversampling,
    1 / (8 A))`` with A the aperture in wavelengths (a coarse grid with narrow
    beams still gets candidates finer than the main lobe).
    """

    def __init__(self, antenna: ArrayAntenna, grid_deg: float, sector_deg: float, oversampling: int,
                 margin: int = 2) -> None:
        self.antenna = antenna
        # candidate step: grid / oversampling, and at most 1/8 of the main-lobe half-width ~ 1 / aperture
        pos = antenna.positions_wl
        aperture = float(pos.max() - pos.min() + (pos[1] - pos[0] if pos.size > 1 else 1.0))
        step = min(np.deg2rad(grid_deg) / oversampling, 1.0 / (8.0 * aperture))
        half = np.deg2rad(sector_deg) / 2
        n = round(2 * half / step)
        self.step = step
        self.candidates = -half + (np.arange(-margin, n + margin + 1)) * step  # rad, (I_c,)
        self._set_weights(antenna)
        self.H = self.atoms(self.candidates)[0]  # (I, I_c) complex128
        self.norms = np.linalg.norm(self.H, axis=0)
        self.Hn = (self.H / self.norms).astype(np.complex64)  # unit-norm columns
        self.Hn_conj = np.ascontiguousarray(self.Hn.conj())  # (I, I_c): resid @ Hn_conj = H_n^H r
        self.kernels = "numpy"
        self._taylor: tuple[np.ndarray, np.ndarray, float] | None = None

    def use_kernels(self, kernels: str) -> AngleDictionary:
        """Evaluate the atoms with ``kernels`` ("numba": :func:`rhs_env.kernels.taylor_atoms`, else numpy); returns self.

        The series pays where the array has more elements than it has terms (M > 2 (N + 1)); a
        smaller array (the 10-element phased array) keeps the direct product, and so does one whose table would
        take more than :data:`rhs_env.kernels.TABLE_WORK_MAX` to build (thousands of elements).
        """
        self.kernels = kernels
        if self._taylor is None:
            self._taylor = self._impl.taylor_table(self)
        return self

    @property
    def _impl(self) -> Any:
        """The chosen stages (:data:`_STAGES`) of the dictionary's ``kernels`` ("numpy" on a bare dictionary)."""
        return _STAGES.choose(getattr(self, "kernels", "numpy"))

    @property
    def slots(self) -> int:
        return self.H.shape[0]

    def _set_weights(self, antenna: ArrayAntenna) -> None:
        """Power-normalised Tx and Rx weights side by side, ``[w_T | w_R]`` (M, 2 I): one product gives t and r."""
        self.antenna = antenna
        wt = (antenna.tx_weights / np.linalg.norm(antenna.tx_weights, axis=1, keepdims=True)).T  # (M, I)
        wr = (antenna.rx_weights / np.linalg.norm(antenna.rx_weights, axis=1, keepdims=True)).T
        self._w2 = np.ascontiguousarray(np.concatenate([wt, wr], axis=1))
        self._x = 2.0 * np.pi * antenna.positions_wl
        self._steer_cache: dict[int, np.ndarray] = {}

    def _steering(self, th: np.ndarray) -> np.ndarray:
        """``steering(positions_wl, th)`` (T, M) for a flat th, rows cached per angle (its bit pattern).

        The OMP evaluates the atoms at the same angle several times (the grid angle and
        the first Newton step, a refined angle and the next pass, the uncertainty of the
        points); ``steering`` is element-wise, so a cached row is the row it would compute.
        """
        cache = self._steer_cache
        keys = th.view(np.int64).tolist()
        rows = [cache.get(k) for k in keys]
        miss = [n for n, r in enumerate(rows) if r is None]
        if len(miss) == len(keys):
            out = steering(self.antenna.positions_wl, th)
        else:
            out = np.empty((th.size, self._x.size), complex)
            for n, r in enumerate(rows):
                if r is not None:
                    out[n] = r
            if miss:
                out[miss] = steering(self.antenna.positions_wl, th[miss])
        if len(cache) + len(miss) > 8192:  # bounded: angles of older scans are not seen again
            cache.clear()
        for n in miss:
            cache[keys[n]] = out[n]
        out.flags.writeable = False  # its rows are cached
        return out

    def atoms(self, theta: np.ndarray, order: int = 0) -> list[np.ndarray]:
        """``[h, dh/dtheta, d2h/dtheta2][:order + 1]``, each (I,) + theta.shape, complex128.

        The steering vector and its derivatives are stacked and multiplied by
        ``[w_T | w_R]`` in one matrix product: rows ``[a, a g1, a g2]`` give ``t, r``
        and their derivatives, with ``g1 = j x cos(theta)`` and ``g2 = g1^2 - j x sin(theta)``.
        """
        th = np.asarray(theta, dtype=float)
        shp = th.shape
        return [o.T.reshape((-1,) + shp) for o in self._atom_rows(th.reshape(-1), order)]

    def _atom_rows(self, th: np.ndarray, order: int) -> list[np.ndarray]:
        """:meth:`atoms` for a flat theta (T,), each (T, I) (not transposed).

        With ``kernels="numba"`` (:meth:`use_kernels`): the Taylor series of :func:`rhs_env.kernels.taylor_atoms`
        (the same values to ~1e-14 relative; for a uniform array the two-way gain's own series, 13 x I coefficients
        per angle against the product's 3 x M x 2 I complex multiply-adds).
        """
        rows: list[np.ndarray] = self._impl.atom_rows(self, th, order)
        return rows

    def _atom_rows_numpy(self, th: np.ndarray, order: int) -> list[np.ndarray]:
        """:meth:`_atom_rows` by the direct product (the reference)."""
        n_t, n_i = th.size, self._w2.shape[1] // 2
        a = self._steering(th)  # (T, M)
        if order == 0:
            tr = a @ self._w2
            return [tr[:, n_i:] * tr[:, :n_i]]
        g1 = 1j * self._x[None, :] * np.cos(th)[:, None]  # (T, M)
        rows = [a, a * g1]
        if order >= 2:
            rows.append(a * (g1 ** 2 - 1j * self._x[None, :] * np.sin(th)[:, None]))
        tr = (np.concatenate(rows, axis=0) @ self._w2).reshape(len(rows), n_t, 2 * n_i)
        t, r = tr[..., :n_i], tr[..., n_i:]
        out = [r[0] * t[0], r[1] * t[0] + r[0] * t[1]]
        if order >= 2:
            out.append(r[2] * t[0] + 2 * r[1] * t[1] + r[0] * t[2])
        return out


def _newton_refine(dic: AngleDictionary, theta: np.ndarray, resid: np.ndarray, steps: int = 2) -> np.ndarray:
    """Newton steps maximising ``f = |h^H r|^2 / ||h||^2`` per row; theta (D,), resid (D, I).

    With ``g = h^H r``, ``G = |g|^2`` and ``n = ||h||^2`` (and their theta
    derivatives from ``h', h''``): ``f' = (G' n - G n') / n^2``,
    ``f'' = (G'' n^2 - G n n'' - 2 G' n n' + 2 G n'^2) / n^3``; a step
    ``-f' / f''`` where f is concave, clipped to half a candidate spacing. Compiled with the
    dictionary's ``kernels="numba"`` (:func:`rhs_env.kernels.newton_refine`, the same equations per row).
    """
    return np.asarray(dic._impl.newton_refine(dic, theta, resid, steps))


@_STAGES.stage("newton_refine", "numpy")
def _newton_refine_numpy(dic: AngleDictionary, theta: np.ndarray, resid: np.ndarray, steps: int = 2) -> np.ndarray:
    """:func:`_newton_refine` in numpy (the reference)."""
    half = 0.5 * dic.step
    n_i = dic.slots
    for _ in range(steps):
        # (3, D, I): conj h, h', h'' (stored slot-major, (3, I, D), as the einsums below have always read it)
        hs = np.empty((3, n_i, theta.size), complex).transpose(0, 2, 1)
        for k, o in enumerate(dic._atom_rows(np.asarray(theta, dtype=float).reshape(-1), 2)):
            np.conjugate(o, out=hs[k])
        g, g1, g2 = np.einsum("kdi,di->kd", hs, resid)
        hc = hs[0].conj()
        n, n1, n2a = np.einsum("kdi,di->kd", hs, hc).real  # ||h||^2, h'^H h, h''^H h
        n1, n2 = 2 * n1, 2 * n2a + 2 * np.einsum("di,di->d", hs[1], hs[1].conj()).real
        G = g.real ** 2 + g.imag ** 2
        G1 = 2 * np.real(np.conj(g) * g1)
        G2 = 2 * (g1.real ** 2 + g1.imag ** 2) + 2 * np.real(np.conj(g) * g2)
        f1 = (G1 * n - G * n1) / n ** 2
        f2 = (G2 * n ** 2 - G * n * n2 - 2 * G1 * n * n1 + 2 * G * n1 ** 2) / n ** 3
        delta = np.divide(-f1, f2, out=np.zeros_like(f1), where=f2 < 0)
        theta = theta + np.minimum(np.maximum(delta, -half), half)
    return theta


def _grid_refine(dic: AngleDictionary, resid: np.ndarray, center: np.ndarray | None, reach: int) -> np.ndarray:
    """Best candidate (within ``reach`` of ``center`` when given) + log-parabola, angles (D,)."""
    corr = np.abs(resid.astype(np.complex64) @ dic.Hn_conj) ** 2  # (D, I_c)
    n_c = corr.shape[1]
    if center is not None:
        j0 = np.clip(np.round((center - dic.candidates[0]) / dic.step).astype(int), 0, n_c - 1)
        cols = np.arange(n_c)[None, :]
        corr = np.where(np.abs(cols - j0[:, None]) <= reach, corr, -1.0)
    j = np.argmax(corr, axis=1)
    rows = np.arange(corr.shape[0])
    jm, jp = np.maximum(j - 1, 0), np.minimum(j + 1, n_c - 1)
    # log-parabola through the three samples (the log of those only)
    lg = np.log(np.maximum(corr[rows[:, None], np.stack([jm, j, jp], 1)], 1e-30))
    off = parabolic_offset(lg[:, 0], lg[:, 1], lg[:, 2])
    off = np.where((j == 0) | (j == n_c - 1), 0.0, off)
    return dic.candidates[j] + off * dic.step


def _lstsq(atoms: np.ndarray, iota: np.ndarray, kernels: str = "numpy") -> np.ndarray:
    """Batched least squares: atoms (D, I, L), iota (D, I, ...) -> (D, L, ...).

    ``s = (A^H A + 1e-12 I)^-1 A^H iota`` (:func:`rhs_common.linalg.batched_lstsq`); with
    ``kernels="numba"`` and one right-hand side (iota (D, I, 1)) a compiled Cholesky solve
    (:func:`rhs_env.kernels.lstsq`, the same s to round-off).
    """
    return np.asarray(_STAGES.choose(kernels).lstsq(atoms, iota))


@dataclass
class OMPResult:
    theta: np.ndarray  # (D, L) rad
    amp: np.ndarray  # (D, L) complex LS amplitude (in units of iota per unit gain)
    valid: np.ndarray  # (D, L) bool
    atoms: np.ndarray  # (D, I, L) the refined atoms h(theta)
    residual: np.ndarray  # (D,) ||r||^2


def omp_angles(dic: AngleDictionary, iota: np.ndarray, max_targets: int, residual_threshold: np.ndarray,
               relative_threshold: float = 0.0, newton_steps: int = 2, min_amplitude: float = 0.0,
               cycles: int = 3) -> OMPResult:
    """Orthogonal matching pursuit over H with off-grid refinement, batched over detections.

    Args:
        dic: the dictionary of the antenna.
        iota: (D, I) measurement vectors.
        max_targets: L_max, at most this many targets per range.
        residual_threshold: (D,) delta_r: stop once ``||r||^2 < delta_r``.
        relative_threshold: also stop once ``||r||^2 < relative_threshold * ||iota||^2``.
        newton_steps: Newton iterations of the off-grid refinement.
        min_amplitude: an atom is accepted only if ``|s| ||h(theta)|| >= min_amplitude``
            (in units of iota: its matched-filter amplitude); a rejected atom ends the row.
        cycles: cyclic re-refinement passes over the support after each new atom.

    Loop (per row, "while l <= L_max and ||r||^2 >= delta_r"): select, refine,
    cyclically re-refine the support, least squares, residual.
    """
    iota = np.asarray(iota, dtype=np.complex128)
    d, i = iota.shape
    theta = np.zeros((d, max_targets))
    amp = np.zeros((d, max_targets), complex)
    valid = np.zeros((d, max_targets), bool)
    atoms = np.zeros((d, i, max_targets), complex)
    resid = iota.copy()
    r2 = np.einsum("di,di->d", resid.conj(), resid).real
    stop_level = np.maximum(np.asarray(residual_threshold, float), relative_threshold * r2)
    active = r2 >= stop_level
    reach = max(1, round(dic.H.shape[1] / max(i, 1)))  # one slot width in candidates
    for l in range(max_targets):
        rows = np.flatnonzero(active)
        if rows.size == 0:
            break
        th_r, at_r, io = theta[rows].copy(), atoms[rows].copy(), iota[rows]
        th = _grid_refine(dic, resid[rows], None, reach)
        if newton_steps:
            th = _newton_refine(dic, th, resid[rows], newton_steps)
        th_r[:, l] = th
        at_r[:, :, l] = dic.atoms(th)[0].T
        s = _lstsq(at_r[:, :, : l + 1], io[:, :, None])[..., 0]  # (D', l+1)
        for _ in range(cycles if l > 0 else 0):
            for k in range(l + 1):
                part = io - np.einsum("dil,dl->di", at_r[:, :, : l + 1], s) + at_r[:, :, k] * s[:, k : k + 1]
                thk = _grid_refine(dic, part, th_r[:, k], reach)
                if newton_steps:
                    thk = _newton_refine(dic, thk, part, newton_steps)
                th_r[:, k] = thk
                at_r[:, :, k] = dic.atoms(thk)[0].T
                s = _lstsq(at_r[:, :, : l + 1], io[:, :, None])[..., 0]
        strength = np.abs(s) * np.linalg.norm(at_r[:, :, : l + 1], axis=1)
        ok = np.all(strength >= min_amplitude, axis=1)
        good = rows[ok]
        theta[good], atoms[good] = th_r[ok], at_r[ok]
        valid[good, l] = True
        amp[good, : l + 1] = s[ok]
        resid[good] = iota[good] - np.einsum("dil,dl->di", atoms[good, :, : l + 1], s[ok])
        r2[good] = np.einsum("di,di->d", resid[good].conj(), resid[good]).real
        active[rows[~ok]] = False
        active[good] = r2[good] >= stop_level[good]
    return OMPResult(theta, amp, valid, atoms, r2)


@functools.lru_cache(maxsize=16)
def _fftfreq(n: int) -> np.ndarray:
    return np.fft.fftfreq(n)


_TIME_INDEX: dict[bytes, tuple[np.ndarray, int, bool]] = {}


def _time_index(tgrid: np.ndarray) -> tuple[np.ndarray, int, bool]:
    """Integer chirp times ``t`` (flattened tgrid), ``n_t = max + 1`` and whether ``t`` is ``0..n_t-1`` (cached per grid)."""
    key = tgrid.tobytes() + repr(tgrid.shape).encode()
    hit = _TIME_INDEX.get(key)
    if hit is None:
        t = tgrid.reshape(-1).astype(int)
        n_t = int(t.max()) + 1
        hit = (t, n_t, bool(t.size == n_t and np.array_equal(t, np.arange(n_t))))
        if len(_TIME_INDEX) < 64:
            _TIME_INDEX[key] = hit
    return hit


@functools.lru_cache(maxsize=16)
def _dtft_kernel(n_t: int, nfft: int, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies ``w_j = 2 pi j / nfft``, ``|j| <= half``, and ``exp(-j w_j t)`` (n_t, 2 half + 1), complex64."""
    w = 2 * np.pi * np.arange(-half, half + 1) / nfft
    return w, np.exp(-1j * np.outer(np.arange(n_t), w)).astype(np.complex64)


@functools.lru_cache(maxsize=16)
def _dtft_kernel_split(n_t: int, nfft: int, half: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_dtft_kernel` as the compiled search reads it: w, and the real and imaginary parts (2 half + 1, n_t) float32
    (the complex64 samples' own parts)."""
    w, kern = _dtft_kernel(n_t, nfft, half)
    kt = kern.T
    return w, np.ascontiguousarray(kt.real), np.ascontiguousarray(kt.imag)


def _narrow_dtft(tgrid: np.ndarray, span: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, int] | None:
    """The DTFT grid of :func:`_doppler_grid_refine`'s narrow search for ``span`` (w, kernel re / im, nfft), None if it takes the FFT."""
    _, n_t, _ = _time_index(tgrid)
    nfft = 1 << math.ceil(math.log2(max(4 * n_t, 64)))
    half = 1 << math.ceil(math.log2(math.ceil(float(np.max(span)) * nfft / (2 * np.pi)) + 1))
    if 2 * half + 1 >= nfft // 8:
        return None
    return (*_dtft_kernel_split(n_t, nfft, half), nfft)


def _doppler_grid_refine(h: np.ndarray, r: np.ndarray, tgrid: np.ndarray, span: np.ndarray,
                         kernels: str = "numpy") -> np.ndarray:
    """Residual chirp-phase rate d_omega (D,) maximising ``|sum_ic conj(h_i) r_ic exp(-j d_omega t_ic)|``.

    h (D, I) atoms, r (D, I, C) Doppler-compensated data, tgrid (I, C) integer
    chirp times (units of T_c), span (D,) half-width of the search, rad/chirp.
    The sum is the DTFT of ``q_t = sum_{t_ic = t} conj(h_i) r_ic``, sampled on the
    grid ``2 pi k / nfft`` (``nfft`` >= 4x oversampled) and refined by a parabola
    through the log-peak; the maximum is taken within ``|d_omega| <= span``. A
    narrow search (the refinements: a few dozen grid points) evaluates the DTFT
    directly on those points (one complex64 matrix product, the same samples as
    the FFT); a wide one takes the zero-padded FFT. With ``kernels="numba"`` the narrow search is
    compiled (:func:`rhs_env.kernels.doppler_dtft_refine`: the same samples, summed in float64).
    """
    d = h.shape[0]
    t, n_t, consecutive = _time_index(tgrid)
    nfft = 1 << math.ceil(math.log2(max(4 * n_t, 64)))
    half = 1 << math.ceil(math.log2(math.ceil(float(np.max(span)) * nfft / (2 * np.pi)) + 1))  # few kernels
    narrow = _STAGES.choose(kernels).narrow_refine(h, r, tgrid, span, t, n_t)  # compiled: a narrow search
    if narrow is not None:
        return np.asarray(narrow)
    prod = (h.conj()[:, :, None] * r).reshape(d, -1)
    if consecutive:
        q = prod  # every chirp has its own time (Doppler phase runs across slots)
    else:
        q = np.zeros((d, n_t), complex)
        np.add.at(q.T, t, prod.T)  # q[:, t] += prod, repeated t accumulated
    if 2 * half + 1 < nfft // 8:
        w, kern = _dtft_kernel(n_t, nfft, half)
        val = np.abs(q.astype(np.complex64) @ kern).astype(float) ** 2  # (D, 2 half + 1)
        j = np.argmax(np.where(np.abs(w)[None, :] <= span[:, None], val, -1.0), axis=1)
        j = np.minimum(np.maximum(j, 1), 2 * half - 1)
        jm, jp = j - 1, j + 1
    else:
        val = np.abs(sfft.fft(q, n=nfft, axis=1, workers=1)) ** 2  # bin k <-> omega = 2 pi k / nfft
        w = 2 * np.pi * _fftfreq(nfft)  # rad/chirp
        j = np.argmax(np.where(np.abs(w)[None, :] <= span[:, None], val, -1.0), axis=1)
        jm, jp = (j - 1) % nfft, (j + 1) % nfft
    # log-parabola through the three samples (the log of those only)
    lg = np.log(np.maximum(val[np.arange(d)[:, None], np.stack([jm, j, jp], 1)], 1e-300))
    off = parabolic_offset(lg[:, 0], lg[:, 1], lg[:, 2])
    return w[j] + off * 2 * np.pi / nfft


def _joint_grid_search(dic: AngleDictionary, r: np.ndarray, w0: np.ndarray, span: np.ndarray, dwell: np.ndarray,
                       tgrid: np.ndarray, max_hyp: int = 33) -> tuple[np.ndarray, np.ndarray]:
    """Joint angle x Doppler grid search, ``max |H_n^H rho(omega)|`` over omega in ``w0 +- span``.

    ``rho_i(omega) = sum_c r_ic exp(-j omega t_ic)``; the Doppler hypotheses are
    spaced ``~0.5 / dwell`` rad/chirp (at most ``max_hyp``), the angle is the best
    candidate plus a log-parabola. Returns (omega, theta), each (D,).
    """
    d = r.shape[0]
    n_h = int(min(max_hyp, 2 * math.ceil(float(np.max(span * dwell)) / 0.5) + 1))
    u = np.linspace(-1.0, 1.0, n_h)
    om = w0[:, None] + span[:, None] * u[None, :]  # (D, H)
    t_slot, t_chirp = tgrid[:, :1] - tgrid[0, 0], tgrid[0] - tgrid[0, 0]
    separable = np.array_equal(tgrid, tgrid[0, 0] + t_slot + t_chirp[None, :])  # t_ic = t_i + t_c
    if separable:  # compiled: the same sums and phases, rounded to complex64 once
        rho = dic._impl.separable_rho(r, om, t_chirp, tgrid[0, 0] + t_slot[:, 0])
    else:
        rho = np.einsum("dic,dhic->dhi", r, np.exp(-1j * om[:, :, None, None] * tgrid[None, None]))
    corr = np.abs(rho.astype(np.complex64) @ dic.Hn_conj) ** 2  # (D, H, I_c)
    flat = corr.reshape(d, -1).argmax(axis=1)
    hbest, j = np.unravel_index(flat, corr.shape[1:])
    rows = np.arange(d)
    n_c = corr.shape[2]
    jm, jp = np.maximum(j - 1, 0), np.minimum(j + 1, n_c - 1)
    # log-parabola through the three samples (the log of those only)
    line = np.log(np.maximum(corr[rows[:, None], hbest[:, None], np.stack([jm, j, jp], 1)], 1e-30))
    off = parabolic_offset(line[:, 0], line[:, 1], line[:, 2])
    return om[rows, hbest], dic.candidates[j] + off * dic.step


def _phasors(dic: AngleDictionary, w: np.ndarray, tgrid: np.ndarray, sign: float = -1.0) -> np.ndarray:
    """``exp(sign j w t)`` (P, I, C) for w (P,) and tgrid (I, C); compiled with the dictionary's ``kernels="numba"``
    (:func:`rhs_env.kernels.phasors`, the same values to ~1e-16 relative)."""
    return np.asarray(dic._impl.phasors(w, tgrid, sign))


def atom_norms(atoms: np.ndarray, kernels: str = "numpy") -> np.ndarray:
    """``np.linalg.norm(atoms, axis=1)`` of atoms (D, Q, L); compiled with ``kernels="numba"`` (:func:`rhs_env.kernels.atom_norms`)."""
    return np.asarray(_STAGES.choose(kernels).atom_norms(atoms))


def _doppler_atoms(dic: AngleDictionary, theta: np.ndarray, omega: np.ndarray, tgrid: np.ndarray,
                   phase: np.ndarray | None = None) -> np.ndarray:
    """Atoms ``a_i,c = h_i(theta) exp(j omega t_ic)`` over slots x chirps, (P, I C) for theta, omega (P,).

    ``phase``: ``exp(j omega t)`` (P, I, C) when the caller has it (the conjugate of the
    ``exp(-j omega t)`` it compensated the data with: the same values, not recomputed).
    """
    h = dic.atoms(theta)[0].T  # (P, I)
    if phase is None:
        phase = _phasors(dic, omega, tgrid, 1.0)
    return (h[:, :, None] * phase).reshape(theta.size, -1)


def joint_refine(dic: AngleDictionary, data: np.ndarray, tgrid: np.ndarray, theta: np.ndarray,
                 domega: np.ndarray, valid: np.ndarray, span: np.ndarray, passes: int = 1,
                 newton_steps: int = 2, atoms: np.ndarray | None = None,
                 amp: np.ndarray | None = None, tol: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Joint (angle, Doppler) refinement of every target on the full slot x chirp data.

    Model: ``data[i, c] = sum_k s_k h_i(theta_k) exp(j d_omega_k t_ic) + noise``
    (t_ic = chirp time / T_c over the sweep). Each pass re-fits every target
    ``k`` of every row at once (Jacobi sweep, batched over all (row, target)
    pairs) against its own partial residual ``data - sum_{j != k} a_j s_j``:
    d_omega by :func:`_doppler_grid_refine` (around the current value, half-width
    ``span``), then theta by Newton steps on the Doppler-compensated slot vector
    ``rho_i = sum_c r_ic exp(-j d_omega t_ic)``; then least squares for all
    amplitudes with atoms ``a_k = h(theta_k) exp(j d_omega_k t)``. ``atoms`` /
    ``amp``: the current atoms (D, I C, L) and amplitudes, when the caller has them.
    ``tol``: a row whose pass lowered its residual ``||data - A s||^2`` by less than this fraction has converged and takes no
    further pass (``passes`` is then the most a row takes; ``tol <= 0``: every row takes every pass).
    Returns theta, d_omega, amplitudes (D, L) and atoms (D, I C, L).

    With the dictionary's ``kernels="numba"`` (Taylor atoms, a narrow Doppler search) the passes run in
    one compiled call (:func:`rhs_env.kernels.joint_refine`, the same steps).
    """
    d, i, c = data.shape
    flat = data.reshape(d, i * c)
    theta, domega = theta.copy(), domega.copy()
    dd, kk = np.nonzero(valid)
    if atoms is None:
        atoms = np.zeros((d, i * c, theta.shape[1]), complex)
        atoms[dd, :, kk] = _doppler_atoms(dic, theta[dd, kk], domega[dd, kk], tgrid)
    a = atoms.copy()
    s = _lstsq(a, flat[..., None], dic.kernels)[..., 0] if amp is None else amp.copy()
    if dd.size:  # compiled (Taylor atoms, a narrow Doppler search): every pass in one call
        one_call = dic._impl.refine_call(dic, flat, tgrid, theta, domega, valid, span, passes, newton_steps, a, s, tol)
        if one_call is not None:
            return one_call
    base = _phasors(dic, domega[dd, kk], tgrid)  # exp(-j d_omega t) of each pair, (P, I, C)
    moving = np.zeros(d, bool)  # the rows still refined
    moving[dd] = True
    r2 = np.sum(np.abs(flat - np.einsum("dkl,dl->dk", a, s)) ** 2, axis=1) if tol > 0 else None
    for _ in range(passes):
        m = np.flatnonzero(moving[dd])  # the pairs of the moving rows
        if m.size == 0:
            break
        dm, km = dd[m], kk[m]
        fit = np.einsum("dkl,dl->dk", a[dm], s[dm])
        part = (flat[dm] - fit + a[dm, :, km] * s[dm, km][:, None]).reshape(-1, i, c)
        h = a[dm, :, km].reshape(-1, i, c)[:, :, 0] * base[m, :, 0]  # h(theta) of the current atom, (M, I)
        dw = domega[dm, km] + _doppler_grid_refine(h, part * base[m], tgrid, span[dm], dic.kernels)
        th = theta[dm, km]
        base[m] = _phasors(dic, dw, tgrid)
        if newton_steps:
            rho = np.sum(part * base[m], axis=2)
            th = _newton_refine(dic, th, rho, newton_steps)
        theta[dm, km], domega[dm, km] = th, dw
        a[dm, :, km] = _doppler_atoms(dic, th, dw, tgrid, np.conj(base[m]))
        rows = np.unique(dm)
        s[rows] = _lstsq(a[rows], flat[rows][..., None], dic.kernels)[..., 0]
        if r2 is not None:
            r2_new = np.sum(np.abs(flat[rows] - np.einsum("dkl,dl->dk", a[rows], s[rows])) ** 2, axis=1)
            moving[rows] = r2[rows] - r2_new >= tol * r2[rows]
            r2[rows] = r2_new
    return theta, domega, s * valid, a


@dataclass
class DopplerOMPResult:
    theta: np.ndarray  # (D, L) rad
    omega: np.ndarray  # (D, L) chirp-to-chirp phase, rad per chirp
    amp: np.ndarray  # (D, L) complex LS amplitude per unit atom
    valid: np.ndarray  # (D, L) bool
    atoms: np.ndarray  # (D, I C, L) atoms h_i(theta) exp(j omega t_ic)
    residual: np.ndarray  # (D,) ||r||^2


def _new_atom(dic: AngleDictionary, res: np.ndarray, tgrid: np.ndarray, noise_var: float,
              newton_steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The next atom (theta, omega), each (D,), of the residuals ``res`` (D, I, C) (steps 1-2 of :func:`omp_doppler`).

    Coarse Doppler from the chirp pairs, best dictionary candidate on the
    Doppler-compensated slot vector (one complex64 matrix product for all rows),
    a joint angle x Doppler search for the rows whose coarse-Doppler error
    (5 sigma) turns into more than pi/2 of phase over the target's dwell, fine
    Doppler over the sweep, Newton steps on the angle. Also returns ``exp(j omega t)``
    (D, I, C) of the new atoms when the Newton steps computed it (else None).
    """
    _, i, c = res.shape
    t_span = float(tgrid.max() + 1)
    reach = max(1, round(dic.H.shape[1] / max(i, 1)))
    w0 = np.angle(np.einsum("dic,dic->d", res[:, :, 1:], res[:, :, :-1].conj()))
    rc = res * _phasors(dic, w0, tgrid)
    th = _grid_refine(dic, rc.sum(axis=2), None, reach)
    p_res = np.abs(res) ** 2
    snr = np.maximum(np.sum(p_res, axis=(1, 2)) / noise_var - i * c, 1.0)
    span = np.minimum(np.maximum(5.0 / np.sqrt(snr), min(np.pi, 8 * np.pi / t_span)), np.pi)
    # rows whose Doppler uncertainty turns into > pi/2 of phase ramp over the target's dwell
    # (long dwell: weak beams such as the random patterns) get a joint angle x Doppler search
    e_slot = np.maximum(np.sum(p_res, axis=2) - c * noise_var, 0.0)
    dwell = e_slot.sum(1) ** 2 / np.maximum(np.sum(e_slot ** 2, axis=1), 1e-300) * c
    dwell = np.minimum(np.maximum(dwell, c), t_span)
    wide = 5.0 / np.sqrt(snr) * dwell > 0.5 * np.pi  # 5-sigma coarse-Doppler error -> > pi/2 of ramp
    if np.any(wide):
        sub = np.flatnonzero(wide)
        w_s, th_s = _joint_grid_search(dic, res[sub], w0[sub], span[sub], dwell[sub], tgrid)
        w0[sub], th[sub] = w_s, th_s
        rc[sub] = res[sub] * _phasors(dic, w_s, tgrid)
        span[sub] = np.minimum(span[sub], np.pi / dwell[sub])
    w = w0 + _doppler_grid_refine(dic.atoms(th)[0].T, rc, tgrid, span, dic.kernels)
    phase = None
    if newton_steps:
        comp = _phasors(dic, w, tgrid)
        rho = np.sum(res * comp, axis=2)
        th = _newton_refine(dic, th, rho, newton_steps)
        phase = np.conj(comp, out=comp)
    return th, w, phase


@functools.lru_cache(maxsize=8)
def _twiddles(nfft: int) -> tuple[np.ndarray, np.ndarray]:
    """``exp(-2 pi j m / nfft)``, m = 0..nfft-1, as real and imaginary parts (the compiled Doppler searches' table)."""
    e = np.exp(-2j * np.pi * np.arange(nfft) / nfft)
    return np.ascontiguousarray(e.real), np.ascontiguousarray(e.imag)


def _compiled_operands(dic: AngleDictionary, tgrid: np.ndarray) -> tuple | None:
    """The dictionary's and chirp times' operands of the one-call OMP's kernels (:func:`rhs_env.kernels.omp_doppler`,
    :func:`rhs_env.kernels.warm_refinement`): the Taylor table, ``u_c``, ``x_c``, the first candidate and the step,
    ``w2``, ``x``, the chirp times (contiguous), their time index ``t`` and count ``n_t``, the fine DTFT grid (re, im,
    w) and its ``nfft``; None where the one-call OMP does not apply (numpy kernels, no Taylor table, chirp times
    not ``t_ic = t_i + t_c``, a wide fine grid)."""
    return dic._impl.one_call_operands(dic, tgrid)


@_STAGES.stage("one_call_operands", "numba")
def _one_call_operands_compiled(dic: AngleDictionary, tgrid: np.ndarray) -> tuple | None:
    """:func:`_compiled_operands` with the compiled stages (None without a Taylor table)."""
    taylor = getattr(dic, "_taylor", None)
    if taylor is None:
        return None
    t_slot, t_chirp = tgrid[:, :1] - tgrid[0, 0], tgrid[0] - tgrid[0, 0]
    if not np.array_equal(tgrid, tgrid[0, 0] + t_slot + t_chirp[None, :]):
        return None
    fine = _narrow_dtft(tgrid, np.array([min(np.pi, 8 * np.pi / float(tgrid.max() + 1))]))
    if fine is None:
        return None
    table, u_c, x_c = taylor
    t, n_t, _ = _time_index(tgrid)
    fine_w, fine_re, fine_im, nfft = fine
    return (table, u_c, x_c, float(dic.candidates[0]), float(dic.step), dic._w2, dic._x,
            np.ascontiguousarray(tgrid, dtype=float), t, n_t, fine_re, fine_im, fine_w, nfft)


def _compiled_omp(dic: AngleDictionary, data: np.ndarray, tgrid: np.ndarray, max_targets: int,
                  residual_threshold: np.ndarray, noise_var: float, relative_threshold: float, min_amplitude: float,
                  newton_steps: int, cycles: int, detected: bool, refine_tol: float = 0.0) -> DopplerOMPResult | None:
    """:func:`omp_doppler` as one compiled call (:func:`rhs_env.kernels.omp_doppler`; its Python body on the compiled
    stages while a background process compiles it, :data:`rhs_env.kernels.omp_doppler_tiered`), or None where it
    does not apply.

    It applies with the dictionary's ``kernels="numba"``, Taylor-table atoms, separable chirp times
    (``t_ic = t_i + t_c``) and a narrow fine-Doppler grid; the other configurations keep the numpy steps.
    """
    ops = _compiled_operands(dic, tgrid)
    if ops is None or data.shape[0] == 0:
        return None
    from rhs_env import kernels

    table, u_c, x_c, lo, step, w2, x, tgrid_c, t, n_t, fine_re, fine_im, fine_w, nfft = ops
    e_re, e_im = _twiddles(nfft)
    _, tab_re, tab_im = _dtft_kernel_split(n_t, nfft, nfft // 32)  # every narrow search: half <= nfft / 32
    d = data.shape[0]
    out = kernels.omp_doppler_tiered(table, u_c, x_c, lo, step, w2, x, dic.Hn_conj,
                                     np.ascontiguousarray(dic.candidates, dtype=float), np.ascontiguousarray(data),
                                     tgrid_c, t, n_t, nfft, e_re, e_im, tab_re, tab_im, fine_re, fine_im, fine_w,
                                     int(max_targets),
                                     np.ascontiguousarray(np.broadcast_to(np.asarray(residual_threshold, float), (d,))),
                                     float(noise_var), float(relative_threshold), float(min_amplitude),
                                     int(newton_steps), int(cycles), float(refine_tol), bool(detected))
    return DopplerOMPResult(*out)


def warm_refinement_kernels(dic: AngleDictionary, tgrid: np.ndarray, max_targets: int, refine_passes: int,
                            newton_steps: int, refine_tol: float) -> None:
    """Compile (or load) the one-call OMP's refinement kernels (:func:`rhs_env.kernels.warm_refinement`) for the
    dictionary ``dic`` and chirp times ``tgrid``, with the operands :func:`_compiled_omp` passes
    (:func:`_compiled_operands`; nothing where the one-call OMP does not apply)."""
    ops = _compiled_operands(dic, tgrid)
    if ops is None:
        return
    from rhs_env import kernels

    table, u_c, x_c, lo, step, w2, x, tgrid_c, t, n_t, fine_re, fine_im, fine_w, nfft = ops
    kernels.warm_refinement(table, u_c, x_c, lo, step, w2, x, tgrid_c, t, n_t, fine_re, fine_im, fine_w, nfft,
                            int(max_targets), int(refine_passes), int(newton_steps), float(refine_tol))


def omp_doppler(dic: AngleDictionary, data: np.ndarray, tgrid: np.ndarray, max_targets: int,
                residual_threshold: np.ndarray, noise_var: float, relative_threshold: float = 0.0,
                min_amplitude: float = 0.0, newton_steps: int = 2, cycles: int = 2,
                detected: bool = False, refine_tol: float = 0.0) -> DopplerOMPResult:
    """OMP over the slot x chirp data with a Doppler per atom (the swept-beam OMP of paper Alg. 1).

    Model: ``data[d, i, c] = sum_k s_k h_i(theta_k) exp(j omega_k t_ic) + noise``,
    t_ic the integer chirp time (units of T_c) of chirp c of slot i over the sweep.
    Batched over the rows d (all detections of a scan); each iteration, on the
    residual R of every active row:

    1. coarse Doppler from the chirp pairs of R, ``omega = arg sum R[i, c+1] R*[i, c]``
       (unambiguous, one per range but recomputed on every residual, so targets
       at the same range with different radial speeds are each compensated);
    2. angle: best candidate of ``|H_n^H rho|`` with ``rho_i = sum_c R_ic exp(-j omega t_ic)``,
       then fine Doppler over the whole sweep (:func:`_doppler_grid_refine`) and
       Newton steps on the angle (:func:`_new_atom`);
    3. least squares for every amplitude on the support; with several atoms,
       up to ``cycles`` passes of :func:`joint_refine` (each atom re-fitted in angle and
       Doppler against its own partial residual; a row stops once a pass lowers its ``||R||^2``
       by less than the fraction ``refine_tol``, ``refine_tol = 0``: always ``cycles`` passes);
    4. accept the new atom only if every ``|s_k| ||a_k|| >= min_amplitude``;
       continue while ``l < max_targets`` and ``||R||^2 >= max(delta_r, rel ||data||^2)``.

    ``detected``: the rows passed a detector matched to the beam (:mod:`rhs_env.detection`),
    so the first atom is taken without the residual and amplitude tests (both are
    slot-summed statistics, weaker than that detector); the later atoms keep them.
    """
    data = np.asarray(data, complex)
    compiled = _compiled_omp(dic, data, tgrid, max_targets, residual_threshold, noise_var, relative_threshold,
                             min_amplitude, newton_steps, cycles, detected, refine_tol)
    if compiled is not None:
        return compiled
    d, i, c = data.shape
    n_l = max_targets
    theta, omega = np.zeros((d, n_l)), np.zeros((d, n_l))
    amp = np.zeros((d, n_l), complex)
    valid = np.zeros((d, n_l), bool)
    atoms = np.zeros((d, i * c, n_l), complex)
    resid = data.copy()
    r2 = np.sum(np.abs(resid) ** 2, axis=(1, 2))
    stop = np.maximum(np.asarray(residual_threshold, float), relative_threshold * r2)
    active = np.ones(d, bool) if detected else r2 >= stop
    fine_span = min(np.pi, 8 * np.pi / float(tgrid.max() + 1))
    for l in range(n_l):
        rows = np.flatnonzero(active)
        if rows.size == 0:
            break
        th, w, phase = _new_atom(dic, resid[rows], tgrid, noise_var, newton_steps)
        th_r, om_r, val_r, a = theta[rows], omega[rows], valid[rows], atoms[rows]
        th_r[:, l], om_r[:, l], val_r[:, l] = th, w, True
        a[:, :, l] = _doppler_atoms(dic, th, w, tgrid, phase)
        s = _lstsq(a, data[rows].reshape(rows.size, -1, 1), dic.kernels)[..., 0] * val_r
        ok = np.all((np.abs(s) * atom_norms(a, dic.kernels) >= min_amplitude) | ~val_r, axis=1) | (detected and l == 0)
        if l > 0 and cycles and np.any(ok):  # joint refinement of the rows that keep the new atom
            k = np.flatnonzero(ok)
            th_r[k], om_r[k], s[k], a[k] = joint_refine(dic, data[rows[k]], tgrid, th_r[k], om_r[k], val_r[k],
                                                        np.full(k.size, fine_span), passes=cycles,
                                                        newton_steps=newton_steps, atoms=a[k], amp=s[k],
                                                        tol=refine_tol)
            ok &= np.all((np.abs(s) * atom_norms(a, dic.kernels) >= min_amplitude) | ~val_r, axis=1)
        good = rows[ok]
        theta[good], omega[good], valid[good], amp[good], atoms[good] = th_r[ok], om_r[ok], val_r[ok], s[ok], a[ok]
        resid[good] = data[good] - np.einsum("dkl,dl->dk", a[ok], s[ok]).reshape(-1, i, c)
        r2[good] = np.sum(np.abs(resid[good]) ** 2, axis=(1, 2))
        active[rows[~ok]] = False
        active[good] = r2[good] >= stop[good]
    return DopplerOMPResult(theta, omega, amp, valid, atoms, r2)


def residual_threshold(noise_var: float | np.ndarray, slots: int, pfa: float) -> np.ndarray:
    """delta_r = sigma^2 Gamma^{-1}(1 - pfa; I): ||n||^2 of I complex Gaussian noise cells exceeds it w.p. pfa."""
    return np.asarray(noise_var) * stats.gamma.isf(pfa, slots)


_STAGES.stage("atom_rows", "numpy")(AngleDictionary._atom_rows_numpy)
_STAGES.stage("one_call_operands", "numpy")(lambda dic, tgrid: None)


@_STAGES.stage("taylor_table", "numpy")
def _taylor_table_numpy(dic: AngleDictionary) -> None:
    """No Taylor table: the numpy atoms are the direct product."""


@_STAGES.stage("taylor_table", "numba")
def _taylor_table_compiled(dic: AngleDictionary) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The Taylor table of :func:`rhs_env.kernels.taylor_tables` (re, im interleaved: the kernels' layout), ``u_c``,
    ``x_c``; None where the series does not pay: an array with fewer elements than it has terms (M <= 2 (N + 1),
    the 10-element phased array), or a table past :data:`rhs_env.kernels.TABLE_WORK_MAX` (thousands of elements)."""
    from rhs_env.kernels import TABLE_WORK_MAX, TAYLOR_ORDER, taylor_tables

    work = dic.candidates.size * dic._x.size * dic._w2.shape[1]
    if 2 * (TAYLOR_ORDER + 1) >= dic._x.size or work > TABLE_WORK_MAX:
        return None
    table, u_c, x_c = taylor_tables(dic._w2, dic._x, dic.candidates)
    return table.view(np.float64), u_c, x_c


@_STAGES.stage("atom_rows", "numba")
def _atom_rows_compiled(dic: AngleDictionary, th: np.ndarray, order: int) -> list[np.ndarray]:
    """:meth:`AngleDictionary._atom_rows` from the Taylor series (:func:`rhs_env.kernels.taylor_atoms`), the direct
    product without a table."""
    taylor = getattr(dic, "_taylor", None)  # (absent on the bare dictionaries of angle_crb)
    if taylor is None:
        return dic._atom_rows_numpy(th, order)
    from rhs_env.kernels import taylor_atoms

    table, u_c, x_c = taylor
    return list(taylor_atoms(table, u_c, x_c, float(dic.candidates[0]), float(dic.step), dic._w2, dic._x,
                             np.ascontiguousarray(th, dtype=float), order))


@_STAGES.stage("newton_refine", "numba")
def _newton_refine_compiled(dic: AngleDictionary, theta: np.ndarray, resid: np.ndarray, steps: int = 2) -> np.ndarray:
    """:func:`_newton_refine` on the Taylor atoms (:func:`rhs_env.kernels.newton_refine`), numpy without a table."""
    taylor = getattr(dic, "_taylor", None)
    if taylor is None:
        return _newton_refine_numpy(dic, theta, resid, steps)
    from rhs_env.kernels import newton_refine

    table, u_c, x_c = taylor
    return np.asarray(newton_refine(table, u_c, x_c, float(dic.candidates[0]), float(dic.step), dic._w2, dic._x,
                                    np.ascontiguousarray(theta, dtype=float), np.ascontiguousarray(resid, dtype=complex),
                                    steps))


@_STAGES.stage("lstsq", "numpy")
def _lstsq_numpy(atoms: np.ndarray, iota: np.ndarray) -> np.ndarray:
    """:func:`_lstsq` by :func:`rhs_common.linalg.batched_lstsq` (the reference)."""
    return np.asarray(batched_lstsq(atoms, iota))


@_STAGES.stage("lstsq", "numba")
def _lstsq_compiled(atoms: np.ndarray, iota: np.ndarray) -> np.ndarray:
    """:func:`_lstsq` for one right-hand side (iota (D, I, 1)) by a compiled Cholesky solve
    (:func:`rhs_env.kernels.lstsq`, the same s to round-off); numpy for several."""
    if iota.ndim != 3 or iota.shape[2] != 1:
        return _lstsq_numpy(atoms, iota)
    from rhs_env.kernels import lstsq

    return np.asarray(lstsq(np.ascontiguousarray(atoms, dtype=complex),
                            np.ascontiguousarray(iota[..., 0], dtype=complex))[..., None])


@_STAGES.stage("narrow_refine", "numpy")
def _narrow_refine_numpy(h: np.ndarray, r: np.ndarray, tgrid: np.ndarray, span: np.ndarray, t: np.ndarray,
                         n_t: int) -> None:
    """numpy: no separate narrow search (:func:`_doppler_grid_refine` computes every search itself)."""


@_STAGES.stage("narrow_refine", "numba")
def _narrow_refine_compiled(h: np.ndarray, r: np.ndarray, tgrid: np.ndarray, span: np.ndarray, t: np.ndarray,
                            n_t: int) -> np.ndarray | None:
    """:func:`_doppler_grid_refine`'s narrow search compiled (:func:`rhs_env.kernels.doppler_dtft_refine`: the same
    samples, summed in float64); None for a wide search (the FFT, numpy)."""
    narrow = _narrow_dtft(tgrid, span)
    if narrow is None:
        return None
    from rhs_env.kernels import doppler_dtft_refine

    w, kern_re, kern_im, nfft = narrow
    return np.asarray(doppler_dtft_refine(np.ascontiguousarray(h, dtype=complex), np.ascontiguousarray(r, dtype=complex),
                                          t, n_t, kern_re, kern_im, w, np.ascontiguousarray(span, dtype=float), nfft))


@_STAGES.stage("separable_rho", "numpy")
def _separable_rho_numpy(r: np.ndarray, om: np.ndarray, t_chirp: np.ndarray, t_slot: np.ndarray) -> np.ndarray:
    """``rho_dhi = sum_c r_dic exp(-j om_dh (t_i + t_c))`` (D, H, I) for separable chirp times ``t_ic = t_i + t_c``."""
    rho = np.einsum("dic,dhc->dhi", r, np.exp(-1j * om[:, :, None] * t_chirp))
    rho *= np.exp(-1j * om[:, :, None] * t_slot)
    return np.asarray(rho)


@_STAGES.stage("separable_rho", "numba")
def _separable_rho_compiled(r: np.ndarray, om: np.ndarray, t_chirp: np.ndarray, t_slot: np.ndarray) -> np.ndarray:
    """:func:`_separable_rho_numpy` compiled (:func:`rhs_env.kernels.joint_rho`: the same sums and phases, complex64)."""
    from rhs_env.kernels import joint_rho

    return np.asarray(joint_rho(np.ascontiguousarray(r, dtype=complex), np.ascontiguousarray(om), t_chirp.astype(float),
                                np.asarray(t_slot).astype(float)))


@_STAGES.stage("phasors", "numpy")
def _phasors_numpy(w: np.ndarray, tgrid: np.ndarray, sign: float) -> np.ndarray:
    """``exp(sign j w t)`` (P, I, C), numpy (the reference)."""
    return np.exp((-1j if sign < 0 else 1j) * w[:, None, None] * tgrid[None])


@_STAGES.stage("phasors", "numba")
def _phasors_compiled(w: np.ndarray, tgrid: np.ndarray, sign: float) -> np.ndarray:
    """:func:`_phasors_numpy` compiled (:func:`rhs_env.kernels.phasors`, the same values to ~1e-16 relative)."""
    from rhs_env.kernels import phasors

    return np.asarray(phasors(np.ascontiguousarray(w, dtype=float), np.ascontiguousarray(tgrid, dtype=float),
                              float(sign)))


@_STAGES.stage("atom_norms", "numpy")
def _atom_norms_numpy(atoms: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(atoms, axis=1)`` (the reference)."""
    return np.asarray(np.linalg.norm(atoms, axis=1))


@_STAGES.stage("atom_norms", "numba")
def _atom_norms_compiled(atoms: np.ndarray) -> np.ndarray:
    """:func:`_atom_norms_numpy` compiled (:func:`rhs_env.kernels.atom_norms`)."""
    from rhs_env.kernels import atom_norms as compiled

    return np.asarray(compiled(np.ascontiguousarray(atoms, dtype=complex)))


@_STAGES.stage("refine_call", "numpy")
def _refine_call_numpy(dic: AngleDictionary, *args: Any) -> None:
    """numpy: :func:`joint_refine` runs its passes step by step."""


@_STAGES.stage("refine_call", "numba")
def _refine_call_compiled(dic: AngleDictionary, flat: np.ndarray, tgrid: np.ndarray, theta: np.ndarray,
                          domega: np.ndarray, valid: np.ndarray, span: np.ndarray, passes: int, newton_steps: int,
                          a: np.ndarray, s: np.ndarray, tol: float) -> tuple | None:
    """:func:`joint_refine`'s passes in one compiled call (:func:`rhs_env.kernels.joint_refine`, the same steps) with
    Taylor atoms and a narrow Doppler search; None otherwise (the numpy steps)."""
    taylor = getattr(dic, "_taylor", None)
    narrow = _narrow_dtft(tgrid, span) if taylor is not None else None
    if narrow is None or taylor is None:
        return None
    from rhs_env import kernels

    table, u_c, x_c = taylor
    t, n_t, _ = _time_index(tgrid)
    w, kern_re, kern_im, nfft = narrow
    out: tuple = kernels.joint_refine(
        table, u_c, x_c, float(dic.candidates[0]), float(dic.step), dic._w2, dic._x,
        np.ascontiguousarray(flat, dtype=complex), np.ascontiguousarray(tgrid, dtype=float), t, n_t, kern_re, kern_im, w,
        nfft, np.ascontiguousarray(theta, dtype=float), np.ascontiguousarray(domega, dtype=float),
        np.ascontiguousarray(valid), np.ascontiguousarray(span, dtype=float), passes, newton_steps, a,
        np.ascontiguousarray(s, dtype=complex), float(tol))
    return out
