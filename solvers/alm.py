"""Our solver ("asc"): augmented Lagrangian + Gauss-Newton + MPRGP + active-set Cholesky (DESIGN 5).

    minimize R(p) = 1/2 sum w_j (p_j - p0_j)^2   s.t.   c(p) = 0,   lower <= p <= upper.

Outer loop (augmented Lagrangian, PERMON SMALXE-style accounting):
    L(p, lam) = R(p) + lam^T c(p) + mu/2 |c(p)|^2,
    after each inner solve lam <- lam + mu c; when |c|_inf did not fall below a quarter of its
    previous value (the constraint stalls), the equality-constrained SQP step on the free variables
    is tried first and taken, with its multipliers, if it at least halves |c|_inf (_sqp_step);
    otherwise mu <- 10 mu. mu starts at ALGENCAN's scale-free value, floored at mu0 = 100
    (_initial_penalty): mu0 from p0, about ten times R / |c|^2 from the linear start. From p0, mu0 =
    10 had let the first inner solve of a 400-vertex strand end at |c|_inf = 10 (worse than p0's 1:
    the regularizer outweighed the penalty), and 11 more outer iterations followed. Against mu0 = 10,
    mean Gauss-Newton steps per strand (same statuses and R, measured with the former
    strand-stiffness start, which began from p0): groom(40, 100, seed=0) 18.5 -> 12.9, groom(100,
    100, seed=5) 21.7 -> 15.4, groom(40, 25, seed=0) 16.8 -> 12.7, groom(20, 200, seed=3) 24.3 ->
    17.9, groom(20, 400, seed=0) 23.8 -> 18.5, groom(10, 400, seed=1..3) 36.0, 45.4, 32.6 -> 26.2,
    21.6, 24.6. Larger is not safer from p0: 1000 was better still up to 200 vertices, but 3000
    sent 400-vertex strands crawling (groom(10, 400, seed=1): 63 steps, 1e4: 85 and one
    max_iterations): Gauss-Newton omits lam^T c'', and the usable range of mu narrows as the
    bending modes soften with n.
Inner loop (primal): Gauss-Newton on L with the banded Hessian H = diag(w) + mu J^T J (damped by
    1e-13 of its diagonal, see _Model.hessian); each step solves the box QP
    min g^T d + 1/2 d^T H d,  lower - p <= d <= upper - p  by MPRGP, preconditioned by the active-set
    Cholesky and warm-started with the previous step's active bounds, then a nonmonotone Armijo
    backtracking line search on L (memory 5; 23% fewer steps than monotone on 100-vertex groom
    strands) keeps p feasible.
Start: per-element stiffness starts from the least rest-shape change that balances gravity,
    stiffened where it leaves the boxes (_linear_start), with least-squares multipliers.
    The first inner solve is loose (omega0 = 1): with lam = 0 it lands far from feasible anyway, and
    converging it tightly wasted ~20% of all Gauss-Newton steps. From p0, though, the scaled
    projected gradient is often below omega already (1e-6 on 400-vertex groom strands); an outer
    iteration without a step then only tightens omega: updating lam <- lam + mu c and mu there
    (what the plain method does) had grown |lam| to ~1e3 and mu to 1e4 before the first step, and
    with such multipliers Gauss-Newton (which omits lam^T c'') crawled at alpha = 1 for 40 steps
    on a 400-vertex strand (7 steps now).
Scale: a rest-length entry moves c about 1e7 times more than a stiffness multiplier (the strain that
    holds gravity is ~1e-8), so gradients are compared in the scaled projected gradient
        pi(p, g) = ||P(p - g / h) - p||_inf,   h_j = w_j + ||J_{:,j}||^2,
    a Newton-like step length in the units of p that is the same for every block. The inner loop
    stops when pi of the gradient of L is below omega_k (tightening by 10 per outer iteration down to
    ``optimality_tol``) or when the model predicts no decrease above the rounding of L.
Converged: |c|_inf <= tol and pi of the gradient of the Lagrangian R + lam^T c (updated lam)
    is <= its target (optimality_tol), confirmed by the KKT distance of the kkt module (the
    constrained step with the regularizer's Hessian) <= kkt.TOLERANCE, the measure every solver's
    status uses. Where pi is small but the distance is not (a flat valley along the bilinear fibres
    stiffness x (kbar - kappa*): on `horizontal` in element mode pi stopped 3.6e-3 from Ipopt's
    optimum with R 3.8e-7 too high), the target is tightened 1000-fold (counted as ``tightened``)
    and the outer loop goes on: one tightening and 7 more Gauss-Newton steps reach Ipopt's optimum
    there (0.02 s; taking constrained SQP steps instead needed 300 of them, 1.65 s).
Stall: the rounding estimate of L can be too optimistic: on a 400-vertex groom strand the model
    still predicted a decrease (slope 3.6e-12 against a rounding estimate of 1.7e-12) while L moved
    by +-5e-12, and hundreds of accepted steps of ~1e-9 made no progress until max_gauss_newton
    (strand 33 of groom(40, 400, seed=0): 600 steps). STALL accepted steps in a row that lower L by
    less than its rounding end the inner loop; on a feasible p the KKT distance then decides
    convergence (that strand: 17 Gauss-Newton steps, KKT distance 6e-12).
Crawl: an inner solve ends after INNER_STEPS Gauss-Newton steps, and the outer loop decides (the SQP
    step, lam, mu). Strand 0 of groom(6, 400, seed=13) sat at |c|_inf = 2e-5 for 480 accepted steps
    of one inner solve (510 in all); with the cap of 30, 71 (with 20: 45, but strand 23 of
    groom(30, 100, seed=4) with curvature_budget 0.2, infeasible, then ran into max_gauss_newton:
    the infeasibility test needs inner solves that reach the stationary point of |c|). Since the
    SQP step has its second-order correction that strand takes 5 steps with or without the cap;
    the cap still saves 14% of the steps on that curvature_budget 0.2 set (20.9 -> 18.0 per strand,
    same statuses).
Infeasible: once mu has reached 10^4 mu0, the best box-constrained Gauss-Newton step for |c|^2 alone
    reduces |c| by less than 1%: p is a stationary point of the constraint violation inside the box.
    The message names the bounds that bind (the blocks and vertices whose relaxation would reduce
    |c|), so a user knows what to relax.
"""
from __future__ import annotations

