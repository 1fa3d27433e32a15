"""Bordered banded symmetric matrices: storage, products and the active-set Cholesky (DESIGN 5).

The Gauss-Newton Hessian H = diag(R'') + mu J^T J is banded when p is ordered along the strand
(element stiffness), except for the single strand multiplier of ``stiffness="strand"``, which couples
to everything. So H is stored as a band of the first nb = n - m variables plus a dense border of the
last m (m = 0 or 1):

    H = [[B, C^T], [C, D]],  B banded (lower storage band[k, j] = B[j + k, j], k = 0..w),
    C dense (m, nb), D dense (m, m).

The active-set Cholesky factors H with the rows and columns of the active (bound) variables replaced by
the identity: the band keeps its width, so a factorization costs O(nb w^2 + m^2 nb) and a solve
O(nb w + m nb). When the free set changes, only the columns from the first changed variable on (less
w) are refactored: on the Gauss-Newton QPs of 20 groom strands (100 vertices) that recomputed 76% of
the rows of a full factorization per refactorization. Everything here is compiled with numba and
allocation-free in the solve path.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import scipy.sparse as sp

from sagfree.formulation.jacobian import StrandJacobian


@dataclass
class BorderedBand:
    """H as (band, border, corner); see the module docstring."""

    band: np.ndarray    # (w + 1, nb)
    border: np.ndarray  # (m, nb)
    corner: np.ndarray  # (m, m)

    @property
    def size(self) -> int:
        return self.band.shape[1] + self.corner.shape[0]

    def to_dense(self) -> np.ndarray:
        nb, m = self.band.shape[1], self.corner.shape[0]
        dense = np.zeros((nb + m, nb + m))
        for k in range(self.band.shape[0]):
            idx = np.arange(nb - k)
            dense[idx + k, idx] = self.band[k, : nb - k]
            dense[idx, idx + k] = self.band[k, : nb - k]
        dense[nb:, :nb] = self.border
        dense[:nb, nb:] = self.border.T
        dense[nb:, nb:] = self.corner
        return dense


def bordered_band(matrix: sp.spmatrix, border: int) -> BorderedBand:
    """Split a symmetric sparse matrix into band + dense border of the last ``border`` variables."""
    coo = sp.tril(matrix, format="coo")
    n = matrix.shape[0]
    nb = n - border
    in_band = coo.col < nb
    in_band &= coo.row < nb
    width = int((coo.row[in_band] - coo.col[in_band]).max(initial=0))
    band = np.zeros((width + 1, nb))
    np.add.at(band, (coo.row[in_band] - coo.col[in_band], coo.col[in_band]), coo.data[in_band])
    dense = sp.csr_matrix(matrix)[nb:].toarray() if border else np.zeros((0, n))
    return BorderedBand(band, np.ascontiguousarray(dense[:, :nb]), np.ascontiguousarray(dense[:, nb:]))


@numba.njit(cache=True)
def matvec(band, border, corner, x, out):  # pragma: no cover - compiled
    """out = H x."""
    w1, nb = band.shape
    m = corner.shape[0]
    for j in range(nb):
        out[j] = band[0, j] * x[j]
    for k in range(1, w1):
        for j in range(nb - k):
            out[j + k] += band[k, j] * x[j]
            out[j] += band[k, j] * x[j + k]
    for r in range(m):
        s = 0.0
        for j in range(nb):
            out[j] += border[r, j] * x[nb + r]
            s += border[r, j] * x[j]
        for c in range(m):
            s += corner[r, c] * x[nb + c]
        out[nb + r] = s


@numba.njit(cache=True)
def gershgorin_bound(band, border, corner):  # pragma: no cover - compiled
    """An upper bound of the largest eigenvalue of H: the largest absolute row sum."""
    w1, nb = band.shape
    m = corner.shape[0]
    rows = np.zeros(nb + m)
    for j in range(nb):
        rows[j] += abs(band[0, j])
    for k in range(1, w1):
        for j in range(nb - k):
            rows[j + k] += abs(band[k, j])
            rows[j] += abs(band[k, j])
    for r in range(m):
        for j in range(nb):
            rows[j] += abs(border[r, j])
            rows[nb + r] += abs(border[r, j])
        for c in range(m):
            rows[nb + r] += abs(corner[r, c])
    return rows.max()


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
        _eliminate(cols, j, j + 1)
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


def gram(J: sp.spmatrix | StrandJacobian, diagonal: np.ndarray, scale: float, border: int) -> BorderedBand:
    """diag(diagonal) + scale J^T J as a bordered band, accumulated row by row from J (no sparse
    matrix product): each row of J touches only the parameters of a few neighbouring elements."""
    if isinstance(J, StrandJacobian):
        indptr, indices, data = J.csr()
    else:
        J = sp.csr_matrix(J)
        J = J if J.has_sorted_indices else J.sorted_indices()
        indptr, indices, data = J.indptr, J.indices.astype(np.int64), J.data
    n = J.shape[1]
    nb = n - border
    width = _row_span(indptr, indices, nb)
    band = np.zeros((width + 1, nb))
    band[0] = diagonal[:nb]
    bord = np.zeros((border, nb))
    corner = np.diag(diagonal[nb:]).astype(float).reshape(border, border)
    _accumulate_gram(indptr, indices, data, nb, scale, band, bord, corner)
    return BorderedBand(band, bord, corner)


@numba.njit(cache=True)
def _row_span(indptr, indices, nb):  # pragma: no cover - compiled
    """Largest distance between two band columns (< nb) that share a row."""
    width = 0
    for r in range(indptr.size - 1):
        lo, hi = nb, -1
        for k in range(indptr[r], indptr[r + 1]):
            c = indices[k]
            if c < nb:
                lo = min(lo, c)
                hi = max(hi, c)
        width = max(width, hi - lo)
    return width


@numba.njit(cache=True)
def _accumulate_gram(indptr, indices, data, nb, scale, band, border, corner):  # pragma: no cover
    """Add scale J^T J, each pair of a row's entries once (the row's columns are sorted, so the
    band column comes first and border columns last)."""
    for r in range(indptr.size - 1):
        for a in range(indptr[r], indptr[r + 1]):
            ca, va = indices[a], scale * data[a]
            for b in range(a, indptr[r + 1]):
                cb = indices[b]
                if cb < nb:
                    band[cb - ca, ca] += va * data[b]
                elif ca < nb:
                    border[cb - nb, ca] += va * data[b]
                else:
                    corner[ca - nb, cb - nb] += va * data[b]
                    if cb != ca:
                        corner[cb - nb, ca - nb] += va * data[b]


def csc_arrays(J: sp.spmatrix | StrandJacobian) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indptr, indices, data) of J in compressed columns, int64 indices (numba kernels)."""
    if isinstance(J, StrandJacobian):
        return J.pattern.indptr, J.pattern.indices, J.data
    J = sp.csc_matrix(J)
    return J.indptr.astype(np.int64), J.indices.astype(np.int64), J.data


