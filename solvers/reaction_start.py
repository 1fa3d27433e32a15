"""asc's start for a strand held at points besides its root: the optimum over the held points' reactions.

A strand held by its root alone is statically determinate: its rest blocks' columns of dc/dp at p0
form a square system whose one solution fixes every element's stresses, and the parameter problem
falls apart element by element (solvers.statics_start). Hold more points (a pinned tip, pins) and
their reactions are k more unknowns (3 per held point): the structure stays, one level up.

- Drop the holds and the strand is its root-held companion (the same strand, tip free, no pins):
  the square system J_R d = -c(p0) of its free DOFs, the held points' included.
- A rest change d balances the held strand exactly when it balances the companion up to forces on
  the held DOFs: J_R d = -c(p0) + E F, F in R^k those DOFs' reactions (rows of c, in units of
  their row scales), E their unit columns. So the balancing changes are d(F) = d0 + N F with
  d0 = J_R^-1 (-c(p0)) (alm.linear_start's change of the companion) and N = J_R^-1 E: one band LU,
  k + 1 solves (linalg.square).
- For each F the rest of the problem is the root-held one: statics_optimum(d(F)) is the least R
  among the p whose stresses are d(F)'s, in closed form element by element. So the held strand's
  problem is the minimization of Phi(F) = R(statics_optimum(d(F))) over k unknowns (Phi = inf
  where a box admits no multiplier for d(F)).

Each element's share is the value of a convex problem in one multiplier, so Phi varies smoothly
between the reactions at which a box starts or stops binding, where its curvature jumps. The
search runs on F scaled by the strand's total external force over each held row's scale, from
F = 0 (the root carries everything; a floored twin of the stabilization from the last search's F;
where a box admits no multiplier there, from the first F Nelder-Mead finds on the boxes' violation,
``reaction_violation``, whose zeros are where Phi is finite but for statics_optimum's choice of
rest lengths): BFGS with exact gradients (statics_start.optimum_gradient: forward differences
took twice the values) and an Armijo line search (Nocedal & Wright, Numerical Optimization,
algorithm 6.1). Where Phi descends towards the edge of its domain (tight boxes: the line search
fails on values of inf), a round of Nelder-Mead (Lagarias et al., SIAM J. Optim. 9, 1998:
reflection 1, expansion 2, contraction 1/2, shrink 1/2) on a simplex of edge FIRST_STEP moves along
that edge and BFGS goes on from its best point. Where a jump in curvature stopped BFGS short (a
small step along an axis, or a diagonal between two, still lowers Phi), one round of Nelder-Mead on
a small simplex around its end follows. On groom strands with a pinned tip or a pin (k = 3) that
takes ~85 values of Phi, where Nelder-Mead alone took ~420. The whole search is one compiled call
(``reaction_values`` counts its values). asc then confirms the point by its KKT distance, as it
confirms a root-held strand's start; where the search ended at a kink a hair from the KKT point
(a bound starting to bind), a few SQP steps reach it (solvers.confirmed_start.corrected), and
otherwise asc's outer loop polishes it. The front end's whole solve (frontend.whole_solve) runs
the search, that confirmation and the stabilization's re-solves in one compiled call
(``family_optimum``, its searches logged in a ``search_state``).

Why: from p0 or the linear start the augmented Lagrangian has to find the reactions through the
whole parameter space, where the problem is nonconvex; it crawled to max_iterations at feasible
non-KKT points (groom strands pinned at their middle vertex, 400 vertices: 4 of 20; a pinned tip
from 3000 vertices on) and converged at worse optima elsewhere. Over k unknowns the search reaches
the optimum Ipopt finds on those (benchmarks/RESULTS.md, 2026-12-05, thirty-first session).

Applies where statics_start's decomposition does but for the holds (per-element stiffness, twist
coupled to bend, every block optimized, no bodies, a clamped root), to holds of points only (a
pinned tip, pins; a clamped tip's held twist and the rest blocks that act on no free DOF there fall
outside d(F)), and where the companion's system is square; ``None`` elsewhere and where no F
evaluated admits multipliers (a strand the boxes may not balance: asc's own path decides).
"""
from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp

from sagfree.formulation.parameters import REST_BLOCKS
from sagfree.formulation.problem import Problem
from sagfree.linalg.band import column_norms
from sagfree.linalg.compressed import csc_column_norms
from sagfree.linalg.square import square_column_solves

