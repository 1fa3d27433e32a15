"""The equality-constrained step of a strand problem: the saddle system

    [[W_F, J_F^T], [J_F, 0]] [d_F; lam] = -[g_F; c],    W = diag(w),

solved by band LU with its unknowns interleaved along the strand (the optimality measure, the
SQP steps and the linear start of ``asc`` all take it).
"""
from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from . import lapack
from .band import csc_arrays, dense_columns
from .compressed import csc_matvec, csc_rmatvec
from .identity import IdentityMemo
from .timing import LINEAR_ALGEBRA, timed


class SaddleFactor:
    """The factored saddle system [[W_F, J_F^T], [J_F, 0]] of a Jacobian J, weights w and free set F
    (W = diag(w) + ``curvature``: None, a sparse symmetric matrix, or its (rows, columns, values)
    triplets, duplicates summed), for several right-hand sides:
    ``solve(gradient, c)`` is one pair of triangular solves. ``singular`` when the system is (J_F
    rank deficient: more constraints than free directions); then ``solve`` must not be called.

    Factored by an LU with partial pivoting of the free variables' system, its unknowns interleaved
    along the strand (each parameter next to the rows its column touches): the order of J's pattern
    (_saddle_order, shared by the strands of a size) with the variables off F left out
    (_reduced_saddle_band). The system is then a band (half-width 25 on a 100-vertex element strand with
    every variable free, 19 at the linear start, whose stiffness multipliers are fixed) that
    LAPACK's dgbtrf factors in O(n), about 2.5 times faster than SuperLU; a solve (dgbtrs) costs
    about a fifth of the factorization (27 against 151 us at 100 vertices). A column that fills
    most rows (the strand multiplier of ``stiffness="strand"``) would make the band full: then SuperLU on the
    system of F alone, assembled in compressed columns. ``curvature`` (the constraints' curvature in
    the exact Hessian of a Lagrangian, asc's Newton-SQP) couples the entries of each stencil, which
    sit next to each other in the interleaved order: it widens the band a little. Where the system
    is numerically but not exactly singular, the band LU goes through and the solution is huge
    (SuperLU, given such systems from long-hair strands, printed BLAS errors on stdout and raised).
    """

    @timed(LINEAR_ALGEBRA)
    def __init__(self, J, w, free, curvature=None):
        self.free = np.asarray(free, dtype=bool)
        self.rows, self.n = J.shape
        self.w, self.plain = w, curvature is None
        self.singular = bool(self.free.sum() < self.rows)  # J_F cannot have full row rank
        if self.singular:
            return
        indptr, indices, data = csc_arrays(J)
        w = np.asarray(w, dtype=float)
        order = _saddle_order(indptr, indices, self.rows)
        self._band = order is not None
        if self._band:
            rows, columns, values = _free_entries(curvature, self.free)
            self._kept, self._position, self._half, self._lu, self._pivots, info = _factored_band(
                lapack.DGBTRF, indptr, indices, data, w, self.free, order[0], rows, columns, values)
            self.singular = info != 0
        else:
            system = _free_system(J, indptr, indices, data, w, self.free, curvature)
            try:
                self._lu = splu(system)
            except RuntimeError:
                self.singular = True

    @timed(LINEAR_ALGEBRA)
    def solve(self, gradient, c):
        """(d, lam) of [[W_F, J_F^T], [J_F, 0]] [d_F; lam] = -[gradient_F; c], d = 0 off F."""
        n = self.n
        if self._band:
            return _band_solution(lapack.DGBTRS, self._lu, self._half, self._pivots, self._kept, self._position,
                                  np.ascontiguousarray(gradient, dtype=float), np.ascontiguousarray(c, dtype=float),
                                  n, self.rows)
        rhs = -np.concatenate([np.where(self.free, gradient, 0.0), c])
        reduced = self._lu.solve(np.concatenate([rhs[:n][self.free], rhs[n:]]))
        solution = np.zeros(n + self.rows)
        size = reduced.size - self.rows
        solution[np.flatnonzero(self.free)] = reduced[:size]
        solution[n:] = reduced[size:]
        return np.where(self.free, solution[:n], 0.0), solution[n:]

    def solve_nearby(self, J, gradient, c, accuracy: float):
        """(d, lam) of the saddle system of another Jacobian J (same weights, no curvature, same free
        set) from this factorization, by iterative refinement, or None where it does not converge
        within REFINEMENTS corrections: each correction solves this system for the residual of J's,
        so the error contracts by ~|K^-1 (K_J - K)|, small for the J of a nearby p (the point after
        the SQP step that this factor made). Converged when a correction moves d by at most
        ``accuracy`` (absolute, p's units: near a KKT point d is ~1e-10 and the rounding of the
        residual's O(1) terms that cancel leaves it 1e-14..1e-11 of noise, whatever the
        factorization) and lam by at most REFINED of its largest entry. After the SQP step of
        asc, one correction reaches that noise; each (two triangular solves and two products with J)
        takes about a third of a band LU's time (54 against 151 us at 100 vertices)."""
        gradient, c = np.asarray(gradient, dtype=float), np.asarray(c, dtype=float)
        if self._band:  # the loop below in one compiled call, the same arithmetic
            indptr, indices, data = csc_arrays(J)
            converged, d, lam = refined_band_solution(
                lapack.DGBTRS, self._lu, self._half, self._pivots, self._kept, self._position, indptr, indices,
                data, np.ascontiguousarray(self.w, dtype=float), self.free, np.ascontiguousarray(gradient),
                np.ascontiguousarray(c), accuracy, REFINEMENTS, REFINED)
            return (d, lam) if converged else None
        d, lam = self.solve(gradient, c)
        for _ in range(REFINEMENTS):
            # K_J [d; lam] + [gradient_F; c] on the free rows and the constraints: the residual
            residual_gradient = np.where(self.free, gradient + self.w * d + J.T @ lam, 0.0)
            step, step_lam = self.solve(residual_gradient, c + J @ d)
            d += step
            lam += step_lam
            if not (np.all(np.isfinite(step)) and np.all(np.isfinite(step_lam))):
                return None
            if (np.abs(step).max(initial=0.0) <= accuracy
                    and np.abs(step_lam).max(initial=0.0) <= REFINED * np.abs(lam).max(initial=0.0)):
                return d, lam
        return None