import time

import numpy as np

from sagfree.formulation.jacobian import StrandJacobian
from sagfree.formulation.problem import Problem

from .banded import gram
from .kkt import TOLERANCE as KKT_TOLERANCE
from .kkt import (column_norms, constrained_step, gradient_scale, kkt_optimality,
                  least_squares_multipliers, scaled_projected_gradient)
from .mprgp import solve_box_qp
from .result import Result, make_result

ARMIJO = 1e-4
ROUNDING = 1e-13  # relative rounding of the merit function: changes below it are noise
DAMPING = (1e-13, 1e-11, 1e-9)  # relative Levenberg-Marquardt damping, escalated on breakdown
NONMONOTONE = 5  # Grippo-Lampariello-Lucidi memory of the line search
STALL = 3  # accepted Gauss-Newton steps in a row that lower L by less than its rounding end the inner loop
INNER_STEPS = 30  # Gauss-Newton steps per inner solve (module docstring, Crawl)
SQP_DECREASE = 0.5  # the SQP step is taken if it reduces |c|_inf at least by this factor (_sqp_step)
MIN_TARGET = 1e-14  # floor of the inner target when the KKT distance keeps disagreeing


class _Model:
    """The regularizer's data, the merit function L and the Gauss-Newton Hessian of one problem."""

    def __init__(self, problem: Problem):
        self.w, self.p0 = problem.layout.weights, problem.layout.p0
        self.border = 1 if "strand_stiffness" in problem.blocks else 0

    def merit(self, p, c, lam, mu) -> float:
        d = p - self.p0
        return 0.5 * float(np.sum(self.w * d * d)) + float(lam @ c) + 0.5 * mu * float(c @ c)

    def merit_scale(self, p, c, lam, mu) -> float:
        """Sum of the magnitudes of the merit's terms: the size its rounding error scales with."""
        d = p - self.p0
        return (0.5 * float(np.sum(self.w * d * d)) + float(np.abs(lam) @ np.abs(c))
                + 0.5 * mu * float(c @ c))

    def hessian(self, J: StrandJacobian, mu: float, damping: float):
        """Bordered band of diag(w) + mu J^T J + damping * mu diag(J^T J).

        The stiff rest-length columns (~1e7 times the others) push the condition number of H past
        1e16 once mu grows, and the active-set Cholesky then meets a non-positive pivot. A damping
        relative to each variable's own diagonal (Levenberg-Marquardt) bounds the scaled condition
        number by 1/damping; at 1e-13 it stays far below the smooth bending modes that hold a
        cantilever up (a (pi/n)^4 share of the diagonal, 4e-9 at n = 400). A shift relative to the
        LARGEST diagonal entry would erase those modes. The 1e-12 absolute shift keeps H definite
        when a weight is zero and its column vanishes."""
        return gram(J, self.w + 1e-12 + damping * mu * column_norms(J), mu, self.border)


