"""``arcsin``, ``arctan``, ``tan``, ``power`` and 2-vector dot products for the compiled traffic, to the bit as numpy.

highway-env calls numpy's ufuncs on scalars. On a CPU with AVX-512 (numpy's ``AVX512_SKX`` dispatch) numpy
evaluates these four with Intel's SVML (the high-accuracy ``__svml_*8_ha`` variants it links), which differ from
the C library that numba calls in the last bit for 0.3-6 % of the arguments (``sin``, ``cos`` and ``sqrt`` agree).
Those last bits are harmless while the vehicles drive, but highway-env's steering controller divides by
``not_zero(speed)`` = 0.01 m/s when a vehicle stands still, which multiplies them by about 10^4 per frame. So the
kernels call the very SVML functions numpy uses (exported by numpy's ``_multiarray_umath`` extension): the
argument broadcast into an 8-lane vector, lane 0 of the result, the lane numpy's own loop computes for one value.

Where numpy does not use SVML (no AVX-512, a numpy built without it, ``NUMBA_DISABLE_JIT=1``, a numba target CPU
other than the host's, whose vector calling convention would differ) the functions are numpy's own
(``np.arcsin`` ... in numba: the C library, as numpy's scalar loop there). :data:`USE_SVML` says which;
``tests/test_traffic_core.py`` checks them against numpy on many arguments.

Dot products. highway-env's ``np.dot`` of two 2-vectors (lane coordinates, the IDM's closing speed, the polygon
projections, ``np.linalg.norm``) runs BLAS's ``ddot``, which on a CPU with FMA (x86-64 since 2013, every ARM64)
computes ``fma(a1, b1, a0 * b0)`` (LLVM's ``fma`` in :func:`dot2`: exact on any CPU), except where OpenBLAS's
kernel for the CPU rounds each product (AMD EPYC, OpenBLAS 0.3.31's Zen kernel): :data:`DOT_FMA` says which
numpy does here (:func:`numpy_dot_is_fma`, :func:`numpy_dot_is_plain`), and :func:`dot2` does the same.

Cache. The choices are fixed when a kernel is compiled: :data:`USE_SVML` follows from the CPU and numba's target,
both part of numba's cache key, and from numpy's dispatch (``NPY_DISABLE_CPU_FEATURES`` can cap it), which every
kernel's cache stamp holds (:func:`rhs_common.jit.numpy_dispatch_stamp`), so a cached kernel always matches the
process that loads it.
"""

from __future__ import annotations

import ctypes
import glob
import os
from typing import Any

import numpy as np

from rhs_common.jit import njit, numba_module

__all__ = ["DOT_FMA", "USE_SVML", "arcsin", "arctan", "dot2", "numpy_dot_is_fma", "numpy_dot_is_plain", "power", "tan"]

#: SVML function -> number of arguments
SVML_FUNCTIONS = {"__svml_asin8_ha": 1, "__svml_atan8_ha": 1, "__svml_tan8_ha": 1, "__svml_pow8_ha": 2}


def _numpy_svml() -> dict[str, int]:
    """Addresses of numpy's SVML functions when numpy dispatches these ufuncs to them here, else {}."""
    numba = numba_module()
    if numba.config.DISABLE_JIT or (numba.config.CPU_NAME or "host") != "host" or numba.config.CPU_FEATURES:
        return {}
    import importlib

    try:
        umath = importlib.import_module("numpy._core._multiarray_umath")
    except ImportError:  # numpy < 2
        return {}
    if not getattr(umath, "__cpu_features__", {}).get("AVX512_SKX"):
        return {}
    found = glob.glob(os.path.join(os.path.dirname(str(umath.__file__)), "_multiarray_umath*.so"))
    if not found:
        return {}
    try:
        lib = ctypes.CDLL(found[0])
        return {name: ctypes.cast(getattr(lib, name), ctypes.c_void_p).value or 0 for name in SVML_FUNCTIONS}
    except (OSError, AttributeError):
        return {}


def _svml_intrinsic(symbol: str, nargs: int) -> Any:
    """A numba intrinsic ``float64 -> float64`` (or of two) calling ``symbol`` on 8-lane vectors, lane 0 back."""
    from llvmlite import ir
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic

    vec = ir.VectorType(ir.DoubleType(), 8)
    lane0 = ir.Constant(ir.IntType(32), 0)

    def broadcast(builder: Any, x: Any) -> Any:
        v = ir.Constant(vec, ir.Undefined)
        for i in range(8):
            v = builder.insert_element(v, x, ir.Constant(ir.IntType(32), i))
        return v

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(vec, [vec] * nargs), symbol)
        return builder.extract_element(builder.call(fn, [broadcast(builder, a) for a in args]), lane0)

    if nargs == 1:
        def unary(typingctx: Any, x: Any) -> Any:
            return types.float64(types.float64), codegen

        return intrinsic(unary)

    def binary(typingctx: Any, x: Any, y: Any) -> Any:
        return types.float64(types.float64, types.float64), codegen

    return intrinsic(binary)