def band_order(indptr, indices, rows: int) -> np.ndarray | None:
    """The position of each unknown [d; lam] in the band order of the saddle system of J (its
    compressed columns' pattern, ``rows`` rows; _saddle_order, shared by the strands of a size), or
    None where a dense column leaves SuperLU to factor it: the ``position`` of ``plain_band_step``."""
    order = _saddle_order(indptr, indices, rows)
    return None if order is None else order[0]


@numba.njit(cache=True)
def plain_band_step(dgbtrf, dgbtrs, indptr, indices, data, w, free, position, gradient, c):  # pragma: no cover
    """(singular, d, lam): ``SaddleFactor(J, w, free).solve(gradient, c)`` without curvature, callable
    from compiled code (J in compressed columns, ``position`` from ``band_order``, the LAPACK
    addresses of linalg.lapack), the same arithmetic; singular as SaddleFactor.singular (then d and
    lam are empty)."""
    n, rows = indptr.size - 1, c.size
    count = 0
    for j in range(n):
        count += free[j]
    if count < rows:
        return True, np.empty(0), np.empty(0)
    none = np.zeros(0, dtype=np.int64)
    kept, reduced, half, band, pivots, info = _factored_band(dgbtrf, indptr, indices, data, w, free, position, none,
                                                             none, np.zeros(0))
    if info != 0:
        return True, np.empty(0), np.empty(0)
    d, lam = _band_solution(dgbtrs, band, half, pivots, kept, reduced, gradient, c, n, rows)
    return False, d, lam


