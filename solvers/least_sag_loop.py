"""The least sag's minimization as one compiled call: solvers.least_sag's StaticSag and
solvers.reflective's trust-region loop, line by line, with no Python between evaluations.

An evaluation of the least sag is a continued static solve (newton.newton_kernel), each accepted
point a linearization (the free Hessian band at the equilibrium, its banded Cholesky factor, dc/dp
there by at_state.jacobian_values) and each step conjugate gradients through the sag operator
(solvers.sag_operator); driven from Python, the calls between them were ~12% of an infeasible
strand's time. ``least_sag_loop`` runs the whole minimization and records the visited equilibria in
arrays made by ``model_arguments``; the candidates' confirmation from q* (least_sag.least_sag)
stays in Python: at most VERIFIED static solves, each one compiled call.

The model's state lives in arrays that the loop's helpers update in place: the last equilibrium
found (q and its frames), the point p it is at, and the last linearization (the p and equilibrium
it was taken at, K's factor and B's values); ``flags`` numbers the equilibria found so that "the
linearization is at the current equilibrium" is StaticSag's ``known[0] is self.state``. The
arithmetic is StaticSag's and reflective_least_squares' (the same kernels and numeric helpers,
solvers.reflective), so the two paths visit the same points bit for bit (tests/test_least_sag.py).

numba optimizes every kernel together with the whole call tree linked into it, so each kernel
that calls the static solve pays for it again, and each inlined copy of a call adds to its
kernel's compile: the model's evaluations are one kernel (``_model``) holding one call of the
static solve and one of the linearization (a kernel per helper compiled 40% longer;
benchmarks/RESULTS.md).
"""
from __future__ import annotations

import numba
import numpy as np

from sagfree.formulation import at_state
from sagfree.formulation.newton import CONVERGED, MU_MIN, STAGNATED, TINY_STEP, newton_kernel, roundoff_floor
from sagfree.formulation.parameters import evaluate_slots
from sagfree.linalg import timing

from . import reflective as trf
from .sag_operator import (CG_ITERATIONS, CG_TOLERANCE, cgls, estimated_column_norms, jacobian_product,
                           jacobian_transposed_product, scaled_rows, stiffness_factor, tangent_step)

#: places in ``flags``: the equilibrium's number, whether ``at`` holds its p, the number of the
#: equilibrium the linearization was taken at (-1: none yet), the static solves' Newton steps, and
#: the visited equilibria recorded
STATE, AT, LINEARIZED, NEWTON, VISITS = range(5)
#: seconds' places: model evaluation, linear algebra (timing.MODEL, timing.LINEAR_ALGEBRA)
_MODEL, _ALGEBRA = 0, 1


@numba.njit(cache=True, inline="always")
def _static_solve(q, tangents, a1, twist, p, newton, constants, tol, max_steps, clock, clock_id,
                  seconds):  # pragma: no cover - compiled
    """simulation.equilibrium from (q, frames) with damping MU_MIN (a continuation's start):
    (q, converged, tangents, a1, twist, Newton steps)."""
    slots, strand, drivers, plan, gather, free, external, bodies = newton
    scale, metric, step_limit, geometry, anchor = constants
    squared_radius, reach, weight, lengths = geometry
    modulus = np.ascontiguousarray(evaluate_slots(slots[0][0], slots[0][1], slots[0][2], slots[0][3], p)[:, 1])
    floor = roundoff_floor(modulus, squared_radius, lengths, reach, weight)
    residuals, counts, empty = np.empty(max_steps + 1), np.zeros(5, dtype=np.int64), np.empty(0)
    q, outcome, _, tangents, a1, twist = newton_kernel(
        q, MU_MIN, tangents, a1, twist, p, slots, strand, drivers, plan, gather, free, external, bodies, empty, empty,
        scale, metric, step_limit, floor, anchor, tol, max_steps, residuals, counts, clock, clock_id, seconds)
    converged = outcome == CONVERGED or outcome == TINY_STEP or outcome == STAGNATED
    return q, converged, tangents, a1, twist, counts[1]


@numba.njit(cache=True, inline="always")
def _settle(p, state, flags, at, linearized, pattern, newton, constants, tol, max_steps, clock, clock_id,
            seconds):  # pragma: no cover - compiled
    """StaticSag._settle: continue the equilibrium to p from its tangent's prediction where the
    last linearization is at it (else, or where Newton fails from the prediction, from the
    equilibrium itself); the state updated in place where one was found. Whether one was."""
    q, tangents, a1, twist = state
    at_p, factor, data = linearized
    indptr, indices = pattern
    free = newton[5]
    predicted = flags[LINEARIZED] == flags[STATE]
    converged = False
    for attempt in range(2 if predicted else 1):
        start = q
        if attempt == 0 and predicted:
            start = q.copy()
            step = tangent_step(factor, indptr, indices, data, np.ascontiguousarray(p - at_p))
            for k in range(free.size):
                start[free[k]] += step[k]
        found, converged, found_tangents, found_a1, found_twist, steps = _static_solve(
            start, tangents, a1, twist, p, newton, constants, tol, max_steps, clock, clock_id, seconds)
        flags[NEWTON] += steps
        if converged:
            q[:] = found
            tangents[:] = found_tangents
            a1[:] = found_a1
            twist[:] = found_twist
            at[:] = p
            flags[STATE] += 1
            flags[AT] = 1
            break
    return converged


