"""First-order optimality of the bound-constrained problem, measured the same way for every solver.

    minimize R(p)  s.t.  c(p) = 0,  lower <= p <= upper;   Lagrangian gradient  grad R + J^T lam.

A rest-length entry moves c about 1e7 times more than a stiffness multiplier, so gradients are
compared in the scaled projected gradient pi(p, g) = ||P(p - g / h) - p||_inf with h_j = w_j +
||J_{:,j}||^2 (the Gauss-Newton diagonal): a Newton-like step in the units of p, the same for every
block, zero exactly at a KKT point. A solver's status is ``converged`` only if |c|_inf <= ``tol``
and ``kkt_optimality`` <= ``kkt_tol`` (options module; defaults TOL and KKT_TOL).
"""
from __future__ import annotations

import numba
import numpy as np

from sagfree.formulation.problem import Problem
from sagfree.linalg import lapack
from sagfree.linalg.band import column_norms, csc_arrays
from sagfree.linalg.compressed import csc_column_norms, csc_rmatvec
from sagfree.linalg.saddle import (REFINED, REFINEMENTS, band_order, constrained_step, no_band_factors,
                                   plain_band_step, refined_band_solution)
from sagfree.linalg.timing import LINEAR_ALGEBRA, timed

#: |c|_inf (unit-free) at or below which a strand is in equilibrium (DESIGN section 4).
TOL = 1e-8
#: KKT distance (kkt_optimality, in the units of p) at or below which a solver's status may be
#: ``converged``. 1e-6 is below what rounding allows on some 200-vertex strands (2.1e-6 at the best
#: point ours or Ipopt found on one of them).
KKT_TOL = 1e-5
#: accuracy (p's units) of a KKT distance found by refining a nearby factorization (kkt_optimality)
REFINED_DISTANCE = 1e-4 * KKT_TOL


def scaled_projected_gradient(p, gradient, scale, lower, upper) -> float:
    """||P(p - gradient / scale) - p||_inf: zero exactly at a KKT point of a box-constrained problem."""
    return float(scaled_projected_gradient_kernel(np.asarray(p, dtype=float), np.asarray(gradient, dtype=float),
                                            np.asarray(scale, dtype=float), np.asarray(lower, dtype=float),
                                            np.asarray(upper, dtype=float)))


@numba.njit(cache=True)
def scaled_projected_gradient_kernel(p, gradient, scale, lower, upper):  # pragma: no cover - compiled
    """``scaled_projected_gradient`` in one compiled pass, callable from compiled code (asc evaluates
    it ~20 times per strand; numpy's clip and max cost ~10 us there)."""
    largest = 0.0
    for j in range(p.size):
        target = p[j] - gradient[j] / scale[j]
        if np.isnan(target):
            return np.nan  # as numpy's clip and max: a NaN gradient is never stationary
        moved = abs(min(max(target, lower[j]), upper[j]) - p[j])
        if moved > largest:
            largest = moved
    return largest


def gradient_scale(weights: np.ndarray, J) -> np.ndarray:
    """h_j = w_j + ||J_{:,j}||^2, the diagonal of the Gauss-Newton Hessian at mu = 1."""
    return weights + column_norms(J) + 1e-300


@numba.njit(cache=True)
def gradient_scale_kernel(w, indptr, data):  # pragma: no cover - compiled
    """``gradient_scale`` of J in compressed columns (indptr, data), callable from compiled code."""
    return w + csc_column_norms(indptr, data) + 1e-300


@numba.njit(cache=True)
def working_set_kernel(p, lower, upper, near):  # pragma: no cover - compiled
    """``working_set``, callable from compiled code."""
    free = np.empty(p.size, dtype=np.bool_)
    for j in range(p.size):
        slack = near * (upper[j] - lower[j])
        free[j] = (p[j] - lower[j] > slack) and (upper[j] - p[j] > slack)
    return free


def working_set(p, lower, upper, near: float = 1e-6) -> np.ndarray:
    """The variables farther than ``near`` of their box's width from both bounds (kkt_optimality's
    first working set)."""
    slack = near * (upper - lower)
    return (p - lower > slack) & (upper - p > slack)


