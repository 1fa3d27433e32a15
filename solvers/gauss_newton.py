"""asc's inner solve compiled: Gauss-Newton on the augmented Lagrangian with no Python between steps.

One call of ``inner_solve`` runs the inner loop of ``solve_alm`` (alm module docstring, "Inner loop",
"Crawl", "Stall") from p until it stops: the gradient of L(p) = R(p) + lam^T c(p) + mu/2 |c(p)|^2
and its scaled projected gradient, the banded Gauss-Newton Hessian diag(w) + mu J^T J (damped as
alm._Model.hessian says), the box QP (mprgp.box_qp: MPRGP with the active-set Cholesky, warm-started
on the previous step's bounds), the nonmonotone Armijo line search on L with the full step's
second-order correction (``corrected_trial``, which the Python loop calls too), and c and dc/dp at each
trial point, evaluated by the same compiled kernels as Problem.residual and Problem.strand_jacobian
(formulation.at_rest, numba calling the CasADi stencils at their addresses). The
Python loop in alm (``_inner_solve_python``) does the same in the same order, and stays for
problems whose model the kernels cannot evaluate (no C compiler): the two give the same
p, bit for bit (the merit's sums are numpy's pairwise sums, ``pairwise_sum``, and the dot
products the same BLAS ddot), which tests/test_gauss_newton.py checks.

Why: in Python each Gauss-Newton step paid for dozens of calls between its compiled kernels (QP
set-up, Gram assembly, merit, line search, memo lookups); compiled, a groom's strands take about a
tenth less time in all, most of a strand's time being outside the inner solves (measurements in
benchmarks/RESULTS.md).

The loop reads a monotonic clock (clock_gettime, as time.perf_counter) for ``max_seconds`` and for
the time split: the model evaluations count as ``model``, the Gram assembly and the QPs as
``linear_algebra`` (linalg.timing). Where the C library has no clock_gettime, solve_alm keeps the
Python loop.
"""
from __future__ import annotations

import numba
import numpy as np

from sagfree.contract.optimality import scaled_projected_gradient_kernel
from sagfree.formulation import at_rest
from sagfree.formulation.jacobian import StrandJacobian
from sagfree.formulation.problem import Problem
from sagfree.linalg import timing
from sagfree.linalg.band import gram_arrays
from sagfree.linalg.cholesky import factor_active, solve_factored
from sagfree.linalg.compressed import csc_column_norms, csc_matvec, csc_rmatvec
from sagfree.linalg.pairwise import pairwise_sum

from . import mprgp

# the constants of the inner loop (alm module docstring; alm imports them from here)
ARMIJO = 1e-4
ROUNDING = 1e-13  # relative rounding of the merit function: changes below it are noise
DAMPING = (1e-13, 1e-11, 1e-9)  # relative Levenberg-Marquardt damping, escalated on breakdown
NONMONOTONE = 5  # Grippo-Lampariello-Lucidi memory of the line search
STALL = 3  # accepted Gauss-Newton steps in a row that lower L by less than its rounding end the inner loop
INNER_STEPS = 30  # Gauss-Newton steps per inner solve (alm module docstring, Crawl)
CRAWL_WINDOW = 5  # ... fewer when the last CRAWL_WINDOW steps reduced neither |c|_inf nor pi
CRAWL_DROP = 0.9  # ... by at least 10%
CRAWL_NEAR = 100.0  # ... where |c|_inf <= CRAWL_NEAR tol (far from it, the infeasibility test needs the full solve)
QP_MAX_ITERATIONS = 10_000  # solve_box_qp's default
CURVATURE_NEAR = 1e-2  # |c|_inf at or below which a strand held at both ends adds c's curvature (curved_hessian)

