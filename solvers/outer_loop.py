"""asc's outer loop compiled: the augmented Lagrangian iterations with no Python between them.

One call of ``outer_iterations`` runs solve_alm's outer iterations (alm module docstring: "Outer
loop", "Converged", "Scale", "Newton-SQP") from its current state until the solve ends or needs the
infeasibility test: each inner solve (gauss_newton's compiled loop, called directly), the
multiplier update lam <- lam + mu c and its least-squares alternative at a feasible p
(linalg.normal's compiled semi-normal equations), the convergence test and its KKT confirmation
(contract.optimality.nearby_band_kkt_distance, refining the last SQP step's band LU where its
free set is the working set), the SQP step where the constraint stalls or no Gauss-Newton step
has moved p yet (a band LU, its second-order correction with the same factors; alm._sqp_step,
alm "Start"), Newton-SQP with the constraints'
curvature (formulation.at_rest.constraint_hessian_entries; alm._newton_sqp and _newton_trial),
the penalty's growth and the inner target's tightening. The Python loop in alm does the same in
the same order, and the two give the same p bit for bit (the same kernels on the same inputs;
tests/test_gauss_newton.py compares whole solves).

The infeasibility test and its best effort (the least residual's QPs, the static sag's
minimization through scipy) hand the iteration back to solve_alm, which takes them in Python
and calls again if the solve goes on: a strand that reaches them is one the boxes cannot balance,
whose best effort costs far more than the iterations. The strands of a groom on a head never
do: every iteration of their solves runs here.

It applies where the inner loop and the constraints' curvature are compiled (gauss_newton.available,
Problem.curvature_kernels) and the saddle system is a band without a dense column (no strand
multiplier: linalg.saddle.band_order).
"""
from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from sagfree.contract.optimality import (band_kkt_distance, gradient_scale_kernel, nearby_band_kkt_distance,
                                         scaled_projected_gradient_kernel, working_set_kernel)
from sagfree.formulation import at_rest
from sagfree.formulation.problem import Problem
from sagfree.linalg import lapack, timing
from sagfree.linalg.band import dense_count
from sagfree.linalg.compressed import csc_matvec, csc_rmatvec
from sagfree.linalg.normal import seminormal_kernel
from sagfree.linalg.saddle import (band_factors, band_order, no_band_factors, plain_band_factors,
                                   solve_band_factors)

from . import gauss_newton, mprgp
from .gauss_newton import (INNER_STEPS, MAX_ITERATIONS, MAX_SECONDS, QP_FAILED, STALL, at_rest_residual,
                           largest_magnitude, regularizer_value)
from .multipliers import SHIFT

# why outer_iterations returned: converged (the distance in Stop.distance); an inner solve's limit or
# failure (Stop.reason, Stop.qp_status); out of outer iterations; the infeasibility test for solve_alm;
# Gauss-Newton crawled at a feasible p after the last Newton-SQP attempt (solve_alm ends the solve)
CONVERGED, INNER_STOPPED, OUT_OF_OUTER, INFEASIBILITY, CRAWLED = range(5)
#: outer counters the loop advances, in the order of its array
OUTER_COUNTED = ("outer", "sqp", "tightened", "newton_sqp")

# solve_alm's constants, repeated here for the compiled loop (alm imports them from here)
SQP_DECREASE = 0.5  # the SQP step is taken if it reduces |c|_inf at least by this factor (alm._sqp_step)
MIN_TARGET = 1e-14  # floor of the inner target when the KKT distance keeps disagreeing
NEWTON_NEAR = 1e-4  # |c|_inf at or below which a stalled constraint whose SQP step fails gets Newton-SQP
NEWTON_ATTEMPTS = 3  # attempts per solve
NEWTON_AFTER = 1  # ... each after this many crawling outer iterations in a row at a feasible p
NEWTON_STEPS = 30  # exact-Hessian SQP steps per attempt (alm module docstring, Newton-SQP)
NEWTON_GROWTH = 10.0  # a retried attempt halves a step while it leaves |c|_inf above this factor of its start ...
NEWTON_HALVINGS = 8  # ... at most this many times (alm._newton_trial)
CRAWL_ROUNDS = 10  # feasible crawling outer iterations in a row after the last attempt that end the solve
BOUND_ROUNDS = 5  # primal-dual active-set rounds of a bounded Newton-SQP step (bounded_newton_step)
NEAR = 1e-6  # contract.optimality.working_set's default: the free set of the SQP step and the KKT distance