@numba.njit(cache=True)
def band_factors(dgbtrf, indptr, indices, data, w, free, position, curvature_rows, curvature_columns,
                 curvature_values):  # pragma: no cover - compiled
    """(factors, half-bandwidth, pivots, kept, reduced positions, free) of ``SaddleFactor(J, w,
    free, curvature)`` as it holds them, for compiled code (J in compressed columns, ``position``
    from ``band_order``, the curvature as triplets between free variables); no_band_factors()
    where the system is singular."""
    n, rows = indptr.size - 1, position.size - (indptr.size - 1)
    count = 0
    for j in range(n):
        count += free[j]
    if count < rows:
        return no_band_factors()
    kept, reduced, half, band, pivots, info = _factored_band(dgbtrf, indptr, indices, data, w, free, position,
                                                             curvature_rows, curvature_columns, curvature_values)
    if info != 0:
        return no_band_factors()
    return band, half, pivots, kept, reduced, free.copy()


@numba.njit(cache=True)
def plain_band_factors(dgbtrf, indptr, indices, data, w, free, position):  # pragma: no cover - compiled
    """``band_factors`` without curvature (SaddleFactor(J, w, free))."""
    none = np.zeros(0, dtype=np.int64)
    return band_factors(dgbtrf, indptr, indices, data, w, free, position, none, none, np.zeros(0))


@numba.njit(cache=True)
def solve_band_factors(dgbtrs, factors, gradient, c):  # pragma: no cover - compiled
    """(d, lam) of SaddleFactor.solve from ``band_factors``' tuple."""
    band, half, pivots, kept, reduced, _ = factors
    return _band_solution(dgbtrs, band, half, pivots, kept, reduced, gradient, c, gradient.size, c.size)


@numba.njit(cache=True)
def no_band_factors():  # pragma: no cover - compiled
    """``band_factors``' tuple of no factorization (its factors empty)."""
    return (np.empty((0, 0)), np.int64(0), np.empty(0, dtype=np.int32), np.empty(0, dtype=np.int64),
            np.empty(0, dtype=np.int64), np.empty(0, dtype=np.bool_))


#: corrections of SaddleFactor.solve_nearby before it gives up, and the relative size of a last
#: correction of the multipliers that ends it
REFINEMENTS = 4
REFINED = 1e-10


def constrained_step(J, w, gradient, c, free, nearby: SaddleFactor | None = None, accuracy: float = 1e-9):
    """(d, lam) of [[W_F, J_F^T], [J_F, 0]] [d_F; lam] = -[gradient_F; c] with W = diag(w), d = 0
    off F; None if the system is singular (SaddleFactor, factored for this one solve). ``nearby``:
    a factorization of the same system at a nearby p (same w, same F, no curvature), tried first
    by iterative refinement to ``accuracy`` in d (SaddleFactor.solve_nearby)."""
    if (nearby is not None and not nearby.singular and nearby.plain
            and np.array_equal(nearby.free, free) and (nearby.w is w or np.array_equal(nearby.w, w))):
        solution = nearby.solve_nearby(J, gradient, c, accuracy)
        if solution is not None:
            return solution
    factor = SaddleFactor(J, w, free)
    return None if factor.singular else factor.solve(gradient, c)


def _free_system(J, indptr, indices, data, w, free, curvature) -> sp.csc_matrix:
    """[[W_FF, J_F^T], [J_F, 0]] on the free variables alone, in compressed columns (SaddleFactor's
    SuperLU path)."""
    if curvature is not None:
        if isinstance(curvature, tuple):
            rows, columns, values = curvature
            curvature = sp.csr_matrix((values, (rows, columns)), shape=(J.shape[1],) * 2)
        columns = np.flatnonzero(free)
        J_free = sp.csc_matrix((data, indices, indptr), shape=J.shape)[:, columns]
        W_free = sp.csr_matrix(sp.diags(w) + curvature)[columns][:, columns]
        return sp.bmat([[W_free, J_free.T], [J_free, None]], format="csc")
    row_csr = sp.csc_matrix((data, indices, indptr), shape=J.shape).tocsr()
    size, rows = int(free.sum()), J.shape[0]
    inside = np.cumsum(free) - 1  # index of each free variable in d_F
    return sp.csc_matrix(_kkt_system(indptr, indices, data, row_csr.indptr.astype(np.int64),
                                     row_csr.indices.astype(np.int64), row_csr.data, w, free, inside, size),
                         shape=(size + rows, size + rows))


