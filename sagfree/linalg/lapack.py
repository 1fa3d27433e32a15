"""LAPACK's band LU (dgbtrf, dgbtrs) callable from numba-compiled code.

scipy.linalg.cython_lapack exports the LAPACK that scipy.linalg.lapack wraps as C function pointers;
compiled code calls them at their integer addresses through llvmlite intrinsics (as
formulation.at_rest calls the stencil drivers): a function pointer baked into numba's cached code
would point into the process that compiled it. Same routines, same library: the factors and
solutions are scipy.linalg.lapack's bit for bit, without f2py's argument handling around each call
(the saddle systems of asc are factored and solved a few times per strand, linalg.saddle).

Storage: LAPACK's general band storage of an n x n matrix with kl sub- and ku superdiagonals, kept
as a C-contiguous (n, 2 kl + ku + 1) array ``columns`` whose row j is column j of LAPACK's
(2 kl + ku + 1, n) Fortran array: entry (i, j) at columns[j, kl + ku + i - j].
"""
from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import get_cython_function_address, intrinsic

#: the routines' addresses in scipy's LAPACK (LP64: Fortran integers are int32), for ``band_lu`` and
#: ``band_lu_solve``
DGBTRF = get_cython_function_address("scipy.linalg.cython_lapack", "dgbtrf")
DGBTRS = get_cython_function_address("scipy.linalg.cython_lapack", "dgbtrs")


def _pointer_call(arity: int):
    """An intrinsic calling void f(void*, ... arity times) at an integer address with integer
    (address) arguments: Fortran passes every argument by reference."""

    @intrinsic
    def call(typing_context, address, arguments):
        if not (isinstance(address, types.Integer) and isinstance(arguments, types.BaseTuple)
                and len(arguments) == arity and all(isinstance(t, types.Integer) for t in arguments)):
            return None

        def codegen(context, builder, signature, args):
            byte_pointer = ir.IntType(8).as_pointer()
            function_type = ir.FunctionType(ir.VoidType(), [byte_pointer] * arity)
            function = builder.inttoptr(args[0], function_type.as_pointer())
            values = [builder.inttoptr(builder.extract_value(args[1], k), byte_pointer) for k in range(arity)]
            builder.call(function, values)
            return context.get_dummy_value()

        return types.void(address, arguments), codegen

    return call


_call8 = _pointer_call(8)
_call11 = _pointer_call(11)


@numba.njit(cache=True)
def band_lu(dgbtrf, columns, kl, ku, pivots):  # pragma: no cover - compiled
    """LU with partial pivoting of the band matrix in ``columns`` (module docstring), in place, by
    the dgbtrf at address ``dgbtrf`` (``DGBTRF``: an argument, not a global, which numba would
    freeze into its cache); pivots: int32 (n,) receives LAPACK's 1-based row interchanges. Returns
    LAPACK's info (> 0: a zero pivot, the matrix is singular)."""
    n, ldab = columns.shape
    integers = np.array([n, n, kl, ku, ldab, 0], dtype=np.int32)  # m, n, kl, ku, ldab, info
    at = integers.ctypes.data
    step = integers.itemsize
    _call8(dgbtrf, (at, at + step, at + 2 * step, at + 3 * step, columns.ctypes.data, at + 4 * step,
                    pivots.ctypes.data, at + 5 * step))
    return integers[5]


@numba.njit(cache=True)
def band_lu_solve(dgbtrs, columns, kl, ku, pivots, rhs):  # pragma: no cover - compiled
    """Solve A x = rhs in place (rhs: (n,) float64) from ``band_lu``'s factors, by the dgbtrs at
    address ``dgbtrs`` (``DGBTRS``). Returns LAPACK's info (0: done)."""
    n, ldab = columns.shape
    integers = np.array([n, kl, ku, 1, ldab, n, 0], dtype=np.int32)  # n, kl, ku, nrhs, ldab, ldb, info
    transpose = np.array([ord("N")], dtype=np.uint8)
    at = integers.ctypes.data
    step = integers.itemsize
    _call11(dgbtrs, (transpose.ctypes.data, at, at + step, at + 2 * step, at + 3 * step, columns.ctypes.data,
                     at + 4 * step, pivots.ctypes.data, rhs.ctypes.data, at + 5 * step, at + 6 * step))
    return integers[6]
