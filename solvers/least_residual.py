"""The least residual force inside the box: asc's best effort for a strand the box cannot balance.

    minimize 1/2 |c(p)|^2 + eps R(p)    over lower <= p <= upper      (eps = LEAST_RESIDUAL_TIEBREAK)

|c| is the force on each free DOF over its weight, so this is the weighted least-squares force of
the predecessor's objective f^T M^-1 f with the weights of c; eps R breaks the ties among
least-residual points. The method is projected Levenberg-Marquardt from each of the caller's starts
(the point where the augmented Lagrangian stalled and its start: the problem is nonconvex, and
either can be the better basin), keeping the lowest. Each step is a box QP on diag(eps w + 1e-12 +
lambda diag(J^T J)) + J^T J solved by MPRGP with the active-set Cholesky (mprgp.box_qp),
warm-started with the previous step's active bounds (without it each QP started from the free face
and walked the active set back), then an Armijo line search on the objective. Marquardt's lambda
adapts as a trust region's radius would (``_next_damping``): divided by alpha after a step the line
search cut to alpha, so the next step is about as long as the last one that held, and by
DAMPING_FALL after a full step, down to MIN_DAMPING. With lambda fixed at its floor, the long
strands' steps were cut several times each and their QPs walked through active sets that the cut
step never reached: the adaptive lambda took 14% less time on infeasible strands, with the same
static sags (benchmarks/RESULTS.md). A run stops when its
remaining steps, at the rate of its last one, could not bring its objective below (1 -
LEAST_RESIDUAL_GAIN) of itself nor, for the second run, below the first run's: on long strands the
stall point's run reached its value in a step or two and the run from p0 crawled towards a worse
one, each for all of its 100 steps. The QPs stop at a relative projected gradient of max(qp_rtol,
LEAST_RESIDUAL_QP_RTOL): a Levenberg-Marquardt step needs a descent direction, not the QP's optimum,
and the point is only the least sag's start (or the augmented Lagrangian's restart, whose own QPs
are tight): tight QPs multiplied the phase's factorizations several times over for the same sag
(benchmarks/RESULTS.md).

Each run is one compiled call (``least_residual_loop``: c and dc/dp by the at-rest kernels, the Gram
matrix, the QP and the line search with no Python between steps), as asc's Gauss-Newton loop
(solvers.gauss_newton) is; the Python loop (``_run_python``) does the same in the same order and
stays for problems whose stencils are not compiled. The two give the same p bit for bit
(tests/test_least_residual.py).
"""
from __future__ import annotations

import numba
import numpy as np

from sagfree.formulation import at_rest
from sagfree.formulation.parameters import STRAND_BLOCK
from sagfree.formulation.problem import Problem
from sagfree.linalg import timing
from sagfree.linalg.band import column_norms, gram, gram_arrays
from sagfree.linalg.compressed import csc_column_norms, csc_rmatvec

from . import mprgp
from .gauss_newton import ARMIJO, QP_MAX_ITERATIONS, at_rest_residual, regularizer_value
from .mprgp import on_previous_bounds, solve_box_qp

#: weight of R against 1/2 |c|^2: a tie-break among least-residual points
LEAST_RESIDUAL_TIEBREAK = 1e-8
#: relative decrease of the objective a run must still be able to reach to go on
LEAST_RESIDUAL_GAIN = 1e-4
#: loosest relative tolerance of the steps' box QPs
LEAST_RESIDUAL_QP_RTOL = 1e-6
#: Marquardt's damping of the steps (relative to J^T J's diagonal): its floor, and its fall after a
#: full step (``_next_damping``)
MIN_DAMPING = 1e-11
DAMPING_FALL = 4.0
#: halvings of a step's line search before the run ends
HALVINGS = 40
#: solve counters a run advances (solve_alm's counts), in the order of the compiled loop's counts array
COUNTED = ("least_residual", "line_search", "cg", "expansion", "proportioning", "active_set", "interior",
           "factorizations", "factored_rows")
_STEPS, _LINE_SEARCH = 0, 1  # their places in that array
_QP_COUNTS = (mprgp.CG, mprgp.EXPANSION, mprgp.PROPORTIONING, mprgp.ACTIVE_SET, mprgp.INTERIOR,
              mprgp.FACTORIZATIONS, mprgp.FACTORED_ROWS)  # COUNTED[2:] in mprgp's counts layout