_ADDRESSES = _numpy_svml()
#: whether the functions below call numpy's SVML (module docstring)
USE_SVML = bool(_ADDRESSES) and all(_ADDRESSES.values())
if USE_SVML:
    import llvmlite.binding as llvm

    for _name, _address in _ADDRESSES.items():
        llvm.add_symbol(_name, _address)  # before any kernel that calls it is compiled or loaded from the cache
    _asin = _svml_intrinsic("__svml_asin8_ha", 1)
    _atan = _svml_intrinsic("__svml_atan8_ha", 1)
    _tan = _svml_intrinsic("__svml_tan8_ha", 1)
    _pow = _svml_intrinsic("__svml_pow8_ha", 2)

    @njit
    def arcsin(x: float) -> float:
        """``np.arcsin`` of a scalar, as numpy computes it."""
        return _asin(x)

    @njit
    def arctan(x: float) -> float:
        """``np.arctan`` of a scalar, as numpy computes it."""
        return _atan(x)

    @njit
    def tan(x: float) -> float:
        """``np.tan`` of a scalar, as numpy computes it."""
        return _tan(x)

    @njit
    def power(x: float, y: float) -> float:
        """``np.power`` of two float scalars, as numpy computes it."""
        return _pow(x, y)

else:

    @njit
    def arcsin(x: float) -> float:
        """``np.arcsin`` of a scalar, as numpy computes it."""
        return np.arcsin(x)

    @njit
    def arctan(x: float) -> float:
        """``np.arctan`` of a scalar, as numpy computes it."""
        return np.arctan(x)

    @njit
    def tan(x: float) -> float:
        """``np.tan`` of a scalar, as numpy computes it."""
        return np.tan(x)

    @njit
    def power(x: float, y: float) -> float:
        """``np.power`` of two float scalars, as numpy computes it."""
        return np.power(x, y)


def _exact_fma(a: float, b: float, c: float) -> float:
    """``a * b + c`` rounded once (for the probe and for ``NUMBA_DISABLE_JIT=1``)."""
    from fractions import Fraction

    return float(Fraction(a) * Fraction(b) + Fraction(c))


def numpy_dot_is_fma() -> bool:
    """Whether numpy's ``np.dot`` of 2-vectors rounds as ``fma(a1, b1, a0 * b0)`` here, as :func:`dot2` (probed on 64
    random pairs, many of which round differently fused and plain)."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(0.0, 1e3, (64, 2)), rng.normal(0.0, 1.0, (64, 2))
    fused = [_exact_fma(float(x[1]), float(y[1]), float(x[0] * y[0])) for x, y in zip(a, b, strict=True)]
    return [float(np.dot(x, y)) for x, y in zip(a, b, strict=True)] == fused


def _fma_intrinsic() -> Any:
    from numba import types
    from numba.extending import intrinsic

    def fused(typingctx: Any, a: Any, b: Any, c: Any) -> Any:
        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            return builder.fma(*args)

        return types.float64(types.float64, types.float64, types.float64), codegen

    return intrinsic(fused)


if numba_module().config.DISABLE_JIT:
    _fma = _exact_fma
else:
    _fma = _fma_intrinsic()


def numpy_dot_is_plain() -> bool:
    """Whether numpy's ``np.dot`` of 2-vectors rounds as ``a0 * b0 + a1 * b1`` (no FMA) here (the same probe as
    :func:`numpy_dot_is_fma`): OpenBLAS's ``ddot`` on some CPUs with FMA (AMD's Zen kernels) does."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(0.0, 1e3, (64, 2)), rng.normal(0.0, 1.0, (64, 2))
    return [float(np.dot(x, y)) for x, y in zip(a, b, strict=True)] == [
        float(x[0] * y[0]) + float(x[1] * y[1]) for x, y in zip(a, b, strict=True)]


#: how :func:`dot2` rounds: as numpy's ``np.dot`` here, fused (``fma(a1, b1, a0 * b0)``) unless numpy's BLAS
#: rounds each product (:func:`numpy_dot_is_plain`). Fixed when the kernels compile; numba's cache key holds the
#: CPU, which picks OpenBLAS's kernel, so a cached kernel matches the numpy of the process that compiled it
DOT_FMA = not numpy_dot_is_plain()

if DOT_FMA:

    @njit
    def dot2(a0: float, a1: float, b0: float, b1: float) -> float:
        """``np.dot([a0, a1], [b0, b1])`` as BLAS's ``ddot`` computes it on a CPU with FMA."""
        return _fma(a1, b1, a0 * b0)

else:

    @njit
    def dot2(a0: float, a1: float, b0: float, b1: float) -> float:
        """``np.dot([a0, a1], [b0, b1])`` as BLAS's ``ddot`` computes it here (each product rounded)."""
        return a0 * b0 + a1 * b1
