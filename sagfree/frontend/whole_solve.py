"""asc's whole solve of a strand, its stabilization included, in one compiled call.

For most strands of a groom, asc's solve is its start (the statics optimum), the KKT distance that
confirms it and the stability there (solvers.confirmed_start), and where that optimum is below the
stability margin, rounds of stiffness floors, each re-solve again a confirmed start
(frontend.floor_steps.stabilization_rounds). Those were two compiled calls with Python between them:
the first solve's Result, the margin test (Problem.meets_margin: the Rayleigh quotient bound, else
the unstressed strand's eigenvalue) and the rounds' inputs. ``whole_solve`` makes them one call, in
the same order on the same inputs, so its start, margin verdict, floors, solution and eigenpairs
are the two calls' bit for bit (tests/test_whole_solve.py); the front end then builds the one
Result (frontend.stabilize).

A strand held at points besides its root (a pinned tip, pins) takes the same call with the reaction
search (solvers.reaction_start) as its start and each re-solve's, the floors' landings restiffened
(frontend.floor_steps): its family of balancing rest changes is computed before the call (one band
LU of its root-held companion, memoized with the Problem), and the call's start, floors, solutions
and counts of Phi's values are the Python path's (solve_alm from the reaction start, then
frontend.stabilize.floors_loop) bit for bit.

Where any part leaves that path (the start is not confirmed at once, it is p0 itself, a round's
re-solve would need asc's outer loop, or the path does not apply at all: confirmed_start's
conditions) the call says so and nothing of it is kept but a held strand's searches (the Python
path would take the same ones first: it reads them from reaction_start's memo): the caller solves
the strand the usual way, from scratch.
"""
from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from sagfree.formulation import at_rest
from sagfree.formulation.parameters import REST_BLOCKS
from sagfree.formulation.problem import STABILITY_FRACTION, Problem
from sagfree.linalg import lapack, timing
from sagfree.solvers.confirmed_start import (CONFIRMED, CORRECTIONS, compiled_start_inputs, confirmed_at,
                                             confirmed_kernel)
from sagfree.solvers.gauss_newton import at_rest_residual, largest_magnitude
from sagfree.solvers.reaction_start import family_optimum, held_family, remember_searches, search_state
from sagfree.solvers.statics_start import statics_indices

from .floor_steps import _NOT_APPLICABLE, _STABLE, ENDINGS, _stabilization_rounds

#: whole_solve's kernel outcome where the path does not hold (the others: floor_steps' endings)
_DECLINED = -1


class WholeSolve(NamedTuple):
    """What ``whole_solve`` found. The first solve (asc's confirmed start): its p, |c|_inf at p0 and
    at p, KKT distance, and the seconds of its stability evaluation. The stabilization: the margin
    it compared with (NaN where the Rayleigh quotient proved it without its eigenvalue, or without
    stabilization), its rounds and ending
    (floor_steps.ENDINGS; "stable" without a round where the first solve is stable or the problem
    is not stabilized), the floored lower bounds, and the last solution p with its |c|_inf, KKT
    distance and smallest eigenvalue (the first solve's where no round was taken); the values of
    the reaction search's Phi it took and the SQP steps towards KKT points from its ends (0 for a
    strand held by its root alone; confirmed_start.corrected)."""
    first: np.ndarray
    start_violation: float
    first_violation: float
    first_distance: float
    stability_seconds: float
    margin: float
    rounds: int
    ending: str
    lower: np.ndarray
    p: np.ndarray
    violation: float
    distance: float
    value: float
    reaction_values: int
    sqp: int


