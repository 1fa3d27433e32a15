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
import scipy.sparse as sp
import scipy.sparse.linalg  # noqa: F401 - sp.linalg.splu

from sagfree.formulation.jacobian import StrandJacobian
from sagfree.formulation.problem import Problem

from .banded import NormalFactor

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
    square J's condition number; on a 60-vertex element strand with bound variables the
    multipliers without that correction were ~20% off the least-squares optimum.
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


def constrained_step(J, w, regularizer_gradient, c, free, method: str = "lu"):
    """(d, lam) of [[W_F, J_F^T], [J_F, 0]] [d_F; lam] = -[grad R_F; c] with W = diag(w), d = 0 off
    F; None if the system is singular (J_F rank deficient: more constraints than free directions).

    method "lu": the sparse LU of the full system, assembled directly in compressed columns
    (_kkt_system; scipy's bmat took 0.56 of the ~1.9 ms this cost on a 100-vertex strand).
    method "schur" (needs w_F > 0): the Schur complement A = J_F W_F^-1 J_F^T, which is banded
    (banded.NormalFactor, ~0.2 ms): A lam = c - J_F W_F^-1 grad R_F, d_F = -W_F^-1 (grad R + J^T
    lam)_F, then one step of iterative refinement on the full system. It squares cond(J_F): at the
    groom strands' optima, where the free rest-length columns are ~1e8 times the stiffness
    columns and cond(J_F) reaches ~4e8, its Cholesky broke down or lost every digit on most
    strands, so the KKT measure uses "lu". On the rest blocks at p0 (alm's linear start) the two
    steps differed by at most 6e-5 of the largest entry over 65 groom strands of 25-400 vertices.
    """
    if free.sum() < J.shape[0]:  # J_F cannot have full row rank
        return None
    if method == "schur":
        return _schur_step(J, w, regularizer_gradient, c, free)
    if isinstance(J, StrandJacobian):
        indptr, indices, data = J.pattern.indptr, J.pattern.indices, J.data
        row_indptr, row_indices, row_data = J.csr()
    else:
        J = sp.csc_matrix(J)
        indptr, indices, data = J.indptr.astype(np.int64), J.indices.astype(np.int64), J.data
        rows_first = J.tocsr()
        row_indptr, row_indices, row_data = (rows_first.indptr.astype(np.int64),
                                             rows_first.indices.astype(np.int64), rows_first.data)
    size = int(free.sum())
    position = np.cumsum(free) - 1  # index of each free variable in d_F
    n = size + J.shape[0]
    system = sp.csc_matrix(_kkt_system(indptr, indices, data, row_indptr, row_indices, row_data,
                                       np.asarray(w, dtype=float), free, position, size), shape=(n, n))
    try:
        solution = sp.linalg.splu(system).solve(-np.concatenate([regularizer_gradient[free], c]))
    except RuntimeError:
        return None
    d = np.zeros_like(w)
    d[free] = solution[:size]
    return d, solution[size:]


def _schur_step(J, w, regularizer_gradient, c, free):
    """constrained_step by the banded Schur complement (method "schur")."""
    if not np.all(w[free] > 0):
        return None
    inverse_w = np.where(free, 1.0 / np.where(free, w, 1.0), 0.0)
    factor = NormalFactor(J, inverse_w, free)
    if not factor.definite:
        return None
    d, lam = np.zeros_like(w), np.zeros(J.shape[0])
    r1, r2 = -np.where(free, regularizer_gradient, 0.0), -c
    for _ in range(2):  # the solve, then one refinement with the residual of the full system
        d_lam = factor.solve(J @ (inverse_w * r1) - r2)
        d += inverse_w * (r1 - J.T @ d_lam)
        lam += d_lam
        r1 = -np.where(free, regularizer_gradient + w * d + J.T @ lam, 0.0)
        r2 = -c - J @ d
    return d, lam


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
