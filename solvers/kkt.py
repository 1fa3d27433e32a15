"""First-order optimality of the bound-constrained problem, measured the same way for every solver.

    minimize R(p)  s.t.  c(p) = 0,  lower <= p <= upper;   Lagrangian gradient  grad R + J^T lam.

A rest-length entry moves c about 1e7 times more than a stiffness multiplier, so gradients are
compared in the scaled projected gradient pi(p, g) = ||P(p - g / h) - p||_inf with h_j = w_j +
||J_{:,j}||^2 (the Gauss-Newton diagonal): a Newton-like step in the units of p, the same for every
block, zero exactly at a KKT point.
"""
from __future__ import annotations

import numba
import numpy as np
import scipy.linalg.lapack
import scipy.sparse as sp
import scipy.sparse.linalg  # noqa: F401 - sp.linalg.splu

from sagfree.formulation.jacobian import StrandJacobian
from sagfree.formulation.problem import Problem

from .banded import NormalFactor, csc_arrays, dense_columns

#: KKT distance (kkt_optimality, in the units of p) below which every solver's status may be
#: ``converged``. 1e-6 is below what rounding allows on some 200-vertex strands (2.1e-6 at the best
#: point ours or Ipopt found on `groom(10, 200, seed=0)[9]`, where Ipopt ends at 2.5e-5).
TOLERANCE = 1e-5


def scaled_projected_gradient(p, gradient, scale, lower, upper) -> float:
    """||P(p - gradient / scale) - p||_inf: zero exactly at a KKT point of a box-constrained problem."""
    return float(np.abs(np.clip(p - gradient / scale, lower, upper) - p).max(initial=0.0))


def column_norms(J: sp.spmatrix | StrandJacobian) -> np.ndarray:
    """||J_{:,j}||^2 per parameter (summed per CSC column: J.multiply(J) cost 0.2 ms per call)."""
    if isinstance(J, StrandJacobian):
        return J.column_norms()
    J = sp.csc_matrix(J)
    norms = np.zeros(J.shape[1])
    filled = np.diff(J.indptr) > 0
    norms[filled] = np.add.reduceat(J.data**2, J.indptr[:-1][filled])
    return norms


def gradient_scale(weights: np.ndarray, J: sp.csc_matrix) -> np.ndarray:
    """h_j = w_j + ||J_{:,j}||^2, the diagonal of the Gauss-Newton Hessian at mu = 1."""
    return weights + column_norms(J) + 1e-300


def least_squares_multipliers(regularizer_gradient, J, scale, p, lower, upper) -> np.ndarray:
    """lam minimizing the scaled Lagrangian gradient on the free variables F,
    ||(grad R + J^T lam)_F / sqrt(h_F)||_2 (a feasible p's multipliers), from the normal equations
    A lam = -J_F (grad R / h)_F with A = J_F diag(h_F)^-1 J_F^T (banded.NormalFactor, banded with
    the strand multiplier's dense column added back by Woodbury), plus one step of the corrected
    semi-normal equations: lam += A^-1 (-J_F e_F), e = (grad R + J^T lam) / h. Normal equations
    square J's condition number: at the linear start and the optimum of 28 groom strands of 60-400
    vertices the multipliers were up to 1.2e-4 (relative) off numpy's least squares after the
    first solve, 1.3e-8 after the correction.
    NaN if A is singular (J_F rank deficient); the caller then keeps its multipliers.
    """
    free = (p > lower) & (p < upper)
    factor = NormalFactor(J, 1.0 / scale, free, shift=1e-14)
    if not factor.definite:
        return np.full(J.shape[0], np.nan)
    lam = np.zeros(J.shape[0])
    for _ in range(2):  # the solve, then the correction
        lam += factor.solve(-(J @ np.where(free, (regularizer_gradient + J.T @ lam) / scale, 0.0)))
    return lam


def constrained_step(J, w, regularizer_gradient, c, free):
    """(d, lam) of [[W_F, J_F^T], [J_F, 0]] [d_F; lam] = -[grad R_F; c] with W = diag(w), d = 0 off
    F; None if the system is singular (J_F rank deficient: more constraints than free directions).

    Solved by an LU with partial pivoting of the whole system. The variables off F are kept as
    unknowns with the rows d_j = 0, so the system's pattern is J's whatever F is, and its unknowns
    are interleaved along the strand (each parameter next to the rows its column touches,
    _saddle_order): the system is then a band (half-widths 25 on a 100-vertex element strand, 982
    unknowns; 25 at 400 vertices) that LAPACK's dgbsv factors in ~0.4 ms, against ~1 ms for SuperLU
    on the free variables' system of the same strand and ~1.9 ms with scipy's bmat assembly before.
    A column that fills most rows (the strand multiplier of ``stiffness="strand"``) would make the
    band full: then SuperLU on the system of F alone, assembled in compressed columns (_kkt_system;
    with the rows d_j = 0 kept and scipy's bmat it took 2.0 ms instead of 1.3 ms on a 100-vertex
    strand).
    """
    if free.sum() < J.shape[0]:  # J_F cannot have full row rank
        return None
    indptr, indices, data = csc_arrays(J)
    rows, n = J.shape
    w = np.asarray(w, dtype=float)
    rhs = -np.concatenate([np.where(free, regularizer_gradient, 0.0), c])
    order = _saddle_order(indptr, indices, rows)
    if order is not None:
        position, half = order
        band = _saddle_band(indptr, indices, data, w, free, position, half)
        permuted = np.empty_like(rhs)
        permuted[position] = rhs
        _, _, solution, info = scipy.linalg.lapack.dgbsv(half, half, band, permuted, overwrite_ab=True,
                                                         overwrite_b=True)
        if info != 0:
            return None
        solution = solution[position]
    else:
        row_csr = sp.csc_matrix((data, indices, indptr), shape=J.shape).tocsr()
        size = int(free.sum())
        inside = np.cumsum(free) - 1  # index of each free variable in d_F
        system = sp.csc_matrix(_kkt_system(indptr, indices, data, row_csr.indptr.astype(np.int64),
                                           row_csr.indices.astype(np.int64), row_csr.data, w, free, inside,
                                           size), shape=(size + rows, size + rows))
        try:
            reduced = sp.linalg.splu(system).solve(np.concatenate([rhs[:n][free], rhs[n:]]))
        except RuntimeError:
            return None
        solution = np.zeros(n + rows)
        solution[np.flatnonzero(free)] = reduced[:size]
        solution[n:] = reduced[size:]
    return np.where(free, solution[:n], 0.0), solution[n:]


