"""Compiled dictionary atoms (numba): Taylor tables of the RHS's gains and the atoms read from them.

:func:`taylor_tables` (numpy, once per dictionary) tabulates the centred gains' Taylor coefficients in
``u = sin(theta)`` at every candidate angle; :func:`taylor_atoms` evaluates the atoms and their first two angle
derivatives at any angle from them (:meth:`rhs_env.point_cloud.AngleDictionary.atoms`, to ~1e-15 relative), and
:func:`newton_refine` runs the OMP's Newton steps on them (:func:`rhs_env.point_cloud._newton_refine`).
"""

from __future__ import annotations

import numpy as np

from rhs_common.jit import njit

__all__ = [
    "PRODUCT_ORDER", "PRODUCT_SERIES_BOUND", "TABLE_WORK_MAX", "TAYLOR_ORDER", "newton_refine", "taylor_atoms",
    "taylor_tables",
]


#: order of the one-way gains' Taylor series in u = sin(theta): the error term
#: ``(|x - x_c| du)^(N + 1) / (N + 1)!`` is ~1e-19 for the 60-element RHS at the default candidate spacing
#: (at half the candidates, ``oversampling=2``, 2^11 times that; the second derivative ~1e-11 relative, measured)
TAYLOR_ORDER = 10
#: order of the two-way gain's own series, whose exponents span twice the aperture: ~3e-20 for the RHS at the
#: default spacing, its second derivative 6e-15 relative to the direct sums (measured; 8.9e-13 at order 10);
#: 13 x 2 I coefficients read per atom instead of 11 x 4 I
PRODUCT_ORDER = 12
#: the largest remainder bound ``(max |y~| du / 2)^(N + 1) / (N + 1)!`` at which the two-way gain's own series is used
PRODUCT_SERIES_BOUND = 1e-15
#: the most candidates x elements x table columns (I_c M 2 I) a Taylor table is built for: ~4e6 for the default RHS;
#: past it (thousands of elements) the build would take minutes and the atoms come from the direct product
TABLE_WORK_MAX = 1e8