#: interleaved orders of saddle systems by J's pattern (_saddle_order): the strands of a groom share a few
_ORDERS: dict = {}


def _saddle_order(indptr, indices, rows):
    """(position of each unknown [d; lam] in the band order, half-bandwidth) of the system
    [[W, J^T], [J, 0]], or None if a column of J fills most rows. A parameter is placed at the
    middle row its column touches (an empty column after the previous parameter), the rows of J
    at their own index; sorted stably, parameters before rows at the same place."""
    known = _ORDERS_BY_ARRAYS.get((indptr, indices), rows)
    if known is not None:
        return known
    key = (rows, indptr.tobytes(), indices.tobytes())
    if key in _ORDERS:
        return _ORDERS_BY_ARRAYS.put((indptr, indices), rows, _ORDERS[key])
    counts = np.diff(indptr)
    if np.any(dense_columns(indptr, rows)):
        order = None
    else:
        n = counts.size
        filled = counts > 0
        middle = np.zeros(n)
        starts = indptr[:-1][filled]
        middle[filled] = 0.5 * (np.minimum.reduceat(indices, starts) + np.maximum.reduceat(indices, starts))
        middle = np.maximum.accumulate(np.where(filled, middle, -np.inf))  # empty: the previous place
        keys = np.concatenate([np.where(np.isfinite(middle), middle, 0.0), np.arange(rows) + 0.25])
        position = np.empty(n + rows, dtype=np.int64)
        position[np.argsort(keys, kind="stable")] = np.arange(n + rows)
        column = np.repeat(np.arange(n), counts)
        half = int(np.abs(position[column] - position[n + indices]).max(initial=0))
        order = (position, half)
    if len(_ORDERS) >= 16:
        _ORDERS.pop(next(iter(_ORDERS)))
    _ORDERS[key] = order
    return _ORDERS_BY_ARRAYS.put((indptr, indices), rows, order)


#: the same orders by the identity of J's index arrays: a StrandJacobian's are its pattern's, shared
#: by every Jacobian of a strand and by the strands of a groom (jacobian._STRUCTURES), and hashing
#: their bytes for _ORDERS cost ~14 us per factorization
_ORDERS_BY_ARRAYS = IdentityMemo()


@numba.njit(cache=True)
def _factored_band(dgbtrf, indptr, indices, data, w, free, position, curvature_rows, curvature_columns,
                   curvature_values):  # pragma: no cover - compiled
    """(kept, positions, half-bandwidth, LU factors, pivots, LAPACK info) of the saddle system of
    the free variables (_reduced_saddle_band), factored by LAPACK's dgbtrf (linalg.lapack)."""
    kept, reduced, half, band = _reduced_saddle_band(indptr, indices, data, w, free, position, curvature_rows,
                                                     curvature_columns, curvature_values)
    pivots = np.empty(band.shape[0], dtype=np.int32)
    info = lapack.band_lu(dgbtrf, band, half, half, pivots)
    return kept, reduced, half, band, pivots, info


@numba.njit(cache=True)
def _band_solution(dgbtrs, factors, half, pivots, kept, position, gradient, c, n, rows):  # pragma: no cover
    """(d, lam) of SaddleFactor.solve from _factored_band's factors: -[gradient; c] permuted into the
    band order, LAPACK's dgbtrs, and back (d zero off the kept parameters)."""
    permuted = _permuted_rhs(gradient, c, kept, position)
    lapack.band_lu_solve(dgbtrs, factors, half, half, pivots, permuted)
    return _unpermuted(permuted, kept, position, n, rows)


