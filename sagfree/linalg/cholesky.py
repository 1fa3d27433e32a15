"""The banded Cholesky factorization, with an active set (DESIGN section 5).

``factor_active`` factors a bordered band matrix H (band module) with the rows and columns of the
active (bound) variables replaced by the identity: the band keeps its width, so a factorization costs
O(nb w^2 + m^2 nb) and a solve O(nb w + m nb). When the free set changes, only the columns from the
first changed variable on (less w) are refactored. The kernels are compiled with numba and
allocation-free in the solve path. ``band_cholesky`` / ``band_solve`` are the same kernels on a plain
symmetric band with every variable free (the simulation's Newton steps, the eigenvalue code, the
predecessor baseline).
"""
from __future__ import annotations

import numba
import numpy as np

from .band import ROWS_11, ROWS_13, ROWS_19
from .timing import LINEAR_ALGEBRA, timed


@timed(LINEAR_ALGEBRA)
def band_cholesky(band: np.ndarray, shift: float = 0.0) -> np.ndarray | None:
    """Cholesky factor of H + shift I for H in LAPACK lower band storage band[k, j] = H[j + k, j];
    returned as cols[j, k] = L[j + k, j] (for ``band_solve``), or None if H + shift I is not
    positive definite."""
    band = np.array(band, dtype=float)
    band[0] += shift
    n = band.shape[1]
    cols = np.empty((n, band.shape[0]))
    no_border, no_corner = np.zeros((0, n)), np.zeros((0, 0))
    if not factor_active(band, no_border, no_corner, np.ones(n, dtype=np.bool_), cols, no_border, no_corner, 0, 0):
        return None
    return cols


