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
band triangular solves and one sparse product, O(n) (``sag_product``): formed, it and its
products grow like n^2 (at 2000 vertices ~2 GB with its intermediates).

The steps: trust-region reflective least squares (solvers.reflective: scipy's least_squares
method "trf", ported, which keeps every iterate strictly inside the box), its Gauss-Newton
direction by CG_ITERATIONS of conjugate gradients at most, compiled with the products
(``gauss_newton_direction``; scipy's LSMR ran the same iterations in Python, a Python call per
product: benchmarks/RESULTS.md, 2026-12-05).
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
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numba
import numpy as np

from sagfree.formulation import dofs
from sagfree.formulation.problem import Problem
from sagfree.formulation.simulation import Equilibrium, equilibrium
from sagfree.linalg.cholesky import band_cholesky, band_solve_many, plain_solve
from sagfree.linalg.compressed import csc_matvec, csc_rmatvec
from sagfree.linalg.timing import LINEAR_ALGEBRA, timed

from .reflective import reflective_least_squares

#: Model evaluations (static solves) the minimization may take: enough for the large early gains,
#: bounded so that a groom of long hair costs seconds per strand.
MAX_EVALUATIONS = 60
#: Candidates (visited stable points, least S first) confirmed by a static solve from q*.
VERIFIED = 3
#: Newton steps of a continued static solve before the step counts as too long.
CONTINUATION_STEPS = 100
#: Conjugate-gradient iterations of a step's Gauss-Newton direction (``gauss_newton_direction``),
#: and the relative normal-equations residual that stops them sooner: the step only needs a
#: direction better than the gradient's, and uncapped the iterations grow with the strand.
CG_ITERATIONS = 30
CG_TOLERANCE = 1e-6
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
        self.visited: list[tuple[float, np.ndarray, Equilibrium]] = []  # (S, p, equilibrium) of each equilibrium found
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
        q[self.problem.free_index] += _tangent_step(factor, indptr, indices, data, np.ascontiguousarray(p - at))
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
        self.visited.append((0.5 * float(residuals @ residuals), p.copy(), self.state))
        return residuals

    def stable_visits(self):
        """The visited p whose equilibrium has its smallest eigenvalue at least the stability margin,
        least S first. A generator: each stability is measured when its turn comes (the first
        candidate usually holds, so one or two measurements where measuring every visit took 8% of
        the best effort's time)."""
        problem = self.problem
        for _, p, state in sorted(self.visited, key=lambda visit: visit[0]):
            if problem.stability(p, q=state.q, frames=state.frames) >= problem.stability_margin:
                yield p

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
        signs = np.random.default_rng(seed).choice([-1.0, 1.0], size=(self.moving.size, probes))
        solved = band_solve_many(factor, self._pulled(signs))  # (free DOFs, probes)
        products = _rows_transposed_times(indptr, indices, data, solved, p.size)  # (parameters, probes): J^T v
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
        factor, shift = band_cholesky(band), 0.0
        masses = problem.dof_masses[free]
        while factor is None:
            shift = max(4.0 * shift, 1.0)
            shifted = band.copy()
            shifted[0] += shift * masses
            factor = band_cholesky(shifted)
        indptr, indices, data = problem.strand_jacobian(p, state.q, state.frames).csr()
        scaled = (indptr, indices, data * np.repeat(problem.row_scale[free], np.diff(indptr)))
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


def compile_kernels() -> None:
    """Compile (or load from numba's cache) the least sag's kernels on a two-row system, with the
    argument types of a strand's: only a strand the boxes cannot balance runs them, and
    frontend.warm calls this before any timed solve."""
    indptr, indices, data, rows = np.array([0, 1, 2]), np.array([0, 1]), np.ones(2), np.arange(2)
    operator = (np.ones((2, 2)), indptr, indices, data, rows, rows, np.ones(2), 2, 2)
    sag_transposed_product(*operator, sag_product(*operator, np.ones(2)))
    gauss_newton_direction(*operator, np.ones(2), np.ones(2), np.ones(2))
    _rows_transposed_times(indptr, indices, data, np.ones((2, 1)), 2)
    _tangent_step(operator[0], indptr, indices, data, np.ones(2))


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
    evaluations = reflective_least_squares(model.residuals, model.linearization, model.estimated_column_norms, p,
                                           lower, upper, max_evaluations, RESCALE_EVALUATIONS).evaluations
    best, rest = p, start
    for candidate in itertools.islice(model.stable_visits(), VERIFIED):
        candidate = np.clip(candidate, lower, upper)
        settled = equilibrium(problem, candidate)
        if (settled.converged and (not start.converged or settled.relative_sag < start.relative_sag)
                and problem.stability(candidate, q=settled.q, frames=settled.frames) >= problem.stability_margin):
            best, rest = candidate, settled
            break
    return LeastSag(best, rest, start, naive, evaluations, model.newton)


@timed(LINEAR_ALGEBRA)
def sag_product(factor, indptr, indices, data, moving, rows, weights, size, columns, v) -> np.ndarray:
    """J v for the least-sag Jacobian J = W P K^-1 B (the arguments of StaticSag.operator): one band
    solve and one sparse product."""
    return _product(factor, indptr, indices, data, moving, rows, weights, size, np.ascontiguousarray(v, dtype=float))