# why an inner solve stopped (``inner_solve``): the first three are decided by solve_alm's outer loop
TARGET, CRAWL, NO_PROGRESS, MAX_ITERATIONS, MAX_SECONDS, QP_FAILED = range(6)
#: solve counters the loop advances, in the order of its counts array
COUNTED = ("gauss_newton", "line_search", "cg", "expansion", "proportioning", "active_set", "interior",
           "factorizations", "factored_rows", "corrected")
_GAUSS_NEWTON, _LINE_SEARCH, _CORRECTED = 0, 1, 9  # their places in the counts array
_QP_COUNTS = (mprgp.CG, mprgp.EXPANSION, mprgp.PROPORTIONING, mprgp.ACTIVE_SET, mprgp.INTERIOR,
              mprgp.FACTORIZATIONS, mprgp.FACTORED_ROWS)  # COUNTED[2:] in mprgp's counts layout


def available(problem: Problem) -> bool:
    """True where ``inner_solve`` can run on ``problem`` (compiled stencils and constraint
    curvature, a clock)."""
    return (timing.CLOCK is not None and problem.at_rest_kernels is not None
            and problem.curvature_kernels is not None)


def curvature_applies(problem: Problem, border: int) -> bool:
    """True where the inner Hessian takes the constraints' curvature near feasibility
    (curved_hessian): a strand held at both ends (a tip or pins) off bodies, per-element stiffness."""
    strand = problem.strand
    return (border == 0 and not problem.bodies and (strand.tip is not None or len(strand.pins) > 0)
            and problem.curvature_kernels is not None)


@numba.njit(cache=True)
def curved_hessian(band, rows, columns, values):  # pragma: no cover - compiled
    """The Gauss-Newton Hessian's band (no border) plus the constraints' curvature sum_r (lam + mu
    c)_r c_r'' (its (rows, columns, values) triplets, both triangles: the lower one is added), the
    exact Hessian of the augmented Lagrangian, shifted where it is not definite by tau |H_GN,jj| on
    the diagonal, tau = 0, then 1e-8 up to 1 tenfold, the first whose Cholesky goes through; empty
    where none does or a triplet lies outside the band (the caller keeps Gauss-Newton's).

    Why: on a strand held at both ends the internal forces are not fixed by statics, and along the
    feasible set the optimum trades through the curvature that Gauss-Newton omits: it crawled
    there, and Newton-SQP's equality-constrained steps left the box (long strands with a pinned
    tip ended max_iterations). Far from feasibility (|c|_inf > CURVATURE_NEAR) lam + mu c
    is large and the curvature misleads; on bodies it doubled the work (benchmarks/RESULTS.md,
    2026-12-05)."""
    half, nb = band.shape[0] - 1, band.shape[1]
    curved = band.copy()
    for k in range(rows.size):
        if rows[k] < columns[k]:
            continue
        offset = rows[k] - columns[k]
        if offset > half:
            return np.empty((0, 0))
        curved[offset, columns[k]] += values[k]
    shifted = curved.copy()
    factor, no_border, no_corner = np.empty((nb, half + 1)), np.zeros((0, nb)), np.zeros((0, 0))
    free = np.ones(nb, dtype=np.bool_)
    tau = 0.0
    while tau <= 1.0:
        for j in range(nb):
            shifted[0, j] = curved[0, j] + tau * abs(band[0, j])
        if factor_active(shifted, no_border, no_corner, free, factor, no_border, no_corner, np.int64(0), np.int64(0)):
            return shifted
        tau = 1e-8 if tau == 0.0 else 10.0 * tau
    return np.empty((0, 0))


class InnerState:
    """What an inner solve reads and advances: the point p with c(p), J(p) (a StrandJacobian) and
    the gradient scale h(p) (contract.optimality.gradient_scale), and the bounds the last QP ended on
    (the next QP's warm start)."""

    def __init__(self, p, c, J: StrandJacobian, scale, at_lower, at_upper):
        self.p, self.c, self.J, self.scale = p, c, J, scale
        self.at_lower, self.at_upper = at_lower, at_upper