from .gauss_newton import regularizer_value
from .statics_start import (decomposable, least_multipliers, optimum_gradient, square_rest_system, statics_indices,
                            statics_optimum)

#: values of Phi per search, all its phases together
MAX_EVALUATIONS = 4000
#: the quasi-Newton phase: the longest first trial step (scaled units) and the Armijo constant
MAX_STEP = 1.0
ARMIJO = 1e-4
#: relative change of Phi below which the quasi-Newton phase stops (rounding: gauss_newton's ROUNDING)
ROUNDING = 1e-13
#: the simplex edge (scaled units) of the Nelder-Mead rounds on the boxes' violation where Phi is inf
#: at F = 0 and along the edge of Phi's domain, and of the round that polishes the quasi-Newton
#: phase's end (a kink can stop it short; also the axis steps that test for that)
FIRST_STEP = 0.1
POLISH_STEP = 1e-5
#: a round ends when its simplex is within this (scaled units) or its values within VALUE_SPREAD (relative)
SIMPLEX_SIZE = 1e-10
VALUE_SPREAD = 1e-15


def compile_kernels() -> None:
    """Compile (or load from numba's cache) the search and the family's many-right-hand-side band
    solve with the argument types of a strand's, on a strand of two edges: only strands held at more
    points than their root run them, and frontend.warm calls this before any timed solve."""
    J = sp.csc_matrix(np.eye(2))
    square_column_solves(J, np.ones(2, dtype=bool), np.eye(2))
    integers = np.arange(8)
    integers.flags.writeable = False  # as the layout's block indices are
    p0 = np.r_[0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    lower, upper = p0 - np.r_[0.1, 0.1, 0.5, 0.5, 0.5, 1.0, 1.0, 1.0], p0 + 1.0
    least_over_reactions(np.zeros(1), np.zeros(8), np.zeros((8, 1)), np.ones(1), p0, np.ones(8), lower, upper,
                         integers[:2], integers[2:4], integers[4:5], integers[5:].reshape(1, 3).copy(), np.ones(2))


def applies(problem: Problem) -> bool:
    """True where the module's decomposition can hold (module docstring, last paragraph)."""
    strand = problem.strand
    return decomposable(problem) and strand.tip != "clamped" and (strand.tip == "pinned" or len(strand.pins) > 0)


def reaction_start(problem: Problem, counts: dict | None = None) -> np.ndarray | None:
    """The least R over the held points' reactions (module docstring), or None where the module does
    not apply or no reaction tried admits multipliers; searched once per box (the Problem and its
    floored twins with the same lower bounds share it: a compiled whole solve that hands a strand
    back leaves its searches here, remember_searches). The values of Phi a search took are added to
    ``counts["reaction_values"]`` by the first call that passes ``counts``."""
    found = problem.bound_independent("reaction searches", dict)
    key = problem.layout.lower.tobytes()
    if key not in found:
        found[key] = list(_searched(problem))
    entry = found[key]
    if counts is not None and entry[1]:
        counts["reaction_values"] = counts.get("reaction_values", 0) + entry[1]
        entry[1] = 0
    return None if entry[0] is None else entry[0].copy()


def held_family(problem: Problem) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """(d0, N, scale, last reactions) of ``problem`` (reaction_family, and the search's last scaled
    reactions, shared with its floored twins), or None where the module does not apply."""
    if not applies(problem):
        return None
    family = problem.bound_independent("reaction family", lambda: reaction_family(problem))
    if family is None:
        return None
    return (*family, problem.bound_independent("last reactions", lambda: np.zeros(family[1].shape[1])))


def _searched(problem: Problem) -> tuple[np.ndarray | None, int]:
    family = held_family(problem)
    if family is None:
        return None, 0
    change, basis, scale, last = family
    layout = problem.layout
    # the last search's reactions, shared with the floored twins: a floor moves the optimum a little
    p, reactions, evaluations = least_over_reactions(last, change, basis, scale, layout.p0, layout.weights,
                                                     layout.lower, layout.upper, *statics_indices(problem),
                                                     problem.edge_lengths)
    last[:] = reactions
    return (p if p.size else None), int(evaluations)


def reaction_family(problem: Problem) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(d0, N, scale): the balancing rest changes d0 + N F of the module docstring (N: (parameters,
    k), one column per held DOF in the order of the companion's rows), and each F entry's scale,
    the sum of |external force| over the strand in units of its row's scale; None where the
    companion's system is not square or its rest columns that act are not the held strand's."""
    companion = Problem(problem.strand.root_held(), **{**problem.options, "stabilize": False})
    if not square_rest_system(companion):
        return None
    rest = problem.layout.block_mask(REST_BLOCKS)
    J = companion.strand_jacobian(companion.layout.p0)
    acting = rest & (column_norms(J) > 0)
    held = ~problem.free[companion.free_index]
    held_rows = np.flatnonzero(held)
    # the held strand's dc/dp at p0 is the companion's without the held rows
    indptr, indices, data = J.csc()
    if not np.array_equal(acting, rest & (csc_column_norms(indptr, np.where(held[indices], 0.0, data)) > 0)):
        return None
    rhs = np.zeros((J.shape[0], 1 + held_rows.size))
    rhs[:, 0] = -companion.residual(companion.layout.p0)
    rhs[held_rows, 1 + np.arange(held_rows.size)] = 1.0
    solutions = square_column_solves(J, acting, rhs)
    if solutions is None:
        return None
    total = float(np.abs(problem.external_forces).sum())
    scale = total / companion.row_scale[companion.free_index[held_rows]]
    return solutions[:, 0].copy(), np.ascontiguousarray(solutions[:, 1:]), scale


@numba.njit(cache=True)
def reaction_value(x, change, basis, scale, p0, w, lower, upper, rate, multiplier, bend, rest, lengths,
                   work):  # pragma: no cover - compiled
    """(Phi, p) at the scaled reactions x (F = scale x): R at statics_optimum(d0 + N F), inf (p
    empty) where a box admits no multiplier."""
    d = change + basis @ (scale * x)
    p = statics_optimum(d, p0, w, lower, upper, rate, multiplier, bend, rest, lengths)
    if p.size == 0:
        return np.inf, p
    return regularizer_value(w, p, p0, work), p


@numba.njit(cache=True)
def reaction_violation(x, change, basis, scale, p0, w, lower, upper, rate, multiplier, bend, rest, lengths,
                       work):  # pragma: no cover - compiled
    """V >= 0 at the scaled reactions x: the edges' empty intervals of b and the vertices' least
    multipliers above their upper bounds (statics_start.least_multipliers), each over its
    multiplier's box; inf where a rest change has no room on its side at all. V = 0 exactly where
    some p in the boxes carries these reactions (statics_start.unbalanceable's certificate, exact
    both ways); Phi is finite there but where statics_optimum's choice of rest lengths leaves a
    vertex above its bound (one of 24 strands with budgets cut to 0.2 rad, benchmarks/RESULTS.md)."""
    d = change + basis @ (scale * x)
    low, high, least = least_multipliers(d, p0, w, lower, upper, rate, multiplier, rest, lengths)
    violation = 0.0
    for e in range(1, rate.size):  # the root edge's rest length acts on no free DOF
        ia = multiplier[e]
        width = upper[ia] - lower[ia]
        gap = max(low[e] - high[e], 0.0) + (1e-12 * width - low[e] if low[e] <= 0.0 else 0.0)
        violation += gap / width if width > 0.0 else (np.inf if gap > 0.0 else 0.0)
    for v in range(bend.size):
        if not np.isfinite(least[v]):
            return np.inf
        ib = bend[v]
        if least[v] > upper[ib]:
            violation += (least[v] - upper[ib]) / upper[ib]
    return violation


def search_state(change: np.ndarray, basis: np.ndarray, scale: np.ndarray, reactions: np.ndarray,
                 searches: int) -> tuple:
    """family_optimum's ``search`` tuple: the family (d0, N, scale; N without a column for a strand
    held by its root alone, whose start is then statics_optimum), the scaled reactions to start from
    (a copy), the values of Phi taken (int64 [1]), and the log of at most ``searches`` searches: each
    one's lower bounds, p (where found), values of Phi and whether it found one, and how many were
    logged (int64 [1])."""
    rows = searches if basis.shape[1] else 0
    return (change, basis, scale, reactions.copy(), np.zeros(1, dtype=np.int64), np.empty((rows, basis.shape[0])),
            np.empty((rows, basis.shape[0])), np.zeros(rows, dtype=np.int64), np.zeros(rows, dtype=np.bool_),
            np.zeros(1, dtype=np.int64))


def remember_searches(problem: Problem, search: tuple, counted: bool) -> None:
    """The searches a compiled call logged in ``search`` (search_state) remembered as reaction_start's
    outcomes for the boxes they searched, their values of Phi left for the solve that reads each
    to count unless ``counted``; the shared last reactions set to the last search's end."""
    _, basis, _, reactions, _, lowers, found, values, found_any, logged = search
    if basis.shape[1] == 0:
        return
    memo = problem.bound_independent("reaction searches", dict)
    for row in range(int(logged[0])):
        memo[lowers[row].tobytes()] = [found[row].copy() if found_any[row] else None, 0 if counted else
                                       int(values[row])]
    problem.bound_independent("last reactions", lambda: np.zeros(basis.shape[1]))[:] = reactions


@numba.njit(cache=True)
def family_optimum(search, p0, w, lower, upper, rate, multiplier, bend, rest, lengths):  # pragma: no cover - compiled
    """asc's start under the box [lower, upper] in one compiled call: statics_optimum of the least
    rest change where the family in ``search`` (search_state) has no reaction (a strand held by its
    root alone), else least_over_reactions from its reactions, which receive its end (as
    reaction_start's "last reactions" do), its values of Phi counted and the search logged (while
    the log has room); empty where it finds none."""
    change, basis, scale, reactions, evaluations, lowers, found, values, found_any, logged = search
    if basis.shape[1] == 0:
        return statics_optimum(change, p0, w, lower, upper, rate, multiplier, bend, rest, lengths)
    p, x, taken = least_over_reactions(reactions, change, basis, scale, p0, w, lower, upper, rate, multiplier,
                                       bend, rest, lengths)
    reactions[:] = x
    evaluations[0] += taken
    row = logged[0]
    if row < values.size:
        lowers[row] = lower
        values[row], found_any[row] = taken, p.size > 0
        if p.size:
            found[row] = p
        logged[0] = row + 1
    return p


@numba.njit(cache=True)
def least_over_reactions(start, change, basis, scale, p0, w, lower, upper, rate, multiplier, bend, rest,
                         lengths):  # pragma: no cover - compiled
    """(p, x, evaluations): statics_optimum at the scaled reactions x that minimize Phi (module
    docstring), p empty where every value met was inf, and the values of Phi it took (at most
    about MAX_EVALUATIONS). From ``start`` (F = 0 where Phi is inf there), or where Phi is inf at
    F = 0 too from the point where a Nelder-Mead round on V (reaction_violation, a simplex of edge
    FIRST_STEP) reaches 0: quasi-Newton (after each stop at the edge of Phi's domain, a Nelder-Mead
    round of edge FIRST_STEP and quasi-Newton again while that lowers Phi), then, where it stopped
    short of a minimum (_improvable), a Nelder-Mead round on a simplex of edge POLISH_STEP around
    its end."""
    work = np.empty(p0.size)
    args = (change, basis, scale, p0, w, lower, upper, rate, multiplier, bend, rest, lengths, work)
    x = start.copy()
    value, p = reaction_value(x, *args)
    evaluations = 1
    if not np.isfinite(value) and np.any(x != 0.0):
        x[:] = 0.0
        value, p = reaction_value(x, *args)
        evaluations += 1
    if not np.isfinite(value):  # a reaction the boxes admit, first (V = 0)
        violation = reaction_violation(x, *args)
        x, violation, evaluations = _nelder_mead_round(x, violation, FIRST_STEP, evaluations + 1, np.bool_(True), args)
        value, p = reaction_value(x, *args)
        evaluations += 1
    if np.isfinite(value):
        x, value, evaluations, walled = _quasi_newton(x, value, p, evaluations, args)
        while walled and evaluations < MAX_EVALUATIONS:  # around the edge of Phi's domain, then on
            moved, moved_value, evaluations = _nelder_mead_round(x, value, FIRST_STEP, evaluations, np.bool_(False),
                                                                 args)
            if not moved_value < value:
                break
            moved_value, p = reaction_value(moved, *args)
            x, value, evaluations, walled = _quasi_newton(moved, moved_value, p, evaluations + 1, args)
        improvable, evaluations = _improvable(x, value, evaluations, args)
        if improvable:
            x, value, evaluations = _nelder_mead_round(x, value, POLISH_STEP, evaluations, np.bool_(False), args)
    if not np.isfinite(value):
        return np.empty(0), x, evaluations
    value, p = reaction_value(x, *args)
    return p, x, evaluations + 1


@numba.njit(cache=True)
def _improvable(x, value, evaluations, args):  # pragma: no cover - compiled
    """(improvable, evaluations): True where a step of POLISH_STEP along some axis or diagonal
    between two axes, either way, lowers Phi by more than its ROUNDING: the quasi-Newton phase
    stopped short of a minimum (at a kink), not at one. Axes alone missed a kink on one groom strand
    pinned at the middle (KKT distance 2.7e-3 at the search's end)."""
    k = x.size
    for i in range(k):
        for j in range(i, k):  # the axis (j = i) either way, then the diagonals' four sign pairs
            half = 1 if j == i else 2
            for signs in range(2 * half):
                moved = x.copy()
                moved[i] += (-1.0 if signs < half else 1.0) * POLISH_STEP
                if j != i:
                    moved[j] += (-1.0 if signs % 2 == 0 else 1.0) * POLISH_STEP
                moved_value, _p = reaction_value(moved, *args)
                evaluations += 1
                if moved_value < value - ROUNDING * abs(value):
                    return True, evaluations
    return False, evaluations


@numba.njit(cache=True)
def _objective(x, violation, args):  # pragma: no cover - compiled
    """Phi at x, or with ``violation`` V (reaction_violation)."""
    if violation:
        return reaction_violation(x, *args)
    value, _p = reaction_value(x, *args)
    return value


@numba.njit(cache=True)
def _nelder_mead_round(x, value, step, evaluations, violation, args):  # pragma: no cover - compiled
    """(x, value, evaluations) at the best vertex of Nelder-Mead (_nelder_mead, on V with
    ``violation``) from the simplex of x and x + step e_i."""
    k = x.size
    simplex, values = np.empty((k + 1, k)), np.empty(k + 1)
    simplex[0], values[0] = x, value
    for i in range(k):
        simplex[i + 1] = x
        simplex[i + 1, i] += step
        values[i + 1] = _objective(simplex[i + 1], violation, args)
    evaluations = _nelder_mead(simplex, values, evaluations + k, violation, args)
    best = np.argmin(values)
    if values[best] < value:
        return simplex[best].copy(), values[best], evaluations
    return x, value, evaluations


@numba.njit(cache=True)
def reaction_gradient(x, p, change, basis, scale, p0, w, lower, upper, rate, multiplier, bend, rest, lengths,
                      work):  # pragma: no cover - compiled
    """Phi's gradient at the scaled reactions x, where p = statics_optimum(d0 + N F) (reaction_value's):
    scale N^T dR/dd (statics_start.optimum_gradient)."""
    d = change + basis @ (scale * x)
    return scale * (basis.T @ optimum_gradient(d, p, p0, w, lower, upper, rate, multiplier, bend, rest, lengths))


@numba.njit(cache=True)
def _quasi_newton(x, value, p, evaluations, args):  # pragma: no cover - compiled
    """BFGS on Phi from x (p: statics_optimum there; inverse Hessian scaled by y's/s's ratio after the
    first step, Nocedal & Wright 6.20), the gradients exact (reaction_gradient), Armijo backtracking
    that treats inf as no decrease and a step taken whole doubled while Phi falls (Phi can fall
    linearly over many units: a strand pulled taut between its holds); ends when a step moves x by
    at most SIMPLEX_SIZE or lowers Phi by at most ROUNDING of itself, the line search fails, or
    MAX_EVALUATIONS. Returns (x, value, evaluations, walled): walled where the line search failed on
    values of inf (Phi descends towards the edge of its domain there)."""
    k = x.size
    inverse = np.eye(k)
    gradient = reaction_gradient(x, p, *args)
    first = True
    while evaluations < MAX_EVALUATIONS and np.all(np.isfinite(gradient)):
        direction = -(inverse @ gradient)
        slope = direction @ gradient
        if not slope < 0.0:
            inverse = np.eye(k)
            direction, slope = -gradient, -(gradient @ gradient)
            if not slope < 0.0:
                break
        longest = np.abs(direction).max()
        t = min(1.0, MAX_STEP / longest) if longest > 0.0 else 1.0
        accepted = backtracked = walled = False
        while t * longest > SIMPLEX_SIZE and evaluations < MAX_EVALUATIONS:
            trial = x + t * direction
            trial_value, trial_p = reaction_value(trial, *args)
            evaluations += 1
            if trial_value <= value + ARMIJO * t * slope:
                accepted = True
                break
            walled = not np.isfinite(trial_value)
            t *= 0.5
            backtracked = True
        if not accepted:
            return x, value, evaluations, walled
        # a step taken whole: doubled while that lowers Phi
        while not backtracked and evaluations < MAX_EVALUATIONS:
            farther = x + 2.0 * t * direction
            farther_value, farther_p = reaction_value(farther, *args)
            evaluations += 1
            if not farther_value < trial_value:
                break
            t, trial, trial_value, trial_p = 2.0 * t, farther, farther_value, farther_p
        if value - trial_value <= ROUNDING * abs(value) or np.abs(trial - x).max() <= SIMPLEX_SIZE:
            x, value = trial, trial_value  # at Phi's rounding: nothing left to resolve
            break
        new_gradient = reaction_gradient(trial, trial_p, *args)
        s, y = trial - x, new_gradient - gradient
        x, value, gradient = trial, trial_value, new_gradient
        sy = s @ y
        if sy > 1e-12 * np.sqrt((s @ s) * (y @ y)):
            if first:
                inverse = np.eye(k) * (sy / (y @ y))
                first = False
            rho = 1.0 / sy
            hy = inverse @ y
            inverse += (rho * rho * (y @ hy) + rho) * np.outer(s, s) - rho * (np.outer(hy, s) + np.outer(s, hy))
    return x, value, evaluations, False


@numba.njit(cache=True, inline="always")
def _nelder_mead(simplex, values, evaluations, violation, args):  # pragma: no cover - compiled
    """Nelder-Mead iterations on ``simplex`` (k + 1 rows) and its ``values`` in place, on Phi, or
    with ``violation`` on V (reaction_violation), until the simplex is within SIMPLEX_SIZE or its
    values within VALUE_SPREAD, V is 0, or MAX_EVALUATIONS; returns the evaluations counted so far."""
    k = simplex.shape[1]
    while evaluations < MAX_EVALUATIONS:
        order = np.argsort(values)
        simplex[:] = simplex[order]
        values[:] = values[order]
        size = 0.0
        for i in range(1, k + 1):
            for j in range(k):
                size = max(size, abs(simplex[i, j] - simplex[0, j]))
        if not np.isfinite(values[0]) or size <= SIMPLEX_SIZE or values[k] - values[0] <= VALUE_SPREAD * values[0]:
            break
        if violation and values[0] <= 0.0:
            break
        centroid = np.zeros(k)
        for i in range(k):
            centroid += simplex[i]
        centroid /= k
        reflected = 2.0 * centroid - simplex[k]
        reflected_value = _objective(reflected, violation, args)
        evaluations += 1
        if reflected_value < values[0]:
            expanded = 3.0 * centroid - 2.0 * simplex[k]
            expanded_value = _objective(expanded, violation, args)
            evaluations += 1
            if expanded_value < reflected_value:
                simplex[k], values[k] = expanded, expanded_value
            else:
                simplex[k], values[k] = reflected, reflected_value
            continue
        if reflected_value < values[k - 1]:
            simplex[k], values[k] = reflected, reflected_value
            continue
        if reflected_value < values[k]:  # outside contraction
            contracted = 0.5 * (centroid + reflected)
            contracted_value = _objective(contracted, violation, args)
            evaluations += 1
            if contracted_value <= reflected_value:
                simplex[k], values[k] = contracted, contracted_value
                continue
        else:  # inside contraction
            contracted = 0.5 * (centroid + simplex[k])
            contracted_value = _objective(contracted, violation, args)
            evaluations += 1
            if contracted_value < values[k]:
                simplex[k], values[k] = contracted, contracted_value
                continue
        for i in range(1, k + 1):  # shrink towards the best vertex
            simplex[i] = 0.5 * (simplex[0] + simplex[i])
            values[i] = _objective(simplex[i], violation, args)
        evaluations += k
    return evaluations
