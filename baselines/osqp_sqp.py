"""The `osqp` baseline: SQP whose QP subproblems are solved by the OSQP package (DESIGN section 6).

At p_k, with c = c(p_k), J = dc/dp(p_k) and g = grad R(p_k) = w (p_k - p0), the step d solves

    minimize 1/2 d^T diag(w) d + g^T d   s.t.   J d = -c,   lower - p_k <= d <= upper - p_k,

the regularizer's Hessian with the linearized constraints as equality rows and the box as bound rows
of OSQP's  l <= A d <= u  (see _subproblem for the scaling and the elastic form used when this QP is
infeasible). R is quadratic, so diag(w) is R's exact Hessian; the constraint curvature is left out,
which keeps every QP strictly convex (the Lagrangian's Hessian is indefinite in element mode).
OSQP's polishing (an exact solve on the active set ADMM found) takes each subproblem beyond ADMM's
accuracy, which the 1e-8 target needs. A backtracking line search on the l1 merit function
R(p) / mean(w) + nu |c(p)|_1, nu ten times the largest multiplier seen (at least 1e3), sets the step
length (the objective scaled to O(1) per element, _objective_scale).
Stops like ours: |c|_inf <= tol and the KKT distance (contract.optimality) <= kkt_tol.

What to expect (measured on the reference scenes, see tests/test_baselines.py and
benchmarks/bench_baselines.py): the QPs have condition numbers of ~1e4 after scaling and ADMM needs
1e4 to 1e5 iterations per QP; where polishing keeps succeeding the SQP converges to the optimum of
ours and Ipopt in 5-30 iterations (all four single reference strands), elsewhere the line search
stalls (3 of 5 100-vertex groom strands) and the Result says so.
Iterations: ``sqp`` steps, ``admm`` (total ADMM iterations over all subproblems), ``line_search``
trials, ``elastic`` subproblems and ``polish_failures`` (subproblems whose polishing still failed
after the two tightenings).
"""
from __future__ import annotations

import importlib
import time

import numpy as np
import scipy.sparse as sp

from sagfree.contract.feasibility import judged_tolerance, raised_note
from sagfree.contract.optimality import KKT_TOL, TOL, gradient_scale, kkt_optimality
from sagfree.contract.result import Result, make_result
from sagfree.formulation.problem import Problem
from sagfree.linalg.timing import LINEAR_ALGEBRA, timed

ARMIJO = 1e-4
#: OSQP settings: no OSQP scaling (the step is scaled by S already; OSQP's Ruiz scaling on top of it
#: left ADMM at max_iter on these QPs), a small initial rho, and polishing with a small
#: regularization delta and more refinement, which the QPs' ~1e4 condition number needs. rho adapts
#: every 200 ADMM iterations: OSQP's default interval follows a wall-time heuristic, which made the
#: SQP's outcome change from run to run (`wavy` converged in one run, stalled in the next); of the
#: fixed intervals 25 / 50 / 100 / 200, 200 converged on the most reference scenes, fastest.
OSQP_SETTINGS = dict(verbose=False, scaling=0, rho=1e-4, polishing=True, delta=1e-10,
                     polish_refine_iter=30, warm_starting=True, adaptive_rho_interval=200)
PENALTY = 1e3  # initial l1 penalty nu (c is unit-free, R is O(1) to O(100))


def available() -> bool:
    """True where osqp imports (an optional dependency: the baseline is then left out of the table)."""
    try:
        importlib.import_module("osqp")
    except ImportError:
        return False
    return True


def _objective_scale(problem: Problem) -> float:
    """1 / mean weight: the regularizer in the units where its Hessian is O(1) per element. R weighs
    each element by its share of the strand (~1/n); OSQP's absolute tolerances and the penalty nu
    assume an O(1) objective, and unscaled the SQP stalled at |c|_inf ~1e-8 on groom strands."""
    return 1.0 / float(np.mean(problem.layout.weights))


def _merit(problem: Problem, p, c, nu) -> float:
    return _objective_scale(problem) * problem.objective(p) + nu * float(np.abs(c).sum())