class Stop(NamedTuple):
    """Where ``outer_iterations`` returned: the event, the loop's variables as solve_alm keeps them
    (J a StrandJacobian; nearby the last SQP step's band factors, or None), and this iteration's
    values a branch reads (violation, the KKT distance where measured, converged, stalls)."""
    event: int
    reason: int
    qp_status: str
    p: np.ndarray
    c: np.ndarray
    J: object
    scale: np.ndarray
    lam: np.ndarray
    at_lower: np.ndarray
    at_upper: np.ndarray
    mu: float
    omega: float
    target: float
    previous_violation: float
    feasible_rounds: int
    attempts: int
    violation: float
    distance: float
    converged: bool
    stalls: bool
    nearby: tuple | None
    kept: tuple | None


def available(problem: Problem) -> bool:
    """True where ``outer_iterations`` can run on ``problem`` (module docstring)."""
    if not gauss_newton.available(problem) or problem.curvature_kernels is None:
        return False
    structure = problem.at_rest_kernels[4]
    indptr, indices, rows = structure[0], structure[1], problem.free_index.size
    return (band_order(indptr, indices, rows) is not None
            and int(np.diff(indptr).max(initial=0)) <= dense_count(rows))


def outer_iterations(problem: Problem, model, p, c, J, scale, lam, at_lower, at_upper, mu: float, omega: float,
                     target: float, previous_violation: float, feasible_rounds: int, attempts: int, nearby,
                     tol: float, kkt_tol: float, gradient_tol: float, max_outer: int, max_iterations: int,
                     deadline: float, mu0: float, mu_growth: float, qp_rtol: float, preconditioner: str,
                     counts: dict, history: list, kept) -> Stop:
    """Run solve_alm's outer iterations from its variables (module docstring) until an event;
    counts and history are advanced as the Python loop advances them. deadline: the
    time.perf_counter() value of max_seconds. kept: Newton-SQP's KKT point that raised R, (p, c,
    KKT distance) or None (alm._newton_attempt), in and out (Stop.kept)."""
    forces_args, jacobian_args, free, row_scale, structure = problem.at_rest_kernels
    lower, upper = problem.layout.lower, problem.layout.upper
    position = band_order(structure[0], structure[1], free.size)
    border = model.border
    inner_counts = np.array([counts[name] for name in gauss_newton.COUNTED], dtype=np.int64)
    outer_counts = np.array([counts[name] for name in OUTER_COUNTED], dtype=np.int64)
    real = np.array([mu, omega, target, previous_violation, np.nan, np.nan, np.inf if kept is None else kept[2]])
    integer = np.array([feasible_rounds, attempts, 0, 0, 0, 0, 0, 0], dtype=np.int64)
    seconds = np.zeros(2)
    # one per Gauss-Newton step, at most one per SQP step or Newton-SQP attempt
    steps = np.empty(max_iterations + 2 * max_outer + 2)
    clock, clock_id = timing.CLOCK
    event, p, c, f, values, scale, lam, nearby, kept_p, kept_c = _outer(
        forces_args, jacobian_args, problem.curvature_kernels, gauss_newton.curvature_applies(problem, border), free,
        row_scale, structure, position, lapack.DGBTRF, lapack.DGBTRS, clock, clock_id, model.w, model.p0, lower, upper,
        np.ascontiguousarray(p, dtype=float),
        np.ascontiguousarray(c, dtype=float), J.csc()[2], np.ascontiguousarray(scale, dtype=float),
        np.ascontiguousarray(lam, dtype=float), at_lower, at_upper, no_band_factors() if nearby is None else nearby,
        float(tol), float(kkt_tol), float(gradient_tol), int(max_outer), int(max_iterations),
        float(deadline - timing.clock_offset()), float(mu0), float(mu_growth), float(qp_rtol),
        mprgp.PRECONDITIONERS[preconditioner], border, mprgp.ACTIVE_SET_STEPS if border == 0 else 0, mprgp.WALKING,
        real, integer, inner_counts, outer_counts, seconds, steps, np.empty(0) if kept is None else kept[0],
        np.empty(0) if kept is None else kept[1])
    timing.add(timing.MODEL, seconds[0])
    timing.add(timing.LINEAR_ALGEBRA, seconds[1])
    for name, value in zip(gauss_newton.COUNTED, inner_counts.tolist()):
        counts[name] = value
    for name, value in zip(OUTER_COUNTED, outer_counts.tolist()):
        counts[name] = value
    feasible_rounds, attempts, converged, stalls, reason, qp_status, recorded, moved = integer.tolist()
    history.extend(steps[:recorded].tolist())
    if moved:
        problem.remember_at_rest(p, f, values)
        J = problem.strand_jacobian(p)
    return Stop(event, reason, mprgp.STATUS[qp_status], p, c, J, scale, lam, at_lower, at_upper, *real[:4].tolist(),
                feasible_rounds, attempts, float(real[4]), float(real[5]), bool(converged), bool(stalls),
                nearby if nearby[0].size else None, (kept_p, kept_c, float(real[6])) if kept_p.size else None)


