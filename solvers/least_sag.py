"""The best effort for a strand the boxes cannot balance: the least static sag inside the box.

Where no p in the box makes q* an equilibrium (long fine hair: the moment its own weight exerts at
the root exceeds what the stiffest, most pre-bent rest shape of the box can hold), the strand will
rest elsewhere: at the static equilibrium q_s(p) that q* relaxes into (simulation.equilibrium). What
a user sees is how far that is from the groom, so the best effort minimizes it directly:

    S(p) = 1/2 sum_i (m_i / M) |x_i(q_s(p)) - x_i*|^2 / L^2      over lower <= p <= upper,

the mass-weighted mean squared displacement (unit-free; m_i the vertex masses, M their sum). Its
Jacobian follows from the equilibrium itself: f(q_s, p) = 0 gives

    dq_s/dp = K^-1 D dc/dp                                                  (K d^2E/dq^2 at q_s)

with c = D^-1 S f at q_s (``Problem.strand_jacobian(p, q, frames)``): one banded Cholesky of K per
Jacobian, which is never formed but applied, each product with it or its transpose one pair of
band triangular solves and one sparse product, O(n) (solvers.sag_operator): formed, it and its
products grow like n^2 (at 2000 vertices ~2 GB with its intermediates).

The steps: trust-region reflective least squares (solvers.reflective: scipy's least_squares
method "trf", ported, which keeps every iterate strictly inside the box), its Gauss-Newton
direction by sag_operator.CG_ITERATIONS of conjugate gradients at most, compiled with the products
(sag_operator.gauss_newton_direction; scipy's LSMR ran the same iterations in Python, a Python
call per product: benchmarks/RESULTS.md, 2026-12-05).
The steps are taken in the variables' scales of the Jacobian's column norms, which change by orders
of magnitude as the multipliers reach their bounds; they are re-estimated every
RESCALE_EVALUATIONS evaluations where the minimization is, from NORM_PROBES random products
(``StaticSag.estimated_column_norms``, Hutchinson's estimator, O(n)). Each evaluation continues the
last equilibrium found (``equilibrium(start=...)``, from its tangent's first-order prediction where
the Jacobian was last factored there), so p moves along one branch of equilibria; where the
continuation fails (CONTINUATION_STEPS Newton steps), the step was too long for it and the trust
region shrinks. (A restart from q* follows the whole fall: ~7 times the Newton steps at
100 vertices.)

S weighs the whole strand, not only the vertex that moves most: smooth, and a Gauss-Newton problem;
the reported sag (the largest displacement) falls with it (benchmarks/RESULTS.md). The start is the
solver's own best effort (alm: the least residual force at q*, restiffened to the largest
stiffness). The least sag lies where the box runs out, often next to a fold of the equilibria
where the resting state turns soft, so the answer must rest STABLY: it is the visited point of
least S whose equilibrium has its smallest mass-normalized eigenvalue at least
``Problem.stability_margin``, confirmed by the equilibrium from q* (the one ``equilibrium`` finds
and every report measures: stable, and sagging less than the start); VERIFIED candidates are tried
in order of S, else the start stays.

The minimization runs as one compiled call (solvers.least_sag_loop: the continued static solves,
linearizations, column norms and trust-region steps with no Python between evaluations) wherever
the static solve is compiled (Problem.newton_kernels, no friction) and the stencils' parameter
Jacobians are; ``StaticSag`` through solvers.reflective is its Python form, kept for the rest (the
lagged friction is numpy code), and visits the same points bit for bit (tests/test_least_sag.py).
Driven from Python, the calls between evaluations were ~12% of an infeasible strand's time.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np

from sagfree.formulation import dofs
from sagfree.formulation.frames import Frames
from sagfree.formulation.problem import Problem
from sagfree.formulation.simulation import RESIDUAL_TOLERANCE, Equilibrium, equilibrium, static_solve_constants
from sagfree.linalg import timing

from .least_sag_loop import NEWTON, VISITS, least_sag_loop, model_arguments, prepare_model
from .reflective import reflective_least_squares
from .sag_operator import (estimated_column_norms, gauss_newton_direction, sag_product, sag_transposed_product,
                           scaled_rows, stiffness_factor, tangent_step)

#: Model evaluations (static solves) the minimization may take: enough for the large early gains,
#: bounded so that a groom of long hair costs seconds per strand.
MAX_EVALUATIONS = 60
#: Candidates (visited stable points, least S first) confirmed by a static solve from q*.
VERIFIED = 3
#: Newton steps of a continued static solve before the step counts as too long.
CONTINUATION_STEPS = 100
#: Evaluations between rescalings (the Jacobian's column norms re-estimated where the minimization is).
RESCALE_EVALUATIONS = 5
#: Random sign vectors of StaticSag.estimated_column_norms (Hutchinson's estimator).
NORM_PROBES = 32


@dataclass
class LeastSag:
    """The least-sag parameters and where they rest.

    p: parameters inside the box; rest: the static equilibrium from q* of p (Equilibrium, the sag
    a report measures); start: that of the starting parameters; naive: that of p0 (the sag a
    report compares with); evaluations: static solves taken by the minimization; newton: their
    Newton steps.
    """

    p: np.ndarray
    rest: Equilibrium
    start: Equilibrium
    naive: Equilibrium
    evaluations: int
    newton: int


class StaticSag:
    """S(p) of the module docstring as least-squares residuals, continuing the equilibrium."""

    def __init__(self, problem: Problem, start: Equilibrium):
        self.problem, self.state, self.at, self.newton = problem, start, None, 0
        self.visited: list[tuple[float, np.ndarray, np.ndarray, Frames]] = []  # (S, p, q, frames) of each one found
        self.positions, self.position_weights, self.moving, self.moving_rows, self.moving_weights = \
            residual_rows(problem)
        self._linearized = None  # (state, p, factor, B) of the last _linearization

    def _settle(self, p: np.ndarray) -> bool:
        """Continue the equilibrium to p from its first-order prediction (``_predicted``), or from
        the last equilibrium itself where Newton fails from the prediction; whether one was found."""
        start = self._predicted(p)
        state = equilibrium(self.problem, p, max_steps=CONTINUATION_STEPS, start=start)
        self.newton += state.newton.steps
        if not state.converged and start is not self.state:
            state = equilibrium(self.problem, p, max_steps=CONTINUATION_STEPS, start=self.state)
            self.newton += state.newton.steps
        if state.converged:
            self.state, self.at = state, p.copy()
        return state.converged

    def _predicted(self, p: np.ndarray) -> Equilibrium:
        """The last equilibrium moved to its tangent's prediction at p, q_s + K^-1 B (p - p_lin),
        where the last linearization (K, B at p_lin) is at that equilibrium; else the equilibrium
        itself. The Euler predictor of continuation methods: the trust region's trial points are
        each a step from the point it linearized at, and Newton from the prediction took 45% fewer
        steps (80 infeasible strands: the same sags to a geometric mean of 1.001, per strand
        within the trust region's own path dependence; benchmarks/RESULTS.md)."""
        known = self._linearized
        if known is None or known[0] is not self.state:
            return self.state
        state, at, factor, (indptr, indices, data) = known
        q = state.q.copy()
        q[self.problem.free_index] += tangent_step(factor, indptr, indices, data, np.ascontiguousarray(p - at))
        return replace(state, q=q)

    def linearization(self, p: np.ndarray) -> "SagLinearization":
        """The Jacobian at p (``operator``) as solvers.reflective applies it."""
        return SagLinearization(self.operator(p))

    def residuals(self, p: np.ndarray) -> np.ndarray:
        """sqrt(m_i / M) (x_i - x_i*) / L at the equilibrium of p; NaN where none was found (the
        trust region then shrinks)."""
        if not self._settle(p):
            return np.full(3 * self.problem.n_vertices, np.nan)
        residuals = self.position_weights * (self.state.positions - self.problem.strand.points).ravel()
        self.visited.append((0.5 * float(residuals @ residuals), p.copy(), self.state.q, self.state.frames))
        return residuals

    def operator(self, p: np.ndarray) -> tuple:
        """The arguments of ``sag_product`` and ``sag_transposed_product`` before the vector: the
        Jacobian of the residuals at the equilibrium of p, d residuals / dp = W P K^-1 B (W: the
        residuals' weights, P: the position rows, K = d^2E/dq^2 on the free DOFs, B = D dc/dp
        there), applied by one banded Cholesky solve and one sparse product, O(n)."""
        factor, (indptr, indices, data) = self._linearization(p)
        return (factor, indptr, indices, data, self.moving, self.moving_rows, self.moving_weights,
                self.positions.size, p.size)

    def estimated_column_norms(self, p: np.ndarray, probes: int = NORM_PROBES, seed: int = 0) -> np.ndarray:
        """Hutchinson's estimate of the column norms: |J e_j|^2 = E[(J^T v)_j^2] over random signs v
        (3n residual rows), averaged over ``probes`` draws (a fixed ``seed``: the same p gives the
        same scales), each J^T v one band solve: O(n probes) where the exact norms take 3n solves
        (O(n^2)).
        Relative error about sqrt(2 / probes) (25% at 32), enough for variable scales that span
        ~1e7 between the blocks."""
        factor, (indptr, indices, data) = self._linearization(p)
        return estimated_column_norms(factor, indptr, indices, data, self.moving_rows, self.moving_weights,
                                      probe_signs(self.moving.size, probes, seed), p.size)

    def _linearization(self, p: np.ndarray):
        """(Cholesky factor of K, B) at the equilibrium of p (continued there if it is not the last
        one): K the free block of the static Hessian, shifted by the mass metric where E has a
        saddle (as Newton's damping does); B the rows of D dc/dp on the free DOFs as compressed
        rows (indptr, indices, data). Kept for the next call at the same p and equilibrium (the
        column norms, then the steps)."""
        problem = self.problem
        if self.at is None or not np.array_equal(p, self.at):
            self._settle(p)
        state, free = self.state, problem.free_index
        known = self._linearized
        if known is not None and known[0] is state and np.array_equal(known[1], p):
            return known[2], known[3]
        band = problem.free_band(problem.static_hessian_band(p, state.q, state.frames))
        factor = stiffness_factor(band, np.ascontiguousarray(problem.dof_masses[free]))
        jacobian = problem.strand_jacobian(p, state.q, state.frames)
        pattern = jacobian.pattern
        scaled = (pattern.csr_indptr, pattern.csr_indices,
                  scaled_rows(jacobian.data, pattern.csr_indptr, pattern.csr_order, problem.row_scale[free]))
        self._linearized = (state, p.copy(), factor, scaled)
        return factor, scaled


class SagLinearization:
    """The least-sag Jacobian at a point (StaticSag.operator's arguments) as solvers.reflective
    applies it: products, transposed products, the Gauss-Newton direction."""

    def __init__(self, operator: tuple):
        self.operator = operator

    def product(self, v: np.ndarray) -> np.ndarray:
        return sag_product(*self.operator, v)

    def transposed_product(self, u: np.ndarray) -> np.ndarray:
        return sag_transposed_product(*self.operator, u)

    def direction(self, d: np.ndarray, damping: np.ndarray, f: np.ndarray) -> np.ndarray:
        return gauss_newton_direction(*self.operator, d, damping, f)


def least_sag(problem: Problem, p: np.ndarray, max_evaluations: int = MAX_EVALUATIONS) -> LeastSag:
    """The least-sag parameters in the box from ``p`` (module docstring). Where neither p's static
    solve nor p0's converges there is no equilibrium to continue from: p is kept, unminimized (a
    10,000-vertex strand whose static solves each ran out of Newton steps spent minutes more in
    continuations that could not converge). The minimization is one compiled call
    (solvers.least_sag_loop) where the static solves and the stencils' parameter Jacobians are
    compiled, else StaticSag through solvers.reflective (the same steps)."""
    lower, upper = problem.layout.lower, problem.layout.upper
    p = np.clip(problem.check_parameters(p), lower, upper)
    start, naive = equilibrium(problem, p), equilibrium(problem, problem.p0)
    if not (start.converged or naive.converged):
        return LeastSag(p, start, start, naive, 0, 0)
    continued = start if start.converged else naive
    if compiled_least_sag(problem):
        evaluations, newton, visited = _minimized_compiled(problem, continued, p, max_evaluations)
    else:
        model = StaticSag(problem, continued)
        evaluations = reflective_least_squares(model.residuals, model.linearization, model.estimated_column_norms, p,
                                               lower, upper, max_evaluations, RESCALE_EVALUATIONS).evaluations
        newton, visited = model.newton, model.visited
    best, rest = p, start
    for candidate in itertools.islice(_stable_visits(problem, visited), VERIFIED):
        candidate = np.clip(candidate, lower, upper)
        settled = equilibrium(problem, candidate)
        if (settled.converged and (not start.converged or settled.relative_sag < start.relative_sag)
                and problem.stability(candidate, q=settled.q, frames=settled.frames) >= problem.stability_margin):
            best, rest = candidate, settled
            break
    return LeastSag(best, rest, start, naive, evaluations, newton)


def compiled_least_sag(problem: Problem) -> bool:
    """Whether ``least_sag`` minimizes in one compiled call: the static solve compiled
    (Problem.newton_kernels; no friction, whose lagged forces are numpy code), the parameter
    Jacobians' stencils compiled, and a monotonic clock for the timers."""
    return (problem.newton_kernels is not None and problem.state_jacobian_kernels is not None
            and timing.CLOCK is not None and not (problem.friction > 0 and problem.contacts.count))


def _stable_visits(problem: Problem, visited: list):
    """The visited p (``visited``: (S, p, q, frames) per equilibrium found) whose equilibrium has its
    smallest eigenvalue at least the stability margin, least S first. A generator: each stability is
    measured when its turn comes (the first candidate usually holds, so one or two measurements where
    measuring every visit took 8% of the best effort's time)."""
    for _, p, q, frames in sorted(visited, key=lambda visit: visit[0]):
        if problem.stability(p, q=q, frames=frames) >= problem.stability_margin:
            yield p


def probe_signs(count: int, probes: int, seed: int) -> np.ndarray:
    """(count, probes) random signs of Hutchinson's estimator (StaticSag.estimated_column_norms), the
    same for the same arguments."""
    return np.random.default_rng(seed).choice([-1.0, 1.0], size=(count, probes))


def _minimized_compiled(problem: Problem, continued: Equilibrium, p: np.ndarray, max_evaluations: int):
    """(evaluations, Newton steps, visited as StaticSag records them) of StaticSag's minimization
    from p in one compiled call (least_sag_loop), continuing ``continued``."""
    x0, (memory, factor, data, fixed, operator_rows), signs = _loop_arguments(problem, continued, p, max_evaluations)
    evaluations = least_sag_loop(x0, problem.layout.lower, problem.layout.upper, memory, factor, data, fixed,
                                 operator_rows, signs, int(max_evaluations), RESCALE_EVALUATIONS)
    seconds, (costs, ps, qs, tangents, a1, twists), flags = fixed[-1], fixed[5], memory[1]
    timing.add(timing.MODEL, seconds[0])
    timing.add(timing.LINEAR_ALGEBRA, seconds[1])
    visited = [(float(costs[k]), ps[k], qs[k], Frames(tangents[k], a1[k], twists[k])) for k in range(flags[VISITS])]
    return int(evaluations), int(flags[NEWTON]), visited


def residual_rows(problem: Problem) -> tuple:
    """The residuals' rows of S (module docstring): each vertex position's index in q and its weight
    sqrt(m_i / M) / L; the rows whose position is free (a prescribed one has no sensitivity: its
    row of the Jacobian is zero), their DOFs' rows in the free block of K and their weights."""
    weight = np.sqrt(problem.masses / problem.masses.sum()) / problem.strand.length
    positions, weights = dofs.position_index(problem.n_vertices).ravel(), np.repeat(weight, 3)
    row_of = np.full(problem.q_star.size, -1)
    row_of[problem.free_index] = np.arange(problem.free_index.size)
    moving = np.flatnonzero(row_of[positions] >= 0)
    return positions, weights, moving, row_of[positions][moving], weights[moving]


def _loop_arguments(problem: Problem, continued: Equilibrium, p: np.ndarray, max_evaluations: int):
    """(x0, least_sag_loop.model_arguments, the column norms' signs) for a minimization from p
    continuing ``continued``."""
    positions, weights, moving, moving_rows, moving_weights = residual_rows(problem)
    frames = continued.frames
    state = tuple(np.array(a, dtype=float) for a in (continued.q, frames.tangents, frames.a1, frames.reference_twist))
    rows = (np.ascontiguousarray(positions, dtype=np.int64), weights,
            np.ascontiguousarray(problem.strand.points, dtype=float).ravel(), moving,
            np.ascontiguousarray(moving_rows, dtype=np.int64), moving_weights)
    arguments = model_arguments(p, state, problem.newton_kernels, static_solve_constants(problem),
                                problem.state_jacobian_kernels, rows,
                                np.ascontiguousarray(problem.dof_masses[problem.free_index]), RESIDUAL_TOLERANCE,
                                CONTINUATION_STEPS, int(max_evaluations), *timing.CLOCK, np.zeros(2))
    return np.array(p, dtype=float), arguments, probe_signs(moving.size, NORM_PROBES, 0)


def compile_model(problem: Problem) -> None:
    """Compile (or load) the compiled least sag's model kernel alone, on ``problem`` at p0
    (least_sag_loop.prepare_model): priming's first child does, so that its sibling, which compiles
    the loop, loads it. Where the least sag is not compiled for the problem, nothing."""
    if compiled_least_sag(problem):
        continued = equilibrium(problem, problem.p0)
        x0, (memory, factor, data, fixed, _), _ = _loop_arguments(problem, continued, problem.p0, 1)
        prepare_model(x0, memory, factor, data, fixed)