def inner_solve(problem: Problem, model, state: InnerState, lam, mu: float, omega: float, tol: float,
                max_iterations: int, deadline: float, qp_rtol: float, preconditioner: str, counts: dict,
                history: list) -> tuple[int, str, float, int, bool]:
    """Run the inner loop from ``state`` (advanced in place) with multipliers lam, penalty mu and
    target omega; counts (solve_alm's dict) and history (|c|_inf after each accepted step) are
    extended. Returns (reason, the QP's status if it failed (mprgp.STATUS), the last scaled
    projected gradient, the stall count, whether p moved). deadline: time.perf_counter() value at
    which to stop (max_seconds).
    """
    lower, upper = problem.layout.lower, problem.layout.upper
    # the loop's first test, here: about half of the calls meet the target at once, and this small
    # call is cheaper than the loop's (unboxing its arrays)
    indptr, indices, data = state.J.csc()
    p, c, scale, lam = (np.ascontiguousarray(a, dtype=float) for a in (state.p, state.c, state.scale, lam))
    optimality = _lagrangian_optimality(model.w, p, model.p0, indptr, indices, data, lam, float(mu), c, scale,
                                        lower, upper)[0]
    if optimality <= omega:
        return TARGET, "", optimality, 0, False
    forces_args, jacobian_args, free, row_scale, structure = problem.at_rest_kernels
    border = model.border
    active_set_steps = mprgp.ACTIVE_SET_STEPS if border == 0 else 0  # solve_box_qp's default
    totals = np.array([counts[name] for name in COUNTED], dtype=np.int64)
    seconds = np.zeros(2)
    steps = np.empty(INNER_STEPS + 1)
    clock, clock_id = timing.CLOCK
    deadline -= timing.clock_offset()  # on the loop's clock
    (reason, qp_status, optimality, stalled, moved, recorded, p, c, f, values, scale) = inner_loop(
        forces_args, jacobian_args, problem.curvature_kernels, curvature_applies(problem, border), free, row_scale,
        structure, clock, clock_id, model.w, model.p0,
        lower, upper, p, c, data, scale, lam, float(mu),
        float(omega), float(tol), int(max_iterations), float(deadline), float(qp_rtol),
        mprgp.PRECONDITIONERS[preconditioner], border, active_set_steps, mprgp.WALKING, state.at_lower,
        state.at_upper, totals, seconds, steps)
    timing.add(timing.MODEL, seconds[0])
    timing.add(timing.LINEAR_ALGEBRA, seconds[1])
    for name, value in zip(COUNTED, totals.tolist()):
        counts[name] = value
    history.extend(steps[:recorded].tolist())
    if moved:
        problem.remember_at_rest(p, f, values)
        state.p, state.c, state.J, state.scale = p, c, problem.strand_jacobian(p), scale
    return reason, mprgp.STATUS[qp_status], optimality, stalled, moved


@numba.njit(cache=True)
def _merit(w, p, p0, c, lam, mu, work):  # pragma: no cover - compiled
    """(L, the sum of its terms' magnitudes) as alm._Model.merit and merit_scale compute them."""
    regularizer = regularizer_value(w, p, p0, work)
    squares = 0.5 * mu * np.dot(c, c)
    return regularizer + np.dot(lam, c) + squares, regularizer + np.dot(np.abs(lam), np.abs(c)) + squares


@numba.njit(cache=True)
def regularizer_value(w, p, p0, work):  # pragma: no cover - compiled
    """R(p) = 1/2 sum w (p - p0)^2 as Problem.objective sums it (numpy's pairwise sum; work: scratch
    of p's size)."""
    for j in range(p.size):
        d = p[j] - p0[j]
        work[j] = w[j] * d * d
    return 0.5 * pairwise_sum(work)