def solve_alm(problem: Problem, tol: float = 1e-8, optimality_tol: float = 1e-6, max_outer: int = 60,
              max_gauss_newton: int = 600, mu0: float = 100.0, mu_growth: float = 10.0,
              omega0: float = 1.0, preconditioner: str = "cholesky", qp_rtol: float = 1e-10,
              start: str = "auto", p_start=None) -> Result:
    """Solve ``problem`` with our augmented Lagrangian solver; see the module docstring.

    tol: |c|_inf target (unit-free, relative to each DOF's weight). optimality_tol: projected gradient
    of the Lagrangian. preconditioner: "cholesky" (active-set Cholesky), "jacobi" or "none".
    start: "auto" starts per-element stiffness from _linear_start, "p0" from p0; p_start overrides
    both.
    """
    clock = time.perf_counter()
    history: list[float] = []
    lower, upper = problem.layout.lower, problem.layout.upper
    model = _Model(problem)
    counts = dict(outer=0, gauss_newton=0, cg=0, expansion=0, proportioning=0, active_set=0, interior=0,
                  factorizations=0, factored_rows=0, line_search=0, sqp=0, tightened=0)
    if p_start is None:
        p_start = problem.p0
        if start == "auto" and problem.layout.stiffness == "element" and any(
                b in problem.blocks for b in ("stretch_stiffness", "bend_stiffness", "twist_stiffness")):
            linear = _linear_start(problem)
            if linear is not None:
                p_start, history = linear, [float(np.abs(problem.residual(problem.p0)).max(initial=0.0))]
    p = np.clip(np.asarray(p_start, dtype=float), lower, upper)
    target = optimality_tol  # inner target; tightened when the KKT distance disagrees
    c, J = problem.residual(p), problem.strand_jacobian(p)
    mu, omega = _initial_penalty(mu0, problem.objective(p), c), omega0
    scale = gradient_scale(model.w, J)
    lam = np.zeros(int(problem.free.sum()))
    if history:  # started from the linear start: its least-squares multipliers (_linear_start)
        estimate = least_squares_multipliers(model.w * (p - model.p0), J, scale, p, lower, upper)
        lam = estimate if np.all(np.isfinite(estimate)) else lam
    history = history + [float(np.abs(c).max(initial=0.0))]
    previous_violation = np.inf
    at_lower, at_upper = p <= lower, p >= upper

    def finish(status, message):
        return make_result(problem, p, "asc", status, message, counts, time.perf_counter() - clock, history)

    while counts["outer"] < max_outer:
        counts["outer"] += 1
        # ---- inner: Gauss-Newton on the augmented Lagrangian ----
        recent: list[float] = []
        stalled = 0
        steps_before = counts["gauss_newton"]
        while True:
            gradient = model.w * (p - model.p0) + J.T @ (lam + mu * c)
            if scaled_projected_gradient(p, gradient, scale, lower, upper) <= omega:
                break
            if counts["gauss_newton"] - steps_before >= INNER_STEPS:
                break  # a crawling inner solve: let the outer loop (SQP step or mu) decide
            if counts["gauss_newton"] >= max_gauss_newton:
                return finish("max_iterations", f"stopped after {max_gauss_newton} Gauss-Newton steps "
                              f"with |c|_inf = {history[-1]:.3g}; raise max_gauss_newton")
            counts["gauss_newton"] += 1
            # warm start: the bounds active in the previous step's QP are active again
            d_lower, d_upper = lower - p, upper - p
            start_step = np.where(at_lower, d_lower, np.where(at_upper, d_upper, 0.0))
            for damping in DAMPING:  # escalate only if rounding breaks the factorization
                qp = solve_box_qp(model.hessian(J, mu, damping), -gradient, d_lower, d_upper,
                                  x0=start_step, rtol=qp_rtol, preconditioner=preconditioner)
                if qp.status != "not_positive_definite":
                    break
            at_lower, at_upper = qp.x <= d_lower, qp.x >= d_upper
            for key in ("cg", "expansion", "proportioning", "active_set", "interior", "factorizations",
                        "factored_rows"):
                counts[key] += getattr(qp, key)
            if qp.status not in ("converged", "max_iterations"):
                return finish("failed", f"the Gauss-Newton QP failed ({qp.status}) at step "
                              f"{counts['gauss_newton']}")
            step, slope = qp.x, float(gradient @ qp.x)
            merit = model.merit(p, c, lam, mu)
            recent.append(merit)
            reference = max(recent[-NONMONOTONE:])
            rounding = ROUNDING * (abs(merit) + model.merit_scale(p, c, lam, mu))
            if -slope <= rounding:
                break  # the model predicts no decrease above the rounding of L
            alpha, accepted = 1.0, False
            for _ in range(40):
                counts["line_search"] += 1
                trial = np.clip(p + alpha * step, lower, upper)
                c_trial = problem.residual(trial)
                merit_trial = model.merit(trial, c_trial, lam, mu)
                if merit_trial <= reference + ARMIJO * alpha * slope + rounding:
                    accepted = np.all(np.isfinite(c_trial))
                    break
                alpha *= 0.5
            if not accepted:
                break  # no descent left at this accuracy: let the outer loop decide
            stalled = stalled + 1 if merit_trial > merit - rounding else 0
            p, c = trial, c_trial
            J = problem.strand_jacobian(p)
            scale = gradient_scale(model.w, J)
            history.append(float(np.abs(c).max(initial=0.0)))
            if stalled >= STALL:
                break  # L no longer decreases above its rounding: let the outer loop decide

        # ---- outer: multipliers, penalty, convergence ----
        violation = float(np.abs(c).max(initial=0.0))
        if counts["gauss_newton"] == steps_before and violation > tol and omega > target:
            # the inner target was met without a step (the loose first one, from p0): a multiplier
            # update there only adds mu c to lam, which grew |lam| to ~1e3 in four such rounds
            # before the first step and made Gauss-Newton crawl; tighten the target instead
            omega = max(target, 0.1 * omega)
            continue
        lam = lam + mu * c
        regularizer_gradient = model.w * (p - model.p0)
        optimality = scaled_projected_gradient(p, regularizer_gradient + J.T @ lam, scale, lower, upper)
        if violation <= tol and optimality > optimality_tol:
            # the first-order update may lag behind a feasible p: try the least-squares multipliers
            estimate = least_squares_multipliers(regularizer_gradient, J, scale, p, lower, upper)
            kkt = scaled_projected_gradient(p, regularizer_gradient + J.T @ estimate, scale, lower, upper)
            if kkt < optimality:
                lam, optimality = estimate, kkt
        # a stalled inner loop on a feasible p: only the KKT distance can tell (below)
        converged = violation <= tol and (optimality <= target or stalled >= STALL)
        if converged:
            # the scaled gradient can be small in a flat valley away from the optimum: confirm with
            # the KKT distance of the kkt module, and tighten the inner target if it disagrees
            distance = kkt_optimality(problem, p)
            converged = distance <= KKT_TOLERANCE
            if not converged:
                counts["tightened"] += 1
                target = max(1e-3 * target, MIN_TARGET)
        if converged:
            return finish("converged", f"|c|_inf = {violation:.2e} <= {tol:g} and KKT distance {distance:.2e} <= "
                          f"{KKT_TOLERANCE:g} after "
                          f"{counts['outer']} outer and {counts['gauss_newton']} Gauss-Newton iterations")
        if violation > tol and violation > 0.25 * previous_violation:
            # the constraint stalls: before growing mu, try the constrained step (SQP)
            sqp = _sqp_step(problem, model, p, c, J, SQP_DECREASE * violation)
            if sqp is not None:
                counts["sqp"] += 1
                p, c, lam = sqp
                J = problem.strand_jacobian(p)
                scale = gradient_scale(model.w, J)
                history.append(float(np.abs(c).max(initial=0.0)))
                previous_violation = violation
                continue
            mu *= mu_growth
            if mu >= 1e4 * mu0:
                verdict = _infeasibility(problem, p, c, J, lower, upper)
                if verdict:
                    return finish("infeasible", verdict)
        previous_violation = violation
        omega = max(target, 0.1 * omega)
    return finish("max_iterations", f"stopped after {max_outer} outer iterations with |c|_inf = "
                  f"{history[-1]:.3g} (target {tol:g}); raise max_outer")