@numba.njit(cache=True)
def _outer(forces_args, jacobian_args, curvature_args, curved, free, row_scale, structure, position, dgbtrf, dgbtrs,
           clock, clock_id, w, p0, lower, upper, p, c, values, scale, lam, at_lower, at_upper, nearby, tol, kkt_tol,
           gradient_tol, max_outer, max_iterations, deadline, mu0, mu_growth, qp_rtol, precond, border,
           active_set_steps, walking, real, integer, counts, outer_counts, seconds, history, kept_p,
           kept_c):  # pragma: no cover - compiled
    """The loop of ``outer_iterations`` (solve_alm's, line by line). real: [mu, omega, target,
    previous violation, violation, distance, kept's KKT distance] and integer: [feasible rounds,
    Newton attempts, converged, stalls, inner reason, QP status, history entries, moved] are read and written in
    place; counts in gauss_newton.COUNTED order, outer_counts in OUTER_COUNTED order; curvature_args:
    Problem.curvature_kernels (Newton-SQP's constraint curvature, and the inner Hessian's where
    ``curved``: gauss_newton.curvature_applies); seconds
    [model, linear algebra]; kept_p, kept_c: Newton-SQP's KKT point that raised R (empty if none;
    alm._newton_attempt). Returns (event, p, c, f(p) or empty if p did not move, dc/dp values,
    scale, lam, nearby, kept_p, kept_c)."""
    indptr, indices = structure[0], structure[1]
    lam = lam.copy()  # updated in place below; the caller's stays as it was
    mu, omega, target, previous_violation = real[0], real[1], real[2], real[3]
    feasible_rounds, attempts, kept_distance = integer[0], integer[1], real[6]
    buffer = np.zeros(2, dtype=np.int64)
    steps = np.empty(INNER_STEPS + 1)
    rows = c.size
    f = np.empty(0)
    recorded, moved_any, event = 0, False, OUT_OF_OUTER
    violation, distance, converged, stalls = np.nan, np.nan, False, False
    while outer_counts[0] < max_outer:
        outer_counts[0] += 1
        # ---- inner: Gauss-Newton on the augmented Lagrangian ----
        steps_before = counts[0]
        (reason, qp_status, optimality, stalled, moved, taken, p_inner, c_inner, f_inner, values_inner,
         scale_inner) = gauss_newton.inner_loop(
            forces_args, jacobian_args, curvature_args, curved, free, row_scale, structure, clock, clock_id, w, p0,
            lower, upper, p, c, values, scale, lam, mu, omega, tol, max_iterations, deadline, qp_rtol, precond, border,
            active_set_steps, walking, at_lower, at_upper, counts, seconds, steps)
        for k in range(taken):
            history[recorded + k] = steps[k]
        recorded += taken
        if moved:
            p, c, f, values, scale = p_inner, c_inner, f_inner, values_inner, scale_inner
            moved_any = True
            nearby = no_band_factors()
        if reason == MAX_ITERATIONS or reason == MAX_SECONDS or reason == QP_FAILED:
            integer[4], integer[5] = reason, qp_status
            event = INNER_STOPPED
            break
        # ---- outer: multipliers, penalty, convergence ----
        violation = largest_magnitude(c)
        unmoved = counts[0] == 0 and 0.1 * optimality < omega
        if counts[0] == steps_before and violation > tol and (omega > target or unmoved):
            if omega > target:  # alm: a multiplier update here would not move p
                omega = max(target, 0.1 * omega)
                while omega > target and optimality <= omega:
                    omega = max(target, 0.1 * omega)
            else:  # alm: p has not moved by a Gauss-Newton step: the SQP step, then a target that steps
                taken, p, c, f, lam, nearby, values, scale = _tried_sqp_step(
                    forces_args, jacobian_args, free, row_scale, indptr, indices, position, dgbtrf, dgbtrs, w, p0,
                    lower, upper, p, c, f, lam, nearby, values, scale, violation, tol, clock, clock_id, outer_counts,
                    seconds, history, recorded)
                if taken:
                    moved_any, recorded = True, recorded + 1
                omega = 0.1 * optimality
            continue
        for r in range(rows):
            lam[r] = lam[r] + mu * c[r]
        regularizer_gradient = w * (p - p0)
        optimality = _lagrangian_stationarity(p, regularizer_gradient, indptr, indices, values, lam, scale, lower,
                                              upper)
        if violation <= tol and optimality > gradient_tol:
            estimate = _least_squares_multipliers(indptr, indices, values, rows, regularizer_gradient, scale, p,
                                                  lower, upper)
            kkt = _lagrangian_stationarity(p, regularizer_gradient, indptr, indices, values, estimate, scale, lower,
                                           upper)
            if kkt < optimality:
                lam, optimality = estimate, kkt
        converged = violation <= tol and (optimality <= gradient_tol or stalled >= STALL)
        if converged:
            started = timing.clock_seconds(clock, clock_id, buffer)
            distance = nearby_band_kkt_distance(dgbtrf, dgbtrs, indptr, indices, values, position, w,
                                                regularizer_gradient, c, p, lower, upper, NEAR, nearby)
            seconds[1] += timing.clock_seconds(clock, clock_id, buffer) - started
            converged = distance <= kkt_tol
            if not converged and (optimality <= target or stalled >= STALL):
                outer_counts[2] += 1
                target = max(1e-3 * target, MIN_TARGET)
        crawled = violation <= tol and counts[0] > steps_before
        feasible_rounds = feasible_rounds + 1 if crawled else 0
        stalls = violation > tol and violation > 0.25 * previous_violation
        if stalls:  # before growing mu, try the constrained step (SQP)
            taken, p, c, f, lam, nearby, values, scale = _tried_sqp_step(
                forces_args, jacobian_args, free, row_scale, indptr, indices, position, dgbtrf, dgbtrs, w, p0, lower,
                upper, p, c, f, lam, nearby, values, scale, violation, tol, clock, clock_id, outer_counts, seconds,
                history, recorded)
            if taken:
                moved_any, recorded = True, recorded + 1
                previous_violation = violation
                continue
        # Newton-SQP where Gauss-Newton crawls at a feasible p or the SQP step failed near it
        if (not converged and attempts < NEWTON_ATTEMPTS
                and (feasible_rounds >= NEWTON_AFTER or (stalls and violation <= NEWTON_NEAR))):
            attempts, feasible_rounds = attempts + 1, 0
            newton = (forces_args, jacobian_args, curvature_args, free, row_scale, indptr, indices, position, dgbtrf,
                      dgbtrs, w, p0, lower, upper, p, c, values, tol, kkt_tol, clock, clock_id, outer_counts, seconds)
            # np.int64: literal ints would compile _newton_sqp once for each; alm._newton_attempt: the
            # bounded steps, the equality steps, then those halved while they leave |c|_inf far above
            # their start
            found, raised = False, False
            for variant in range(3):
                halvings = np.int64(NEWTON_HALVINGS) if variant == 2 else np.int64(0)
                bounded = variant == 0
                found, raised, x, c_x, f_x, values_x, distance_x = _newton_sqp(*newton, halvings, bounded)
                if found and raised:
                    kept_p, kept_c, kept_distance = _kept(w, p0, x, c_x, distance_x, kept_p, kept_c, kept_distance)
                    found = False
                if found:
                    break
            if found:
                p, c, f, values, distance, moved_any = x, c_x, f_x, values_x, distance_x, True
                violation = largest_magnitude(c)
                history[recorded] = violation
                recorded += 1
                converged = True
        if converged:
            event = CONVERGED
            break
        if attempts >= NEWTON_ATTEMPTS and feasible_rounds >= CRAWL_ROUNDS:
            event = CRAWLED  # alm: the crawl ends the solve (module docstring, Newton-SQP)
            break
        if stalls:
            mu *= mu_growth
            if mu >= 1e4 * mu0:
                event = INFEASIBILITY  # solve_alm takes the infeasibility test, then the rest of this iteration
                break
        previous_violation = violation
        omega = max(target, 0.1 * omega)
    real[0], real[1], real[2], real[3], real[4], real[5] = mu, omega, target, previous_violation, violation, distance
    real[6] = kept_distance
    integer[0], integer[1], integer[2], integer[3] = feasible_rounds, attempts, converged, stalls
    integer[6], integer[7] = recorded, moved_any
    return event, p, c, f, values, scale, lam, nearby, kept_p, kept_c