@numba.njit(cache=True)
def at_rest_residual(p, forces_args, free, row_scale):  # pragma: no cover - compiled
    """(c(p), f(q*, p)) as Problem.residual and Problem.forces give them."""
    f = at_rest.forces(p, *forces_args)
    c = np.empty(free.size)
    for r in range(free.size):
        c[r] = f[free[r]] / row_scale[r]
    return c, f


@numba.njit(cache=True)
def largest_magnitude(c):  # pragma: no cover - compiled
    """np.abs(c).max(initial=0.0): a NaN entry makes it NaN (a residual that is not a number is not small)."""
    largest = 0.0
    for value in c:
        magnitude = abs(value)
        if not magnitude <= largest:  # larger, or NaN: kept from then on
            largest = magnitude if largest == largest else largest
    return largest


@numba.njit(cache=True)
def corrected_trial(band, band_border, corner, at_lower, at_upper, indptr, indices, values, p, step, c, c_trial, mu,
                    lower, upper):  # pragma: no cover - compiled
    """The full Gauss-Newton step with its second-order correction (alm module docstring, Inner loop):
    p + d + e clipped into the box, e = -H_F^-1 mu J^T r on the QP's free variables F (zero on the
    bounds it ended on: at_lower / at_upper), r = c(p + d) - c(p) - J d the error of c's
    linearization, H (band, band_border, corner) the step's Gauss-Newton Hessian, J at p in
    compressed columns. Empty where H_F does not factor."""
    n = p.size
    predicted = csc_matvec(indptr, indices, values, step, c.size)
    error = np.empty(c.size)
    for r in range(c.size):
        error[r] = mu * (c_trial[r] - c[r] - predicted[r])
    pulled = csc_rmatvec(indptr, indices, values, error)
    free, rhs = np.empty(n, dtype=np.bool_), np.empty(n)
    for j in range(n):
        free[j] = not (at_lower[j] or at_upper[j])
        rhs[j] = -pulled[j] if free[j] else 0.0
    nb, m = band.shape[1], corner.shape[0]
    cols, lborder, lcorner = np.empty((nb, band.shape[0])), np.empty((m, nb)), np.empty((m, m))
    if not factor_active(band, band_border, corner, free, cols, lborder, lcorner, np.int64(0), np.int64(0)):
        return np.empty(0)
    correction = np.empty(n)
    solve_factored(cols, lborder, lcorner, rhs, correction)
    trial = np.empty(n)
    for j in range(n):
        trial[j] = min(max(p[j] + step[j] + correction[j], lower[j]), upper[j])
    return trial


@numba.njit(cache=True)
def _lagrangian_optimality(w, p, p0, indptr, indices, data, lam, mu, c, scale, lower, upper):  # pragma: no cover
    """(scaled projected gradient, gradient) of the augmented Lagrangian at p: gradient = w (p - p0)
    + J^T (lam + mu c), J in compressed columns; the inner loop's stopping test."""
    multiplier = np.empty(c.size)
    for r in range(c.size):
        multiplier[r] = lam[r] + mu * c[r]
    pulled = csc_rmatvec(indptr, indices, data, multiplier)
    gradient = np.empty(p.size)
    for j in range(p.size):
        gradient[j] = w[j] * (p[j] - p0[j]) + pulled[j]
    return scaled_projected_gradient_kernel(p, gradient, scale, lower, upper), gradient