@numba.njit(cache=True)
def refined_band_solution(dgbtrs, factors, half, pivots, kept, position, indptr, indices, data, w, free, gradient,
                          c, accuracy, refinements, refined):  # pragma: no cover - compiled
    """(converged, d, lam) of SaddleFactor.solve_nearby's refinement on the band factors, for the
    Jacobian (indptr, indices, data) in compressed columns."""
    n, rows = gradient.size, c.size
    d, lam = _band_solution(dgbtrs, factors, half, pivots, kept, position, gradient, c, n, rows)
    residual_gradient, residual_c = np.empty(n), np.empty(rows)
    for _ in range(refinements):
        pulled = csc_rmatvec(indptr, indices, data, lam)
        for j in range(n):
            residual_gradient[j] = gradient[j] + w[j] * d[j] + pulled[j] if free[j] else 0.0
        moved = csc_matvec(indptr, indices, data, d, rows)
        for r in range(rows):
            residual_c[r] = c[r] + moved[r]
        step, step_lam = _band_solution(dgbtrs, factors, half, pivots, kept, position, residual_gradient, residual_c,
                                        n, rows)
        finite, largest_step, largest_step_lam, largest_lam = True, 0.0, 0.0, 0.0
        for j in range(n):
            d[j] += step[j]
            finite &= np.isfinite(step[j])
            largest_step = max(largest_step, abs(step[j]))
        for r in range(rows):
            lam[r] += step_lam[r]
            finite &= np.isfinite(step_lam[r])
            largest_step_lam = max(largest_step_lam, abs(step_lam[r]))
            largest_lam = max(largest_lam, abs(lam[r]))
        if not finite:
            return False, d, lam
        if largest_step <= accuracy and largest_step_lam <= refined * largest_lam:
            return True, d, lam
    return False, d, lam


@numba.njit(cache=True)
def _reduced_saddle_band(indptr, indices, data, w, free, position, curvature_rows, curvature_columns,
                         curvature_values):  # pragma: no cover - compiled
    """(kept, positions, half-bandwidth, band) of the saddle system of the free variables: the
    unknowns kept (the free parameters, then the rows: indices into [d; lam]), the position of each
    in the band order of the system without the others (which keep their relative order from
    ``position``, _saddle_order; -1 for those left out), and the band of _saddle_band. One
    compiled call: the same steps in numpy cost ~50 us of Python around a 100-vertex strand's
    0.2 ms factorization."""
    n, rows = indptr.size - 1, position.size - (indptr.size - 1)
    kept = np.empty(position.size, dtype=np.int64)
    size = 0
    for j in range(n):
        if free[j]:
            kept[size] = j
            size += 1
    for r in range(rows):
        kept[size] = n + r
        size += 1
    kept = kept[:size]
    in_order = np.zeros(position.size, dtype=np.bool_)
    for k in kept:
        in_order[position[k]] = True
    rank = np.empty(position.size, dtype=np.int64)
    count = -1
    for k in range(position.size):
        count += in_order[k]
        rank[k] = count
    reduced = np.full(position.size, -1, dtype=np.int64)
    for k in kept:
        reduced[k] = rank[position[k]]
    half = _reduced_half(indptr, indices, free, reduced, curvature_rows, curvature_columns)
    band = _saddle_band(indptr, indices, data, w, free, reduced, size, half, curvature_rows, curvature_columns,
                        curvature_values)
    return kept, reduced, half, band


@numba.njit(cache=True)
def _permuted_rhs(gradient, c, kept, position):  # pragma: no cover - compiled
    """-[gradient; c] on the kept unknowns, in the band order (SaddleFactor.solve)."""
    n = gradient.size
    out = np.empty(kept.size)
    for k in kept:
        out[position[k]] = -(gradient[k] if k < n else c[k - n])
    return out


@numba.njit(cache=True)
def _unpermuted(reduced, kept, position, n, rows):  # pragma: no cover - compiled
    """(d, lam) from the band-ordered solution: d zero off the kept parameters."""
    d, lam = np.zeros(n), np.empty(rows)
    for k in kept:
        if k < n:
            d[k] = reduced[position[k]]
        else:
            lam[k - n] = reduced[position[k]]
    return d, lam