@numba.njit(cache=True)
def _tried_sqp_step(forces_args, jacobian_args, free, row_scale, indptr, indices, position, dgbtrf, dgbtrs, w, p0,
                    lower, upper, p, c, f, lam, nearby, values, scale, violation, tol, clock, clock_id, outer_counts,
                    seconds, history, recorded):  # pragma: no cover - compiled
    """The SQP step from p (_sqp_step, bound SQP_DECREASE |c|_inf) and, where it is taken, alm._taken:
    (taken, p, c, f, lam, nearby, dc/dp values, gradient scale) at its point, the step counted and
    its |c|_inf recorded at history[recorded]; the inputs as they were where it is not."""
    buffer = np.zeros(2, dtype=np.int64)
    taken, p_sqp, c_sqp, f_sqp, lam_sqp, factors = _sqp_step(
        forces_args, jacobian_args, free, row_scale, indptr, indices, values, position, dgbtrf, dgbtrs, w, p0, lower,
        upper, p, c, SQP_DECREASE * violation, tol, clock, clock_id, seconds)
    if not taken:
        return False, p, c, f, lam, nearby, values, scale
    outer_counts[1] += 1
    history[recorded] = largest_magnitude(c_sqp)
    started = timing.clock_seconds(clock, clock_id, buffer)
    values_sqp = at_rest.jacobian_values(p_sqp, *jacobian_args)
    seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - started
    return True, p_sqp, c_sqp, f_sqp, lam_sqp, factors, values_sqp, gradient_scale_kernel(w, indptr, values_sqp)