def least_residual(problem: Problem, starts: list[np.ndarray], counts: dict, qp_rtol: float = 1e-10,
                   max_steps: int = 100) -> np.ndarray:
    """The lowest of the runs (module docstring) from each of ``starts`` (clipped into the box); their
    steps counted in ``counts`` as ``least_residual``, with their QPs' and line searches' counts."""
    qp_rtol = max(qp_rtol, LEAST_RESIDUAL_QP_RTOL)
    run = _run_compiled if problem.at_rest_kernels is not None and timing.CLOCK is not None else _run_python
    best, lowest = None, np.inf
    for start in starts:
        p, value = run(problem, np.clip(start, problem.layout.lower, problem.layout.upper), counts, qp_rtol,
                       max_steps, lowest)
        if best is None or value < lowest:
            best, lowest = p, value
    return best


def _run_compiled(problem: Problem, p: np.ndarray, counts: dict, qp_rtol: float, max_steps: int,
                  beat: float = np.inf):
    """(p, objective) of one run from p (``least_residual_loop``); its last point's c and dc/dp
    remembered by the problem (the caller evaluates both there)."""
    forces_args, jacobian_args, free, row_scale, structure = problem.at_rest_kernels
    layout = problem.layout
    border = 1 if STRAND_BLOCK in problem.blocks else 0
    totals = np.array([counts[name] for name in COUNTED], dtype=np.int64)
    seconds = np.zeros(2)
    p, value, f, values = least_residual_loop(
        forces_args, jacobian_args, free, row_scale, structure, *timing.CLOCK, layout.weights, layout.p0,
        layout.lower, layout.upper, np.ascontiguousarray(p, dtype=float), float(qp_rtol), int(max_steps),
        float(beat), border, mprgp.PRECONDITIONERS["cholesky"], mprgp.ACTIVE_SET_STEPS if border == 0 else 0,
        mprgp.WALKING, totals, seconds)
    timing.add(timing.MODEL, seconds[0])
    timing.add(timing.LINEAR_ALGEBRA, seconds[1])
    for name, total in zip(COUNTED, totals.tolist()):
        counts[name] = total
    problem.remember_at_rest(p, f, values)
    return p, value


def _run_python(problem: Problem, p: np.ndarray, counts: dict, qp_rtol: float, max_steps: int,
                beat: float = np.inf):
    """``_run_compiled`` in Python, line by line, for problems without compiled stencils."""
    lower, upper = problem.layout.lower, problem.layout.upper
    w, p0 = problem.layout.weights, problem.layout.p0
    border = 1 if STRAND_BLOCK in problem.blocks else 0
    eps = LEAST_RESIDUAL_TIEBREAK

    def objective(x, c):
        return 0.5 * float(c @ c) + eps * problem.objective(x)

    c = problem.residual(p)
    value = objective(p, c)
    at_lower, at_upper = p <= lower, p >= upper
    damping = MIN_DAMPING
    for step in range(max_steps):
        J = problem.strand_jacobian(p)
        gradient = J.T @ c + eps * w * (p - p0)
        hessian = gram(J, eps * w + 1e-12 + damping * column_norms(J), 1.0, border)
        d_lower, d_upper = lower - p, upper - p
        qp = solve_box_qp(hessian, -gradient, d_lower, d_upper, rtol=qp_rtol,
                          x0=on_previous_bounds(at_lower, at_upper, d_lower, d_upper))
        at_lower, at_upper = qp.x <= d_lower, qp.x >= d_upper
        counts["least_residual"] += 1
        for key in COUNTED[2:]:
            counts[key] += getattr(qp, key)
        slope = float(gradient @ qp.x)
        if qp.status not in ("converged", "max_iterations") or not slope < 0:
            break
        alpha = 1.0
        for _ in range(HALVINGS):
            counts["line_search"] += 1
            trial = np.clip(p + alpha * qp.x, lower, upper)
            c_trial = problem.residual(trial)
            trial_value = objective(trial, c_trial)
            if trial_value <= value + ARMIJO * alpha * slope:
                break
            alpha *= 0.5
        else:
            break
        damping = _next_damping(damping, alpha)
        decrease = value - trial_value
        p, c, value = trial, c_trial, trial_value
        if _ends(value, decrease, max_steps - step - 1, beat):
            break
    return p, value


@numba.njit(cache=True)
def _next_damping(damping, alpha):  # pragma: no cover - compiled
    """The next step's damping after one the line search cut to ``alpha``: / DAMPING_FALL (down to
    MIN_DAMPING) after a full step, / alpha after a cut one."""
    return max(damping / DAMPING_FALL, MIN_DAMPING) if alpha == 1.0 else damping / alpha


@numba.njit(cache=True)
def _ends(value, decrease, remaining, beat):  # pragma: no cover - compiled
    """Whether a run stops after a step that lowered its objective to ``value`` by ``decrease``:
    no decrease above rounding, or ``remaining`` more steps at this rate could reach neither
    (1 - LEAST_RESIDUAL_GAIN) of value nor ``beat``."""
    reachable = value - remaining * decrease
    return decrease <= 1e-12 * value or reachable > min(beat, (1.0 - LEAST_RESIDUAL_GAIN) * value)


