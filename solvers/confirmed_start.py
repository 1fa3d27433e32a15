"""asc's start for a strand held by its root alone, its KKT confirmation and its Result's stability,
in one compiled call.

Most strands of a groom are held by their root alone, and for them asc's start is the optimum
(solvers.statics_start): ``solve_alm`` takes the least rest change at p0 (alm.linear_start: c and
dc/dp at p0, one band LU of the square rest system), the optimum it fixes, c and dc/dp there, and
the KKT distance that confirms it (contract.optimality.kkt_optimality: one band LU of the saddle
system), and returns a Result whose stability (Problem.stability: the stressed Hessian band and
its smallest eigenpair) make_result measures. Those compiled kernels took about half of that path's
time and the Python between them most of the rest (benchmarks/study_compiled_floor.py); here they
run in one compiled call, in the same order on the same inputs, so the start, the distance and
the memos it fills are the Python path's bit for bit (tests/test_confirmed_start.py): a
confirmed start's Result then finds its stability in the Problem's memos (solve_alm returns it
from |c|_inf and the distance given here, without looking c up again), and linear_start (the
stabilization's landings) the least rest change. The stability is the Result's
measurement, not the solve's: its seconds are returned for solve_alm to leave out of
Result.time. Where the path does not apply (no compiled stencils, bodies, another attachment, a
rest system that is not square or singular, a box that admits no multiplier) the call returns
None and solve_alm takes its Python path. Its kernel (``confirmed_kernel``) is also the first part
of the front end's whole solve of such a strand, stabilization included (frontend.whole_solve);
its confirmation at a given start (``confirmed_at``) also confirms the reaction search's start of
a strand held at more points there, where a start that balances but is a hair from the KKT point
(the search's end at a kink of its objective) takes a few SQP steps to it first (``corrected``).
"""
from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from sagfree.contract.optimality import KKT_TOL, TOL, band_kkt, band_kkt_step
from sagfree.formulation import at_rest
from sagfree.formulation.parameters import REST_BLOCKS
from sagfree.formulation.problem import Problem
from sagfree.linalg import lapack, timing
from sagfree.linalg.compressed import csc_column_norms
from sagfree.linalg.saddle import band_order
from sagfree.linalg.square import square_solution

from .gauss_newton import at_rest_residual, largest_magnitude
from .reaction_start import applies as reaction_applies
from .statics_start import applies, statics_indices, statics_optimum


class ConfirmedStart(NamedTuple):
    """What ``confirmed_start`` found: asc's start p, its KKT distance, the seconds of its Result's
    stability evaluation (for solve_alm to leave out of the time, as make_result's are), and
    |c|_inf at p0 (NaN where it was not evaluated here: a stabilization twin) and at p, each as
    np.abs(c).max(initial=0.0)."""
    p: np.ndarray
    distance: float
    stability_seconds: float
    start_violation: float
    violation: float


def confirmed_start(problem: Problem, tol: float = TOL, kkt_tol: float = KKT_TOL,
                    near: float = 1e-6) -> ConfirmedStart | None:
    """The ConfirmedStart of asc's start where statics_start applies (module docstring), the
    distance as ``kkt_optimality(problem, p, near)``; None elsewhere. Fills the Problem's memos: c
    and dc/dp at p0 and at p, the least rest change and the square-system verdict, and where the
    start is confirmed (|c|_inf <= tol, distance <= kkt_tol) the stability at p that its Result
    reports."""
    kernels = compiled_start_inputs(problem)
    if kernels is None:
        return None
    forces_args, jacobian_args, free, row_scale, indptr, indices, position = kernels
    stability = problem.stability_kernels
    known = problem.remembered("least rest change")  # by a twin: the stabilization's floored problems
    if known is not None and not problem.remembered("square rest system"):
        return None  # the saddle system's least change: statics_start does not apply
    layout = problem.layout
    rate, multiplier, bend, rest = statics_indices(problem)
    seconds, violations = np.zeros(3), np.full(2, np.nan)
    outcome, change, p, f0, values0, f, values, distance, eigenvalue, mode = confirmed_kernel(
        forces_args, jacobian_args, free, row_scale, indptr, indices, layout.block_mask(REST_BLOCKS), layout.p0,
        layout.weights, layout.lower, layout.upper, rate, multiplier, bend, rest, problem.edge_lengths, position,
        np.empty(0) if known is None else known, lapack.DGBTRF, lapack.DGBTRS, float(near), *timing.CLOCK,
        float(tol), float(kkt_tol), *stability, seconds, violations)
    timing.add(timing.MODEL, seconds[0])
    timing.add(timing.LINEAR_ALGEBRA, seconds[1])
    if f0.size:  # evaluated at p0 here
        problem.remember_at_rest(layout.p0, f0, values0)
        problem.bound_independent("square rest system", lambda: outcome != _NOT_SQUARE)
    if outcome == CONFIRMED:
        problem.bound_independent("least rest change", lambda: change)
        problem.remember_at_rest(p, f, values)
        if mode.size:
            problem.remember_stability(p, float(eigenvalue), mode)
        return ConfirmedStart(p, float(distance), float(seconds[2]), float(violations[0]),
                              float(violations[1]))
    return None


