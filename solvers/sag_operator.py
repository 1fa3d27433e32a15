"""The least sag's Jacobian as an operator: J = W P K^-1 B, applied, never formed.

The residuals of solvers.least_sag are the weighted positions of the static equilibrium q_s(p), and
f(q_s, p) = 0 gives dq_s/dp = K^-1 B (K = d2E/dq2 on the free DOFs at q_s, by its banded Cholesky
factor; B = D dc/dp there, in compressed rows). J picks the position rows P of dq_s/dp and weighs
them (W): each product J v or J^T u is one pair of band triangular solves and one sparse product,
O(n); formed, J and its products grow like n^2 (at 2000 vertices ~2 GB with its intermediates).

An operator is the tuple (factor, indptr, indices, data, moving, rows, weights, size, columns):
the Cholesky factor of K, B's compressed rows, the residual rows whose positions are free
(``moving``), their DOFs' rows in K and their weights, the number of residuals and of parameters.
The compiled least sag (solvers.least_sag_loop) and its Python form (solvers.least_sag) take the
same products through these kernels.
"""
from __future__ import annotations

import numba
import numpy as np

from sagfree.linalg.cholesky import factor_active, plain_solve, solve_rows
from sagfree.linalg.compressed import csc_matvec, csc_rmatvec
from sagfree.linalg.timing import LINEAR_ALGEBRA, timed

#: Conjugate-gradient iterations of a step's Gauss-Newton direction (``gauss_newton_direction``),
#: and the relative normal-equations residual that stops them sooner: the step only needs a
#: direction better than the gradient's, and uncapped the iterations grow with the strand.
CG_ITERATIONS = 30
CG_TOLERANCE = 1e-6


def compile_kernels() -> None:
    """Compile (or load from numba's cache) the operator's kernels on a two-row system, with the
    argument types of a strand's: only a strand the boxes cannot balance runs them, and
    frontend.warm calls this before any timed solve."""
    indptr, indices, data, rows = np.array([0, 1, 2]), np.array([0, 1]), np.ones(2), np.arange(2)
    operator = (np.ones((2, 2)), indptr, indices, data, rows, rows, np.ones(2), 2, 2)
    sag_transposed_product(*operator, sag_product(*operator, np.ones(2)))
    gauss_newton_direction(*operator, np.ones(2), np.ones(2), np.ones(2))
    rows_transposed_times(indptr, indices, data, np.ones((2, 1)), 2)
    tangent_step(operator[0], indptr, indices, data, np.ones(2))
    estimated_column_norms(operator[0], indptr, indices, data, rows, np.ones(2), np.ones((2, 1)), 2)
    scaled_rows(data, indptr, rows, np.ones(2))
    stiffness_factor(np.ones((2, 2)), np.ones(2))


@timed(LINEAR_ALGEBRA)
def sag_product(factor, indptr, indices, data, moving, rows, weights, size, columns, v) -> np.ndarray:
    """J v for the least-sag Jacobian J = W P K^-1 B (the arguments of StaticSag.operator): one band
    solve and one sparse product."""
    return jacobian_product(factor, indptr, indices, data, moving, rows, weights, size,
                            np.ascontiguousarray(v, dtype=float))


@timed(LINEAR_ALGEBRA)
def sag_transposed_product(factor, indptr, indices, data, moving, rows, weights, size, columns, u) -> np.ndarray:
    """J^T u for the least-sag Jacobian (``sag_product``)."""
    return jacobian_transposed_product(factor, indptr, indices, data, moving, rows, weights, columns,
                                       np.ascontiguousarray(u, dtype=float))


@numba.njit(cache=True)
def jacobian_product(factor, indptr, indices, data, moving, rows, weights, size, v):  # pragma: no cover - compiled
    """J v (sag_product): the moving rows of K^-1 B v (``tangent_step``), weighted."""
    solved = tangent_step(factor, indptr, indices, data, v)
    out = np.zeros(size)
    for i in range(moving.size):
        out[moving[i]] = weights[i] * solved[rows[i]]
    return out


@numba.njit(cache=True)
def jacobian_transposed_product(factor, indptr, indices, data, moving, rows, weights, columns, u):  # pragma: no cover
    """J^T u (sag_transposed_product): B^T K^-1 P^T W u."""
    pulled = np.zeros(factor.shape[0])
    for i in range(moving.size):
        pulled[rows[i]] = weights[i] * u[moving[i]]
    solved = np.empty(factor.shape[0])
    plain_solve(factor, pulled, solved)
    return csc_matvec(indptr, indices, data, solved, columns)  # B^T: the rows as csc columns of B^T


@timed(LINEAR_ALGEBRA)
def gauss_newton_direction(factor, indptr, indices, data, moving, rows, weights, size, columns, d, damping,
                           f) -> np.ndarray:
    """An approximate minimizer of |J diag(d) p + f|^2 + |damping^(1/2) p|^2 for the least-sag
    Jacobian J (``sag_product``): CG_ITERATIONS of conjugate gradients on its normal equations at
    most (``cgls``), the trust region's Gauss-Newton direction (solvers.reflective)."""
    return cgls(factor, indptr, indices, data, moving, rows, weights, size, columns, d, np.sqrt(damping), f,
                 CG_ITERATIONS, CG_TOLERANCE)