def whole_solve(problem: Problem, stiffness: np.ndarray, overshoot: float, relevant: float, steps: int,
                max_rounds: int, tol: float, kkt_tol: float, near: float = 1e-6) -> WholeSolve | None:
    """asc's solve of ``problem`` from its default start and, with ``problem.stabilize``, the
    stabilization's rounds (frontend.stabilize: the floors of the multipliers ``stiffness`` by the
    first-order steps with ``overshoot``, ``relevant``, ``steps``, at most ``max_rounds``) in one
    compiled call (module docstring), or None where that path does not hold. Fills the Problem's
    memos as the two calls do (c and dc/dp at p0 and at the last p, the least rest change or the
    reaction search's outcome, the eigenpair at the last p, the margin where it was computed), where
    the Result reads them."""
    kernels = compiled_start_inputs(problem, held=True)
    held = kernels is not None
    kernels = kernels if held else compiled_start_inputs(problem)
    if kernels is None or problem.remembered("least rest change") is not None:
        return None  # (a twin's memo: confirmed_start would take its stabilization-twin branch)
    if held:
        family = held_family(problem)
        if family is None or problem.layout.lower.tobytes() in problem.bound_independent("reaction searches", dict):
            return None  # (searched before: the solve reads that memo)
        search = search_state(*family, 1 + max_rounds * (steps + 1))  # room for every search it may take
    else:
        search = search_state(np.empty(0), np.empty((problem.layout.p0.size, 0)), np.empty(0), np.empty(0), 0)
    stiffening, form = problem.stiffening_kernel, problem.unstressed_form_kernel
    if stiffening is None or form is None:
        return None
    stability, stabilize = problem.stability_kernels, problem.stabilize and bool(stiffness.any())
    forces_args, jacobian_args, free, row_scale, indptr, indices, position = kernels
    layout = problem.layout
    known = problem.__dict__.get("stability_margin", np.nan) if problem.min_eigenvalue is None else \
        float(problem.min_eigenvalue)
    seconds, violations, outputs = np.zeros(3), np.full(2, np.nan), np.full(5, np.nan)
    corrections = np.zeros(1, dtype=np.int64)  # the SQP steps of held strands' starts (confirmed_start.corrected)
    (ending, rounds, change, first, f0, values0, first_f, first_values, first_value, first_mode, lower, p, f, values,
     value, mode) = _whole_solve(
        forces_args, jacobian_args, free, row_scale, indptr, indices, layout.block_mask(REST_BLOCKS), layout.p0,
        layout.weights, layout.lower, layout.upper, *statics_indices(problem), problem.edge_lengths, position,
        lapack.DGBTRF, lapack.DGBTRS, float(near), *timing.CLOCK, float(tol), float(kkt_tol), *stability,
        stabilize, float(known), form, problem.dof_masses, stiffness, float(overshoot), float(relevant), int(steps),
        int(max_rounds), stiffening, search, corrections, seconds, violations, outputs)
    # the searches are kept whatever follows: a solve that takes over reads them, and counts their values
    remember_searches(problem, search, counted=ending != _DECLINED)
    if ending == _DECLINED:
        return None
    timing.add(timing.MODEL, seconds[0])
    timing.add(timing.LINEAR_ALGEBRA, seconds[1])
    # the memos confirmed_start and stabilization_rounds fill
    if not held:
        problem.remember_at_rest(layout.p0, f0, values0)
        problem.bound_independent("square rest system", lambda: True)
        problem.bound_independent("least rest change", lambda: change)
    problem.remember_at_rest(first, first_f, first_values)
    problem.remember_stability(first, float(first_value), first_mode)
    margin = outputs[4]
    if np.isnan(known) and np.isfinite(margin):
        problem.__dict__["stability_margin"] = float(margin)  # Problem.stability_margin, as computed there
    if rounds:
        problem.remember_at_rest(p, f, values)
        problem.remember_stability(p, float(value), mode)
    distance = outputs[3] if rounds else outputs[1]
    return WholeSolve(first, float(violations[0]), float(outputs[0]), float(outputs[1]), float(seconds[2]),
                      float(margin), int(rounds), ENDINGS[ending], lower, p, float(outputs[2] if rounds else
                                                                                 outputs[0]),
                      float(distance), float(value), int(search[4][0]), int(corrections[0]))