@numba.njit(cache=True)
def inner_loop(forces_args, jacobian_args, curvature_args, curved, free, row_scale, structure, clock, clock_id, w,
               p0, lower, upper, p, c, values, scale, lam, mu, omega, tol, max_iterations, deadline, qp_rtol, precond,
               border, active_set_steps, walking, at_lower, at_upper, counts, seconds, steps):  # pragma: no cover
    """The loop of ``inner_solve`` (alm._inner_solve_python line by line; solvers.outer_loop calls it
    directly, whose first test is inner_solve's own); counts in COUNTED order,
    seconds [model, linear algebra] accumulated, steps receives |c|_inf after each accepted step.
    Returns (reason, QP status, optimality, stalled, moved, steps recorded, p, c, f, values, scale)."""
    csc_indptr, csc_indices, csr_indptr, csr_indices, csr_order = structure
    n = p.size
    buffer = np.zeros(2, dtype=np.int64)
    work = np.empty(n)
    recent = np.empty(INNER_STEPS + 1)
    progress_violation, progress_optimality = np.empty(INNER_STEPS + 1), np.empty(INNER_STEPS + 1)
    qp_counts = np.zeros(8, dtype=np.int64)
    no_curvature = (np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64), np.empty(0))
    f = np.empty(0)
    steps_before = counts[_GAUSS_NEWTON]
    stalled, recorded, tried, moved = 0, 0, 0, False
    reason, qp_status, optimality = TARGET, 0, np.inf
    while True:
        optimality, gradient = _lagrangian_optimality(w, p, p0, csc_indptr, csc_indices, values, lam, mu, c, scale,
                                                      lower, upper)
        if optimality <= omega:
            reason = TARGET
            break
        if counts[_GAUSS_NEWTON] - steps_before >= INNER_STEPS:
            reason = CRAWL  # a crawling inner solve: the outer loop (SQP step or mu) decides
            break
        violation = largest_magnitude(c)
        progress_violation[tried], progress_optimality[tried] = violation, optimality
        tried += 1
        if (violation <= CRAWL_NEAR * tol and tried > CRAWL_WINDOW
                and violation > CRAWL_DROP * progress_violation[tried - 1 - CRAWL_WINDOW]
                and optimality > CRAWL_DROP * progress_optimality[tried - 1 - CRAWL_WINDOW]):
            reason = CRAWL  # the same, detected sooner near feasibility (alm._crawls)
            break
        if counts[_GAUSS_NEWTON] >= max_iterations:
            reason = MAX_ITERATIONS
            break
        if timing.clock_seconds(clock, clock_id, buffer) >= deadline:
            reason = MAX_SECONDS
            break
        counts[_GAUSS_NEWTON] += 1
        # warm start: the bounds active in the previous step's QP are active again
        d_lower, d_upper, start_step, negative = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        for j in range(n):
            d_lower[j], d_upper[j] = lower[j] - p[j], upper[j] - p[j]
            start_step[j] = d_lower[j] if at_lower[j] else (d_upper[j] if at_upper[j] else 0.0)
            negative[j] = -gradient[j]
        norms = csc_column_norms(csc_indptr, values)
        csr_values = values[csr_order]
        rows, columns, entries = no_curvature
        near = curved and violation <= CURVATURE_NEAR  # the augmented Lagrangian's exact Hessian (curved_hessian)
        if near:
            started = timing.clock_seconds(clock, clock_id, buffer)
            weights = np.empty(c.size)
            for r in range(c.size):
                weights[r] = lam[r] + mu * c[r]
            rows, columns, entries = at_rest.constraint_hessian_entries(p, weights, *curvature_args)
            seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - started
        started = timing.clock_seconds(clock, clock_id, buffer)
        step = np.empty(0)
        for damping in DAMPING:  # escalate only if rounding breaks the factorization
            diagonal = np.empty(n)
            for j in range(n):
                diagonal[j] = (w[j] + 1e-12) + damping * mu * norms[j]
            band, band_border, corner = gram_arrays(csr_indptr, csr_indices, csr_values, diagonal, mu, border)
            if near:
                exact = curved_hessian(band, rows, columns, entries)
                if exact.size:
                    band = exact
            qp_counts[:] = 0
            # np.int64: a global int passed on is a literal type, and box_qp (with MPRGP inside) would be
            # compiled a second time for it
            step, qp_status, _ = mprgp.box_qp(band, band_border, corner, negative, d_lower, d_upper, start_step,
                                              qp_rtol, 0.0, np.int64(QP_MAX_ITERATIONS), precond, 1.0,
                                              active_set_steps, walking, qp_counts)
            if qp_status != 2:
                break
        seconds[1] += timing.clock_seconds(clock, clock_id, buffer) - started
        for j in range(n):
            at_lower[j], at_upper[j] = step[j] <= d_lower[j], step[j] >= d_upper[j]
        for k in range(len(_QP_COUNTS)):
            counts[_LINE_SEARCH + 1 + k] += qp_counts[_QP_COUNTS[k]]
        if qp_status != 0 and qp_status != 1:
            reason = QP_FAILED
            break
        slope = np.dot(gradient, step)
        merit, magnitude = _merit(w, p, p0, c, lam, mu, work)
        taken = counts[_GAUSS_NEWTON] - steps_before  # steps of this inner solve, this one included
        recent[taken - 1] = merit
        reference = recent[max(0, taken - NONMONOTONE):taken].max()
        rounding = ROUNDING * (abs(merit) + magnitude)
        if -slope <= rounding:
            reason = NO_PROGRESS  # the model predicts no decrease above the rounding of L
            break
        alpha, accepted, corrected = 1.0, False, False
        trial, c_trial, f_trial, merit_trial = np.empty(n), np.empty(0), np.empty(0), 0.0
        for _ in range(40):
            counts[_LINE_SEARCH] += 1
            for j in range(n):
                trial[j] = min(max(p[j] + alpha * step[j], lower[j]), upper[j])
            started = timing.clock_seconds(clock, clock_id, buffer)
            c_trial, f_trial = at_rest_residual(trial, forces_args, free, row_scale)
            seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - started
            merit_trial = _merit(w, trial, p0, c_trial, lam, mu, work)[0]
            if merit_trial <= reference + ARMIJO * alpha * slope + rounding:
                accepted = np.all(np.isfinite(c_trial))
                break
            if not corrected:  # the full step failed: its second-order correction before any halving
                corrected = True
                started = timing.clock_seconds(clock, clock_id, buffer)
                candidate = corrected_trial(band, band_border, corner, at_lower, at_upper, csc_indptr, csc_indices,
                                            values, p, step, c, c_trial, mu, lower, upper)
                seconds[1] += timing.clock_seconds(clock, clock_id, buffer) - started
                if candidate.size:
                    counts[_LINE_SEARCH] += 1
                    started = timing.clock_seconds(clock, clock_id, buffer)
                    c_candidate, f_candidate = at_rest_residual(candidate, forces_args, free, row_scale)
                    seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - started
                    merit_candidate = _merit(w, candidate, p0, c_candidate, lam, mu, work)[0]
                    if merit_candidate <= reference + ARMIJO * slope + rounding:
                        trial, c_trial, f_trial, merit_trial = candidate, c_candidate, f_candidate, merit_candidate
                        accepted = np.all(np.isfinite(c_trial))
                        counts[_CORRECTED] += 1
                        break
            alpha *= 0.5
        if not accepted:
            reason = NO_PROGRESS  # no descent left at this accuracy: the outer loop decides
            break
        stalled = stalled + 1 if merit_trial > merit - rounding else 0
        p, c, f, moved = trial, c_trial, f_trial, True
        started = timing.clock_seconds(clock, clock_id, buffer)
        values = at_rest.jacobian_values(p, *jacobian_args)
        seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - started
        norms = csc_column_norms(csc_indptr, values)
        scale = np.empty(n)
        for j in range(n):
            scale[j] = w[j] + norms[j] + 1e-300
        steps[recorded] = largest_magnitude(c)
        recorded += 1
        if stalled >= STALL:
            reason = NO_PROGRESS  # L no longer decreases above its rounding: the outer loop decides
            break
    return reason, qp_status, optimality, stalled, moved, recorded, p, c, f, values, scale