@numba.njit(cache=True)
def _model(linearize, p, state, flags, at, linearized, fixed):  # pragma: no cover - compiled
    """StaticSag's two evaluations in one kernel: without ``linearize`` the residuals at p
    (StaticSag.residuals), with it (K's factor, B's values) at the equilibrium of p
    (StaticSag._linearization). Returns (the residuals or nothing, the factor, the values). One
    kernel with one call of each heavy part: every kernel that calls the static solve or the
    linearization cost seconds of compilation of its own. ``fixed``: least_sag_loop's arguments
    (newton, constants, tol, max_steps, the residuals' rows, visited, jacobian, masses, clock,
    clock_id, seconds)."""
    newton, constants, tol, max_steps, rows, visited, jacobian, masses, clock, clock_id, seconds = fixed
    at_p, factor, data = linearized
    settled = True
    if not linearize or not flags[AT] or not np.array_equal(p, at):
        settled = _settle(p, state, flags, at, linearized, jacobian[6][:2], newton, constants, tol, max_steps, clock,
                          clock_id, seconds)
    if not linearize:
        return _recorded(p, settled, state, flags, rows, visited), factor, data
    if not (flags[LINEARIZED] == flags[STATE] and np.array_equal(at_p, p)):
        factor, data = _linearized(p, state, newton, constants, jacobian, masses, clock, clock_id, seconds)
        at_p[:] = p
        flags[LINEARIZED] = flags[STATE]
    return np.empty(0), factor, data


@numba.njit(cache=True, inline="always")
def _residuals(p, memory, factor, data, fixed):  # pragma: no cover - compiled
    """StaticSag.residuals(p) (``_model``); memory: the model's (state, flags, at, at_linear)."""
    state, flags, at, at_linear = memory
    return _model(np.bool_(False), p, state, flags, at, (at_linear, factor, data), fixed)[0]


@numba.njit(cache=True, inline="always")
def _linearization(p, memory, factor, data, fixed):  # pragma: no cover - compiled
    """StaticSag._linearization(p) (``_model``): (K's factor, B's values), the last ones if unchanged."""
    state, flags, at, at_linear = memory
    _, factor, data = _model(np.bool_(True), p, state, flags, at, (at_linear, factor, data), fixed)
    return factor, data


@numba.njit(cache=True, inline="always")
def _recorded(p, settled, state, flags, rows, visited):  # pragma: no cover - compiled
    """StaticSag.residuals after its settle: sqrt(m_i / M) (x_i - x_i*) / L at the equilibrium
    (NaN where none was found), recorded in ``visited`` (S, p, q, tangents, a1, twist)."""
    positions, weights, points = rows[0], rows[1], rows[2]
    out = np.full(positions.size, np.nan)
    if not settled:
        return out
    q, tangents, a1, twist = state
    for k in range(positions.size):
        out[k] = weights[k] * (q[positions[k]] - points[k])
    costs, ps, qs, all_tangents, all_a1, twists = visited
    k = flags[VISITS]
    costs[k] = 0.5 * np.dot(out, out)
    ps[k] = p
    qs[k] = q
    all_tangents[k] = tangents
    all_a1[k] = a1
    twists[k] = twist
    flags[VISITS] += 1
    return out


@numba.njit(cache=True, inline="always")
def _linearized(p, state, newton, constants, jacobian, masses, clock, clock_id, seconds):  # pragma: no cover
    """(K's Cholesky factor, B's CSR values) at the current equilibrium (StaticSag._linearization):
    K the free static Hessian band, shifted by the mass metric where E has a saddle there, B the
    rows of D dc/dp."""
    q, tangents, a1, twist = state
    buffer = np.zeros(2, dtype=np.int64)
    started = timing.clock_seconds(clock, clock_id, buffer)
    band, values = at_state.linearization(p, q, tangents, a1, twist, newton, jacobian)
    now = timing.clock_seconds(clock, clock_id, buffer)
    seconds[_MODEL] += now - started
    factor = stiffness_factor(band, masses)
    data = scaled_rows(values, jacobian[6][0], jacobian[6][2], constants[0])
    seconds[_ALGEBRA] += timing.clock_seconds(clock, clock_id, buffer) - now
    return factor, data