#: interleaved orders of saddle systems by J's pattern (_saddle_order): the strands of a groom share a few
_ORDERS: dict = {}


def _saddle_order(indptr, indices, rows):
    """(position of each unknown [d; lam] in the band order, half-bandwidth) of the system
    [[W, J^T], [J, 0]], or None if a column of J fills most rows. A parameter is placed at the
    middle row its column touches (an empty column after the previous parameter), the rows of J
    at their own index; sorted stably, parameters before rows at the same place."""
    key = (rows, indptr.tobytes(), indices.tobytes())
    if key in _ORDERS:
        return _ORDERS[key]
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
    return order


@numba.njit(cache=True)
def _saddle_band(indptr, indices, data, w, free, position, half):  # pragma: no cover - compiled
    """[[W_F + I_A, J_F^T], [J_F, 0]] (I_A: the rows d_j = 0 of the variables off F) in LAPACK
    general band storage for dgbsv: entry (i, j) of the permuted system at [2 half + i - j, j]."""
    n = indptr.size - 1
    size = position.size
    band = np.zeros((3 * half + 1, size))
    for j in range(n):
        pj = position[j]
        if free[j]:
            band[2 * half, pj] = w[j]
            for k in range(indptr[j], indptr[j + 1]):
                pr = position[n + indices[k]]
                band[2 * half + pr - pj, pj] = data[k]  # J: row r, column j
                band[2 * half + pj - pr, pr] = data[k]  # J^T: row j, column r
        else:
            band[2 * half, pj] = 1.0
    return band


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


def kkt_optimality(problem: Problem, p: np.ndarray, near: float = 1e-6) -> float:
    """Distance of p from a KKT point, in the units of p (zero exactly at a KKT point): the largest
    entry of the equality-constrained SQP step with the regularizer's Hessian
    W = diag(w) on a working set F of free variables,

        [[W_F, J_F^T], [J_F, 0]] [d_F; lam] = -[grad R_F; c]      (constrained_step),

    where F starts as the variables farther than ``near`` (relative to the box width) from their
    bounds (interior-point solvers stop a hair inside them) and is corrected (at most 10 times) like
    an active-set method: a bound variable whose multiplier (grad R + J^T lam)_j has the wrong sign
    (< 0 at a lower bound, > 0 at an upper one) is released. Any wrong sign left at the end counts
    too, scaled by h as in ``scaled_projected_gradient``. If the system is singular (fewer free
    variables than constraints: strand 1 of groom(6, 400, seed=13) had 1591 for 1592 at its optimum,
    with 579 within ``near`` of a bound but not on it), F becomes the variables not on a bound;
    infinite if it is singular still.

    Unlike the scaled projected gradient, this sees directions in which c can be kept by trading
    one parameter against another (the strand multiplier S against the rest shape): there the
    gradient step g / h is tiny, because h is dominated by ||J_{:,j}||^2, while the constrained
    step is not.
    """
    J = problem.strand_jacobian(p)
    c, regularizer_gradient = problem.residual(p), problem.objective_gradient(p)
    w, lower, upper = problem.layout.weights, problem.layout.lower, problem.layout.upper
    slack = near * (upper - lower)
    at_lower = p - lower <= upper - p
    active = (p - lower <= slack) | (upper - p <= slack)
    scale = gradient_scale(w, J)
    for _ in range(10):
        solution = constrained_step(J, w, regularizer_gradient, c, ~active)
        if solution is None:  # too few free directions: free the variables near but not on a bound
            loose = active & (p > lower) & (p < upper)
            if not loose.any():
                return float("inf")
            active &= ~loose
            continue
        step, lam = solution
        gradient = regularizer_gradient + J.T @ lam  # >= 0 at a lower bound, <= 0 at an upper
        # wrong-signed bound multipliers, above rounding (a 1e-3 share of the tolerance in the
        # scaled measure): releasing rounding-level ones only re-solved the same system
        wrong = active & (np.where(at_lower, -gradient, gradient) > 1e-3 * TOLERANCE * scale)
        if not wrong.any():
            break
        active &= ~wrong
    wrong_size = np.where(wrong, np.abs(gradient), 0.0) / scale
    return max(float(np.abs(step).max(initial=0.0)), float(wrong_size.max(initial=0.0)))