def _sqp_step(problem: Problem, model: _Model, p, c, J, bound: float):
    """(p, c, lam) after the equality-constrained SQP step from p, or None if it leaves
    |c|_inf > bound.

    The step d minimizes the regularizer's quadratic model on the linearized constraint over the
    free variables F (strictly inside their boxes; kkt.constrained_step, one band LU):
        [[W_F, J_F^T], [J_F, 0]] [d_F; lam] = -[grad R_F; c],
    and lam, the multipliers of that step, replace the first-order update lam + mu c. solve_alm
    tries it where it would otherwise grow mu because |c|_inf stalled. Near the solution the
    first-order update converges slowly along the soft bending modes, and the inner solves it
    forces at large mu crawl: strand 0 of groom(10, 400, seed=2) reached |c|_inf = 8.2e-7 at mu =
    1e6 and then took 590 Gauss-Newton steps of ~2e-7 (each lowering L by ~3e-10) into
    max_gauss_newton. With this step: 3 Gauss-Newton and 2 SQP steps (|c|_inf 7.4e-5 -> 1.9e-5
    -> 3.3e-10; the first only quartered it, as the stiffness x rest-shape products curve c).
    Where the curvature of c spoils the step, a second-order correction follows: the least W-norm
    step back to c = 0 from the trial point with the same J (one more band LU). On groom(20, 400,
    seed=0), strands 7 and 16 had the full step raise |c|_inf (5.3e-5 -> 8.4e-5) and crawled for
    67 and 65 Gauss-Newton steps at large mu; with the correction they take 3 each, and the mean
    over the 20 strands fell from 11.3 to 4.0 steps.
    """
    free = (p > problem.layout.lower) & (p < problem.layout.upper)
    step = constrained_step(J, model.w, model.w * (p - model.p0), c, free)
    if step is None:
        return None
    trial = np.clip(p + step[0], problem.layout.lower, problem.layout.upper)
    c_trial = problem.residual(trial)
    if not np.abs(c_trial).max(initial=0.0) <= bound:
        # second-order correction: the least W-norm step back to c = 0 with the same J
        correction = constrained_step(J, model.w, np.zeros_like(p), c_trial, free)
        if correction is None:
            return None
        trial = np.clip(trial + correction[0], problem.layout.lower, problem.layout.upper)
        c_trial = problem.residual(trial)
        if not np.abs(c_trial).max(initial=0.0) <= bound:  # also rejects NaN
            return None
    return trial, c_trial, step[1]