@numba.njit(cache=True, inline="always")
def _product(operator, v):  # pragma: no cover - compiled
    """J v for the sag operator (sag_operator.sag_product)."""
    factor, indptr, indices, data, moving, rows, weights, size, _ = operator
    return jacobian_product(factor, indptr, indices, data, moving, rows, weights, size, v)


@numba.njit(cache=True, inline="always")
def _transposed_product(operator, u):  # pragma: no cover - compiled
    """J^T u for the sag operator (sag_operator.sag_transposed_product)."""
    factor, indptr, indices, data, moving, rows, weights, _, columns = operator
    return jacobian_transposed_product(factor, indptr, indices, data, moving, rows, weights, columns, u)


@numba.njit(cache=True, inline="always")
def _select_step(x, operator, diag_h, g_h, p, p_h, d, radius, lower, upper, theta):  # pragma: no cover - compiled
    """reflective.select_step through the sag operator."""
    if trf.inside(x, p, lower, upper):
        return p, p_h, -trf.quadratic_value(_product(operator, d * p_h), g_h, p_h, diag_h)
    p, p_h, r_h, r, r_stride_l, r_stride_u = trf.reflection(x, p, p_h, d, radius, lower, upper, theta)
    r_value = np.inf
    if r_stride_l <= r_stride_u:
        a, b, c = trf.quadratic_1d_from(_product(operator, d * r_h), _product(operator, d * p_h), g_h, r_h, p_h,
                                        diag_h)
        r_stride, r_value = trf.minimize_quadratic_1d(a, b, r_stride_l, r_stride_u, c)
        r_h = r_h * r_stride + p_h
        r = r_h * d
    p, p_h = p * theta, p_h * theta
    p_value = trf.quadratic_value(_product(operator, d * p_h), g_h, p_h, diag_h)
    ag_h, ag, ag_stride = trf.gradient_step(x, g_h, d, radius, lower, upper, theta)
    a, b = trf.quadratic_1d(_product(operator, d * ag_h), g_h, ag_h, diag_h)
    return trf.least_of_three(p, p_h, p_value, r, r_h, r_value, ag, ag_h, a, b, ag_stride)


@numba.njit(cache=True)
def least_sag_loop(x0, lower, upper, memory, factor, data, fixed, operator_rows, signs, max_evaluations,
                   rescale_every):  # pragma: no cover - compiled
    """reflective_least_squares on StaticSag's residuals from x0 in the box; ``model_arguments``
    gives memory, factor, data, fixed and operator_rows. The equilibrium continued from memory's
    state is updated in place, and fixed's visited receives the equilibria found (flags[VISITS] of
    them). Returns the evaluations."""
    state, flags, at, at_linear = memory
    newton, constants, tol, max_steps, (positions, _, _), visited, jacobian, masses, clock, clock_id, seconds = fixed
    moving, moving_rows, moving_weights = operator_rows
    _, _, _, _, _, _, (indptr, indices, _) = jacobian
    n, size = x0.size, positions.size
    buffer = np.zeros(2, dtype=np.int64)

    x = trf.make_strictly_feasible(x0, lower, upper, 1e-10)
    f = _residuals(x, memory, factor, data, fixed)
    evaluations = 1
    if not np.all(np.isfinite(f)):
        return evaluations
    cost = 0.5 * np.dot(f, f)
    factor, data = _linearization(x, memory, factor, data, fixed)
    operator = (factor, indptr, indices, data, moving, moving_rows, moving_weights, size, n)
    started = timing.clock_seconds(clock, clock_id, buffer)
    g = _transposed_product(operator, f)
    scale = trf.scales_of(estimated_column_norms(factor, indptr, indices, data, moving_rows, moving_weights, signs, n))
    seconds[_ALGEBRA] += timing.clock_seconds(clock, clock_id, buffer) - started
    since = 0
    v, dv = trf.cl_scaling_vector(x, g, lower, upper)
    trf.scaled_variables(v, dv, g, scale)
    radius = trf.first_radius(x, v, scale)
    status = 0
    while True:
        v, dv = trf.cl_scaling_vector(x, g, lower, upper)
        g_norm = trf.gradient_norm(g, v)
        if g_norm < trf.GTOL:
            status = 1
        if status or evaluations >= max_evaluations:
            break
        if since >= rescale_every:
            factor, data = _linearization(x, memory, factor, data, fixed)
            started = timing.clock_seconds(clock, clock_id, buffer)
            scale = trf.scales_of(estimated_column_norms(factor, indptr, indices, data, moving_rows, moving_weights,
                                                         signs, n))
            seconds[_ALGEBRA] += timing.clock_seconds(clock, clock_id, buffer) - started
            since = 0
        started = timing.clock_seconds(clock, clock_id, buffer)
        d, diag_h, g_h = trf.scaled_variables(v, dv, g, scale)
        a, b = trf.quadratic_1d(_product(operator, d * -g_h), g_h, -g_h, diag_h)
        regularization = -trf.minimize_quadratic_1d(a, b, 0.0, radius / trf.norm(g_h))[1] / radius**2
        gn_h = cgls(*operator, d, np.sqrt(diag_h + regularization), f, np.int64(CG_ITERATIONS), CG_TOLERANCE)
        basis = trf.subspace_basis(g_h, gn_h)
        b_s, g_s = trf.subspace_model(_product(operator, d * basis[0]), _product(operator, d * basis[1]), basis,
                                      diag_h, g_h)
        seconds[_ALGEBRA] += timing.clock_seconds(clock, clock_id, buffer) - started
        theta = max(0.995, 1 - g_norm)
        reduction = -1.0
        trial, f_trial, trial_cost = x, f, cost
        while reduction <= 0 and evaluations < max_evaluations:
            started = timing.clock_seconds(clock, clock_id, buffer)
            p_s, _ = trf.solve_trust_region_2d(b_s, g_s, radius)
            p_h = trf.in_subspace(basis, p_s)
            step, step_h, predicted = _select_step(x, operator, diag_h, g_h, d * p_h, p_h, d, radius, lower, upper,
                                                   theta)
            seconds[_ALGEBRA] += timing.clock_seconds(clock, clock_id, buffer) - started
            trial = trf.make_strictly_feasible(x + step, lower, upper)
            f_trial = _residuals(trial, memory, factor, data, fixed)
            evaluations, since = evaluations + 1, since + 1
            step_h_norm = trf.norm(step_h)
            if not np.all(np.isfinite(f_trial)):
                radius = 0.25 * step_h_norm
                continue
            trial_cost = 0.5 * np.dot(f_trial, f_trial)
            reduction = cost - trial_cost
            new_radius, ratio = trf.update_tr_radius(radius, reduction, predicted, step_h_norm,
                                                     step_h_norm > 0.95 * radius)
            status = trf.check_termination(reduction, cost, trf.norm(step), trf.norm(x), ratio, trf.FTOL, trf.XTOL)
            if status:
                break
            radius = new_radius
        if reduction > 0:
            x, f, cost = trial, f_trial, trial_cost
            factor, data = _linearization(x, memory, factor, data, fixed)
            operator = (factor, indptr, indices, data, moving, moving_rows, moving_weights, size, n)
            started = timing.clock_seconds(clock, clock_id, buffer)
            g = _transposed_product(operator, f)
            seconds[_ALGEBRA] += timing.clock_seconds(clock, clock_id, buffer) - started
    return evaluations


