"""The row-space normal matrix A = J_C diag(d_C) J_C^T + shift I of a strand Jacobian, factored."""
from __future__ import annotations

import numba
import numpy as np

from .band import csc_arrays, dense_columns, dense_count
from .cholesky import factor_active, solve_factored
from .compressed import csc_matvec, csc_rmatvec
from .timing import LINEAR_ALGEBRA, timed


class NormalFactor:
    """Cholesky factor of the row-space matrix A = J_C diag(d_C) J_C^T + shift I, for least-squares
    multipliers (solvers.multipliers).

    The rows of J (the free DOFs) are in strand order and each parameter column touches a few
    neighbouring rows, so A is banded and factors in O(rows w^2) with the active-set Cholesky's
    kernels (all variables free). A column that fills most rows (the strand multiplier of
    ``stiffness="strand"``) would fill the band: such columns U (scaled by sqrt(d)) are kept out and
    added back by the Woodbury identity, (A + U U^T)^-1 = A^-1 - A^-1 U (I + U^T A^-1 U)^-1 U^T A^-1.
    The band factor is about ten times faster than a sparse LU of the same matrix.
    """

    @timed(LINEAR_ALGEBRA)
    def __init__(self, J, d: np.ndarray, columns: np.ndarray, shift: float = 0.0):
        """J: (rows x n); d: (n,) column weights; columns: (n,) bool mask of the columns in A."""
        indptr, indices, data = csc_arrays(J)
        rows = J.shape[0]
        dense = columns & dense_columns(indptr, rows)
        self._cols, self.definite = _factored_normal(indptr, indices, data, rows, np.asarray(d, dtype=float),
                                                     columns & ~dense, shift)
        self._empty_border, self._empty_corner = np.zeros((0, rows)), np.zeros((0, 0))
        self._U = np.zeros((rows, int(dense.sum())))
        for k, j in enumerate(np.flatnonzero(dense)):
            self._U[indices[indptr[j]:indptr[j + 1]], k] = data[indptr[j]:indptr[j + 1]] * np.sqrt(d[j])
        if self.definite and self._U.shape[1]:
            self._AU = np.column_stack([self._band_solve(u) for u in self._U.T])
            self._capacitance = np.eye(self._U.shape[1]) + self._U.T @ self._AU

    def _band_solve(self, rhs: np.ndarray) -> np.ndarray:
        out = np.empty(rhs.size)
        solve_factored(self._cols, self._empty_border, self._empty_corner, np.ascontiguousarray(rhs, dtype=float),
                       out)
        return out

    @timed(LINEAR_ALGEBRA)
    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """A^-1 rhs (only if ``definite``)."""
        x = self._band_solve(rhs)
        if self._U.shape[1]:
            x -= self._AU @ np.linalg.solve(self._capacitance, self._U.T @ x)
        return x


@timed(LINEAR_ALGEBRA)
def seminormal_least_squares(J, gradient: np.ndarray, scale: np.ndarray, free: np.ndarray,
                             shift: float) -> np.ndarray | None:
    """lam minimizing ||(gradient + J^T lam)_F / sqrt(scale_F)||_2 over the columns F of ``free``:
    the normal equations A lam = -J_F (gradient / scale)_F, A = J_F diag(1 / scale_F) J_F^T + shift I
    (NormalFactor), then one step of the corrected semi-normal equations, lam += A^-1 (-J_F e_F) with
    e = (gradient + J^T lam) / scale: solvers.multipliers's steps in one compiled call. NaN if A is
    not definite; None where a free column of J is dense (NormalFactor's Woodbury path does those)."""
    indptr, indices, data = csc_arrays(J)
    return _seminormal_least_squares(indptr, indices, data, J.shape[0], np.ascontiguousarray(gradient, dtype=float),
                                     np.ascontiguousarray(scale, dtype=float), np.asarray(free, dtype=np.bool_),
                                     shift, dense_count(J.shape[0]))