def dense_columns(indptr: np.ndarray, rows: int) -> np.ndarray:
    """Columns that fill most rows (the strand multiplier of ``stiffness="strand"``): in a band they
    would fill it, so the banded factorizations keep them apart."""
    return np.diff(indptr) > max(50, rows // 5)


class NormalFactor:
    """Cholesky factor of the row-space matrix A = J_C diag(d_C) J_C^T + shift I, for least-squares
    multipliers (solvers.kkt).

    The rows of J (the free DOFs) are in strand order and each parameter column touches a few
    neighbouring rows, so A is banded and factors in O(rows w^2) with the active-set Cholesky's
    kernels (all variables free). A column that fills most rows (the strand multiplier of
    ``stiffness="strand"``) would fill the band: such columns U (scaled by sqrt(d)) are kept out and
    added back by the Woodbury identity, (A + U U^T)^-1 = A^-1 - A^-1 U (I + U^T A^-1 U)^-1 U^T A^-1.
    On a 100-vertex groom strand this costs 0.17 ms (least-squares multipliers with it 0.27 ms; with
    the sparse LU of the same matrix and scipy's construction around it they took ~2.8 ms).
    """

    def __init__(self, J: sp.spmatrix | StrandJacobian, d: np.ndarray, columns: np.ndarray, shift: float = 0.0):
        """J: (rows x n); d: (n,) column weights; columns: (n,) bool mask of the columns in A."""
        indptr, indices, data = csc_arrays(J)
        rows = J.shape[0]
        dense = columns & dense_columns(indptr, rows)
        sparse_columns = columns & ~dense
        band = np.zeros((_column_span(indptr, indices, sparse_columns) + 1, rows))
        band[0] = shift
        _accumulate_row_gram(indptr, indices, data, np.asarray(d, dtype=float), sparse_columns, band)
        self._cols = np.empty((rows, band.shape[0]))
        self._empty_border, self._empty_corner = np.zeros((0, rows)), np.zeros((0, 0))
        self.definite = factor_active(band, self._empty_border, self._empty_corner, np.ones(rows, dtype=np.bool_),
                                      self._cols, self._empty_border, self._empty_corner, 0, 0)
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

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """A^-1 rhs (only if ``definite``)."""
        x = self._band_solve(rhs)
        if self._U.shape[1]:
            x -= self._AU @ np.linalg.solve(self._capacitance, self._U.T @ x)
        return x


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
def _accumulate_row_gram(indptr, indices, data, d, include, band):  # pragma: no cover - compiled
    """Add d_j J[:, j] J[:, j]^T of every included column j to the lower band (rows x rows)."""
    for j in range(indptr.size - 1):
        if not include[j]:
            continue
        for a in range(indptr[j], indptr[j + 1]):
            ra, va = indices[a], d[j] * data[a]
            for b in range(indptr[j], indptr[j + 1]):
                rb = indices[b]
                if rb >= ra:
                    band[rb - ra, ra] += va * data[b]