@numba.njit(cache=True)
def _lagrangian_stationarity(p, regularizer_gradient, indptr, indices, values, lam, scale, lower,
                             upper):  # pragma: no cover - compiled
    """scaled_projected_gradient(p, grad R + J^T lam, scale, lower, upper) (solve_alm's)."""
    gradient = regularizer_gradient + csc_rmatvec(indptr, indices, values, lam)
    return scaled_projected_gradient_kernel(p, gradient, scale, lower, upper)


@numba.njit(cache=True)
def _least_squares_multipliers(indptr, indices, values, rows, regularizer_gradient, scale, p, lower,
                               upper):  # pragma: no cover - compiled
    """solvers.multipliers.least_squares_multipliers on a Jacobian without a dense column
    (``available`` checks that), its free set the variables strictly inside their box."""
    free = np.empty(p.size, dtype=np.bool_)
    for j in range(p.size):
        free[j] = p[j] > lower[j] and p[j] < upper[j]
    return seminormal_kernel(indptr, indices, values, rows, regularizer_gradient, scale, free, SHIFT)


@numba.njit(cache=True)
def _sqp_step(forces_args, jacobian_args, free_index, row_scale, indptr, indices, values, position, dgbtrf, dgbtrs, w,
              p0, lower, upper, p, c, bound, tol, clock, clock_id, seconds):  # pragma: no cover - compiled
    """alm._sqp_step: (taken, p, c, f, lam, band factors at p for the KKT confirmation); not taken
    where the saddle system is singular or the step leaves |c|_inf > bound."""
    buffer = np.zeros(2, dtype=np.int64)
    n = p.size
    free = working_set_kernel(p, lower, upper, NEAR)
    empty = np.empty(0)
    started = timing.clock_seconds(clock, clock_id, buffer)
    factors = plain_band_factors(dgbtrf, indptr, indices, values, w, free, position)
    if factors[0].size == 0:
        seconds[1] += timing.clock_seconds(clock, clock_id, buffer) - started
        return False, p, c, empty, empty, factors
    step, lam = solve_band_factors(dgbtrs, factors, w * (p - p0), c)
    now = timing.clock_seconds(clock, clock_id, buffer)
    seconds[1] += now - started
    trial = np.minimum(np.maximum(p + step, lower), upper)
    c_trial, f_trial = at_rest_residual(trial, forces_args, free_index, row_scale)
    seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - now
    violation = largest_magnitude(c_trial)
    if not violation <= tol:
        # second-order correction: the least W-norm step back to c = 0 with the same J and factors
        started = timing.clock_seconds(clock, clock_id, buffer)
        correction, _ = solve_band_factors(dgbtrs, factors, np.zeros(n), c_trial)
        now = timing.clock_seconds(clock, clock_id, buffer)
        seconds[1] += now - started
        corrected = np.minimum(np.maximum(trial + correction, lower), upper)
        c_corrected, f_corrected = at_rest_residual(corrected, forces_args, free_index, row_scale)
        seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - now
        if largest_magnitude(c_corrected) < violation or not violation <= bound:
            trial, c_trial, f_trial = corrected, c_corrected, f_corrected
    if not largest_magnitude(c_trial) <= bound:  # also rejects NaN
        return False, p, c, empty, empty, factors
    return True, trial, c_trial, f_trial, lam, factors