@timed(LINEAR_ALGEBRA)
def _subproblem(form: str, problem: Problem, J: sp.csc_matrix, c, gradient, d_lower, d_upper, nu,
                settings: dict, warm_multipliers):
    """Solve one SQP subproblem with OSQP: (OSQP result, ADMM iterations, step d, equality
    multipliers, |s|_1); d and the multipliers are None if OSQP returned no finite point.

    In the scaled step y = d / S, S = diag(h)^-1/2 with h = w + ||J_{:,j}||^2 at the current p (kkt
    module), which takes the ~1e7 spread of J's column norms out of OSQP's ADMM:

    hard:     minimize 1/2 y^T (S W S) y + (S g)^T y   s.t.  J S y = -c,  (lower - p)/S <= y <= (upper - p)/S;
    elastic:  the same with a slack s in  J S y - s = -c  at the cost nu/2 |s|^2, used when the hard QP
              is infeasible (at p0 the stiffness multipliers do not enter J, and the rest-shape boxes
              alone may not reach c = 0 to first order). A quadratic cost rather than the l1 cost of
              S-l1-QP: with a linear cost the slacks have no curvature and ADMM did not converge.

    The scaling changes with p (a stiffness column of J is zero at p0), so OSQP is set up for each
    subproblem, warm-started from d = 0 and the previous subproblem's equality multipliers
    (``warm_multipliers``). When polishing fails (ADMM's active set was not yet right), ADMM
    continues from where it stopped (warm start) with a 100 times tighter tolerance and polishes
    again, twice at most: a step from an unpolished ADMM point is too inaccurate for the line search
    near the solution."""
    import osqp

    m, n = J.shape
    w = _objective_scale(problem) * problem.layout.weights
    scale = 1.0 / np.sqrt(gradient_scale(w, J))
    slacks = m if form == "elastic" else 0
    blocks = [J @ sp.diags(scale), -sp.identity(m)] if slacks else [J @ sp.diags(scale)]
    box = [sp.identity(n), sp.csc_matrix((n, m))] if slacks else [sp.identity(n)]
    A = sp.vstack([sp.hstack(blocks), sp.hstack(box)], format="csc")
    weights = np.concatenate([w * scale**2 + 1e-12, np.full(slacks, nu)])
    solver = osqp.OSQP()
    solver.setup(sp.diags(weights, format="csc"), np.concatenate([gradient * scale, np.zeros(slacks)]),
                 A, np.concatenate([-c, d_lower / scale]), np.concatenate([-c, d_upper / scale]),
                 **settings)
    if warm_multipliers is not None:
        solver.warm_start(x=np.zeros(n + slacks), y=np.concatenate([warm_multipliers, np.zeros(n)]))
    solution = solver.solve(raise_error=False)  # statuses are handled here
    iterations = solution.info.iter
    for _ in range(2):  # polishing failed: tighten ADMM (warm-started where it stopped) and polish again
        if solution.info.status_polish == 1 or solution.x is None or not np.all(np.isfinite(solution.x)):
            break
        solver.update_settings(eps_abs=solver.settings.eps_abs * 1e-2, eps_rel=solver.settings.eps_rel * 1e-2)
        solver.warm_start(x=solution.x, y=solution.y)
        solution = solver.solve(raise_error=False)  # statuses are handled here
        iterations += solution.info.iter
    if solution.x is None or not np.all(np.isfinite(solution.x)):
        return solution, iterations, None, None, np.inf
    x = np.asarray(solution.x)
    return solution, iterations, x[:n] * scale, np.asarray(solution.y)[:m], float(np.abs(x[n:]).sum())


