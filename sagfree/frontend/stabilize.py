"""Stable rest states for every solver: the stabilized problem and its loop (DESIGN section 4).

A converged strand must be a STABLE rest state: ``problem.stability(p) >= problem.stability_margin``
(mass-normalized smallest eigenvalue, s^-2). For a strand held by its root alone the internal moments
at q* are fixed by statics, so the Hessian is a fixed stress term plus sum_j k_j G_j (G_j PSD): only
stiffness restores stability, the smallest eigenvalue is concave in the multipliers k, and a rise of
k_j that keeps k_j (kbar_j - kappa*) (formulation.rest_change.restiffen) keeps c = 0. (A held tip,
pins or bodies add reactions the optimum may redistribute; the loop below then is a first-order
method without that guarantee, and the result is still checked for stability.) Self-weight buckling
of strands that point upward is what the boxes alone never prevent.

The stabilized problem is the bare one with stiffness FLOORS: lower bounds on the multipliers that
make its optimum stable. They are found by a cutting-plane loop on the bare problem (``floors_loop``):

1. solve; if the solution is stable (lambda >= margin), done;
2. otherwise raise the lower bounds of the multipliers that matter and are below their upper bounds
   (d lambda / d k above RELEVANT of the largest of all multipliers) along the least-R step that the
   eigenvalue's first-order model says lifts it to OVERSHOOT x the margin: dk = t g / h, g =
   d lambda / d k (Problem.stiffening_gradient), h the regularizer's curvature w a of each
   multiplier (lambda is concave in k, so the model is optimistic and the overshoot saves rounds);
   then check the step where it lands without a solve: for a strand held by its root alone the
   floored problem's optimum is asc's start (solvers.statics_start), elsewhere the solution
   restiffened onto the floors keeps c = 0 (restiffen), so lambda there is one eigenvalue; while it
   is below the margin, the step is repeated from there (at most FLOOR_STEPS times). From a strongly unstable optimum
   (lambda ~ -10 x the margin) the first step falls short by the concavity, and each shortfall cost
   a whole re-solve (these steps nearly halve a groom's rounds, benchmarks/RESULTS.md). For a
   strand held by its root alone the step and its checks are one compiled call (floor_steps);
3. solve the floored problem from the solver's own start again, and repeat.

For a strand held by its root alone, or at more points (a pinned tip, pins), solved by asc, the
solve, the margin test and the whole loop are one compiled call (frontend.whole_solve: asc's
confirmed start, the statics optimum or the reaction search, then floor_steps'
rounds, each re-solve again a confirmed start), with the Python loop's floors, solutions and
messages bit for bit; where a solve needs asc's outer loop, the strand takes the usual path, and
its loop runs in Python (``floors_loop``) around asc's compiled solves.

The floors of a strand must not depend on the solver, or solvers would be compared on different
problems: the floored problems are nonconvex like the bare one, and two solvers' intermediate optima
(hence their floors) can differ. So the floors are always found by the loop with ``asc`` (fast; its
time counts in every solver's), and any other solver then solves the floored problem, warm-started
from its own bare solution raised onto the floors with the forces kept (restiffen). With ``asc`` the
loop's last solve is the answer. A strand whose stabilizing multipliers are all at their upper
bounds cannot be stabilized inside the boxes: ``infeasible``, saying so. Iterations of every solve
are summed; ``stabilization`` counts the loop's rounds. A strand the boxes cannot balance (infeasible
with a residual force) does not rest at q*, so floors that stabilize q* mean nothing for it: it gets
the least static sag instead (frontend.best_effort), its stability measured where it rests.
"""
from __future__ import annotations

import dataclasses
import time
from typing import NamedTuple

import numpy as np

