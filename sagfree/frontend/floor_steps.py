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

``stabilization_rounds`` runs the whole loop there in one compiled call: each round's floors as
above, then the floored problem's solve as asc makes it (solvers.confirmed_start: the statics
optimum under the new floors, c and dc/dp there and the KKT distance that confirms it), and its
stability, until a solution is stable, no multiplier has room, or the rounds run out. The floors,
the solutions and the eigenvalues are the Python loop's (frontend.stabilize.floors_loop) bit for
bit (tests/test_floor_steps.py); only the intermediate Results and floored Problems are not made.
Where a re-solve is not confirmed at once (asc's outer loop would polish it) the call hands the
whole loop back to Python, which starts it again.

The same rounds serve a strand held at points besides its root (frontend.whole_solve): there each
check is at the solution restiffened onto the floors (rest_change.restiffened_elements, the Python
path's landing) and each re-solve's start is the reaction search under the new floors
(solvers.reaction_start.family_optimum).
"""
from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from sagfree.formulation import at_rest
from sagfree.formulation.problem import Problem
from sagfree.formulation.rest_change import restiffened_elements
from sagfree.linalg import lapack, timing
from sagfree.linalg.pairwise import pairwise_sum
from sagfree.solvers.confirmed_start import CORRECTIONS, compiled_start_inputs, confirmed_at
from sagfree.solvers.gauss_newton import at_rest_residual
from sagfree.solvers.reaction_start import family_optimum, search_state
from sagfree.solvers.statics_start import applies, statics_indices

#: checked_floors' kernel outcomes: floors raised; no multiplier that would raise the eigenvalue has
#: room (the strand cannot be stabilized inside the boxes); the compiled path does not apply here;
#: and stabilization_rounds' endings besides those: the last solution is stable; the rounds ran out
_RAISED, _NO_ROOM, _NOT_APPLICABLE, _STABLE, _MAX_ROUNDS = 0, 1, 2, 3, 4
#: stabilization_rounds' endings by name (Rounds.ending)
ENDINGS = {_STABLE: "stable", _NO_ROOM: "no room", _MAX_ROUNDS: "max rounds"}


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
    outcome, floors, landing, landing_value, landing_mode, _ = _checked_floors(
        np.ascontiguousarray(p, dtype=float), float(value), np.ascontiguousarray(mode, dtype=float), layout.lower,
        layout.upper, layout.weights, stiffness, float(margin), float(overshoot), float(relevant), int(steps),
        float(tol), root_held_search(change), layout.p0, *statics_indices(problem), problem.edge_lengths,
        forces_args, free, row_scale, *stability, stiffening, *timing.CLOCK, seconds)
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
def _checked_floors(p, value, mode, lower, upper, weights, stiffness, margin, overshoot, relevant, steps, tol, search,
                    p0, rate, multiplier, bend, rest, lengths, forces_args, free, row_scale, hessian_args, eigen_args,
                    scale, free_index, stiffening_args, clock, clock_id, seconds):  # pragma: no cover - compiled
    """(outcome, floors, last landing, its eigenvalue, its mode, the lower bounds it landed under) of
    checked_floors: the step from p, then at most ``steps`` checks, each at the floored problem's
    start (reaction_start.family_optimum of ``search``: not clipped, as alm.linear_start gives it;
    for a strand held at points besides its root, whose start is a search, p restiffened onto the
    floors, as stabilize._landing makes it), stepping again from there while its eigenvalue is
    below the margin; the lower bounds are empty where the landing is not the floored start.
    seconds[0] and [1] accumulate model evaluation and linear algebra."""
    buffer = np.zeros(2, dtype=np.int64)
    empty = np.empty(0)
    gradient = at_rest.stiffening_gradient(mode, p, *stiffening_args)
    floors = raised_floors(gradient, p, lower, upper, weights, stiffness, value, margin, overshoot, relevant)
    if floors.size == 0:
        return _NO_ROOM, empty, empty, np.nan, empty, empty
    held = search[1].shape[1] > 0
    landing, landing_value, landing_mode, floored = empty, np.nan, empty, empty
    for _ in range(steps):
        floored = np.minimum(np.maximum(lower, floors), upper)  # Problem.with_lower_bounds
        if held:  # stabilize._landing: p restiffened onto the floors, c kept
            landing = restiffened_elements(p, np.maximum(p, floored), p0, rate, multiplier, bend, rest)
        else:
            landing = family_optimum(search, p0, weights, floored, upper, rate, multiplier, bend, rest, lengths)
            if landing.size == 0 or np.array_equal(landing, p0):  # the Python path's spread start, or p0's Hessian
                return _NOT_APPLICABLE, empty, empty, np.nan, empty, empty
            start = timing.clock_seconds(clock, clock_id, buffer)
            c, _ = at_rest_residual(landing, forces_args, free, row_scale)
            seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - start
            for r in range(c.size):
                if not abs(c[r]) <= tol:  # stabilize._landing restiffens instead
                    return _NOT_APPLICABLE, empty, empty, np.nan, empty, empty
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
    return _RAISED, floors, landing, landing_value, landing_mode, empty if held else floored


class Rounds(NamedTuple):
    """What ``stabilization_rounds`` found: the floored lower bounds, the last solution p (the bare
    problem's p where no round was taken), its |c|_inf and KKT distance (NaN without a round), its
    smallest eigenvalue, the rounds taken and how the loop ended (ENDINGS: "stable", "no room" where
    no multiplier that would raise the eigenvalue has room, "max rounds")."""
    lower: np.ndarray
    p: np.ndarray
    violation: float
    distance: float
    value: float
    rounds: int
    ending: str


def stabilization_rounds(problem: Problem, p: np.ndarray, value: float, mode: np.ndarray, stiffness: np.ndarray,
                         margin: float, overshoot: float, relevant: float, steps: int, max_rounds: int, tol: float,
                         kkt_tol: float, near: float = 1e-6) -> Rounds | None:
    """The Rounds of frontend.stabilize.floors_loop with asc from p, asc's converged solution of
    ``problem`` with smallest eigenvalue ``value`` and mode ``mode`` (module docstring), or None
    where a round is not on the compiled path (checked_floors' conditions, a saddle system that is
    not a band, a re-solve that is not confirmed at once): the caller then runs the loop in Python
    from the start. The last solution's forces, dc/dp and eigenpair go into the Problem's memos,
    where its Result reads them."""
    kernels, stiffening = compiled_start_inputs(problem), problem.stiffening_kernel
    change = problem.remembered("least rest change")
    if kernels is None or stiffening is None or change is None or not problem.remembered("square rest system"):
        return None
    forces_args, jacobian_args, free, row_scale, indptr, indices, position = kernels
    stability = problem.stability_kernels
    layout = problem.layout
    seconds = np.zeros(3)
    ending, rounds, lower, p, value, mode, f, values, violation, distance = _stabilization_rounds(
        np.ascontiguousarray(p, dtype=float), float(value), np.ascontiguousarray(mode, dtype=float), layout.lower,
        layout.upper, layout.weights, stiffness, float(margin), float(overshoot), float(relevant), int(steps),
        int(max_rounds), float(tol), float(kkt_tol), float(near), root_held_search(change),
        np.zeros(1, dtype=np.int64), layout.p0, *statics_indices(problem), problem.edge_lengths, forces_args,
        jacobian_args, free, row_scale, indptr, indices, position, lapack.DGBTRF, lapack.DGBTRS, *stability,
        stiffening, *timing.CLOCK, seconds)
    timing.add(timing.MODEL, seconds[0])
    timing.add(timing.LINEAR_ALGEBRA, seconds[1])
    if ending == _NOT_APPLICABLE:
        return None
    if rounds:
        problem.remember_at_rest(p, f, values)
        problem.remember_stability(p, float(value), mode)
    return Rounds(lower, p, float(violation), float(distance), float(value), int(rounds), ENDINGS[ending])


@numba.njit(cache=True)
def _stabilization_rounds(p, value, mode, lower, upper, weights, stiffness, margin, overshoot, relevant, steps,
                          max_rounds, tol, kkt_tol, near, search, corrections, p0, rate, multiplier, bend, rest,
                          lengths, forces_args, jacobian_args, free, row_scale, indptr, indices, position, dgbtrf,
                          dgbtrs, hessian_args, eigen_args, scale, free_index, stiffening_args, clock, clock_id,
                          seconds):  # pragma: no cover - compiled
    """(ending, rounds, lower bounds, p, its eigenvalue and mode, f and dc/dp values at p, |c|_inf,
    KKT distance) of stabilization_rounds: floors_loop's turns, each round _checked_floors and the
    floored problem's confirmed start (confirmed_at the floored start, reaction_start.family_optimum
    of ``search``: the round's last landing where it landed under these floors, as the start's memo
    gives it to the Python path's re-solve), its stability the landing's where it is the landing
    (the memo the Python path reads), else measured; a held strand's start may take SQP steps
    towards the KKT point (confirmed_start.corrected), counted in corrections[0]. seconds[0] and [1]
    accumulate model evaluation and linear algebra."""
    empty = np.empty(0)
    timed = seconds[:2]
    # the stability is measured below; np.bool_: a literal False would type the tuple apart from
    # confirmed_kernel's and compile confirmed_at a second time (tests/test_kernel_calls.py)
    unmeasured = (np.bool_(False), tol, kkt_tol, hessian_args, eigen_args, scale, free_index)
    rounds, f, values, violation, distance = 0, empty, empty, np.nan, np.nan
    violations = np.empty(2)  # confirmed_at's |c|_inf at p0 (unused here) and at its p
    while True:
        if value >= margin:
            return _STABLE, rounds, lower, p, value, mode, f, values, violation, distance
        if rounds == max_rounds:
            return _MAX_ROUNDS, rounds, lower, p, value, mode, f, values, violation, distance
        outcome, floors, landing, landing_value, landing_mode, landed = _checked_floors(
            p, value, mode, lower, upper, weights, stiffness, margin, overshoot, relevant, steps, tol, search, p0,
            rate, multiplier, bend, rest, lengths, forces_args, free, row_scale, hessian_args, eigen_args, scale,
            free_index, stiffening_args, clock, clock_id, timed)
        if outcome == _NOT_APPLICABLE:
            return _NOT_APPLICABLE, rounds, lower, p, value, mode, f, values, violation, distance
        if outcome == _NO_ROOM:
            return _NO_ROOM, rounds, lower, p, value, mode, f, values, violation, distance
        lower = np.minimum(np.maximum(lower, floors), upper)  # Problem.with_lower_bounds
        start = landing
        if not np.array_equal(landed, lower):
            start = family_optimum(search, p0, weights, lower, upper, rate, multiplier, bend, rest, lengths)
        if start.size == 0:
            return _NOT_APPLICABLE, rounds, lower, p, value, mode, f, values, violation, distance
        _, _, p, _, _, f, values, distance, _, _ = confirmed_at(
            start, forces_args, jacobian_args, free, row_scale, indptr, indices, p0, weights, lower, upper, position,
            search[0], empty, empty, dgbtrf, dgbtrs, near, clock, clock_id, unmeasured, seconds, violations,
            CORRECTIONS if search[1].shape[1] else 0, corrections)
        violation = violations[1]
        if not (violation <= tol and distance <= kkt_tol):  # asc's outer loop would go on from here
            return _NOT_APPLICABLE, rounds, lower, p, value, mode, f, values, violation, distance
        if landing_mode.size and np.array_equal(p, landing):
            value, mode = landing_value, landing_mode
        else:
            value, mode = at_rest.stability(p, hessian_args, eigen_args, scale, free_index, clock, clock_id, timed)
        rounds += 1


def root_held_search(change: np.ndarray) -> tuple:
    """The compiled rounds' ``search`` (reaction_start.search_state) for a strand held by its root
    alone: its least rest change, and no reaction (family_optimum is then statics_optimum)."""
    return search_state(change, np.empty((change.size, 0)), np.empty(0), np.empty(0), 0)