def kkt_optimality(problem: Problem, p: np.ndarray, near: float = 1e-6, nearby=None) -> float:
    """Distance of p from a KKT point, in the units of p (zero exactly at a KKT point): the largest
    entry of the equality-constrained SQP step with the regularizer's Hessian
    W = diag(w) on a working set F of free variables,

        [[W_F, J_F^T], [J_F, 0]] [d_F; lam] = -[grad R_F; c]      (constrained_step),

    where F starts as the variables farther than ``near`` (relative to the box width) from their
    bounds (interior-point solvers stop a hair inside them) and is corrected (at most 10 times) like
    an active-set method: a bound variable whose multiplier (grad R + J^T lam)_j has the wrong sign
    (< 0 at a lower bound, > 0 at an upper one) is released. Any wrong sign left at the end counts
    too, scaled by h as in ``scaled_projected_gradient``. If the system is singular (fewer free
    variables than constraints, as when many variables sit within ``near`` of a bound but not on
    it), F becomes the variables not on a bound; infinite if it is singular still.

    Unlike the scaled projected gradient, this sees directions in which c can be kept by trading
    one parameter against another (the strand multiplier S against the rest shape): there the
    gradient step g / h is tiny, because h is dominated by ||J_{:,j}||^2, while the constrained
    step is not.

    ``nearby``: the linalg.saddle.SaddleFactor of a solver's last step at a point near p (asc's SQP
    step), reused by iterative refinement where its free set is the first working set
    (constrained_step): the distance is the same to rounding, without a factorization. Without one,
    where the saddle system is a band (linalg.saddle.band_order; not with a strand multiplier), the
    loop below runs as one compiled call, ``band_kkt_distance``, with the same arithmetic.
    """
    J = problem.strand_jacobian(p)
    c, regularizer_gradient = problem.residual(p), problem.objective_gradient(p)
    w, lower, upper = problem.layout.weights, problem.layout.lower, problem.layout.upper
    banded = band_kkt(problem, p, near) if nearby is None else None
    if banded is not None:  # the loop below in one compiled call
        return banded[0]
    at_lower = p - lower <= upper - p
    active = ~working_set(p, lower, upper, near)
    scale = gradient_scale(w, J)
    wrong = None
    for _ in range(10):
        solution = constrained_step(J, w, regularizer_gradient, c, ~active, nearby, REFINED_DISTANCE)
        nearby = None  # a changed working set needs its own factorization
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
        wrong = active & (np.where(at_lower, -gradient, gradient) > 1e-3 * KKT_TOL * scale)
        if not wrong.any():
            break
        active &= ~wrong
    if wrong is None:  # no working set gave a solvable system
        return float("inf")
    wrong_size = np.where(wrong, np.abs(gradient), 0.0) / scale
    return max(float(np.abs(step).max(initial=0.0)), float(wrong_size.max(initial=0.0)))


@numba.njit(cache=True, inline="always")
def band_kkt_distance(dgbtrf, dgbtrs, indptr, indices, data, position, w, regularizer_gradient, c, p, lower, upper,
                      near):  # pragma: no cover - compiled
    """``kkt_optimality`` where the saddle system is a band (linalg.saddle.band_order gives
    ``position``) and no nearby factorization is offered: its loop line by line, the same
    arithmetic, in one compiled call (J in compressed columns; callable from compiled code, as
    solvers.confirmed_start calls it)."""
    return nearby_band_kkt_distance(dgbtrf, dgbtrs, indptr, indices, data, position, w, regularizer_gradient, c, p,
                                    lower, upper, near, no_band_factors())


@numba.njit(cache=True, inline="always")
def nearby_band_kkt_distance(dgbtrf, dgbtrs, indptr, indices, data, position, w, regularizer_gradient, c, p, lower,
                             upper, near, nearby):  # pragma: no cover - compiled
    """``band_kkt_distance`` with ``kkt_optimality``'s ``nearby``: the band factors of a saddle
    system at a nearby p (linalg.saddle.band_factors' tuple, as SaddleFactor holds them: no
    curvature, the same w), tried first by iterative refinement where its free set is the first
    working set (linalg.saddle.constrained_step); no_band_factors() where there are none."""
    return nearby_band_kkt_step(dgbtrf, dgbtrs, indptr, indices, data, position, w, regularizer_gradient, c, p, lower,
                                upper, near, nearby)[0]