def solve_osqp(problem: Problem, tol: float = TOL, kkt_tol: float = KKT_TOL, max_iterations: int = 50,
               max_seconds: float = 60.0, p_start=None, eps: float = 1e-5, max_admm: int = 50_000) -> Result:
    """Solve ``problem`` by SQP with OSQP subproblems from p0 (or ``p_start``, clipped into the box);
    see the module docstring.

    Common options (contract.options): max_iterations counts SQP iterations; max_seconds is the
    wall-time budget of the whole SQP (checked between iterations: a stalled SQP on a 50-vertex strand
    otherwise spends minutes in ADMM).
    osqp's own: eps: OSQP's absolute and relative tolerance; polishing then refines the ADMM point on
    its active set, so the steps are far more accurate than eps whenever polishing succeeds.
    max_admm: ADMM iterations per OSQP solve."""
    clock = time.perf_counter()
    lower, upper = problem.layout.lower, problem.layout.upper
    p = problem.p0 if p_start is None else np.clip(np.asarray(p_start, dtype=float), lower, upper)
    c, J = problem.residual(p), problem.jacobian(p)
    settings = dict(OSQP_SETTINGS, eps_abs=eps, eps_rel=eps, max_iter=max_admm)
    counts = dict(sqp=0, admm=0, line_search=0, elastic=0, polish_failures=0)
    history = [float(np.abs(c).max(initial=0.0))]
    nu = PENALTY
    warm = None  # the previous subproblem's equality multipliers

    def finish(status, message):
        return make_result(problem, p, "osqp", status, message, counts, time.perf_counter() - clock,
                           history)

    while True:
        violation = history[-1]
        held = judged_tolerance(problem, p, violation, tol)
        optimality = kkt_optimality(problem, p) if violation <= held else np.inf
        if violation <= held and optimality <= kkt_tol:
            return finish("converged", f"|c|_inf = {violation:.2e} <= {held:g} and KKT distance "
                          f"{optimality:.2e} <= {kkt_tol:g} after {counts['sqp']} SQP iterations"
                          + raised_note(tol, held))
        elapsed = time.perf_counter() - clock
        if counts["sqp"] >= max_iterations or elapsed >= max_seconds:
            limit = (f"{max_iterations} SQP iterations" if counts["sqp"] >= max_iterations
                     else f"{elapsed:.0f} s (max_seconds)")
            return finish("max_iterations", f"stopped after {limit} with "
                          f"|c|_inf = {violation:.3g} and KKT distance {optimality:.3g}; the OSQP "
                          f"subproblems reached their tolerance in {counts['sqp'] - counts['polish_failures']} "
                          "of them (polished)")
        counts["sqp"] += 1
        gradient = _objective_scale(problem) * problem.objective_gradient(p)
        for form in ("hard", "elastic"):
            solution, iterations, d, multipliers, slack = _subproblem(form, problem, J, c, gradient, lower - p,
                                                                      upper - p, nu, settings, warm)
            counts["admm"] += int(iterations)
            counts["elastic"] += form == "elastic"
            if d is not None and "infeasible" not in solution.info.status:
                break
        counts["polish_failures"] += int(solution.info.status_polish != 1)
        warm = multipliers
        if d is None:
            return finish("failed", f"OSQP subproblem {counts['sqp']}: {solution.info.status}")
        # directional derivative of the l1 merit along d, as the QP's linearization predicts it
        slope = float(gradient @ d) - nu * (float(np.abs(c).sum()) - slack)
        merit = _merit(problem, p, c, nu)
        alpha, accepted = 1.0, False
        for _ in range(40):
            counts["line_search"] += 1
            trial = np.clip(p + alpha * d, lower, upper)
            c_trial = problem.residual(trial)
            if _merit(problem, trial, c_trial, nu) <= merit + ARMIJO * alpha * min(slope, 0.0):
                accepted = bool(np.all(np.isfinite(c_trial)))
                break
            alpha *= 0.5
        if not accepted:
            return finish("failed", f"the line search found no decrease of the l1 merit at SQP "
                          f"iteration {counts['sqp']} (|c|_inf = {violation:.3g}; OSQP: "
                          f"{solution.info.status}, polish status {solution.info.status_polish})")
        p, c = trial, c_trial
        nu = max(nu, 10.0 * float(np.abs(multipliers).max(initial=0.0)))
        J = problem.jacobian(p)
        history.append(float(np.abs(c).max(initial=0.0)))