from sagfree.contract.optimality import KKT_TOL, TOL
from sagfree.contract.result import Result, make_result, summed_iterations
from sagfree.formulation.parameters import STIFFNESS_BLOCKS, STRAND_BLOCK, number_ranges
from sagfree.formulation.problem import Problem
from sagfree.formulation.rest_change import restiffen
from sagfree.linalg import timing
from sagfree.solvers import solve_alm
from sagfree.solvers.alm import converged_message, linear_start, start_violation, zero_counts
from sagfree.solvers.mprgp import PRECONDITIONERS
from sagfree.solvers.statics_start import square_rest_system

from .best_effort import with_least_sag
from .floor_steps import checked_floors, raised_floors, stabilization_rounds
from .whole_solve import whole_solve

#: Rounds of floors raised and solves repeated before giving up (status max_iterations).
MAX_ROUNDS = 10
#: The first-order step aims at this multiple of the margin (lambda is concave in the multipliers;
#: each step is checked where the re-solve will land, _landing, so a small excess suffices: 1.25
#: raised R by 0.9% (median) on the stabilized strands of groom(300, 100, seed=0), with more eigenvalues).
OVERSHOOT = 1.05
#: Multipliers whose d lambda / d k is below this share of the largest are left alone (a floor a
#: hair above the solution's value would only add nearly active bounds).
RELEVANT = 1e-3
#: First-order steps of the floors along restiffen per round, each checked by one eigenvalue.
FLOOR_STEPS = 3


def solve_stabilized(function, problem: Problem, options: dict) -> Result:
    """``function(problem, **options)``, stabilized by the loop of the module docstring; an
    ``infeasible`` result with a residual force left gets the least static sag of its box
    (frontend.best_effort)."""
    mark = timing.snapshot()
    result = _stabilized(function, problem, options)
    if result.status == "infeasible" and result.residual_inf > options.get("tol", TOL):
        result = with_least_sag(problem, result)
    compiled = timing.compiled_since(mark)  # a kernel's first compilation is setup, not solving
    seconds = max(result.time - compiled, 0.0)
    return dataclasses.replace(result, time=seconds, setup_time=result.setup_time + compiled,
                               time_split=timing.split_since(mark, seconds))


def _stabilized(function, problem: Problem, options: dict) -> Result:
    clock = time.perf_counter()
    if function is solve_alm:
        whole = _whole_solve(problem, options, clock)
        if whole is not None:
            return whole
    result = function(problem, **options)
    stiffness = problem.layout.concatenated_blocks((*STIFFNESS_BLOCKS, STRAND_BLOCK))[1]
    if (not problem.stabilize or not stiffness.size or result.status != "converged"
            or problem.meets_margin(result.p)):
        return result
    first_objective, counts, history = result.objective, dict(result.iterations), list(result.history)
    setup = result.setup_time
    if function is solve_alm:
        floored, result, rounds, verdict = floors_loop(solve_alm, problem, options, result)
        counts = summed_iterations(counts, result.iterations)
    else:  # the floors of asc's loop, then this solver on the floored problem from its own solution
        floored, _, rounds, _ = floors_loop(solve_alm, problem, {})
        result = function(floored, **{**options, "p_start": _restiffened(floored, result.p)})
        counts = summed_iterations(counts, result.iterations)
        setup += result.setup_time
        value = floored.stability(result.p)
        verdict = None
        if value < problem.stability_margin and result.status == "converged":
            verdict = ("failed", f"{result.message}; not stable with asc's stiffness floors: smallest eigenvalue "
                       f"{value:.3g} s^-2 < margin {problem.stability_margin:.3g} s^-2 (another local optimum)")
    history += result.history
    counts["stabilization"] = rounds
    status, message = verdict if verdict else (result.status, result.message)
    message += _floors_note(problem, floored.layout.lower, rounds, first_objective, result.objective)
    return make_result(problem, result.p, result.solver, status, message, counts,
                       time.perf_counter() - clock - setup, history, floored.layout.lower.copy(), setup_time=setup)