def compiled_start_inputs(problem: Problem, held: bool = False):
    """(forces arguments, Jacobian arguments, free index, free rows' scales, dc/dp's CSC indptr and
    indices, its band order) for a compiled confirmed start of ``problem``, or None where there is
    none: stencils or stability not compiled, no process clock, statics_start does not apply (with
    ``held``: reaction_start, a strand held at points besides its root), or the saddle system is
    not a band (Problem.at_rest_kernels, band_order)."""
    if timing.CLOCK is None or not (reaction_applies(problem) if held else applies(problem)):
        return None
    kernels = problem.at_rest_kernels
    if kernels is None or problem.stability_kernels is None:
        return None
    forces_args, jacobian_args, free, row_scale, structure = kernels
    position = band_order(structure[0], structure[1], free.size)
    if position is None:
        return None
    return forces_args, jacobian_args, free, row_scale, structure[0], structure[1], position


#: SQP steps a start that balances may take towards the KKT point (``corrected``), and the largest KKT
#: distance they are tried from (units of p)
CORRECTIONS = 4
CORRECTABLE = 1e-2
#: confirmed_kernel's outcomes: the start and its distance; no optimum (a singular rest system, or a box
#: that admits no multiplier: the Python path says which); the rest system is not square
CONFIRMED, _NO_OPTIMUM, _NOT_SQUARE = 2, 1, 0


@numba.njit(cache=True)
def confirmed_kernel(forces_args, jacobian_args, free, row_scale, indptr, indices, rest_mask, p0, w, lower, upper, rate,
               multiplier, bend, rest, lengths, position, known, dgbtrf, dgbtrs, near, clock, clock_id, tol, kkt_tol,
               hessian_args, eigen_args, scale, free_index, seconds, violations):  # pragma: no cover - compiled
    """(outcome, change, p, f(p0), dc/dp(p0) values, f(p), dc/dp(p) values, KKT distance,
    smallest eigenvalue at p, its mode) of confirmed_start; ``known``: the least rest change if
    known (then nothing is evaluated at p0 and f(p0), dc/dp(p0) are empty: a stabilization twin,
    whose landing measured the stability where its re-solve starts), else empty; otherwise the
    stability is measured where the start is confirmed (|c|_inf <= tol and the distance <= kkt_tol),
    else the mode is empty. seconds[0] and [1] accumulate model evaluation and
    linear algebra (as the Python path's timing splits them), seconds[2] the stability's;
    violations[0] and [1] receive |c|_inf at p0 (where evaluated) and at p."""
    buffer = np.zeros(2, dtype=np.int64)
    empty = np.empty(0)
    stability = (known.size == 0, tol, kkt_tol, hessian_args, eigen_args, scale, free_index)
    if known.size:
        return _confirmed_optimum(known, forces_args, jacobian_args, free, row_scale, indptr, indices, p0, w, lower,
                                  upper, rate, multiplier, bend, rest, lengths, position, empty, empty, dgbtrf, dgbtrs,
                                  near, clock, clock_id, stability, seconds, violations)
    c0, f0, values0 = timed_at_rest(p0, forces_args, jacobian_args, free, row_scale, clock, clock_id, seconds)
    violations[0] = largest_magnitude(c0)
    now = timing.clock_seconds(clock, clock_id, buffer)
    # statics_start.square_rest_system: the rest columns that act are as many as the free DOFs
    norms = csc_column_norms(indptr, values0)
    columns = np.empty(norms.size, dtype=np.bool_)
    acting = 0
    for j in range(norms.size):
        columns[j] = rest_mask[j] and norms[j] > 0.0
        acting += columns[j]
    if acting != free.size:
        return _NOT_SQUARE, empty, empty, f0, values0, empty, empty, np.inf, np.nan, empty
    # alm._least_rest_change: J_R d = -c(p0) by square_column_solve
    start = now
    change = square_solution(dgbtrf, dgbtrs, indptr, indices, values0, columns, -c0)
    now = timing.clock_seconds(clock, clock_id, buffer)
    seconds[1] += now - start
    if change.size == 0 or not np.all(np.isfinite(change)):
        return _NO_OPTIMUM, empty, empty, f0, values0, empty, empty, np.inf, np.nan, empty
    return _confirmed_optimum(change, forces_args, jacobian_args, free, row_scale, indptr, indices, p0, w, lower,
                              upper, rate, multiplier, bend, rest, lengths, position, f0, values0, dgbtrf, dgbtrs, near,
                              clock, clock_id, stability, seconds, violations)