@numba.njit(cache=True)
def _newton_sqp(forces_args, jacobian_args, curvature_args, free_index, row_scale, indptr, indices, position, dgbtrf,
                dgbtrs, w, p0, lower, upper, p, c, values, tol, kkt_tol, clock, clock_id, outer_counts, seconds,
                halvings, bounded):  # pragma: no cover - compiled
    """alm._newton_sqp: (found, raised, p, c, f, dc/dp values, KKT distance) after at most
    NEWTON_STEPS exact-Hessian SQP steps from p (c and dc/dp ``values`` there), each bounded
    (bounded_newton_step) where ``bounded``; found where they end at |c|_inf <= tol and a KKT
    distance <= kkt_tol, raised where R is above alm's bound there. Counts its steps in
    outer_counts[3]."""
    buffer = np.zeros(2, dtype=np.int64)
    n = p.size
    work = np.empty(n)
    empty = np.empty(0)
    start_objective = regularizer_value(w, p, p0, work)
    x, current = p.copy(), True  # values: dc/dp at x while current
    lam = np.empty(0)
    for _ in range(NEWTON_STEPS):
        if not current:
            started = timing.clock_seconds(clock, clock_id, buffer)
            values = at_rest.jacobian_values(x, *jacobian_args)
            seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - started
        gradient = w * (x - p0)
        free = working_set_kernel(x, lower, upper, NEAR)
        if lam.size == 0:  # the first step's; each later one takes the previous step's
            lam = _least_squares_multipliers(indptr, indices, values, c.size, gradient,
                                             gradient_scale_kernel(w, indptr, values), x, lower, upper)
            if not np.all(np.isfinite(lam)):
                return False, False, p, empty, empty, empty, np.inf
            start_objective += feasibility_cost(lam, c)
        started = timing.clock_seconds(clock, clock_id, buffer)
        rows, columns, entries = at_rest.constraint_hessian_entries(x, lam, *curvature_args)
        now = timing.clock_seconds(clock, clock_id, buffer)
        seconds[0] += now - started
        found, step, lam_step, free_step = _newton_direction(bounded, dgbtrf, dgbtrs, indptr, indices, values, w, free,
                                                             position, rows, columns, entries, gradient, c, x, lower,
                                                             upper)
        if not found:  # too few free directions (as in kkt_optimality): free those near a bound
            for j in range(n):
                free[j] = x[j] > lower[j] and x[j] < upper[j]
            found, step, lam_step, free_step = _newton_direction(bounded, dgbtrf, dgbtrs, indptr, indices, values, w,
                                                                 free, position, rows, columns, entries, gradient, c,
                                                                 x, lower, upper)
        seconds[1] += timing.clock_seconds(clock, clock_id, buffer) - now
        if not found:
            return False, False, p, empty, empty, empty, np.inf
        lam, free = lam_step, free_step
        if not np.all(np.isfinite(step)):
            return False, False, p, empty, empty, empty, np.inf
        outer_counts[3] += 1
        usable, trial, c_trial, f_trial = _newton_trial(forces_args, free_index, row_scale, indptr, indices, values,
                                                        position, dgbtrf, dgbtrs, w, lower, upper, x, step, c, free,
                                                        tol, halvings, clock, clock_id, seconds)
        if not usable or not np.all(np.isfinite(c_trial)):
            return False, False, p, empty, empty, empty, np.inf
        x, c, current = trial, c_trial, False
        if largest_magnitude(c_trial) <= tol:
            started = timing.clock_seconds(clock, clock_id, buffer)
            values, current = at_rest.jacobian_values(x, *jacobian_args), True
            now = timing.clock_seconds(clock, clock_id, buffer)
            seconds[0] += now - started
            distance = band_kkt_distance(dgbtrf, dgbtrs, indptr, indices, values, position, w, w * (x - p0), c_trial,
                                         x, lower, upper, NEAR)
            seconds[1] += timing.clock_seconds(clock, clock_id, buffer) - now
            if distance <= kkt_tol:
                raised = not regularizer_value(w, x, p0, work) <= start_objective * (1.0 + 1e-9) + 1e-15
                return True, raised, x, c_trial, f_trial, values, distance
    return False, False, p, empty, empty, empty, np.inf