@numba.njit(cache=True)
def cgls(factor, indptr, indices, data, moving, rows, weights, size, columns, d, root, f, iterations,
         tolerance):  # pragma: no cover - compiled
    """CGLS (conjugate gradients on A^T A p = A^T b without forming A^T A; Hestenes & Stiefel 1952)
    for min |A p - b|, A = [J diag(d); diag(root)], b = [-f; 0], from p = 0: at most ``iterations``,
    stopped where |A^T r| falls below ``tolerance`` of its start."""
    n = d.size
    p, direction, top_step = np.zeros(n), np.empty(n), np.empty(n)
    top, bottom = -f.copy(), np.zeros(n)
    pulled = jacobian_transposed_product(factor, indptr, indices, data, moving, rows, weights, columns, top)
    gradient = np.empty(n)
    for j in range(n):
        gradient[j] = d[j] * pulled[j]
        direction[j] = gradient[j]
    gamma = np.dot(gradient, gradient)
    stop = tolerance * tolerance * gamma
    for _ in range(iterations):
        if not gamma > stop:
            break
        for j in range(n):
            top_step[j] = d[j] * direction[j]
        image = jacobian_product(factor, indptr, indices, data, moving, rows, weights, size, top_step)
        curvature = np.dot(image, image)
        for j in range(n):
            curvature += (root[j] * direction[j]) ** 2
        if not curvature > 0:
            break
        alpha = gamma / curvature
        for j in range(n):
            p[j] += alpha * direction[j]
            bottom[j] -= alpha * root[j] * direction[j]
        for i in range(top.size):
            top[i] -= alpha * image[i]
        pulled = jacobian_transposed_product(factor, indptr, indices, data, moving, rows, weights, columns, top)
        for j in range(n):
            gradient[j] = d[j] * pulled[j] + root[j] * bottom[j]
        previous, gamma = gamma, np.dot(gradient, gradient)
        for j in range(n):
            direction[j] = gradient[j] + gamma / previous * direction[j]
    return p


@numba.njit(cache=True)
def tangent_step(factor, indptr, indices, data, dp):  # pragma: no cover - compiled
    """dq_s = K^-1 B dp on the free DOFs (StaticSag._predicted, and jacobian_product's before it picks the
    residuals' rows): B in compressed rows (B dp: the rows as csc columns of B^T), K by its
    Cholesky factor."""
    solved = np.empty(factor.shape[0])
    plain_solve(factor, csc_rmatvec(indptr, indices, data, dp), solved)
    return solved


@numba.njit(cache=True)
def rows_transposed_times(indptr, indices, data, x, columns):  # pragma: no cover - compiled
    """B^T X for B in compressed rows and X (rows of B x k)."""
    k = x.shape[1]
    out = np.zeros((columns, k))
    for r in range(indptr.size - 1):
        for t in range(indptr[r], indptr[r + 1]):
            j, entry = indices[t], data[t]
            for c in range(k):
                out[j, c] += entry * x[r, c]
    return out


@numba.njit(cache=True)
def estimated_column_norms(factor, indptr, indices, data, moving_rows, moving_weights, signs,
                           columns):  # pragma: no cover - compiled
    """Hutchinson's estimate of J's column norms, |J e_j|^2 = E[(J^T v)_j^2] over random signs v:
    sqrt of the mean over the columns of ``signs`` (moving rows x probes) of (J^T v)_j^2, each J^T v
    one band solve (solvers.least_sag.StaticSag.estimated_column_norms)."""
    probes = signs.shape[1]
    pulled = np.zeros((factor.shape[0], probes))  # (P^T W) v on the free DOFs
    for i in range(moving_rows.size):
        for k in range(probes):
            pulled[moving_rows[i], k] = moving_weights[i] * signs[i, k]
    solve_rows(factor, pulled)
    products = rows_transposed_times(indptr, indices, data, pulled, columns)
    out = np.empty(columns)
    for j in range(columns):
        total = 0.0
        for k in range(probes):
            total += products[j, k] * products[j, k]
        out[j] = np.sqrt(total / probes)
    return out


@numba.njit(cache=True)
def stiffness_factor(band, masses):  # pragma: no cover - compiled
    """The Cholesky factor of K (the free static Hessian, lower band storage), shifted by the mass
    metric (shift 1, 4, 16, ... times ``masses``) until it factors where E has a saddle there, as
    Newton's damping shifts it."""
    size, width = band.shape[1], band.shape[0]
    no_border, no_corner, everything = np.zeros((0, size)), np.zeros((0, 0)), np.ones(size, dtype=np.bool_)
    factor = np.empty((size, width))
    factored, shift = factor_active(band.copy(), no_border, no_corner, everything, factor, no_border, no_corner,
                                    np.int64(0), np.int64(0)), 0.0
    while not factored:
        shift = max(4.0 * shift, 1.0)
        shifted = band.copy()
        for j in range(size):
            shifted[0, j] += shift * masses[j]
        factored = factor_active(shifted, no_border, no_corner, everything, factor, no_border, no_corner,
                                 np.int64(0), np.int64(0))
    return factor


@numba.njit(cache=True)
def scaled_rows(values, indptr, order, row_scale):  # pragma: no cover - compiled
    """B's compressed-row values, B = D dc/dp: dc/dp's CSC ``values`` taken in row order (the
    pattern's csr ``order``, rows ``indptr``), each row times its force scale D."""
    data = np.empty(order.size)
    for r in range(indptr.size - 1):
        for t in range(indptr[r], indptr[r + 1]):
            data[t] = values[order[t]] * row_scale[r]
    return data