@numba.njit(cache=True, inline="always")
def band_kkt_step(dgbtrf, dgbtrs, indptr, indices, data, position, w, regularizer_gradient, c, p, lower, upper,
                  near):  # pragma: no cover - compiled
    """(distance, d): band_kkt_distance and the SQP step d of its last working set, whose largest
    entry the distance is unless a bound's multiplier keeps the wrong sign (empty where no working
    set gave a solvable system)."""
    return nearby_band_kkt_step(dgbtrf, dgbtrs, indptr, indices, data, position, w, regularizer_gradient, c, p, lower,
                                upper, near, no_band_factors())


@numba.njit(cache=True)
def nearby_band_kkt_step(dgbtrf, dgbtrs, indptr, indices, data, position, w, regularizer_gradient, c, p, lower,
                         upper, near, nearby):  # pragma: no cover - compiled
    """(distance, d) of nearby_band_kkt_distance (band_kkt_step's)."""
    factors, half, pivots, kept, reduced, nearby_free = nearby
    n = p.size
    scale = gradient_scale_kernel(w, indptr, data)
    active = ~working_set_kernel(p, lower, upper, near)
    at_lower = np.empty(n, dtype=np.bool_)
    for j in range(n):
        at_lower[j] = p[j] - lower[j] <= upper[j] - p[j]
    threshold = 1e-3 * KKT_TOL
    step, gradient, wrong, solved = np.zeros(n), np.zeros(n), np.zeros(n, dtype=np.bool_), False
    refine = factors.size > 0
    for j in range(n):
        refine &= nearby_free[j] == (not active[j])
    for _ in range(10):
        singular, refined = False, False
        d, lam = np.empty(0), np.empty(0)
        if refine:  # the first working set only: a changed one needs its own factorization
            refine = False
            refined, d, lam = refined_band_solution(dgbtrs, factors, half, pivots, kept, reduced, indptr, indices,
                                                     data, w, ~active, regularizer_gradient, c, REFINED_DISTANCE,
                                                     np.int64(REFINEMENTS), REFINED)
        if not refined:
            singular, d, lam = plain_band_step(dgbtrf, dgbtrs, indptr, indices, data, w, ~active, position,
                                               regularizer_gradient, c)
        if singular:  # too few free directions: free the variables near but not on a bound
            loose = False
            for j in range(n):
                if active[j] and p[j] > lower[j] and p[j] < upper[j]:
                    active[j], loose = False, True
            if not loose:
                return np.inf, np.empty(0)
            continue
        step, solved = d, True
        gradient = regularizer_gradient + csc_rmatvec(indptr, indices, data, lam)
        any_wrong = False
        for j in range(n):
            signed = -gradient[j] if at_lower[j] else gradient[j]
            wrong[j] = active[j] and signed > threshold * scale[j]
            any_wrong |= wrong[j]
        if not any_wrong:
            break
        for j in range(n):
            active[j] &= not wrong[j]
    if not solved:
        return np.inf, np.empty(0)
    largest_step, largest_wrong = 0.0, 0.0
    for j in range(n):  # numpy's max: a NaN is kept from then on
        size = abs(step[j])
        if not size <= largest_step:
            largest_step = size if largest_step == largest_step else largest_step
        wrong_size = (abs(gradient[j]) if wrong[j] else 0.0) / scale[j]
        if not wrong_size <= largest_wrong:
            largest_wrong = wrong_size if largest_wrong == largest_wrong else largest_wrong
    return (largest_wrong if largest_wrong > largest_step else largest_step), step  # Python's max(step, wrong)


def band_kkt(problem: Problem, p: np.ndarray, near: float = 1e-6) -> tuple[float, np.ndarray] | None:
    """(kkt_optimality(problem, p, near), the SQP step of its last working set) in one compiled call
    (band_kkt_step) where the saddle system is a band, else None."""
    J = problem.strand_jacobian(p)
    indptr, indices, data = csc_arrays(J)
    position = band_order(indptr, indices, J.shape[0])
    if position is None:
        return None
    distance, step = _timed_band_kkt_step(lapack.DGBTRF, lapack.DGBTRS, indptr, indices, data, position,
                                          np.asarray(problem.layout.weights, dtype=float),
                                          problem.objective_gradient(p), problem.residual(p),
                                          np.asarray(p, dtype=float), problem.layout.lower, problem.layout.upper,
                                          float(near))
    return float(distance), step


#: the compiled loop as linear algebra in a Result's time split (its factorization is most of it)
_timed_band_kkt_step = timed(LINEAR_ALGEBRA)(band_kkt_step)
