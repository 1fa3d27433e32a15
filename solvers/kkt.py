"""First-order optimality of the bound-constrained problem, measured the same way for every solver.

    minimize R(p)  s.t.  c(p) = 0,  lower <= p <= upper;   Lagrangian gradient  grad R + J^T lam.

A rest-length entry moves c about 1e7 times more than a stiffness multiplier, so gradients are
compared in the scaled projected gradient pi(p, g) = ||P(p - g / h) - p||_inf with h_j = w_j +
||J_{:,j}||^2 (the Gauss-Newton diagonal): a Newton-like step in the units of p, the same for every
block, zero exactly at a KKT point.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg  # noqa: F401 - sp.linalg.splu

from sagfree.formulation.jacobian import StrandJacobian
from sagfree.formulation.problem import Problem

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
    """lam minimizing the scaled Lagrangian gradient on the free variables,
    ||(grad R + J^T lam)_F / sqrt(h_F)||_2 (a feasible p's multipliers), from the normal equations
    (Js Js^T) lam = -Js r_s with Js = J_F diag(h_F)^-1/2.

    A column of J that fills most rows (the strand multiplier of ``stiffness="strand"``) would make
    Js Js^T dense: its sparse LU took 90 ms on a 400-vertex strand. Such columns U are kept out of the
    sparse matrix A = Js' Js'^T and added back by the Woodbury identity,
    (A + U U^T)^-1 = A^-1 - A^-1 U (I + U^T A^-1 U)^-1 U^T A^-1, with one sparse LU of A.
    """
    free = (p > lower) & (p < upper)
    J = J.tocsc() if isinstance(J, StrandJacobian) else sp.csc_matrix(J)
    Js = (J @ sp.diags(1.0 / np.sqrt(scale)))[:, free].tocsc()
    rhs = Js @ ((regularizer_gradient / np.sqrt(scale))[free])
    rows = Js.shape[0]
    dense = np.diff(Js.indptr) > max(50, rows // 5)
    sparse_part, U = Js[:, ~dense], Js[:, dense].toarray()
    normal = (sparse_part @ sparse_part.T).tocsc() + sp.identity(rows, format="csc") * 1e-14
    try:
        solve = sp.linalg.splu(normal).solve
    except RuntimeError:  # singular: keep the caller's multipliers
        return np.full(rows, np.nan)
    lam = solve(rhs)
    if U.shape[1]:
        AU = solve(U)
        lam -= AU @ np.linalg.solve(np.eye(U.shape[1]) + U.T @ AU, U.T @ lam)
    return -lam


def kkt_optimality(problem: Problem, p: np.ndarray, near: float = 1e-6) -> float:
    """Distance of p from a KKT point, in the units of p (zero exactly at a KKT point): the largest
    entry of the equality-constrained SQP step with the regularizer's Hessian
    W = diag(w) on a working set F of free variables,

        [[W_F, J_F^T], [J_F, 0]] [d_F; lam] = -[grad R_F; c],

    where F starts as the variables farther than ``near`` (relative to the box width) from their
    bounds (interior-point solvers stop a hair inside them) and is corrected (at most 10 times) like
    an active-set method: a bound variable whose multiplier (grad R + J^T lam)_j has the wrong sign
    (< 0 at a lower bound, > 0 at an upper one) is released. Any wrong sign left at the end counts
    too, scaled by h as in ``scaled_projected_gradient``.

    Unlike the scaled projected gradient, this sees directions in which c can be kept by trading
    one parameter against another (the strand multiplier S against the rest shape): there the
    gradient step g / h is tiny, because h is dominated by ||J_{:,j}||^2, while the constrained
    step is not.
    """
    J = sp.csc_matrix(problem.jacobian(p))
    c, regularizer_gradient = problem.residual(p), problem.objective_gradient(p)
    w, lower, upper = problem.layout.weights, problem.layout.lower, problem.layout.upper
    slack = near * (upper - lower)
    at_lower = p - lower <= upper - p
    active = (p - lower <= slack) | (upper - p <= slack)
    scale = gradient_scale(w, J)
    for _ in range(10):
        free = ~active
        size = int(free.sum())
        system = sp.bmat([[sp.diags(w[free]), J[:, free].T], [J[:, free], None]], format="csc")
        try:
            solution = sp.linalg.splu(system).solve(-np.concatenate([regularizer_gradient[free], c]))
        except RuntimeError:  # J_F rank deficient: more constraints than free directions
            return float("inf")
        step = np.zeros_like(p)
        step[free] = solution[:size]
        gradient = regularizer_gradient + J.T @ solution[size:]  # >= 0 at a lower bound, <= 0 at an upper
        # wrong-signed bound multipliers, above rounding (a 1e-3 share of the tolerance in the
        # scaled measure): releasing rounding-level ones only re-solved the same system
        wrong = active & (np.where(at_lower, -gradient, gradient) > 1e-3 * TOLERANCE * scale)
        if not wrong.any():
            break
        active &= ~wrong
    wrong_size = np.where(wrong, np.abs(gradient), 0.0) / scale
    return max(float(np.abs(step).max(initial=0.0)), float(wrong_size.max(initial=0.0)))
