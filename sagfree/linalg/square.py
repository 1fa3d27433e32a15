"""A square system J_C x_C = b on a subset C of a strand Jacobian's columns, by band LU.

For a strand held by its root alone the rest blocks' columns of dc/dp that act on a free DOF are
exactly as many as the free DOFs (solvers.statics_start), so the least rest change that balances
gravity is the unique solution of this system: rows and columns both in strand order make
J_C a band (4 sub- and 10 superdiagonals), which LAPACK's dgbtrf factors in O(n) in a sixth of
the time of the saddle system [[W, J_C^T], [J_C, 0]] that the general case takes (linalg.saddle):
half the unknowns, a narrower band.
"""
from __future__ import annotations

import numba
import numpy as np

from . import lapack
from .band import csc_arrays
from .timing import LINEAR_ALGEBRA, timed


@timed(LINEAR_ALGEBRA)
def square_column_solve(J, columns: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
    """x (J.shape[1],), zero off ``columns``, with J[:, columns] x[columns] = rhs; None unless the
    columns are as many as J's rows and the system is nonsingular with a finite solution (LAPACK's
    LU with partial pivoting meets no zero pivot)."""
    columns = np.asarray(columns, dtype=np.bool_)
    if int(columns.sum()) != J.shape[0]:
        return None
    indptr, indices, data = csc_arrays(J)
    x = square_solution(lapack.DGBTRF, lapack.DGBTRS, indptr, indices, data, columns,
                         np.ascontiguousarray(rhs, dtype=float))
    return x if x.size and np.all(np.isfinite(x)) else None


@timed(LINEAR_ALGEBRA)
def square_column_solves(J, columns: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
    """``square_column_solve`` for each column of ``rhs`` (rows, m) from one LU: X (J.shape[1], m)."""
    columns = np.asarray(columns, dtype=np.bool_)
    if int(columns.sum()) != J.shape[0]:
        return None
    indptr, indices, data = csc_arrays(J)
    x = square_solutions(lapack.DGBTRF, lapack.DGBTRS, indptr, indices, data, columns,
                         np.ascontiguousarray(np.asarray(rhs, dtype=float).T))
    return x.T.copy() if x.size and np.all(np.isfinite(x)) else None


@numba.njit(cache=True)
def square_solution(dgbtrf, dgbtrs, indptr, indices, data, columns, rhs):  # pragma: no cover - compiled
    """``square_column_solve`` in one compiled call, callable from compiled code (empty where LAPACK
    reports a zero pivot)."""
    x = square_solutions(dgbtrf, dgbtrs, indptr, indices, data, columns, rhs.reshape(1, rhs.size))
    return x[0] if x.size else np.empty(0)


@numba.njit(cache=True)
def square_solutions(dgbtrf, dgbtrs, indptr, indices, data, columns, rhs):  # pragma: no cover - compiled
    """``square_solution`` for each row of ``rhs`` (m, rows) from one LU: (m, J.shape[1]), empty
    where LAPACK reports a zero pivot."""
    n, rows = indptr.size - 1, rhs.shape[1]
    number = np.full(n, -1, dtype=np.int64)  # each kept column's index in x_C
    kept = 0
    kl, ku = 0, 0
    for j in range(n):
        if columns[j]:
            number[j] = kept
            for e in range(indptr[j], indptr[j + 1]):
                kl = max(kl, indices[e] - kept)
                ku = max(ku, kept - indices[e])
            kept += 1
    band = np.zeros((rows, 2 * kl + ku + 1))  # linalg.lapack's layout: (i, j) at band[j, kl + ku + i - j]
    for j in range(n):
        if columns[j]:
            k = number[j]
            for e in range(indptr[j], indptr[j + 1]):
                band[k, kl + ku + indices[e] - k] = data[e]
    pivots = np.empty(rows, dtype=np.int32)
    if lapack.band_lu(dgbtrf, band, kl, ku, pivots) != 0:
        return np.empty((0, n))
    x = np.zeros((rhs.shape[0], n))
    for m in range(rhs.shape[0]):
        solution = rhs[m].copy()
        lapack.band_lu_solve(dgbtrs, band, kl, ku, pivots, solution)
        for j in range(n):
            if columns[j]:
                x[m, j] = solution[number[j]]
    return x