@numba.njit(cache=True)
def _newton_trial(forces_args, free_index, row_scale, indptr, indices, values, position, dgbtrf, dgbtrs, w, lower,
                  upper, x, step, c, free, tol, halvings, clock, clock_id, seconds):  # pragma: no cover - compiled
    """alm._newton_trial: (usable, trial point, its c, its f); not usable where the correction's
    saddle system is singular."""
    buffer = np.zeros(2, dtype=np.int64)
    bound = NEWTON_GROWTH * max(tol, largest_magnitude(c))
    factors = no_band_factors()
    factored = False
    fraction = 1.0
    trial, c_trial, f_trial = x, c, np.empty(0)
    for _ in range(halvings + 1):
        trial = np.minimum(np.maximum(x + fraction * step, lower), upper)
        started = timing.clock_seconds(clock, clock_id, buffer)
        c_trial, f_trial = at_rest_residual(trial, forces_args, free_index, row_scale)
        seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - started
        if not largest_magnitude(c_trial) <= tol:
            started = timing.clock_seconds(clock, clock_id, buffer)
            if not factored:
                factors, factored = plain_band_factors(dgbtrf, indptr, indices, values, w, free, position), True
            if factors[0].size == 0:
                seconds[1] += timing.clock_seconds(clock, clock_id, buffer) - started
                return False, trial, c_trial, f_trial
            correction, _ = solve_band_factors(dgbtrs, factors, np.zeros(x.size), c_trial)
            now = timing.clock_seconds(clock, clock_id, buffer)
            seconds[1] += now - started
            trial = np.minimum(np.maximum(trial + correction, lower), upper)
            c_trial, f_trial = at_rest_residual(trial, forces_args, free_index, row_scale)
            seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - now
        if largest_magnitude(c_trial) <= bound:
            break
        fraction *= 0.5
    return True, trial, c_trial, f_trial


@numba.njit(cache=True)
def _newton_direction(bounded, dgbtrf, dgbtrs, indptr, indices, values, w, free, position, rows, columns, entries,
                      gradient, c, x, lower, upper):  # pragma: no cover - compiled
    """(found, d, lam, free) of one Newton-SQP step from x: bounded_newton_step where ``bounded``, else
    the equality step on ``free`` (SaddleFactor(J, w, free, curvature).solve(gradient, c)); found false
    where its system is singular."""
    if bounded:
        return bounded_newton_step(dgbtrf, dgbtrs, indptr, indices, values, w, free, position, rows, columns, entries,
                                   gradient, c, x, lower, upper)
    factors = _curved_factors(dgbtrf, indptr, indices, values, w, free, position, rows, columns, entries)
    if factors[0].size == 0:
        return False, np.empty(0), np.empty(0), free
    step, lam = solve_band_factors(dgbtrs, factors, gradient, c)
    return True, step, lam, free