def _initial_penalty(mu0: float, objective: float, c: np.ndarray) -> float:
    """mu at the start: ALGENCAN's scale-free choice (Birgin & Martinez, "Practical Augmented
    Lagrangian Methods for Constrained Optimization", SIAM 2014), floored at mu0,

        mu = max(mu0, min(10 max(1, |R(p)|) / max(1, |c(p)|^2 / 2), 1e8)),

    so that the penalty term weighs about ten times the regularizer. From p0 (R = 0) it is mu0. From
    the linear start, R is 1 to 1e4 (the root's stiffening) at |c|_inf ~1e-3: with mu0 = 100 there
    the first inner solve gave up feasibility for R (|c|_inf from 1e-2 back up to ~1 for 20
    Gauss-Newton steps on 400-vertex strands: 41, 23, 32, 41 steps on groom(4, 400, seed=1) from
    the former strand start, 47, 39, 47, 56 from the linear start; 6, 6, 9, 24 with this penalty).
    """
    return max(mu0, min(10.0 * max(1.0, abs(objective)) / max(1.0, 0.5 * float(c @ c)), 1e8))


def _linear_start(problem: Problem) -> np.ndarray | None:
    """A nearly feasible start for per-element stiffness: the least rest-shape change that balances
    gravity, spread into the boxes by stiffening where it does not fit (None if the linear system is
    singular; the solve then starts from p0).

    At p0 the rest shape is the groomed shape and the stiffness multipliers are 1; c is linear in the
    rest curvatures and twists there, and the rest lengths move by the strain that holds gravity
    (~1e-8). So one equality-constrained least-squares step on the rest blocks R,

        minimize sum_R w_j d_j^2   s.t.   c(p0) + J_R d = 0     (kkt.constrained_step, one band LU),

    nearly balances gravity with no box. A vertex's forces depend on its element only through the
    products y = k (kbar - kappa*) (bend), z = k (mbar - m*) (twist) and k * strain (stretch), and at
    k = 1 these are the step d. Keeping them keeps c (_spread_rest_change): each vertex takes the least
    multiplier its boxes allow, k_i = max(1, |y_i| / b_i, |z_i| / b_m,i), so only the root, where the
    boxes bind, starts stiffened.

    This replaced a start from the solution with one stiffness multiplier S for the whole strand
    (supplement section V; 7.8 of a 100-vertex groom strand's 13.6 Gauss-Newton steps, ~9.7 of its
    ~21 ms): the linear step costs one factorization and lands closer, at |c|_inf ~1e-4 to 1e-3 (the
    spread strand solution: up to 0.7) with R within ~1% of the optimum (up to 5% above it).
    Gauss-Newton steps per strand, strand start -> this one, with the initial penalty of solve_alm
    in both (measured before the SQP step existed): groom(100, 100, seed=0) 11.9 -> 7.2,
    groom(40, 50, seed=4) 13.4 -> 6.5, groom(20, 200, seed=3) 13.9 -> 9.2, groom(10, 400, seed=1)
    15.1 -> 9.2; factorizations 53 -> 19, 49 -> 16, 76 -> 26, 102 -> 30; same statuses and R (to
    1e-7 relative).
    """
    layout, blocks = problem.layout, problem.blocks
    rest = np.zeros(problem.n_parameters, dtype=bool)
    for block in ("rest_length", "rest_curvature", "rest_twist"):
        if block in blocks:
            rest[blocks[block]] = True
    step = constrained_step(problem.strand_jacobian(layout.p0), layout.weights, np.zeros(problem.n_parameters),
                            problem.residual(layout.p0), rest)
    if step is None or not np.all(np.isfinite(step[0])):
        return None
    return _spread_rest_change(problem, step[0])


