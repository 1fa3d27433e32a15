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
Jacobian. scipy's trust-region reflective least squares (``least_squares``, method "trf", which
keeps every iterate inside the box; LSMR for its subproblems, capped at LSMR_ITERATIONS, where the
exact solver's dense SVD grows like the cube of the size) takes the steps. The Jacobian (3n x
parameters) is never formed but applied as an operator, each product with it or its transpose one
pair of band triangular solves, O(n) (``StaticSag.jacobian``): formed, it and its products grow
like n^2 (at 2000 vertices ~2 GB with its intermediates). The steps are taken in the variables'
scales of its column norms, which change by orders of magnitude as the multipliers reach their
bounds; scipy renews scales ("jac") only from a matrix, so the minimization runs in rounds of
RESCALE_EVALUATIONS evaluations, each in the column norms where it starts, estimated from
NORM_PROBES random products (``StaticSag.estimated_column_norms``, Hutchinson's estimator, O(n)).
(With the norms of the start alone the sag stayed twice as large above 400 vertices; the dense
matrix with scipy's own scales sagged about as little, at n^2 cost: benchmarks/RESULTS.md.)
Each evaluation continues the equilibrium from the previous one (``equilibrium(start=...)``), so p
moves along one branch of equilibria; where the continuation fails (CONTINUATION_STEPS Newton
steps), the step was too long for it and the trust region shrinks. (A restart from q* follows the whole fall: ~7 times the
Newton steps at 100 vertices.)

S weighs the whole strand, not only the vertex that moves most: smooth, and a Gauss-Newton problem;
the reported sag (the largest displacement) falls with it (benchmarks/RESULTS.md). The start is the
solver's own best effort (alm: the least residual force at q*, restiffened to the largest
stiffness). The least sag lies where the box runs out, often next to a fold of the equilibria
where the resting state turns soft, so the answer must rest STABLY: it is the visited point of
least S whose equilibrium has its smallest mass-normalized eigenvalue at least
``Problem.stability_margin``, confirmed by the equilibrium from q* (the one ``equilibrium`` finds
and every report measures: stable, and sagging less than the start); VERIFIED candidates are tried
in order of S, else the start stays.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator

from sagfree.formulation import dofs
from sagfree.formulation.problem import Problem
from sagfree.formulation.simulation import Equilibrium, equilibrium
from sagfree.linalg.cholesky import band_cholesky, band_solve, band_solve_many

#: Model evaluations (static solves) the minimization may take: enough for the large early gains,
#: bounded so that a groom of long hair costs seconds per strand.
MAX_EVALUATIONS = 60
#: Candidates (visited stable points, least S first) confirmed by a static solve from q*.
VERIFIED = 3
#: Newton steps of a continued static solve before the step counts as too long.
CONTINUATION_STEPS = 100
#: LSMR iterations per trust-region step (scipy's default, min(3n, parameters), grows with the
#: strand, and made LSMR half of a 400-vertex strand's time; the step only needs a direction better
#: than the gradient's: capped, the sag was the same or less on the strands measured).
LSMR_ITERATIONS = 30
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
    """S(p) of the module docstring as scipy least-squares residuals, continuing the equilibrium."""

    def __init__(self, problem: Problem, start: Equilibrium):
        self.problem, self.state, self.at, self.newton = problem, start, None, 0
        self.visited: list[tuple[float, np.ndarray]] = []  # (S, p) of each stable equilibrium found
        weight = np.sqrt(problem.masses / problem.masses.sum()) / problem.strand.length
        # the residuals' rows: each vertex position's index in q and its weight
        self.positions, self.position_weights = dofs.position_index(problem.n_vertices).ravel(), np.repeat(weight, 3)
        # the rows whose position is free (a prescribed one has no sensitivity: its row of the
        # Jacobian is zero) and their DOFs' rows in the free block of K
        row_of = np.full(problem.q_star.size, -1)
        row_of[problem.free_index] = np.arange(problem.free_index.size)
        self.moving = np.flatnonzero(row_of[self.positions] >= 0)
        self.moving_rows, self.moving_weights = row_of[self.positions][self.moving], self.position_weights[self.moving]
        self._linearized = None  # (state, p, factor, B) of the last _linearization

    def _settle(self, p: np.ndarray) -> bool:
        """Continue the equilibrium to p; whether one was found."""
        state = equilibrium(self.problem, p, max_steps=CONTINUATION_STEPS, start=self.state)
        self.newton += state.newton.steps
        if state.converged:
            self.state, self.at = state, p.copy()
        return state.converged

    def residuals(self, p: np.ndarray) -> np.ndarray:
        """sqrt(m_i / M) (x_i - x_i*) / L at the equilibrium of p; NaN where none was found (the
        trust region then shrinks)."""
        if not self._settle(p):
            return np.full(3 * self.problem.n_vertices, np.nan)
        residuals = self.position_weights * (self.state.positions - self.problem.strand.points).ravel()
        problem, state = self.problem, self.state
        if problem.stability(p, q=state.q, frames=state.frames) >= problem.stability_margin:
            self.visited.append((0.5 * float(residuals @ residuals), p.copy()))
        return residuals

    def jacobian(self, p: np.ndarray) -> LinearOperator:
        """d residuals / dp = W P K^-1 B at the equilibrium of p (W: the residuals' weights, P: the
        position rows, K = d^2E/dq^2 on the free DOFs, B = D dc/dp there) as an operator: a product
        with it or its transpose is one banded Cholesky solve and one sparse product, O(n)."""
        factor, scaled = self._linearization(p)
        moving, rows, weight = self.moving, self.moving_rows, self.moving_weights
        transposed = scaled.T.tocsr()

        def product(v):
            out = np.zeros(self.positions.size)
            out[moving] = weight * band_solve(factor, scaled @ np.ravel(v))[rows]
            return out

        def transposed_product(u):
            return transposed @ band_solve(factor, self._pulled(np.ravel(u)[moving]))

        return LinearOperator((self.positions.size, p.size), matvec=product, rmatvec=transposed_product,
                              dtype=float)

    def estimated_column_norms(self, p: np.ndarray, probes: int = NORM_PROBES, seed: int = 0) -> np.ndarray:
        """Hutchinson's estimate of the column norms: |J e_j|^2 = E[(J^T v)_j^2] over random signs v
        (3n residual rows), averaged over ``probes`` draws (a fixed ``seed``: the same p gives the
        same scales), each J^T v one band solve: O(n probes) where the exact norms take 3n solves
        (O(n^2)).
        Relative error about sqrt(2 / probes) (25% at 32), enough for variable scales that span
        ~1e7 between the blocks."""
        factor, scaled = self._linearization(p)
        signs = np.random.default_rng(seed).choice([-1.0, 1.0], size=(self.moving.size, probes))
        products = scaled.T @ band_solve_many(factor, self._pulled(signs))  # (parameters, probes): J^T v
        return np.sqrt(np.einsum("jk,jk->j", products, products) / probes)

    def _pulled(self, values: np.ndarray) -> np.ndarray:
        """(P^T W) values on the free DOFs: the moving residual rows' ``values`` (one row each, any
        columns) weighted and placed at their DOFs' rows of K, zero elsewhere."""
        pulled = np.zeros((self.problem.free_index.size,) + values.shape[1:])
        pulled[self.moving_rows] = self.moving_weights.reshape((-1,) + (1,) * (values.ndim - 1)) * values
        return pulled

    def _linearization(self, p: np.ndarray):
        """(Cholesky factor of K, B) at the equilibrium of p (continued there if it is not the last
        one): K the free block of the static Hessian, shifted by the mass metric where E has a
        saddle (as Newton's damping does); B the rows of D dc/dp on the free DOFs (CSR). Kept for
        the next call at the same p and equilibrium (the column norms, then the first Jacobian)."""
        problem = self.problem
        if self.at is None or not np.array_equal(p, self.at):
            self._settle(p)
        state, free = self.state, problem.free_index
        known = self._linearized
        if known is not None and known[0] is state and np.array_equal(known[1], p):
            return known[2], known[3]
        band = problem.free_band(problem.static_hessian_band(p, state.q, state.frames))
        factor, shift = band_cholesky(band), 0.0
        masses = problem.dof_masses[free]
        while factor is None:
            shift = max(4.0 * shift, 1.0)
            shifted = band.copy()
            shifted[0] += shift * masses
            factor = band_cholesky(shifted)
        jacobian = problem.strand_jacobian(p, state.q, state.frames).tocsc()
        scaled = (sp.diags(problem.row_scale[free]) @ jacobian).tocsr()
        self._linearized = (state, p.copy(), factor, scaled)
        return factor, scaled


def least_sag(problem: Problem, p: np.ndarray, max_evaluations: int = MAX_EVALUATIONS) -> LeastSag:
    """The least-sag parameters in the box from ``p`` (module docstring). Where neither p's static
    solve nor p0's converges there is no equilibrium to continue from: p is kept, unminimized (a
    10,000-vertex strand whose static solves each ran out of Newton steps spent minutes more in
    continuations that could not converge)."""
    lower, upper = problem.layout.lower, problem.layout.upper
    p = np.clip(problem.check_parameters(p), lower, upper)
    start, naive = equilibrium(problem, p), equilibrium(problem, problem.p0)
    if not (start.converged or naive.converged):
        return LeastSag(p, start, start, naive, 0, 0)
    model = StaticSag(problem, start if start.converged else naive)
    evaluations, x = 0, p
    while evaluations < max_evaluations:  # runs of RESCALE_EVALUATIONS, each in the column norms where it starts
        norms = model.estimated_column_norms(x)
        try:
            run = scipy.optimize.least_squares(
                model.residuals, x, jac=model.jacobian, bounds=(lower, upper), method="trf",
                x_scale=1.0 / np.where(norms > 0, norms, 1.0), tr_solver="lsmr",
                tr_options={"maxiter": LSMR_ITERATIONS}, max_nfev=min(RESCALE_EVALUATIONS, max_evaluations - evaluations))
        except ValueError:  # no equilibrium found at the start itself ("residuals are not finite")
            evaluations += 1
            break
        evaluations += int(run.nfev)
        if np.array_equal(run.x, x):
            break  # no step taken: a rescaling would not move it
        x = run.x
    best, rest = p, start
    for _, candidate in sorted(model.visited, key=lambda visit: visit[0])[:VERIFIED]:
        candidate = np.clip(candidate, lower, upper)
        settled = equilibrium(problem, candidate)
        if (settled.converged and (not start.converged or settled.relative_sag < start.relative_sag)
                and problem.stability(candidate, q=settled.q, frames=settled.frames) >= problem.stability_margin):
            best, rest = candidate, settled
            break
    return LeastSag(best, rest, start, naive, evaluations, model.newton)