def _series(weights: np.ndarray, xt: np.ndarray, u_c: np.ndarray, order: int) -> np.ndarray:
    """``T[c, n, i] = sum_m weights_mi (j x~_m)^n exp(j x~_m u_c) / n!`` (I_c, N + 1, columns) complex128.

    In blocks of candidates whose temporaries stay near 32 MB (a 4096-element array has ~10^4 candidates).
    """
    fact = np.cumprod(np.concatenate([[1.0], np.arange(1, order + 1)]))
    powers = (1j * xt[None, :]) ** np.arange(order + 1)[:, None] / fact[:, None]  # (N + 1, M)
    out = np.empty((u_c.size, order + 1, weights.shape[1]), complex)
    block = max(1, 2**21 // (xt.size * (order + 1)))
    for lo in range(0, u_c.size, block):
        a = np.exp(1j * np.outer(u_c[lo:lo + block], xt))  # (block, M)
        out[lo:lo + block] = (a[:, None, :] * powers[None]) @ weights
    return out


def _product_weights(w2: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The two-way gain as one sum, ``h_i(u) = sum_k v_ki exp(j y_k u)``, for uniformly spaced elements; else None.

    ``h_i = r_i t_i = sum_{m, n} w_T,mi w_R,ni exp(j (x_m + x_n) u)``; with ``x_m = x_0 + m dx`` the sums
    ``y_k = 2 x_0 + k dx``, k < 2 M - 1, and ``v_ki = sum_{m + n = k} w_T,mi w_R,ni`` (a convolution per slot).
    Uniform: every ``x_m`` within 1e-12 (rad per unit u) of ``x_0 + m dx``, so each term's phase within 2e-12
    (the RHS' positions deviate by ~1e-14, their round-off).
    """
    m = x.size
    dx = (x[-1] - x[0]) / max(m - 1, 1)
    if m < 2 or np.abs(x - (x[0] + np.arange(m) * dx)).max() > 1e-12:
        return None
    n_i = w2.shape[1] // 2
    w_t, w_r = w2[:, :n_i], w2[:, n_i:]
    v = np.zeros((2 * m - 1, n_i), complex)
    for k in range(m):
        v[k:k + m] += w_t[k][None, :] * w_r
    return v, 2 * x[0] + np.arange(2 * m - 1) * dx


def taylor_tables(w2: np.ndarray, x: np.ndarray, candidates: np.ndarray, order: int = TAYLOR_ORDER,
                  product_order: int = PRODUCT_ORDER) -> tuple[np.ndarray, np.ndarray, float]:
    """Taylor coefficients of the centred gains in u = sin(theta) at every candidate.

    One-way gains, ``t_i(u) = sum_m w_T,im exp(j x_m u) = exp(j x_c u) t~_i(u)`` with ``x~_m = x_m - x_c``
    (x_c the middle of the aperture: the series converges over the half aperture only), and around
    ``u_c = sin(theta_c)``

        t~_i(u_c + delta) = sum_n T[c, n, i] delta^n,   T[c, n, i] = sum_m w_T,im (j x~_m)^n exp(j x~_m u_c) / n!,

    the same for r with w_R (the columns of ``w2 = [w_T | w_R]`` (M, 2 I)): the table ``[t~ | r~]``
    (I_c, N + 1, 2 I). For uniformly spaced elements whose two-way series (order ``product_order``) converges
    to :data:`PRODUCT_SERIES_BOUND` at the candidate spacing, the table of the two-way gain itself,
    ``h_i = exp(j 2 x_c u) h~_i(u)`` with ``h~_i = sum_k v_ki exp(j (y_k - 2 x_c) u)`` (:func:`_product_weights`):
    (I_c, N + 1, I), half the coefficients read per atom and no product rule. Returns the table (complex128),
    ``u_c`` (I_c,) and ``x_c``; :func:`_atom_at` tells the two apart by the table's width.
    """
    x_c = 0.5 * (float(x.min()) + float(x.max()))
    u_c = np.sin(candidates)
    product = _product_weights(w2, x)
    if product is not None:
        v, y = product
        du = float(np.max(np.abs(np.diff(u_c)))) / 2 if u_c.size > 1 else 1.0
        n = product_order + 1
        if (float(np.abs(y - 2 * x_c).max()) * du) ** n / float(np.prod(np.arange(1.0, n + 1))) <= PRODUCT_SERIES_BOUND:
            return _series(v, y - 2 * x_c, u_c, product_order), u_c, x_c
    return _series(w2, x - x_c, u_c, order), u_c, x_c


@njit
def _horner(table: np.ndarray, c: int, delta: float, order: int, work: np.ndarray) -> None:
    """``work[o] = d^o/ddelta^o sum_n table[c, n] delta^n`` for o <= min(order, 2), on the float64 view (re, im alike).

    One pass per term for the value and its first two derivatives; the three running values of an entry are
    read before any is written, so the loops vectorise.
    """
    n_n, n_f = table.shape[1], table.shape[2]
    for i in range(n_f):
        work[0, i] = table[c, n_n - 1, i]
        work[1, i] = 0.0
        work[2, i] = 0.0
    for n in range(n_n - 2, -1, -1):
        if order >= 2:
            for i in range(n_f):
                a0, a1, a2 = work[0, i], work[1, i], work[2, i]
                work[2, i] = a2 * delta + 2.0 * a1
                work[1, i] = a1 * delta + a0
                work[0, i] = a0 * delta + table[c, n, i]
        elif order == 1:
            for i in range(n_f):
                a0, a1 = work[0, i], work[1, i]
                work[1, i] = a1 * delta + a0
                work[0, i] = a0 * delta + table[c, n, i]
        else:
            for i in range(n_f):
                work[0, i] = work[0, i] * delta + table[c, n, i]


@njit
def _product_atom(work: np.ndarray, y_c: float, u: float, cos_t: float, order: int, h: np.ndarray) -> None:
    """h and its theta derivatives from the two-way series' Horner sums ``work`` (h~, dh~/du, d2h~/du2).

    ``h = p h~`` with ``p = exp(j y_c u)``: ``dh/du = p (j y_c h~ + h~')``, ``d2h/du2 = p (-y_c^2 h~ + 2 j y_c h~'
    + h~'')``; in theta ``h' = cos(theta) dh/du``, ``h'' = cos(theta)^2 d2h/du2 - sin(theta) dh/du``.
    """
    ph = np.exp(1j * y_c * u)
    jy = 1j * y_c
    for i in range(h.shape[1]):
        g0 = complex(work[0, 2 * i], work[0, 2 * i + 1])
        h[0, i] = ph * g0
        if order >= 1:
            g1 = complex(work[1, 2 * i], work[1, 2 * i + 1])
            d1 = ph * (jy * g0 + g1)
            h[1, i] = cos_t * d1
            if order >= 2:
                g2 = complex(work[2, 2 * i], work[2, 2 * i + 1])
                h[2, i] = cos_t * cos_t * (ph * (-y_c * y_c * g0 + 2.0 * jy * g1 + g2)) - u * d1


@njit
def _atom_at(table: np.ndarray, u_c: np.ndarray, x_c: float, lo: float, step: float, w2: np.ndarray, x: np.ndarray,
             th: float, order: int, f0: np.ndarray, f1: np.ndarray, f2: np.ndarray, h: np.ndarray,
             work: np.ndarray) -> None:
    """h (order + 1, I) at one angle th: :func:`taylor_atoms` for one angle (f0, f1, f2: (2 I,) complex and
    ``work`` (3, table width) float work arrays).

    ``table``: the coefficients of :func:`taylor_tables` viewed as float64, re, im interleaved: (I_c, N + 1, 2 I)
    for the two-way gain's own series (:func:`_product_atom`), (I_c, N + 1, 4 I) for ``[t~ | r~]``; delta is
    real, so the Horner steps act on the real and imaginary parts alike (the same values as in complex
    arithmetic, in vectorisable loops).
    """
    n_c, n_f = table.shape[0], table.shape[2]
    n_i2 = w2.shape[1]
    n_i = n_i2 // 2
    u = np.sin(th)
    cos_t = np.cos(th)
    c = int(np.floor((th - lo) / step + 0.5))
    inside = -1 <= c <= n_c
    if inside:
        c = min(max(c, 0), n_c - 1)
        _horner(table, c, u - u_c[c], order, work)
        if n_f == n_i2:  # the two-way gain's series
            _product_atom(work, 2.0 * x_c, u, cos_t, order, h)
            return
        p0 = work[0]
        p1 = work[1]
        p2 = work[2]
        for i in range(n_i2):
            f0[i] = complex(p0[2 * i], p0[2 * i + 1])
            f1[i] = complex(p1[2 * i], p1[2 * i + 1])
            f2[i] = complex(p2[2 * i], p2[2 * i + 1])
        ph = np.exp(1j * x_c * u)
        jx = 1j * x_c
        for i in range(n_i2):
            g0 = f0[i]
            g1 = jx * g0 + f1[i]
            g2 = -x_c * x_c * g0 + 2.0 * jx * f1[i] + f2[i]
            f0[i], f1[i], f2[i] = ph * g0, ph * g1, ph * g2
    else:
        for i in range(n_i2):
            f0[i] = 0
            f1[i] = 0
            f2[i] = 0
        for m in range(x.size):
            a = np.exp(1j * x[m] * u)
            jx = 1j * x[m]
            for i in range(n_i2):
                wa = w2[m, i] * a
                f0[i] += wa
                f1[i] += jx * wa
                f2[i] += jx * jx * wa
    for i in range(n_i):  # u -> theta, then h = r t and its derivatives
        t0, r0 = f0[i], f0[n_i + i]
        h[0, i] = r0 * t0
        if order >= 1:
            t1, r1 = cos_t * f1[i], cos_t * f1[n_i + i]
            h[1, i] = r1 * t0 + r0 * t1
            if order >= 2:
                t2 = cos_t * cos_t * f2[i] - u * f1[i]
                r2 = cos_t * cos_t * f2[n_i + i] - u * f1[n_i + i]
                h[2, i] = r2 * t0 + 2.0 * r1 * t1 + r0 * t2


@njit
def taylor_atoms(table: np.ndarray, u_c: np.ndarray, x_c: float, lo: float, step: float, w2: np.ndarray,
                 x: np.ndarray, theta: np.ndarray, order: int) -> np.ndarray:
    """``[h, dh/dtheta, d2h/dtheta2][:order + 1]`` (order + 1, T, I) of :meth:`rhs_env.point_cloud.AngleDictionary.atoms`.

    ``h_i = r_i t_i``; t, r and their u-derivatives from the series of :func:`taylor_tables` at the
    nearest candidate ``c`` (``delta = sin(theta) - u_c``): ``t~ = sum_n T_n delta^n``,
    ``t~' = sum_n n T_n delta^(n-1)``, ``t~'' = sum_n n (n-1) T_n delta^(n-2)``; with the centring
    phase ``p = exp(j x_c u)``: ``t = p t~``, ``dt/du = p (j x_c t~ + t~')``,
    ``d2t/du2 = p (-x_c^2 t~ + 2 j x_c t~' + t~'')``; in theta ``t' = cos(theta) dt/du``,
    ``t'' = cos(theta)^2 d2t/du2 - sin(theta) dt/du``; then ``h' = r' t + r t'``,
    ``h'' = r'' t + 2 r' t' + r t''``; a table of the two-way gain's own series gives h and its derivatives
    directly, the same way (:func:`_product_atom`). An angle more than one candidate outside the table is
    summed directly, ``t_i = sum_m w_T,im exp(j x_m u)`` (``w2 = [w_T | w_R]``, x in radians per unit u).
    ``table``: the coefficients of :func:`taylor_tables` viewed as float64 (re, im interleaved).
    """
    n_i2 = w2.shape[1]
    out = np.empty((order + 1, theta.size, n_i2 // 2), np.complex128)
    f0 = np.empty(n_i2, np.complex128)
    f1 = np.empty(n_i2, np.complex128)
    f2 = np.empty(n_i2, np.complex128)
    h = np.empty((order + 1, n_i2 // 2), np.complex128)
    work = np.empty((3, table.shape[2]))
    for q in range(theta.size):
        _atom_at(table, u_c, x_c, lo, step, w2, x, theta[q], order, f0, f1, f2, h, work)
        for o in range(order + 1):
            for i in range(n_i2 // 2):
                out[o, q, i] = h[o, i]
    return out


@njit
def newton_refine(table: np.ndarray, u_c: np.ndarray, x_c: float, lo: float, step: float, w2: np.ndarray,
                  x: np.ndarray, theta: np.ndarray, resid: np.ndarray, steps: int) -> np.ndarray:
    """:func:`rhs_env.point_cloud._newton_refine` per row: Newton steps maximising ``f = |h^H r|^2 / ||h||^2``.

    With ``g = h^H r``, ``G = |g|^2``, ``n = ||h||^2`` and their theta derivatives from h', h''
    (:func:`taylor_atoms`): ``G' = 2 Re(g* g')``, ``G'' = 2 |g'|^2 + 2 Re(g* g'')``, ``n' = 2 Re(h'^H h)``,
    ``n'' = 2 Re(h''^H h) + 2 ||h'||^2``; ``f' = (G' n - G n') / n^2``,
    ``f'' = (G'' n^2 - G n n'' - 2 G' n n' + 2 G n'^2) / n^3``; the step ``-f' / f''`` where f'' < 0,
    clipped to half a candidate spacing. theta (D,), resid (D, I).
    """
    half = 0.5 * step
    n_i2 = w2.shape[1]
    n_i = n_i2 // 2
    f0 = np.empty(n_i2, np.complex128)
    f1 = np.empty(n_i2, np.complex128)
    f2 = np.empty(n_i2, np.complex128)
    h = np.empty((3, n_i), np.complex128)
    work = np.empty((3, table.shape[2]))
    out = theta.copy()
    for d in range(theta.size):
        th = theta[d]
        for _ in range(steps):
            _atom_at(table, u_c, x_c, lo, step, w2, x, th, np.int64(2), f0, f1, f2, h, work)
            g = 0j
            g1 = 0j
            g2 = 0j
            n = 0.0
            n1 = 0.0
            n2a = 0.0
            n2b = 0.0
            for i in range(n_i):
                r = resid[d, i]
                h0c, h1c, h2c = np.conj(h[0, i]), np.conj(h[1, i]), np.conj(h[2, i])
                g += h0c * r
                g1 += h1c * r
                g2 += h2c * r
                n += (h0c * h[0, i]).real
                n1 += (h1c * h[0, i]).real
                n2a += (h2c * h[0, i]).real
                n2b += (h1c * h[1, i]).real
            n1, n2 = 2 * n1, 2 * n2a + 2 * n2b
            G = g.real ** 2 + g.imag ** 2
            G1 = 2 * (np.conj(g) * g1).real
            G2 = 2 * (g1.real ** 2 + g1.imag ** 2) + 2 * (np.conj(g) * g2).real
            fd1 = (G1 * n - G * n1) / n ** 2
            fd2 = (G2 * n ** 2 - G * n * n2 - 2 * G1 * n * n1 + 2 * G * n1 ** 2) / n ** 3
            delta = -fd1 / fd2 if fd2 < 0 else 0.0
            th = th + min(max(delta, -half), half)
        out[d] = th
    return out