@numba.njit(cache=True)
def _objective(w, p, p0, c, work):  # pragma: no cover - compiled
    """1/2 |c|^2 + eps R(p), as _run_python sums it (R: regularizer_value, Problem.objective's sum)."""
    return 0.5 * np.dot(c, c) + LEAST_RESIDUAL_TIEBREAK * regularizer_value(w, p, p0, work)


@numba.njit(cache=True)
def least_residual_loop(forces_args, jacobian_args, free, row_scale, structure, clock, clock_id, w, p0, lower, upper,
                        p, qp_rtol, max_steps, beat, border, precond, active_set_steps, walking, counts,
                        seconds):  # pragma: no cover - compiled
    """One run of ``least_residual`` from p (_run_python line by line): counts in COUNTED order,
    seconds [model, linear algebra] accumulated. Returns (p, objective, f(q*, p), dc/dp's CSC
    values at p)."""
    csc_indptr, csc_indices, csr_indptr, csr_indices, csr_order = structure
    n = p.size
    buffer = np.zeros(2, dtype=np.int64)
    work = np.empty(n)
    qp_counts = np.zeros(8, dtype=np.int64)
    started = timing.clock_seconds(clock, clock_id, buffer)
    c, f = at_rest_residual(p, forces_args, free, row_scale)
    values = at_rest.jacobian_values(p, *jacobian_args)
    seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - started
    value = _objective(w, p, p0, c, work)
    at_lower, at_upper = np.empty(n, dtype=np.bool_), np.empty(n, dtype=np.bool_)
    for j in range(n):
        at_lower[j], at_upper[j] = p[j] <= lower[j], p[j] >= upper[j]
    damping = MIN_DAMPING
    for step in range(max_steps):
        started = timing.clock_seconds(clock, clock_id, buffer)
        pulled = csc_rmatvec(csc_indptr, csc_indices, values, c)
        norms = csc_column_norms(csc_indptr, values)
        gradient, negative, diagonal = np.empty(n), np.empty(n), np.empty(n)
        d_lower, d_upper, start_step = np.empty(n), np.empty(n), np.empty(n)
        for j in range(n):
            gradient[j] = pulled[j] + LEAST_RESIDUAL_TIEBREAK * w[j] * (p[j] - p0[j])
            negative[j] = -gradient[j]
            diagonal[j] = LEAST_RESIDUAL_TIEBREAK * w[j] + 1e-12 + damping * norms[j]
            d_lower[j], d_upper[j] = lower[j] - p[j], upper[j] - p[j]
            start_step[j] = d_lower[j] if at_lower[j] else (d_upper[j] if at_upper[j] else 0.0)
        band, band_border, corner = gram_arrays(csr_indptr, csr_indices, values[csr_order], diagonal, 1.0, border)
        qp_counts[:] = 0
        x, qp_status, _ = mprgp.box_qp(band, band_border, corner, negative, d_lower, d_upper, start_step, qp_rtol,
                                       0.0, np.int64(QP_MAX_ITERATIONS), precond, 1.0, active_set_steps, walking,
                                       qp_counts)
        seconds[1] += timing.clock_seconds(clock, clock_id, buffer) - started
        for j in range(n):
            at_lower[j], at_upper[j] = x[j] <= d_lower[j], x[j] >= d_upper[j]
        counts[_STEPS] += 1
        for k in range(len(_QP_COUNTS)):
            counts[_LINE_SEARCH + 1 + k] += qp_counts[_QP_COUNTS[k]]
        slope = np.dot(gradient, x)
        if (qp_status != 0 and qp_status != 1) or not slope < 0:
            break
        alpha, accepted = 1.0, False
        trial, c_trial, f_trial, trial_value = np.empty(n), np.empty(0), np.empty(0), 0.0
        for _ in range(HALVINGS):
            counts[_LINE_SEARCH] += 1
            for j in range(n):
                trial[j] = min(max(p[j] + alpha * x[j], lower[j]), upper[j])
            started = timing.clock_seconds(clock, clock_id, buffer)
            c_trial, f_trial = at_rest_residual(trial, forces_args, free, row_scale)
            seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - started
            trial_value = _objective(w, trial, p0, c_trial, work)
            if trial_value <= value + ARMIJO * alpha * slope:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            break
        damping = _next_damping(damping, alpha)
        decrease = value - trial_value
        p, c, f, value = trial, c_trial, f_trial, trial_value
        started = timing.clock_seconds(clock, clock_id, buffer)
        values = at_rest.jacobian_values(p, *jacobian_args)
        seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - started
        if _ends(value, decrease, max_steps - step - 1, beat):
            break
    return p, value, f, values