@numba.njit(cache=True, inline="always")
def _confirmed_optimum(change, forces_args, jacobian_args, free, row_scale, indptr, indices, p0, w, lower, upper, rate,
                       multiplier, bend, rest, lengths, position, f0, values0, dgbtrf, dgbtrs, near, clock, clock_id,
                       stability, seconds, violations):  # pragma: no cover - compiled
    """confirmed_kernel from the least rest change on: the optimum it fixes, then ``confirmed_at``
    there (f0, values0: passed through). Inlined into confirmed_kernel, its one caller: a kernel of
    its own would optimize and emit confirmed_at's whole call tree once more on a first run."""
    empty = np.empty(0)
    optimum = statics_optimum(change, p0, w, lower, upper, rate, multiplier, bend, rest, lengths)
    if optimum.size == 0:
        return _NO_OPTIMUM, empty, empty, f0, values0, empty, empty, np.inf, np.nan, empty
    return confirmed_at(optimum, forces_args, jacobian_args, free, row_scale, indptr, indices, p0, w, lower, upper,
                        position, change, f0, values0, dgbtrf, dgbtrs, near, clock, clock_id, stability, seconds,
                        violations, np.int64(0), np.zeros(1, dtype=np.int64))


@numba.njit(cache=True)
def confirmed_at(optimum, forces_args, jacobian_args, free, row_scale, indptr, indices, p0, w, lower, upper, position,
                 change, f0, values0, dgbtrf, dgbtrs, near, clock, clock_id, stability, seconds, violations,
                 corrections, taken):  # pragma: no cover - compiled
    """confirmed_kernel's outcome at a start ``optimum`` (the statics optimum, or the reaction
    search's: solvers.reaction_start): clipped into the box, c and dc/dp there (|c|_inf into
    violations[1]), the KKT distance, at most ``corrections`` SQP steps where it is not confirmed
    there (``corrected``; their number added to taken[0]), and the stability (stability:
    confirmed_kernel's arguments of the stability evaluation; change, f0, values0: passed through).
    Also the stabilization's compiled re-solves (frontend.floor_steps.stabilization_rounds)."""
    empty = np.empty(0)
    p = np.minimum(np.maximum(optimum, lower), upper)  # solve_alm's np.clip
    measure, tol, kkt_tol, hessian_args, eigen_args, scale, free_index = stability
    f, values, distance, step = _evaluated(p, forces_args, jacobian_args, free, row_scale, indptr, indices, p0, w,
                                           lower, upper, position, dgbtrf, dgbtrs, near, clock, clock_id, seconds,
                                           violations)
    if corrections and violations[1] <= tol and kkt_tol < distance <= CORRECTABLE and step.size:
        balanced = violations[1]
        x, x_violation, x_f, x_values, x_distance = p, violations[1], f, values, distance
        for _ in range(corrections):
            x = np.minimum(np.maximum(x + step, lower), upper)
            taken[0] += 1
            x_f, x_values, x_distance, step = _evaluated(x, forces_args, jacobian_args, free, row_scale, indptr,
                                                         indices, p0, w, lower, upper, position, dgbtrf, dgbtrs, near,
                                                         clock, clock_id, seconds, violations)
            x_violation = violations[1]
            if (x_violation <= tol and x_distance <= kkt_tol) or step.size == 0:
                break
        if x_violation <= tol and x_distance <= kkt_tol:
            p, f, values, distance = x, x_f, x_values, x_distance
        else:  # not reached: the start stays, for asc's outer loop
            violations[1] = balanced
    eigenvalue, mode = np.nan, empty
    # Problem.stability at q* (its hessian_band's compiled path, which p0 itself does not take)
    if measure and violations[1] <= tol and distance <= kkt_tol and not np.array_equal(p, p0):
        measured = np.zeros(2)
        eigenvalue, mode = at_rest.stability(p, hessian_args, eigen_args, scale, free_index, clock, clock_id, measured)
        seconds[2] += measured[0] + measured[1]
    return CONFIRMED, change, p, f0, values0, f, values, distance, eigenvalue, mode