def model_arguments(x0, state, newton, constants, jacobian, rows, masses, tol, max_steps, max_evaluations, clock,
                    clock_id, seconds):
    """(memory, factor, data, fixed, operator_rows) of ``least_sag_loop`` and ``_model``: state the
    equilibrium to continue (q, tangents, a1, twist; C arrays, updated in place); newton:
    Problem.newton_kernels; constants: simulation.static_solve_constants; jacobian:
    Problem.state_jacobian_kernels; rows: the residuals' (position index in q, weights, groom
    positions, moving rows, their DOFs' rows in K, their weights); masses: the free DOFs' masses;
    tol, max_steps: the continued static solves'; seconds [model, linear algebra] accumulated.
    Made here, in Python, for both: priming compiles ``_model`` with these types on its own
    (``prepare_model``)."""
    positions, weights, points, moving, moving_rows, moving_weights = rows
    n = x0.size
    visited = (np.empty(max_evaluations), np.empty((max_evaluations, n)), np.empty((max_evaluations, state[0].size)),
               np.empty((max_evaluations,) + state[1].shape), np.empty((max_evaluations,) + state[2].shape),
               np.empty((max_evaluations, state[3].size)))
    flags = np.zeros(5, dtype=np.int64)
    flags[LINEARIZED] = -1
    memory = (state, flags, np.zeros(n), np.zeros(n))
    factor, data = np.zeros((masses.size, newton[3][3])), np.zeros(jacobian[6][2].size)
    fixed = (newton, constants, tol, max_steps, (positions, weights, points), visited, jacobian, masses, clock,
             clock_id, seconds)
    return memory, factor, data, fixed, (moving, moving_rows, moving_weights)


def prepare_model(x0, memory, factor, data, fixed) -> None:
    """One residual evaluation of ``_model`` (``model_arguments``' values), which compiles or loads
    it with least_sag_loop's argument types: priming's first child runs this, so that its sibling,
    compiling the loop, loads ``_model`` instead of compiling it too (frontend.priming)."""
    state, flags, at, at_linear = memory
    _model(np.bool_(False), np.array(x0, dtype=float), state, flags, at, (at_linear, factor, data), fixed)