@timed(LINEAR_ALGEBRA)
def band_solve(factor: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """(L L^T)^-1 rhs for the factor of ``band_cholesky``."""
    out = np.empty(factor.shape[0])
    plain_solve(factor, np.ascontiguousarray(rhs, dtype=float), out)
    return out


@timed(LINEAR_ALGEBRA)
def band_solve_many(factor: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """(L L^T)^-1 rhs for the factor of ``band_cholesky`` and many right-hand sides (rows x k)."""
    out = np.array(rhs, dtype=float, order="C")
    solve_rows(factor, out)
    return out


@numba.njit(cache=True)
def solve_rows(factor, x):  # pragma: no cover - compiled
    """x <- (L L^T)^-1 x in place, x C-ordered (rows x k): every update of a row is a contiguous
    axpy over the k right-hand sides, which the compiler vectorizes (LAPACK's dpbtrs solves them one
    at a time, 3x slower on a 400-vertex strand's 1,200)."""
    n, width = factor.shape
    k = x.shape[1]
    for j in range(n):  # L y = x, column by column
        pivot = factor[j, 0]
        for c in range(k):
            x[j, c] /= pivot
        for t in range(1, min(width, n - j)):
            entry = factor[j, t]
            for c in range(k):
                x[j + t, c] -= entry * x[j, c]
    for j in range(n - 1, -1, -1):  # L^T x = y
        for t in range(1, min(width, n - j)):
            entry = factor[j, t]
            for c in range(k):
                x[j, c] -= entry * x[j + t, c]
        pivot = factor[j, 0]
        for c in range(k):
            x[j, c] /= pivot


def compile_kernels() -> None:
    """Compile (or load from numba's cache) ``solve_rows``, which only the best effort of a strand
    the boxes cannot balance runs (solvers.least_sag): frontend.warm calls it before any timed solve."""
    band_solve_many(np.ones((2, 1)), np.ones((2, 1)))


@numba.njit(cache=True)
def plain_solve(factor, rhs, out):  # pragma: no cover - compiled
    """out = (L L^T)^-1 rhs for a factor without border (callable from compiled code)."""
    n = factor.shape[0]
    solve_factored(factor, np.zeros((0, n)), np.zeros((0, 0)), rhs, out)


@numba.njit(cache=True)
def factor_active(band, border, corner, free, cols, lborder, lcorner, start,
                  border_start):  # pragma: no cover - compiled
    """Active-set Cholesky: factor H with non-free rows/columns replaced by the identity.

    Right-looking banded Cholesky in column storage, cols[j, k] = L[j + k, j] (k = 0 the diagonal;
    LAPACK's dpbtrf layout), so that every update is a contiguous axpy.
    Partial refactorization: when the free set changed first at band index ``start``, L changes
    only in columns j >= j0 = start - w (column j < j0 has no entry in a row >= start). Those
    columns are rebuilt from H, minus the updates of the w kept columns before j0, and the
    factorization goes on from j0; ``start = 0`` is a full factorization.
    Then Y = C_F L^-T (``lborder``, kept before column j0 too unless ``border_start`` = 0 because a
    border variable changed) and the Cholesky factor of the Schur complement D - Y Y^T (``lcorner``).
    Returns False if a pivot is not positive (H restricted to the free set is not definite).
    """
    w1, nb = band.shape
    m = corner.shape[0]
    w = w1 - 1
    j0 = max(0, start - w)
    for j in range(j0, nb):
        for k in range(w1):
            cols[j, k] = band[k, j] if (j + k < nb and free[j] and free[j + k]) else 0.0
        if not free[j]:
            cols[j, 0] = 1.0
    for j in range(max(0, j0 - w), j0):  # kept columns: their updates of the rebuilt ones
        _eliminate(cols, j, j0)
    for j in range(j0, nb):
        d = cols[j, 0]
        if not d > 0.0:
            return False
        d = np.sqrt(d)
        cols[j, 0] = d
        for k in range(1, min(w, nb - 1 - j) + 1):
            cols[j, k] /= d
        _eliminate_next(cols, j)
    # border: Y = C_F L^-T, i.e. L Y^T = C_F^T (forward substitution per border row)
    y0 = j0 if border_start > 0 else 0
    for r in range(m):
        active_row = not free[nb + r]
        y = lborder[r]
        for j in range(y0, nb):
            y[j] = 0.0 if (active_row or not free[j]) else border[r, j]
        for j in range(max(0, y0 - w), nb):
            if j >= y0:
                y[j] /= cols[j, 0]
            v = y[j]
            if v != 0.0:
                for k in range(max(1, y0 - j), min(w, nb - 1 - j) + 1):
                    y[j + k] -= cols[j, k] * v
    for r in range(m):
        for c in range(m):
            if free[nb + r] and free[nb + c]:
                s = corner[r, c]
                for j in range(nb):
                    s -= lborder[r, j] * lborder[c, j]
            else:
                s = 1.0 if r == c else 0.0
            lcorner[r, c] = s
    for c in range(m):  # dense Cholesky of the small Schur complement, in place (lower)
        for k in range(c):
            lcorner[c, c] -= lcorner[c, k] ** 2
        if not lcorner[c, c] > 0.0:
            return False
        lcorner[c, c] = np.sqrt(lcorner[c, c])
        for r in range(c + 1, m):
            for k in range(c):
                lcorner[r, c] -= lcorner[r, k] * lcorner[c, k]
            lcorner[r, c] /= lcorner[c, c]
    return True


@numba.njit(cache=True, inline="always")
def _eliminate(cols, j, first):  # pragma: no cover - compiled
    """Subtract column j's outer product L[:, j] L[:, j]^T from the columns >= first it reaches."""
    nb, w1 = cols.shape
    kmax = min(w1 - 1, nb - 1 - j)
    for k in range(max(1, first - j), kmax + 1):
        f = cols[j, k]
        if f != 0.0:
            target = j + k
            for i in range(k, kmax + 1):
                cols[target, i - k] -= cols[j, i] * f


@numba.njit(cache=True, inline="always")
def _eliminate_next(cols, j):  # pragma: no cover - compiled
    """_eliminate(cols, j, j + 1): column j's update of the columns after it, bit for bit, with a
    constant width where the band has one of the default model's widths (band.ROWS_*) and column j
    is an interior one."""
    nb, w1 = cols.shape
    if j + w1 - 1 < nb:
        if w1 == 19:
            _eliminate_interior(cols, j, ROWS_19)
            return
        if w1 == 13:
            _eliminate_interior(cols, j, ROWS_13)
            return
        if w1 == 11:
            _eliminate_interior(cols, j, ROWS_11)
            return
    _eliminate(cols, j, j + 1)


@numba.njit(cache=True, inline="always")
def _eliminate_interior(cols, j, rows):  # pragma: no cover - compiled
    """_eliminate(cols, j, j + 1) for a column with ``len(rows) - 1`` entries below its diagonal (a
    tuple: its length is a constant of the compiled code)."""
    w = len(rows) - 1
    for k in range(1, w + 1):
        f = cols[j, k]
        if f != 0.0:
            target = j + k
            for i in range(k, w + 1):
                cols[target, i - k] -= cols[j, i] * f


@numba.njit(cache=True)
def solve_factored(cols, lborder, lcorner, rhs, out):  # pragma: no cover - compiled
    """out = M^-1 rhs with M = L L^T from factor_active (out may not alias rhs)."""
    nb, w1 = cols.shape
    m = lcorner.shape[0]
    w = w1 - 1
    for j in range(nb + m):
        out[j] = rhs[j]
    for j in range(nb):  # L_B y1 = r1
        v = out[j] / cols[j, 0]
        out[j] = v
        for k in range(1, min(w, nb - 1 - j) + 1):
            out[j + k] -= cols[j, k] * v
    for r in range(m):  # L_S y2 = r2 - Y y1
        s = out[nb + r]
        for j in range(nb):
            s -= lborder[r, j] * out[j]
        for c in range(r):
            s -= lcorner[r, c] * out[nb + c]
        out[nb + r] = s / lcorner[r, r]
    for r in range(m - 1, -1, -1):  # L_S^T x2 = y2
        s = out[nb + r]
        for c in range(r + 1, m):
            s -= lcorner[c, r] * out[nb + c]
        out[nb + r] = s / lcorner[r, r]
    for r in range(m):  # y1 -= Y^T x2
        for j in range(nb):
            out[j] -= lborder[r, j] * out[nb + r]
    for j in range(nb - 1, -1, -1):  # L_B^T x1 = y1
        s = out[j]
        for k in range(1, min(w, nb - 1 - j) + 1):
            s -= cols[j, k] * out[j + k]
        out[j] = s / cols[j, 0]