@numba.njit(cache=True)
def _evaluated(p, forces_args, jacobian_args, free, row_scale, indptr, indices, p0, w, lower, upper, position, dgbtrf,
               dgbtrs, near, clock, clock_id, seconds, violations):  # pragma: no cover - compiled
    """(f, dc/dp values, KKT distance, its SQP step) at p, |c|_inf into violations[1], seconds[0]
    and [1] accumulating model evaluation and linear algebra."""
    c, f, values = timed_at_rest(p, forces_args, jacobian_args, free, row_scale, clock, clock_id, seconds)
    violations[1] = largest_magnitude(c)
    buffer = np.zeros(2, dtype=np.int64)
    now = timing.clock_seconds(clock, clock_id, buffer)
    distance, step = band_kkt_step(dgbtrf, dgbtrs, indptr, indices, values, position, w, w * (p - p0), c, p, lower,
                                   upper, near)
    seconds[1] += timing.clock_seconds(clock, clock_id, buffer) - now
    return f, values, distance, step


@numba.njit(cache=True)
def timed_at_rest(p, forces_args, jacobian_args, free, row_scale, clock, clock_id, seconds):  # pragma: no cover
    """(c, f, dc/dp values) at p (Problem.residual, forces and strand_jacobian's arithmetic), their
    seconds added to seconds[0] (model evaluation)."""
    buffer = np.zeros(2, dtype=np.int64)
    start = timing.clock_seconds(clock, clock_id, buffer)
    c, f = at_rest_residual(p, forces_args, free, row_scale)
    values = at_rest.jacobian_values(p, *jacobian_args)
    seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - start
    return c, f, values


def corrected(problem: Problem, p: np.ndarray, tol: float, kkt_tol: float, counts: dict,
              near: float = 1e-6) -> tuple[np.ndarray, float, float] | None:
    """(p', |c(p')|_inf, its KKT distance) after at most CORRECTIONS SQP steps from a start p that
    balances (|c|_inf <= tol) but is not confirmed (kkt_tol < KKT distance <= CORRECTABLE), or
    None where they do not reach a confirmed point (or the saddle system is not a band): each step
    the KKT distance's own (contract.optimality.kkt_optimality: the equality-constrained step with
    the regularizer's Hessian on its working set), clipped into the box, counted in counts["sqp"];
    confirmed_at's steps in Python, the same arithmetic. Why: the reaction search can end at a kink
    of Phi (a bound starting to bind), a hair from the KKT point on it (1e-4 in p), where asc's outer
    loop took ~13 outer iterations to get there and two or three such steps do."""
    layout = problem.layout
    distance, step = kkt_step(problem, p, near)
    violation = float(np.abs(problem.residual(p)).max(initial=0.0))
    if not (violation <= tol and kkt_tol < distance <= CORRECTABLE and step.size):
        return None
    x = p
    for _ in range(CORRECTIONS):
        x = np.minimum(np.maximum(x + step, layout.lower), layout.upper)
        counts["sqp"] += 1
        distance, step = kkt_step(problem, x, near)
        violation = float(np.abs(problem.residual(x)).max(initial=0.0))
        if (violation <= tol and distance <= kkt_tol) or step.size == 0:
            break
    return (x, violation, distance) if violation <= tol and distance <= kkt_tol else None


def kkt_step(problem: Problem, p: np.ndarray, near: float = 1e-6) -> tuple[float, np.ndarray]:
    """(kkt_optimality(problem, p, near), its SQP step) where the saddle system is a band, else
    (inf, empty) (contract.optimality.band_kkt)."""
    banded = band_kkt(problem, p, near)
    return (np.inf, np.empty(0)) if banded is None else banded
