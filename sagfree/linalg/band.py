"""Bordered banded symmetric matrices: storage, products and J^T J.

The Gauss-Newton Hessian H = diag(R'') + mu J^T J is banded when p is ordered along the strand
(element stiffness), except for the single strand multiplier of ``stiffness="strand"``, which couples
to everything. So H is stored as a band of the first nb = n - m variables plus a dense border of the
last m (m = 0 or 1):

    H = [[B, C^T], [C, D]],  B banded (lower storage band[k, j] = B[j + k, j], k = 0..w),
    C dense (m, nb), D dense (m, m).
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import scipy.sparse as sp


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
    for k in range(1, w1):  # a 1-D row and two loops: each vectorizes (3.7x faster), same sums
        row = band[k]
        for j in range(nb - k):
            out[j + k] += row[j] * x[j]
        for j in range(nb - k):
            out[j] += row[j] * x[j + k]
    for r in range(m):
        s = 0.0
        for j in range(nb):
            out[j] += border[r, j] * x[nb + r]
            s += border[r, j] * x[j]
        for c in range(m):
            s += corner[r, c] * x[nb + c]
        out[nb + r] = s


@numba.njit(cache=True)
def quadratic_form(band, d):  # pragma: no cover - compiled
    """d^T K d for K in lower band storage (band[k, j] = K[j + k, j])."""
    n, value = d.size, 0.0
    for j in range(n):
        value += band[0, j] * d[j] * d[j]
        for k in range(1, min(band.shape[0], n - j)):
            value += 2.0 * band[k, j] * d[j + k] * d[j]
    return value


@numba.njit(cache=True)
def gershgorin_bound(band, border, corner):  # pragma: no cover - compiled
    """An upper bound of the largest eigenvalue of H: the largest absolute row sum."""
    w1, nb = band.shape
    m = corner.shape[0]
    rows = np.zeros(nb + m)
    for j in range(nb):
        rows[j] += abs(band[0, j])
    for k in range(1, w1):  # as in matvec: two loops per diagonal vectorize
        row = band[k]
        for j in range(nb - k):
            rows[j + k] += abs(row[j])
        for j in range(nb - k):
            rows[j] += abs(row[j])
    for r in range(m):
        for j in range(nb):
            rows[j] += abs(border[r, j])
            rows[nb + r] += abs(border[r, j])
        for c in range(m):
            rows[nb + r] += abs(corner[r, c])
    return rows.max()


def gram(J, diagonal: np.ndarray, scale: float, border: int) -> BorderedBand:
    """diag(diagonal) + scale J^T J as a bordered band, accumulated row by row from J (no sparse
    matrix product): each row of J touches only the parameters of a few neighbouring elements."""
    indptr, indices, data = csr_arrays(J)
    return BorderedBand(*gram_arrays(indptr, indices, data, np.asarray(diagonal, dtype=float), float(scale),
                                     border))


@numba.njit(cache=True)
def gram_arrays(indptr, indices, data, diagonal, scale, border):  # pragma: no cover - compiled
    """(band, border, corner) of ``gram`` from J's compressed rows (sorted indices)."""
    nb = diagonal.size - border
    width = _row_span(indptr, indices, nb)
    columns = np.zeros((nb, width + 1))  # columns[j, k] = band[k, j]: a row's updates of a column are contiguous
    for j in range(nb):
        columns[j, 0] = diagonal[j]
    bord = np.zeros((border, nb))
    corner = np.zeros((border, border))
    for r in range(border):
        corner[r, r] = diagonal[nb + r]
    _accumulate_gram(indptr, indices, data, nb, scale, columns, bord, corner)
    return np.ascontiguousarray(columns.T), bord, corner


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
def _accumulate_gram(indptr, indices, data, nb, scale, columns, border, corner):  # pragma: no cover
    """Add scale J^T J, each pair of a row's entries once (the row's columns are sorted, so the
    band columns come first and border columns last); the band part into ``columns`` (the band
    transposed: columns[j, k] = band[k, j]; striding across the band's rows made a 100-vertex
    strand's Gram 93 instead of 80 us). A row's band entries go through a dense copy of the row
    (``_add_row_outer``), its border entries pair by pair. For a finite J every entry receives the
    same products in the same order (rows ascending) as pair by pair; the dense copy only adds
    products with a zero, which leave a sum unchanged (an entry starts at +0 or the diagonal, so it
    is never -0)."""
    w1 = columns.shape[1]
    dense = np.zeros(w1)
    for r in range(indptr.size - 1):
        start, stop = indptr[r], indptr[r + 1]
        split = start  # the first border entry of the row
        while split < stop and indices[split] < nb:
            split += 1
        if split > start:
            _add_row_outer(indices, data, start, split, nb, scale, columns, dense)
        for a in range(start, stop):
            ca, va = indices[a], scale * data[a]
            for b in range(max(a, split), stop):
                cb = indices[b]
                if ca < nb:
                    border[cb - nb, ca] += va * data[b]
                else:
                    corner[ca - nb, cb - nb] += va * data[b]
                    if cb != ca:
                        corner[cb - nb, ca - nb] += va * data[b]