def _whole_solve(problem: Problem, options: dict, clock: float) -> Result | None:
    """The Result of ``_stabilized`` with asc from one compiled call (frontend.whole_solve: a strand
    held by its root alone whose solves are confirmed starts), the same as the two calls' (solve_alm's
    confirmed start, then _compiled_rounds) but for the time; None where that path does not hold
    (asc's options then decide: another start, or an unknown preconditioner it refuses)."""
    if (options.get("p_start") is not None or options.get("start", "auto") != "auto"
            or options.get("preconditioner", "cholesky") not in PRECONDITIONERS):
        return None
    tol, kkt_tol = options.get("tol", TOL), options.get("kkt_tol", KKT_TOL)
    stiffness = problem.layout.block_mask((*STIFFNESS_BLOCKS, STRAND_BLOCK))
    found = whole_solve(problem, stiffness, OVERSHOOT, RELEVANT, FLOOR_STEPS, MAX_ROUNDS, tol, kkt_tol)
    if found is None:
        return None
    counts = zero_counts()
    counts["reaction_values"], counts["sqp"] = found.reaction_values, found.sqp
    message = converged_message(found.first_violation, found.first_distance, tol, kkt_tol, 0, 0)
    history = [found.start_violation, found.first_violation]
    if found.ending == "stable" and not found.rounds:  # solve_alm's Result: its stability is the Result's measurement
        return make_result(problem, found.first, "asc", "converged", message, counts,
                           time.perf_counter() - clock - found.stability_seconds, history)
    # as _stabilized after _compiled_rounds
    last_message, objective = message, problem.objective(found.first)
    if found.rounds:
        last_message = converged_message(found.violation, found.distance, tol, kkt_tol, 0, 0)
        history += [found.start_violation, found.violation]
    else:
        history += history
    counts["stabilization"] = found.rounds
    status, message = (("converged", last_message) if found.ending == "stable"
                       else _verdict(found.ending, last_message, found.value, found.margin))
    message += _floors_note(problem, found.lower, found.rounds, objective, problem.objective(found.p))
    return make_result(problem, found.p, "asc", status, message, counts, time.perf_counter() - clock, history,
                       found.lower.copy())


class LastSolve(NamedTuple):
    """What floors_loop reads of its last solve where the rounds ran compiled (no Result is made
    for it): a Result's fields of the same names."""
    p: np.ndarray
    solver: str
    status: str
    message: str
    iterations: dict
    history: list
    objective: float


def floors_loop(function, problem: Problem, options: dict, result: Result | None = None):
    """(floored problem, its last solve, rounds, verdict) of the loop of the module docstring with
    ``function``, from ``result`` (its solution of the bare problem; solved here if None). The last
    solve (a Result, or a LastSolve where the rounds ran as one compiled call: _compiled_rounds) has
    the iterations of the loop's own solves. verdict: None when the last solution is stable, else
    (status, message)."""
    result = function(problem, **options) if result is None else result
    stiffness = problem.layout.block_mask((*STIFFNESS_BLOCKS, STRAND_BLOCK))
    compiled = _compiled_rounds(function, problem, options, result, stiffness)
    if compiled is not None:
        return compiled
    margin = problem.stability_margin
    current, rounds, counts = problem, 0, {}
    while True:
        value, mode = current.stability(result.p, vector=True)
        if value >= margin:
            verdict = None
            break
        if result.status != "converged":  # infeasible: the floors leave no balance (best effort follows)
            verdict = (result.status, f"stabilization round {rounds}: {result.message}")
            break
        if rounds == MAX_ROUNDS:
            verdict = _verdict("max rounds", result.message, value, margin)
            break
        floors = _next_floors(current, result.p, value, mode, stiffness)
        if floors is None:
            verdict = _verdict("no room", result.message, value, margin)
            break
        current = current.with_lower_bounds(floors)
        result = function(current, **options)
        counts = summed_iterations(counts, result.iterations)
        rounds += 1
    return current, dataclasses.replace(result, iterations=counts), rounds, verdict


