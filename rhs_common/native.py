"""Machine-level helpers of the compiled kernels: a BLAS product added straight into a strided view.

A kernel that must add a product into part of a larger array (the radar's range spectrum, whose
searched bins are a view of the FFT buffer) would otherwise form the product in a temporary and add
it in a second pass. :func:`matmul_add` lets one BLAS call do both: ``cgemm`` with ``beta = 1`` and the
view's own row stride as ``ldc``.

The routine is scipy's (``scipy.linalg.cython_blas``, the BLAS scipy ships with), called
through its address: :func:`cgemm_address` gives it, a kernel takes it as an ``int64`` argument (a ctypes
function object in a kernel's globals would stop numba caching the kernel). Under
``NUMBA_DISABLE_JIT=1`` :func:`matmul_add` is numpy's ``out += a @ b``.

Row-major ``C += A B`` is column-major ``C^T += B^T A^T``: ``cgemm('N', 'N', n, m, k, 1, B, ldb, A, lda, 1, C, ldc)``
with every leading dimension the row stride in elements.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["cgemm_address", "matmul_add"]


@functools.lru_cache(maxsize=1)
def cgemm_address() -> int:
    """The address of scipy's BLAS ``cgemm`` (``scipy.linalg.cython_blas``)."""
    from numba.extending import get_cython_function_address

    return int(get_cython_function_address("scipy.linalg.cython_blas", "cgemm"))


def matmul_add(a: np.ndarray, b: np.ndarray, out: np.ndarray, cgemm: int) -> None:
    """``out += a @ b``: a (M, K), b (K, N), out (M, N) complex64, each with unit stride along its rows.

    Compiled: one ``cgemm`` at the address ``cgemm`` (:func:`cgemm_address`), ``beta = 1``; as Python
    (``NUMBA_DISABLE_JIT=1``): numpy.
    """
    out += a @ b


def _register() -> None:
    """The compiled :func:`matmul_add`: the cgemm call with the views' pointers and row strides."""
    from rhs_common.jit import numba_module

    numba_module()  # numba's cache directory chosen first (rhs_common.jit)
    from llvmlite import ir
    from numba import types
    from numba.extending import intrinsic, overload

    @intrinsic
    def _cgemm_call(typingctx, addr, m, n, k, a, lda, b, ldb, c, ldc):
        sig = types.void(addr, m, n, k, a, lda, b, ldb, c, ldc)

        def codegen(context, builder, signature, args):
            ptr = ir.IntType(8).as_pointer()
            i32 = ir.IntType(32)
            fnty = ir.FunctionType(ir.VoidType(), [ptr] * 13)
            fn = builder.inttoptr(args[0], fnty.as_pointer())

            def int_ptr(value):
                slot = builder.alloca(i32)
                builder.store(builder.trunc(value, i32), slot)
                return builder.bitcast(slot, ptr)

            flt = ir.FloatType()
            one = builder.alloca(ir.ArrayType(flt, 2))
            builder.store(ir.Constant(ir.ArrayType(flt, 2), [1.0, 0.0]), one)
            trans = builder.alloca(ir.IntType(8))
            builder.store(ir.Constant(ir.IntType(8), ord("N")), trans)
            one_p, trans_p = builder.bitcast(one, ptr), trans
            m_, n_, k_, a_, lda_, b_, ldb_, c_, ldc_ = args[1:]
            builder.call(fn, [trans_p, trans_p, int_ptr(n_), int_ptr(m_), int_ptr(k_), one_p,
                              builder.inttoptr(b_, ptr), int_ptr(ldb_), builder.inttoptr(a_, ptr), int_ptr(lda_), one_p,
                              builder.inttoptr(c_, ptr), int_ptr(ldc_)])
            return context.get_dummy_value()

        return sig, codegen

    @overload(matmul_add)
    def _matmul_add(a, b, out, cgemm):
        def impl(a, b, out, cgemm):
            m, k = a.shape
            n = b.shape[1]
            if m == 0 or n == 0 or k == 0:
                return
            item = a.itemsize
            _cgemm_call(cgemm, m, n, k, a.ctypes.data, a.strides[0] // item, b.ctypes.data, b.strides[0] // item,
                        out.ctypes.data, out.strides[0] // item)

        return impl


_register()
