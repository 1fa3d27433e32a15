"""The stabilization's first-order floor steps, checked where they land, in one compiled call.

A round of the stabilization loop (frontend.stabilize, module docstring item 2) raises the stiffness
floors along the first-order step from the solution, then checks the point the floored problem's
solve will land on, and steps again from there while that point is below the margin. For a strand
held by its root alone each check is the landing (solvers.statics_start: the floored problem's
optimum, from the least rest change its first solve remembered), its residual, its stressed
Hessian band and smallest eigenpair, and the stiffening gradient there (at_rest.stiffening_gradient):
compiled kernels with Python between them.
``checked_floors`` runs the round in one compiled call, in the same order on the same inputs, so
its floors and the landing's eigenpair are the Python path's bit for bit
(tests/test_floor_steps.py), and it leaves the landing's eigenpair in the Problem's memo, where
the re-solve's Result reads it. Where the path does not apply (stencils not compiled, bodies,
another attachment, no remembered square rest system, a landing that is not the statics optimum
or does not balance) it says so and the caller takes the Python path. ``raised_floors`` is
the step itself, the arithmetic both paths share.
"""
from __future__ import annotations

import numba
import numpy as np

from sagfree.formulation import at_rest
from sagfree.formulation.problem import Problem
from sagfree.linalg import timing
from sagfree.linalg.pairwise import pairwise_sum
from sagfree.solvers.gauss_newton import at_rest_residual
from sagfree.solvers.statics_start import applies, statics_indices, statics_optimum

#: checked_floors' kernel outcomes: floors raised; no multiplier that would raise the eigenvalue has
#: room (the strand cannot be stabilized inside the boxes); the compiled path does not apply here
_RAISED, _NO_ROOM, _NOT_APPLICABLE = 0, 1, 2


@numba.njit(cache=True)
def raised_floors(gradient, p, lower, upper, weights, stiffness, value, margin, overshoot,
                  relevant):  # pragma: no cover - compiled
    """The lower bounds ``lower`` raised by the first-order step of frontend.stabilize (item 2) from p,
    whose smallest eigenvalue is ``value`` and d lambda / d k ``gradient``: on the multipliers
    (``stiffness``) below their upper bound whose gradient exceeds ``relevant`` x the largest, the
    least-R step dk = t g / h (h = weight + 1e-12) with t such that the linear model reaches
    ``overshoot`` x ``margin``, capped at the upper bounds; empty if no multiplier has room."""
    largest = 0.0
    for j in range(p.size):
        if stiffness[j]:
            largest = max(largest, gradient[j])
    room = np.zeros(p.size, dtype=np.bool_)
    terms = np.empty(p.size)
    count = 0
    for j in range(p.size):
        room[j] = stiffness[j] and p[j] < upper[j] and gradient[j] > relevant * largest
        if room[j]:
            terms[count] = gradient[j] ** 2 / (weights[j] + 1e-12)
            count += 1
    if count == 0:
        return np.empty(0)
    step = (overshoot * margin - value) / pairwise_sum(terms[:count])  # np.sum's bits
    floors = lower.copy()
    for j in range(p.size):
        if room[j]:
            floors[j] = max(floors[j], min(p[j] + step * gradient[j] / (weights[j] + 1e-12), upper[j]))
    return floors


def checked_floors(problem: Problem, p: np.ndarray, value: float, mode: np.ndarray, stiffness: np.ndarray,
                   margin: float, overshoot: float, relevant: float, steps: int, tol: float):
    """``(applies, floors)`` of one round of the stabilization (module docstring) from p, the
    solution of ``problem`` with smallest eigenvalue ``value`` and mode ``mode``: applies False
    where the compiled path does not (floors None: the caller takes the Python path); floors None
    when no multiplier that would raise the eigenvalue has room. The last landing's eigenpair goes
    into the Problem's memo (``remember_stability``)."""
    kernels, stability, stiffening = problem.at_rest_kernels, problem.stability_kernels, problem.stiffening_kernel
    change = problem.remembered("least rest change")
    if (kernels is None or stability is None or stiffening is None or timing.CLOCK is None or change is None
            or not problem.remembered("square rest system") or not applies(problem)):
        return False, None
    forces_args, _, free, row_scale, _ = kernels
    layout = problem.layout
    seconds = np.zeros(2)
    outcome, floors, landing, landing_value, landing_mode = _checked_floors(
        np.ascontiguousarray(p, dtype=float), float(value), np.ascontiguousarray(mode, dtype=float), layout.lower,
        layout.upper, layout.weights, stiffness, float(margin), float(overshoot), float(relevant), int(steps),
        float(tol), change, layout.p0, *statics_indices(problem), problem.edge_lengths, forces_args, free, row_scale,
        *stability, stiffening, *timing.CLOCK, seconds)
    timing.add(timing.MODEL, seconds[0])
    timing.add(timing.LINEAR_ALGEBRA, seconds[1])
    if outcome == _NOT_APPLICABLE:
        return False, None
    if outcome == _NO_ROOM:
        return True, None
    if landing_mode.size:
        problem.remember_stability(landing, float(landing_value), landing_mode)
    return True, floors


@numba.njit(cache=True)
def _checked_floors(p, value, mode, lower, upper, weights, stiffness, margin, overshoot, relevant, steps, tol, change,
                    p0, rate, multiplier, bend, rest, lengths, forces_args, free, row_scale, hessian_args, eigen_args,
                    scale, free_index, stiffening_args, clock, clock_id, seconds):  # pragma: no cover - compiled
    """(outcome, floors, last landing, its eigenvalue, its mode) of checked_floors: the step from p,
    then at most ``steps`` checks, each at the floored problem's statics optimum (not clipped, as
    alm.linear_start gives it), stepping again from there while its eigenvalue is below the margin.
    seconds[0] and [1] accumulate model evaluation and linear algebra."""
    buffer = np.zeros(2, dtype=np.int64)
    empty = np.empty(0)
    gradient = at_rest.stiffening_gradient(mode, p, *stiffening_args)
    floors = raised_floors(gradient, p, lower, upper, weights, stiffness, value, margin, overshoot, relevant)
    if floors.size == 0:
        return _NO_ROOM, empty, empty, np.nan, empty
    landing, landing_value, landing_mode = empty, np.nan, empty
    for _ in range(steps):
        floored = np.minimum(np.maximum(lower, floors), upper)  # Problem.with_lower_bounds
        landing = statics_optimum(change, p0, weights, floored, upper, rate, multiplier, bend, rest, lengths)
        if landing.size == 0 or np.array_equal(landing, p0):  # the Python path's spread start, or p0's Hessian
            return _NOT_APPLICABLE, empty, empty, np.nan, empty
        start = timing.clock_seconds(clock, clock_id, buffer)
        c, _ = at_rest_residual(landing, forces_args, free, row_scale)
        seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - start
        for r in range(c.size):
            if not abs(c[r]) <= tol:  # stabilize._landing restiffens instead
                return _NOT_APPLICABLE, empty, empty, np.nan, empty
        landing_value, landing_mode = at_rest.stability(landing, hessian_args, eigen_args, scale, free_index, clock,
                                                        clock_id, seconds)
        if landing_value >= margin:
            break
        gradient = at_rest.stiffening_gradient(landing_mode, landing, *stiffening_args)
        more = raised_floors(gradient, landing, floored, upper, weights, stiffness, landing_value, margin, overshoot,
                             relevant)
        if more.size == 0:
            break
        floors = more
    return _RAISED, floors, landing, landing_value, landing_mode