def _compiled_rounds(function, problem: Problem, options: dict, result: Result, stiffness: np.ndarray):
    """floors_loop's outcome from one compiled call (floor_steps.stabilization_rounds) where asc's
    solves are its confirmed starts (a strand held by its root alone, asc's own start), else None.
    The same floors, solutions, messages and counts as the Python loop (whose confirmed re-solves
    count no iteration), without its intermediate Results and floored Problems."""
    if (function is not solve_alm or result.status != "converged" or options.get("p_start") is not None
            or options.get("start", "auto") != "auto"):
        return None
    value, mode = problem.stability(result.p, vector=True)
    margin = problem.stability_margin
    tol, kkt_tol = options.get("tol", TOL), options.get("kkt_tol", KKT_TOL)
    found = stabilization_rounds(problem, result.p, value, mode, stiffness, margin, OVERSHOOT, RELEVANT, FLOOR_STEPS,
                                 MAX_ROUNDS, tol, kkt_tol)
    if found is None:
        return None
    last = LastSolve(result.p, result.solver, result.status, result.message, {}, result.history, result.objective)
    if found.rounds:  # the last re-solve, as solve_alm reports a confirmed start
        p, violation = found.p, found.violation
        message = converged_message(violation, found.distance, tol, kkt_tol, 0, 0)
        history = [start_violation(problem), violation]
        last = LastSolve(p, result.solver, "converged", message, dict.fromkeys(result.iterations, 0), history,
                         problem.objective(p))
    verdict = None if found.ending == "stable" else _verdict(found.ending, last.message, found.value, margin)
    return problem.with_lower_bounds(found.lower), last, found.rounds, verdict


def _verdict(ending: str, message: str, value: float, margin: float) -> tuple[str, str]:
    """(status, message) of a loop that ended unstable, after the last solve's ``message``: with no
    multiplier left to raise ("no room") or after MAX_ROUNDS rounds ("max rounds")."""
    if ending == "max rounds":
        return ("max_iterations", f"{message}; not stable after {MAX_ROUNDS} rounds of stiffness floors: smallest "
                f"eigenvalue {value:.3g} s^-2 < margin {margin:.3g} s^-2")
    return ("infeasible", f"{message}; cannot be stabilized inside the boxes: smallest eigenvalue {value:.3g} s^-2 "
            f"< margin {margin:.3g} s^-2 and every stiffness multiplier that would raise it is at its upper bound; "
            "relax the stiffness bounds (bounds={'bend_stiffness': (1, 1000)}; command line: --bound "
            "bend_stiffness=1,1000)")


def warm_floor_steps(problem: Problem) -> None:
    """One round of floors from asc's optimum of ``problem``, whatever its stability, its floors
    thrown away, both ways (the compiled round of a strand held by its root alone, the Python
    steps of the others: a held tip, bodies), and the compiled loop of rounds from there: the
    warm-up's way (frontend.warm) to compile or load their kernels in this process before anything
    is timed."""
    result = solve_alm(problem)
    if result.status == "converged":
        value, mode = problem.stability(result.p, vector=True)
        stiffness = problem.layout.block_mask((*STIFFNESS_BLOCKS, STRAND_BLOCK))
        _next_floors(problem, result.p, value, mode, stiffness)
        _raised_floors(problem, result.p, value, mode, stiffness)
        stabilization_rounds(problem, result.p, value, mode, stiffness, problem.stability_margin, OVERSHOOT,
                             RELEVANT, FLOOR_STEPS, 1, TOL, KKT_TOL)


def _next_floors(problem: Problem, p: np.ndarray, value: float, mode: np.ndarray, stiffness: np.ndarray):
    """The floors of a round (module docstring, item 2) from p, the solution of ``problem`` with
    smallest eigenvalue ``value`` and mode ``mode``: the first-order step, checked where it lands;
    None if no multiplier that would raise the eigenvalue has room below its upper bound. One
    compiled call where floor_steps applies (a strand held by its root alone), else these steps in
    Python, with the same floors."""
    applies, floors = checked_floors(problem, p, value, mode, stiffness, problem.stability_margin, OVERSHOOT,
                                     RELEVANT, FLOOR_STEPS, TOL)
    if applies:
        return floors
    floors = _raised_floors(problem, p, value, mode, stiffness)
    return None if floors is None else _floors_checked_by_restiffening(problem, p, floors, stiffness)