@timed(LINEAR_ALGEBRA)
def sag_transposed_product(factor, indptr, indices, data, moving, rows, weights, size, columns, u) -> np.ndarray:
    """J^T u for the least-sag Jacobian (``sag_product``)."""
    return _transposed_product(factor, indptr, indices, data, moving, rows, weights, columns,
                               np.ascontiguousarray(u, dtype=float))


@numba.njit(cache=True)
def _product(factor, indptr, indices, data, moving, rows, weights, size, v):  # pragma: no cover - compiled
    """J v (sag_product): the moving rows of K^-1 B v (``_tangent_step``), weighted."""
    solved = _tangent_step(factor, indptr, indices, data, v)
    out = np.zeros(size)
    for i in range(moving.size):
        out[moving[i]] = weights[i] * solved[rows[i]]
    return out


@numba.njit(cache=True)
def _transposed_product(factor, indptr, indices, data, moving, rows, weights, columns, u):  # pragma: no cover
    """J^T u (sag_transposed_product): B^T K^-1 P^T W u."""
    pulled = np.zeros(factor.shape[0])
    for i in range(moving.size):
        pulled[rows[i]] = weights[i] * u[moving[i]]
    solved = np.empty(factor.shape[0])
    plain_solve(factor, pulled, solved)
    return csc_matvec(indptr, indices, data, solved, columns)  # B^T: the rows as csc columns of B^T


@timed(LINEAR_ALGEBRA)
def gauss_newton_direction(factor, indptr, indices, data, moving, rows, weights, size, columns, d, damping,
                           f) -> np.ndarray:
    """An approximate minimizer of |J diag(d) p + f|^2 + |damping^(1/2) p|^2 for the least-sag
    Jacobian J (``sag_product``): CG_ITERATIONS of conjugate gradients on its normal equations at
    most (``_cgls``), the trust region's Gauss-Newton direction (solvers.reflective)."""
    return _cgls(factor, indptr, indices, data, moving, rows, weights, size, columns, d, np.sqrt(damping), f,
                 CG_ITERATIONS, CG_TOLERANCE)


@numba.njit(cache=True)
def _cgls(factor, indptr, indices, data, moving, rows, weights, size, columns, d, root, f, iterations,
          tolerance):  # pragma: no cover - compiled
    """CGLS (conjugate gradients on A^T A p = A^T b without forming A^T A; Hestenes & Stiefel 1952)
    for min |A p - b|, A = [J diag(d); diag(root)], b = [-f; 0], from p = 0: at most ``iterations``,
    stopped where |A^T r| falls below ``tolerance`` of its start."""
    n = d.size
    p, direction, top_step = np.zeros(n), np.empty(n), np.empty(n)
    top, bottom = -f.copy(), np.zeros(n)
    pulled = _transposed_product(factor, indptr, indices, data, moving, rows, weights, columns, top)
    gradient = np.empty(n)
    for j in range(n):
        gradient[j] = d[j] * pulled[j]
        direction[j] = gradient[j]
    gamma = np.dot(gradient, gradient)
    stop = tolerance * tolerance * gamma
    for _ in range(iterations):
        if not gamma > stop:
            break
        for j in range(n):
            top_step[j] = d[j] * direction[j]
        image = _product(factor, indptr, indices, data, moving, rows, weights, size, top_step)
        curvature = np.dot(image, image)
        for j in range(n):
            curvature += (root[j] * direction[j]) ** 2
        if not curvature > 0:
            break
        alpha = gamma / curvature
        for j in range(n):
            p[j] += alpha * direction[j]
            bottom[j] -= alpha * root[j] * direction[j]
        for i in range(top.size):
            top[i] -= alpha * image[i]
        pulled = _transposed_product(factor, indptr, indices, data, moving, rows, weights, columns, top)
        for j in range(n):
            gradient[j] = d[j] * pulled[j] + root[j] * bottom[j]
        previous, gamma = gamma, np.dot(gradient, gradient)
        for j in range(n):
            direction[j] = gradient[j] + gamma / previous * direction[j]
    return p


@numba.njit(cache=True)
def _tangent_step(factor, indptr, indices, data, dp):  # pragma: no cover - compiled
    """dq_s = K^-1 B dp on the free DOFs (StaticSag._predicted, and _product's before it picks the
    residuals' rows): B in compressed rows (B dp: the rows as csc columns of B^T), K by its
    Cholesky factor."""
    solved = np.empty(factor.shape[0])
    plain_solve(factor, csc_rmatvec(indptr, indices, data, dp), solved)
    return solved


@numba.njit(cache=True)
def _rows_transposed_times(indptr, indices, data, x, columns):  # pragma: no cover - compiled
    """B^T X for B in compressed rows and X (rows of B x k)."""
    k = x.shape[1]
    out = np.zeros((columns, k))
    for r in range(indptr.size - 1):
        for t in range(indptr[r], indptr[r + 1]):
            j, entry = indices[t], data[t]
            for c in range(k):
                out[j, c] += entry * x[r, c]
    return out