@numba.njit(cache=True)
def bounded_newton_step(dgbtrf, dgbtrs, indptr, indices, values, w, free, position, rows, columns, entries,
                        gradient, c, x, lower, upper):  # pragma: no cover - compiled
    """(found, d, lam, free) of a Newton-SQP step that keeps the box (alm module docstring,
    Newton-SQP): the QP min 1/2 d^T W d + gradient^T d s.t. J d = -c, lower <= x + d <= upper (W =
    diag(w) + the curvature triplets (rows, columns, entries), J in compressed columns ``values``)
    by primal-dual active-set rounds (Hintermueller, Ito & Kunisch 2002) on the saddle system. The
    variables off ``free`` start held on their nearer bound; each round solves the equality QP of the
    others with the held ones on their bounds, then holds those its step pushes out of the box and
    releases the held ones whose bound multiplier (W d + gradient + J^T lam there) has the wrong
    sign. It stops where the sets repeat, after BOUND_ROUNDS, or where the system turns singular,
    with the last round's step. found: false where the first round's system is singular or its step
    not finite. free: the variables the step left free (those its correction moves, _newton_trial)."""
    n = x.size
    current = free.copy()
    held_lower, held_upper = np.empty(n, dtype=np.bool_), np.empty(n, dtype=np.bool_)
    for j in range(n):
        held_lower[j] = not current[j] and x[j] - lower[j] <= upper[j] - x[j]
        held_upper[j] = not current[j] and not held_lower[j]
    found, last_d, last_lam, last_free = False, np.empty(0), np.empty(0), current.copy()
    fixed = np.zeros(n)
    for _ in range(BOUND_ROUNDS + 1):
        for j in range(n):
            fixed[j] = lower[j] - x[j] if held_lower[j] else (upper[j] - x[j] if held_upper[j] else 0.0)
        factors = _curved_factors(dgbtrf, indptr, indices, values, w, current, position, rows, columns, entries)
        if factors[0].size == 0:
            break
        pushed = _curvature_product(rows, columns, entries, fixed)
        for j in range(n):
            pushed[j] += gradient[j] + w[j] * fixed[j]
        step, lam = solve_band_factors(dgbtrs, factors, pushed, c + csc_matvec(indptr, indices, values, fixed, c.size))
        d = np.empty(n)
        for j in range(n):
            d[j] = step[j] if current[j] else fixed[j]
        if not np.all(np.isfinite(d)):
            break
        found, last_d, last_lam, last_free = True, d, lam, current.copy()
        multipliers = _curvature_product(rows, columns, entries, d) + csc_rmatvec(indptr, indices, values, lam)
        changed = False
        for j in range(n):
            bound_multiplier = multipliers[j] + w[j] * d[j] + gradient[j]
            to_lower = (current[j] and x[j] + d[j] < lower[j]) or (held_lower[j] and bound_multiplier >= 0.0)
            to_upper = (current[j] and x[j] + d[j] > upper[j]) or (held_upper[j] and bound_multiplier <= 0.0)
            changed = changed or to_lower != held_lower[j] or to_upper != held_upper[j]
            held_lower[j], held_upper[j] = to_lower, to_upper
        if not changed:
            break
        for j in range(n):
            current[j] = not (held_lower[j] or held_upper[j])
    return found, last_d, last_lam, last_free


@numba.njit(cache=True)
def _curvature_product(rows, columns, entries, v):  # pragma: no cover - compiled
    """(sum of the curvature triplets) v, duplicates summed."""
    out = np.zeros(v.size)
    for k in range(rows.size):
        out[rows[k]] += entries[k] * v[columns[k]]
    return out


@numba.njit(cache=True)
def _kept(w, p0, x, c, distance, kept_p, kept_c, kept_distance):  # pragma: no cover - compiled
    """alm._newton_attempt's choice of (p, c, KKT distance): Newton-SQP's KKT point x where none was
    kept (kept_p empty) or x has the lesser R, else the kept one."""
    work = np.empty(x.size)
    if kept_p.size and not regularizer_value(w, x, p0, work) < regularizer_value(w, kept_p, p0, work):
        return kept_p, kept_c, kept_distance
    return x, c, distance


@numba.njit(cache=True)
def feasibility_cost(lam, c):  # pragma: no cover - compiled
    """max(0, lam^T c): what reaching c = 0 from a point with residual c and multipliers lam adds to
    R, to first order (the allowance of Newton-SQP's test against R at its start; alm._newton_sqp)."""
    total = 0.0
    for r in range(c.size):
        total += lam[r] * c[r]
    return max(0.0, total)


@numba.njit(cache=True)
def _curved_factors(dgbtrf, indptr, indices, values, w, free, position, rows, columns,
                    entries):  # pragma: no cover - compiled
    """``band_factors`` of the saddle system with W = diag(w) + the curvature triplets (rows,
    columns, entries) between free variables (SaddleFactor(J, w, free, curvature))."""
    keep = np.empty(rows.size, dtype=np.bool_)
    for k in range(rows.size):
        keep[k] = free[rows[k]] and free[columns[k]]
    return band_factors(dgbtrf, indptr, indices, values, w, free, position, rows[keep], columns[keep], entries[keep])