#: The default model's band widths (rows of the band storage), for the kernels that run with the
#: width a compile-time constant (the length of these tuples: loops unrolled and vectorized, 1.6x
#: faster on a 100-vertex strand's Gauss-Newton Hessian): the
#: Gauss-Newton band with per-element stiffness (19) and strand stiffness (13), the free DOFs'
#: Hessian and the row-space normal matrix (11). Other widths take the general loops, the same
#: arithmetic.
ROWS_11, ROWS_13, ROWS_19 = (0,) * 11, (0,) * 13, (0,) * 19


@numba.njit(cache=True, inline="always")
def _add_row_outer(indices, data, start, stop, nb, scale, columns, dense):  # pragma: no cover
    """columns += scale v v^T (band part, transposed) for the row v of J with band entries
    start..stop, through ``dense`` (zeros of the band's width on entry and on exit)."""
    w1 = columns.shape[1]
    lo = indices[start]
    for a in range(start, stop):
        dense[indices[a] - lo] = data[a]
    if lo + w1 <= nb and w1 == 19:
        _dense_outer(columns, dense, lo, scale, ROWS_19)
    elif lo + w1 <= nb and w1 == 13:
        _dense_outer(columns, dense, lo, scale, ROWS_13)
    else:
        span = indices[stop - 1] - lo + 1
        for pa in range(span):
            va = scale * dense[pa]
            for pb in range(pa, span):
                columns[lo + pa, pb - pa] += va * dense[pb]
    for a in range(start, stop):
        dense[indices[a] - lo] = 0.0


@numba.njit(cache=True, inline="always")
def _dense_outer(columns, dense, lo, scale, rows):  # pragma: no cover - compiled
    """columns[lo + a, b - a] += scale dense[a] dense[b] for a <= b < len(rows) (a constant)."""
    w1 = len(rows)
    for pa in range(w1):
        va = scale * dense[pa]
        for pb in range(pa, w1):
            columns[lo + pa, pb - pa] += va * dense[pb]


def csr_arrays(J) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indptr, indices, data) of J in compressed rows with sorted int64 indices (numba kernels)."""
    if hasattr(J, "csr"):
        return J.csr()
    J = sp.csr_matrix(J)
    J = J if J.has_sorted_indices else J.sorted_indices()
    return J.indptr.astype(np.int64), J.indices.astype(np.int64), J.data


def csc_arrays(J) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indptr, indices, data) of J in compressed columns, int64 indices (numba kernels)."""
    if hasattr(J, "csc"):
        return J.csc()
    J = sp.csc_matrix(J)
    return J.indptr.astype(np.int64), J.indices.astype(np.int64), J.data


def dense_columns(indptr: np.ndarray, rows: int) -> np.ndarray:
    """Columns that fill most rows (the strand multiplier of ``stiffness="strand"``): in a band they
    would fill it, so the banded factorizations keep them apart."""
    return np.diff(indptr) > dense_count(rows)