@numba.njit(cache=True)
def _whole_solve(forces_args, jacobian_args, free, row_scale, indptr, indices, rest_mask, p0, w, lower, upper, rate,
                 multiplier, bend, rest, lengths, position, dgbtrf, dgbtrs, near, clock, clock_id, tol, kkt_tol,
                 hessian_args, eigen_args, scale, free_index, stabilize, margin, form_args, masses, stiffness,
                 overshoot, relevant, steps, max_rounds, stiffening_args, search, corrections, seconds, violations,
                 outputs):  # pragma: no cover - compiled
    """(ending, rounds, least rest change, first p, f and dc/dp values at p0 and at the first p, the
    first p's eigenvalue and mode, the floored lower bounds, the last p, f and dc/dp values there,
    its eigenvalue and mode) of whole_solve. The first solve: for a strand held by its root alone
    (``search``, reaction_start.search_state, without a reaction) solvers.confirmed_start's
    confirmed_kernel; for one held at more points, c at p0 (f at p0 returned, no dc/dp there), the
    reaction search (reaction_start.family_optimum, which logs it in ``search``) and confirmed_at
    there. Then Problem.meets_margin's test (``margin``: the known margin, or NaN: the Rayleigh
    quotient bound first, then STABILITY_FRACTION of the unstressed strand's eigenvalue), then
    floor_steps._stabilization_rounds (its searches logged too). outputs receive the first p's |c|_inf
    and KKT distance, the last p's, and the margin it compared with (NaN where the quotient proved
    it); violations and seconds as confirmed_kernel's (seconds[2] its stability, [0] and [1] the
    rest's model evaluation and linear algebra)."""
    empty = np.empty(0)
    change, basis = search[0], search[1]
    held = basis.shape[1] > 0
    if not held:
        outcome, change, p, f0, values0, f, values, distance, value, mode = confirmed_kernel(
            forces_args, jacobian_args, free, row_scale, indptr, indices, rest_mask, p0, w, lower, upper, rate,
            multiplier, bend, rest, lengths, position, empty, dgbtrf, dgbtrs, near, clock, clock_id, tol, kkt_tol,
            hessian_args, eigen_args, scale, free_index, seconds, violations)
        # the rounds' starts: statics optima of that change (family_optimum without a reaction)
        search = (change, basis, search[2], search[3], search[4], search[5], search[6], search[7], search[8],
                  search[9])
    else:
        buffer = np.zeros(2, dtype=np.int64)
        start = timing.clock_seconds(clock, clock_id, buffer)
        c0, f0 = at_rest_residual(p0, forces_args, free, row_scale)
        violations[0] = largest_magnitude(c0)
        seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - start
        found = family_optimum(search, p0, w, lower, upper, rate, multiplier, bend, rest, lengths)
        outcome, p, values0, f, values, distance, value, mode = _DECLINED, empty, empty, empty, empty, np.inf, \
            np.nan, empty
        if found.size:
            # the stability is measured: a runtime True (held), as confirmed_kernel's tuple types it
            stability = (held, tol, kkt_tol, hessian_args, eigen_args, scale, free_index)
            outcome, _, p, _, _, f, values, distance, value, mode = confirmed_at(
                found, forces_args, jacobian_args, free, row_scale, indptr, indices, p0, w, lower, upper, position,
                change, f0, empty, dgbtrf, dgbtrs, near, clock, clock_id, stability, seconds, violations,
                np.int64(CORRECTIONS), corrections)
    if outcome != CONFIRMED or not (violations[1] <= tol and distance <= kkt_tol) or mode.size == 0:
        return (_DECLINED, 0, empty, empty, empty, empty, empty, empty, np.nan, empty, lower, empty, empty, empty,
                np.nan, empty)
    outputs[0], outputs[1] = violations[1], distance
    if not stabilize:
        return _STABLE, 0, change, p, f0, values0, f, values, value, mode, lower, p, f, values, value, mode
    # Problem.meets_margin
    if margin != margin:
        curvature = at_rest.unstressed_form(mode, *form_args)
        if value >= STABILITY_FRACTION * curvature / np.dot(masses, mode**2) * (1.0 + 1e-6):
            return _STABLE, 0, change, p, f0, values0, f, values, value, mode, lower, p, f, values, value, mode
        # Problem.unstressed_stability
        margin = STABILITY_FRACTION * at_rest.stability(p0.copy(), hessian_args, eigen_args, scale, free_index, clock,
                                                        clock_id, seconds[:2])[0]
    outputs[4] = margin
    if value >= margin:
        return _STABLE, 0, change, p, f0, values0, f, values, value, mode, lower, p, f, values, value, mode
    ending, rounds, floored, last, last_value, last_mode, last_f, last_values, violation, last_distance = \
        _stabilization_rounds(p, value, mode, lower, upper, w, stiffness, margin, overshoot, relevant, steps,
                              max_rounds, tol, kkt_tol, near, search, corrections, p0, rate, multiplier, bend, rest,
                              lengths, forces_args, jacobian_args, free, row_scale, indptr, indices, position, dgbtrf,
                              dgbtrs, hessian_args, eigen_args, scale, free_index, stiffening_args, clock,
                              clock_id, seconds)
    if ending == _NOT_APPLICABLE:
        return (_DECLINED, 0, empty, empty, empty, empty, empty, empty, np.nan, empty, lower, empty, empty, empty,
                np.nan, empty)
    outputs[2], outputs[3] = violation, last_distance
    if rounds == 0:
        last_f, last_values = f, values
    return (ending, rounds, change, p, f0, values0, f, values, value, mode, floored, last, last_f, last_values,
            last_value, last_mode)