def _spread_rest_change(problem: Problem, change: np.ndarray) -> np.ndarray:
    """Element parameters with the forces of p0 + change at unit stiffness: the least stiffness
    multipliers that bring each element's rest change into its box (see _linear_start)."""
    layout, blocks = problem.layout, problem.blocks
    p0, lower, upper = layout.p0, layout.lower, layout.upper
    half = np.maximum(np.minimum(upper - p0, p0 - lower), 1e-300)  # box half-widths around p0
    p = p0.copy()
    n_inner = problem.n_vertices - 2
    need = {"bend_stiffness": np.ones(n_inner), "twist_stiffness": np.ones(n_inner)}
    for block, target in (("rest_curvature", "bend_stiffness"), ("rest_twist", "twist_stiffness")):
        if block in blocks:
            ix = blocks[block]
            need[target] = np.maximum(1.0, (np.abs(change[ix]) / half[ix]).reshape(n_inner, -1).max(axis=1))
    coupled = layout.couple_twist  # the twist follows the bend multiplier
    bend = np.maximum(need["bend_stiffness"], need["twist_stiffness"]) if coupled else need["bend_stiffness"]
    for block, k in (("bend_stiffness", bend), ("twist_stiffness", need["twist_stiffness"])):
        if block in blocks:
            p[blocks[block]] = np.clip(k, lower[blocks[block]], upper[blocks[block]])
    # the multipliers in force (a block not optimized keeps its specified value 1)
    k_bend = p[blocks["bend_stiffness"]] if "bend_stiffness" in blocks else np.ones(n_inner)
    k_twist = k_bend if coupled else (p[blocks["twist_stiffness"]] if "twist_stiffness" in blocks
                                      else np.ones(n_inner))
    if "rest_curvature" in blocks:
        ix = blocks["rest_curvature"]
        p[ix] = p0[ix] + change[ix] / np.repeat(k_bend, ix.size // n_inner)
    if "rest_twist" in blocks:
        ix = blocks["rest_twist"]
        p[ix] = p0[ix] + change[ix] / k_twist
    if "rest_length" in blocks:  # strain(u) = -u / (1 + u) at q*; keep k * strain
        ix = blocks["rest_length"]
        u = change[ix]
        k = np.ones(ix.size)
        if "stretch_stiffness" in blocks:
            k = np.clip(np.maximum(1.0, np.abs(u) / half[ix]), lower[blocks["stretch_stiffness"]],
                        upper[blocks["stretch_stiffness"]])
            p[blocks["stretch_stiffness"]] = k
        strain = -u / (1.0 + u) / k
        p[ix] = -strain / (1.0 + strain)
    return np.clip(p, lower, upper)


def _infeasibility(problem: Problem, p, c, J, lower, upper) -> str | None:
    """A message naming the binding bounds if p is a stationary point of |c|^2 in the box, else None.

    Tested by the box-constrained Levenberg-Marquardt step for 1/2 |c + J d|^2: if even its linear
    model reduces |c| by less than 1%, no nearby point in the box is closer to equilibrium. The
    damping (1e-11 of the diagonal) keeps the rank-deficient J^T J definite but must stay below the
    smooth bending modes, whose share of the diagonal falls like (pi/n)^4 with n vertices.
    """
    damping = 1e-11 * column_norms(J) + 1e-12
    border = 1 if "strand_stiffness" in problem.blocks else 0
    qp = solve_box_qp(gram(J, damping, 1.0, border), -(J.T @ c), lower - p, upper - p, rtol=1e-10)
    if qp.status != "converged" or np.linalg.norm(c + J @ qp.x) < 0.99 * np.linalg.norm(c):
        return None
    pull = -(J.T @ c)  # the direction in which each parameter would reduce |c|^2
    binding = np.flatnonzero(((p >= upper) & (pull > 0)) | ((p <= lower) & (pull < 0)))
    # what relaxing each bound could buy: the decrease of 1/2 |c|^2 by a scaled gradient step
    gain = pull[binding] ** 2 / gradient_scale(problem.layout.weights, J)[binding]
    binding = binding[gain >= 0.01 * gain.max(initial=0.0)]
    binding = binding[np.argsort(-np.abs(pull[binding]))]
    where: dict[str, list[str]] = {}
    for index in binding:
        block, element = problem.layout.locate(int(index))
        side = "upper" if p[index] >= upper[index] else "lower"
        where.setdefault(f"{block} at its {side} bound", []).append(element)
    details = "; ".join(f"{what} at {', '.join(elements[:6])}{' and more' if len(elements) > 6 else ''}"
                        for what, elements in where.items())
    violation = float(np.abs(c).max())
    return (f"infeasible within bounds: |c|_inf stalls at {violation:.3g} (no parameters inside the box "
            f"balance gravity). Binding: {details or 'none identified'}. Relax those bounds (bounds="
            "{block: (lower, upper)}, or curvature_budget / twist_budget for the rest-shape boxes)")