def dense_count(rows: int) -> int:
    """Entries of a column of ``rows`` rows above which ``dense_columns`` counts it dense."""
    return max(50, rows // 5)


def column_norms(J) -> np.ndarray:
    """||J_{:,j}||^2 per column (summed per compressed column, not through J.multiply(J))."""
    if hasattr(J, "column_norms"):
        return J.column_norms()
    J = sp.csc_matrix(J)
    norms = np.zeros(J.shape[1])
    filled = np.diff(J.indptr) > 0
    norms[filled] = np.add.reduceat(J.data**2, J.indptr[:-1][filled])
    return norms


def principal_band_gather(index: np.ndarray, size: int, half_bandwidth: int) -> tuple[np.ndarray, np.ndarray]:
    """Gather map of the principal submatrix H[index][:, index] in lower band storage.

    H (size x size) is in LAPACK lower band storage band[k, j] = H[j + k, j], k = 0..w; ``index``
    sorted. Deleting rows and columns never widens a band, so the submatrix has half bandwidth <= w
    too. Returns (target, source): flat positions into the (w + 1, len(index)) result and into
    ``band``; ``principal_band(band, map)`` applies it (the prescribed DOFs of a strand leave its
    free block, anywhere along q).
    """
    index = np.asarray(index, dtype=int)
    m = index.size
    targets, sources = [], []
    for k in range(half_bandwidth + 1):
        a = np.arange(m - k)
        distance = index[a + k] - index[a]
        keep = distance <= half_bandwidth
        targets.append(k * m + a[keep])
        sources.append(distance[keep] * size + index[a[keep]])
    return np.concatenate(targets), np.concatenate(sources)


def principal_band(band: np.ndarray, gather: tuple[np.ndarray, np.ndarray], size: int) -> np.ndarray:
    """The principal submatrix of ``principal_band_gather`` (``size`` = len(index)) in band storage."""
    target, source = gather
    out = np.zeros(band.shape[0] * size)
    out[target] = band.ravel()[source]
    return out.reshape(band.shape[0], size)


def lower_band(matrix: sp.spmatrix) -> np.ndarray:
    """A symmetric sparse matrix in LAPACK lower band storage band[k, j] = A[j + k, j], its half
    bandwidth the widest of its entries."""
    coo = sp.tril(matrix).tocoo()
    width = int((coo.row - coo.col).max(initial=0))
    band = np.zeros((width + 1, matrix.shape[0]))
    np.add.at(band, (coo.row - coo.col, coo.col), coo.data)
    return band


def add_vertex_blocks(band: np.ndarray, blocks: np.ndarray, vertices: np.ndarray | None = None) -> None:
    """Add symmetric 3x3 blocks (m, 3, 3) on the consecutive DOFs 4i, 4i+1, 4i+2 of a strand's lower
    band (the vertex positions of the interleaved q) of the distinct ``vertices`` i (default: the
    first m vertices, one block each), in place."""
    first = 4 * (np.arange(len(blocks)) if vertices is None else np.asarray(vertices))
    for k in range(3):
        for j in range(3 - k):
            band[k, first + j] += blocks[:, j + k, j]


@numba.njit(cache=True)
def projected_band(band, support, values):  # pragma: no cover - compiled
    """Lower band of B^T H B for a symmetric H in lower band storage (band[k, j] = H[j + k, j]) and a
    basis B whose column a has the entries values[a, t] in the rows support[a, t] (t < 3; -1: none),
    its columns ordered along H's rows (each column's rows at or after the previous column's), so
    that B^T H B is banded too: its half bandwidth is the widest reach of a column to a later one
    whose rows come within H's. Entry by entry: the sum over both columns' rows of
    B[i, a] H[i, j] B[j, b] (Problem's stability on bodies: the Hessian on the tangent planes)."""
    reach = band.shape[0] - 1
    m = support.shape[0]
    first, last = np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64)
    for a in range(m):
        first[a], last[a] = support[a, 0], support[a, 0]
        for t in range(1, 3):
            if support[a, t] >= 0:
                first[a], last[a] = min(first[a], support[a, t]), max(last[a], support[a, t])
    width = 0
    for a in range(m):
        b = a + 1
        while b < m and first[b] - last[a] <= reach:
            b += 1
        width = max(width, b - 1 - a)
    out = np.zeros((width + 1, m))
    for a in range(m):
        for b in range(a, min(m, a + width + 1)):
            total = 0.0
            for s in range(3):
                i = support[a, s]
                if i < 0:
                    continue
                for t in range(3):
                    j = support[b, t]
                    if j < 0:
                        continue
                    low, high = min(i, j), max(i, j)
                    if high - low <= reach:
                        total += values[a, s] * band[high - low, low] * values[b, t]
            out[b - a, a] = total
    return out