@numba.njit(cache=True)
def _reduced_half(indptr, indices, free, position, curvature_rows, curvature_columns):  # pragma: no cover
    """Half-bandwidth of the saddle system of the free variables in the order ``position``: the
    largest distance between a free parameter and a row of its column, or two coupled parameters."""
    n = indptr.size - 1
    half = 0
    for j in range(n):
        if free[j]:
            for k in range(indptr[j], indptr[j + 1]):
                half = max(half, abs(position[j] - position[n + indices[k]]))
    for k in range(curvature_rows.size):
        half = max(half, abs(position[curvature_rows[k]] - position[curvature_columns[k]]))
    return half


def _free_entries(matrix, free):
    """(rows, columns, values) of a sparse matrix's (or a triplet tuple's) entries between free
    variables (None: none)."""
    if matrix is None:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0)
    if isinstance(matrix, tuple):
        rows, columns, values = (np.asarray(a) for a in matrix)
    else:
        coo = sp.coo_matrix(matrix)
        rows, columns, values = coo.row, coo.col, coo.data
    keep = free[rows] & free[columns]
    return rows[keep].astype(np.int64), columns[keep].astype(np.int64), values[keep].astype(float)


@numba.njit(cache=True)
def _saddle_band(indptr, indices, data, w, free, position, size, half, curvature_rows, curvature_columns,
                 curvature_values):  # pragma: no cover - compiled
    """[[W_FF + C_FF, J_F^T], [J_F, 0]] (W = diag(w), C the curvature entries between free variables
    as triplets) in LAPACK general band storage for dgbtrf, its ``size`` unknowns (the free
    parameters and the rows) at ``position`` (-1: left out): entry (i, j) of the permuted system at
    columns[j, 2 half + i - j] (linalg.lapack's layout: LAPACK's Fortran band, column by column)."""
    n = indptr.size - 1
    columns = np.zeros((size, 3 * half + 1))  # columns[j, r] = band[r, j]
    for j in range(n):
        if free[j]:
            pj = position[j]
            columns[pj, 2 * half] = w[j]
            for k in range(indptr[j], indptr[j + 1]):
                pr = position[n + indices[k]]
                columns[pj, 2 * half + pr - pj] = data[k]  # J: row r, column j
                columns[pr, 2 * half + pj - pr] = data[k]  # J^T: row j, column r
    for k in range(curvature_values.size):
        pi, pj = position[curvature_rows[k]], position[curvature_columns[k]]
        columns[pj, 2 * half + pi - pj] += curvature_values[k]
    return columns


@numba.njit(cache=True)
def _kkt_system(indptr, indices, data, row_indptr, row_indices, row_data, w, free, position,
                size):  # pragma: no cover - compiled
    """(data, indices, indptr) of [[diag(w_F), J_F^T], [J_F, 0]] in compressed columns, from J's
    columns (CSC) and rows (CSR)."""
    rows = row_indptr.size - 1
    nnz = size
    for j in range(indptr.size - 1):
        if free[j]:
            nnz += 2 * (indptr[j + 1] - indptr[j])
    out_indptr = np.zeros(size + rows + 1, dtype=np.int64)
    out_indices = np.empty(nnz, dtype=np.int64)
    out_data = np.empty(nnz)
    k = 0
    for j in range(indptr.size - 1):  # the columns of d_F: w_j, then J's column j below
        if not free[j]:
            continue
        out_indices[k], out_data[k] = position[j], w[j]
        k += 1
        for e in range(indptr[j], indptr[j + 1]):
            out_indices[k], out_data[k] = size + indices[e], data[e]
            k += 1
        out_indptr[position[j] + 1] = k
    for r in range(rows):  # the columns of lam: J's row r, on the free variables
        for e in range(row_indptr[r], row_indptr[r + 1]):
            if free[row_indices[e]]:
                out_indices[k], out_data[k] = position[row_indices[e]], row_data[e]
                k += 1
        out_indptr[size + r + 1] = k
    return out_data, out_indices, out_indptr