@numba.njit(cache=True)
def _seminormal_least_squares(indptr, indices, data, rows, gradient, scale, free, shift,
                              dense_entries):  # pragma: no cover - compiled
    """``seminormal_least_squares``: None where a free column has more than dense_entries entries
    (band.dense_count)."""
    n = indptr.size - 1
    for j in range(n):
        if free[j] and indptr[j + 1] - indptr[j] > dense_entries:
            return None
    return seminormal_kernel(indptr, indices, data, rows, gradient, scale, free, shift)


@numba.njit(cache=True)
def seminormal_kernel(indptr, indices, data, rows, gradient, scale, free, shift):  # pragma: no cover - compiled
    """``seminormal_least_squares``'s steps where no free column is dense, callable from compiled
    code (asc's compiled outer loop)."""
    n = indptr.size - 1
    weights = np.empty(n)
    for j in range(n):
        weights[j] = 1.0 / scale[j]
    factor, definite = _factored_normal(indptr, indices, data, rows, weights, free, shift)
    lam = np.zeros(rows)
    if not definite:
        lam[:] = np.nan
        return lam
    no_border, no_corner = np.zeros((0, rows)), np.zeros((0, 0))
    step, residual = np.empty(rows), np.empty(n)
    for _ in range(2):  # the solve, then the correction
        pulled = csc_rmatvec(indptr, indices, data, lam)
        for j in range(n):
            residual[j] = (gradient[j] + pulled[j]) / scale[j] if free[j] else 0.0
        rhs = csc_matvec(indptr, indices, data, residual, rows)
        for r in range(rows):
            rhs[r] = -rhs[r]
        solve_factored(factor, no_border, no_corner, rhs, step)
        for r in range(rows):
            lam[r] += step[r]
    return lam


@numba.njit(cache=True)
def _factored_normal(indptr, indices, data, rows, d, include, shift):  # pragma: no cover - compiled
    """(Cholesky factor columns, definite) of A = J_C diag(d_C) J_C^T + shift I over the columns C of
    ``include`` (NormalFactor's band, factored by cholesky.factor_active with every row free)."""
    transposed = np.zeros((rows, _column_span(indptr, indices, include) + 1))  # the band transposed
    transposed[:, 0] = shift
    _accumulate_row_gram(indptr, indices, data, d, include, transposed)
    band = np.ascontiguousarray(transposed.T)
    factor = np.empty((rows, band.shape[0]))
    no_border, no_corner = np.zeros((0, rows)), np.zeros((0, 0))
    definite = factor_active(band, no_border, no_corner, np.ones(rows, dtype=np.bool_), factor, no_border, no_corner,
                             np.int64(0), np.int64(0))
    return factor, definite


@numba.njit(cache=True)
def _column_span(indptr, indices, include):  # pragma: no cover - compiled
    """Largest distance between two rows that share an included column."""
    width = 0
    for j in range(indptr.size - 1):
        if include[j] and indptr[j + 1] > indptr[j]:
            lo, hi = indices[indptr[j]], indices[indptr[j]]
            for k in range(indptr[j], indptr[j + 1]):
                lo = min(lo, indices[k])
                hi = max(hi, indices[k])
            width = max(width, hi - lo)
    return width


@numba.njit(cache=True)
def _accumulate_row_gram(indptr, indices, data, d, include, columns):  # pragma: no cover - compiled
    """Add d_j J[:, j] J[:, j]^T of every included column j to the lower band (rows x rows), held
    transposed: columns[r, k] = band[k, r] (contiguous per row, as linalg.band.gram)."""
    for j in range(indptr.size - 1):
        if not include[j]:
            continue
        for a in range(indptr[j], indptr[j + 1]):
            ra, va = indices[a], d[j] * data[a]
            for b in range(indptr[j], indptr[j + 1]):
                rb = indices[b]
                if rb >= ra:
                    columns[ra, rb - ra] += va * data[b]