def _raised_floors(problem: Problem, p: np.ndarray, value: float, mode: np.ndarray, stiffness: np.ndarray):
    """The lower bounds of ``problem`` with the first-order step of the module docstring (item 2)
    from p, whose smallest eigenvalue is ``value`` with ``mode``; None if no multiplier that would
    raise it has room below its upper bound."""
    layout = problem.layout
    floors = raised_floors(problem.stiffening_gradient(p, mode), np.ascontiguousarray(p, dtype=float), layout.lower,
                           layout.upper, layout.weights, stiffness, float(value), float(problem.stability_margin),
                           OVERSHOOT, RELEVANT)
    return floors if floors.size else None


def _floors_checked_by_restiffening(problem: Problem, p: np.ndarray, floors: np.ndarray,
                                    stiffness: np.ndarray) -> np.ndarray:
    """``floors`` raised further until the point the floored problem's solve will land on is stable
    (module docstring, item 2): at most FLOOR_STEPS first-order steps, each from that point
    (_landing)."""
    for _ in range(FLOOR_STEPS):
        floored = problem.with_lower_bounds(floors)
        landing = _landing(floored, p)
        value, mode = floored.stability(landing, vector=True)
        if value >= problem.stability_margin:
            break
        more = _raised_floors(floored, landing, value, mode, stiffness)  # >= floors: it starts from them
        if more is None:
            break
        floors = more
    return floors


def _landing(floored: Problem, p: np.ndarray) -> np.ndarray:
    """The floored problem's solution, found without a solve: for a strand held by its root alone
    its optimum (asc's start, solvers.statics_start, which the re-solve then only confirms: the
    eigenvalue checked here is the one its Result reads, memoized by p); elsewhere p restiffened
    onto the floors (c kept, rest_change.restiffen). Both keep c = 0; the optimum trades some of
    the floors' stiffness back for rest change, so it is less stable than the restiffened p, and
    checking it checks the eigenvalue the Result will report, one evaluation fewer per round. For a
    strand held at more points the floored start is a reaction search (solvers.reaction_start), which
    as the landing cost 25% more time than restiffening for 1% less R (benchmarks/RESULTS.md)."""
    if square_rest_system(floored):
        start = linear_start(floored)
        if start is not None and np.abs(floored.residual(start)).max(initial=0.0) <= TOL:
            return start
    return _restiffened(floored, p)


def _restiffened(floored: Problem, p: np.ndarray) -> np.ndarray:
    """p raised onto the floors of ``floored`` with its forces kept (rest_change.restiffen)."""
    return restiffen(floored, p, np.maximum(p, floored.layout.lower))


def _floors_note(problem: Problem, floors: np.ndarray, rounds: int, before: float, after: float) -> str:
    """Where the stiffness floors (the stabilized problem's lower bounds) rose, and what they cost in
    R: relative, or from what to what where the bare optimum's R is below 1% of it (a strand held
    at both ends can rest nearly as groomed, R 1e-12, and a percentage of that says nothing)."""
    raised = np.flatnonzero(floors > problem.layout.lower)
    places = "; ".join(f"{block} at {'strand' if block == STRAND_BLOCK else number_ranges(numbers)}"
                       for block, numbers in problem.layout.element_numbers(raised).items())
    cost = f"R {(after - before) / before:+.2%}" if before >= 0.01 * after and before else \
        f"R {before:.3g} -> {after:.3g}"
    return (f"; stabilized in {rounds} round{'s' if rounds != 1 else ''}: stiffness floors raised "
            f"({places or 'none'}), {cost}")
