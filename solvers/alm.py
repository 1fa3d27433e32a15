"""Our solver ("asc"): augmented Lagrangian + Gauss-Newton + MPRGP + active-set Cholesky (DESIGN 5).

    minimize R(p) = 1/2 sum w_j (p_j - p0_j)^2   s.t.   c(p) = 0,   lower <= p <= upper.

Outer loop (augmented Lagrangian, PERMON SMALXE-style accounting):
    L(p, lam) = R(p) + lam^T c(p) + mu/2 |c(p)|^2,
    after each inner solve lam <- lam + mu c; mu <- 10 mu when |c|_inf did not fall below
    a quarter of its previous value (the constraint stalls). mu starts at mu0 = 100 (in both the
    strand-stiffness start and the element solve). From 10, the first inner solve of a 400-vertex
    strand's start ended at |c|_inf = 10 (worse than p0's 1: the regularizer outweighed the
    penalty), and 11 more outer iterations followed. Against mu0 = 10, mean Gauss-Newton steps per
    strand (same statuses and R): groom(40, 100, seed=0) 18.5 -> 12.9, groom(100, 100, seed=5)
    21.7 -> 15.4, groom(40, 25, seed=0) 16.8 -> 12.7, groom(20, 200, seed=3) 24.3 -> 17.9,
    groom(20, 400, seed=0) 23.8 -> 18.5, groom(10, 400, seed=1..3) 36.0, 45.4, 32.6 -> 26.2, 21.6,
    24.6; factorizations 10-40% fewer. Larger is not safer: mu0 = 1000 was better still up to 200
    vertices, but 3000 sent 400-vertex strands crawling (groom(10, 400, seed=1): 63 steps, 1e4: 85
    and one max_iterations): Gauss-Newton omits lam^T c'', and the usable range of mu narrows as the
    bending modes soften with n.
Inner loop (primal): Gauss-Newton on L with the banded Hessian H = diag(w) + mu J^T J (damped by
    1e-13 of its diagonal, see _Model.hessian); each step solves the box QP
    min g^T d + 1/2 d^T H d,  lower - p <= d <= upper - p  by MPRGP, preconditioned by the active-set
    Cholesky and warm-started with the previous step's active bounds, then a nonmonotone Armijo
    backtracking line search on L (memory 5; 23% fewer steps than monotone on 100-vertex groom
    strands) keeps p feasible.
Start: per-element stiffness starts from the one-multiplier-per-strand solution (_strand_mode_start).
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
Infeasible: once mu has grown 10^4-fold, the best box-constrained Gauss-Newton step for |c|^2 alone
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
from .kkt import (column_norms, gradient_scale, kkt_optimality, least_squares_multipliers,
                  scaled_projected_gradient)
from .mprgp import solve_box_qp
from .result import Result, bare_result, make_result

ARMIJO = 1e-4
ROUNDING = 1e-13  # relative rounding of the merit function: changes below it are noise
DAMPING = (1e-13, 1e-11, 1e-9)  # relative Levenberg-Marquardt damping, escalated on breakdown
NONMONOTONE = 5  # Grippo-Lampariello-Lucidi memory of the line search
STALL = 3  # accepted Gauss-Newton steps in a row that lower L by less than its rounding end the inner loop
START_GAUSS_NEWTON = 40  # cap of the strand-stiffness start (_strand_mode_start)
START_TOL = 1e-4  # |c|_inf at which the strand-stiffness start stops (_strand_mode_start)
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
              start: str = "auto", p_start=None, confirm: bool = True, measure: bool = True) -> Result:
    """Solve ``problem`` with our augmented Lagrangian solver; see the module docstring.

    tol: |c|_inf target (unit-free, relative to each DOF's weight). optimality_tol: projected gradient
    of the Lagrangian. preconditioner: "cholesky" (active-set Cholesky), "jacobi" or "none".
    start: "auto" starts per-element stiffness from the strand-stiffness solution (see
    _strand_mode_start), "p0" from p0; p_start overrides both. confirm: check convergence with the KKT
    distance of the kkt module (a sparse LU, ~3 ms on a 100-vertex strand; the strand-stiffness
    start skips it). measure: fill the Result's summaries and stability (make_result); without it
    only p, status, message, iterations, time and history are set (the strand-stiffness start, whose
    Result is discarded, skips ~3 ms of a 100-vertex groom strand's ~45 ms this way).
    """
    clock = time.perf_counter()
    history: list[float] = []
    lower, upper = problem.layout.lower, problem.layout.upper
    model = _Model(problem)
    counts = dict(outer=0, gauss_newton=0, cg=0, expansion=0, proportioning=0, active_set=0, interior=0,
                  factorizations=0, factored_rows=0, line_search=0, tightened=0)
    if p_start is None:
        p_start = problem.p0
        if start == "auto" and problem.layout.stiffness == "element" and any(
                b in problem.blocks for b in ("stretch_stiffness", "bend_stiffness", "twist_stiffness")):
            p_start, history = _strand_mode_start(problem, counts, mu0=mu0, tol=max(tol, START_TOL),
                                                  optimality_tol=optimality_tol, preconditioner=preconditioner,
                                                  qp_rtol=qp_rtol)
    p = np.clip(np.asarray(p_start, dtype=float), lower, upper)
    mu, omega = mu0, omega0
    target = optimality_tol  # inner target; tightened when the KKT distance disagrees
    c, J = problem.residual(p), problem.strand_jacobian(p)
    scale = gradient_scale(model.w, J)
    lam = np.zeros(int(problem.free.sum()))
    if history:  # started from the strand solution: its least-squares multipliers (_strand_mode_start)
        estimate = least_squares_multipliers(model.w * (p - model.p0), J, scale, p, lower, upper)
        lam = estimate if np.all(np.isfinite(estimate)) else lam
    history = history + [float(np.abs(c).max(initial=0.0))]
    previous_violation = np.inf
    at_lower, at_upper = p <= lower, p >= upper

    def finish(status, message):
        build = make_result if measure else bare_result
        return build(problem, p, "asc", status, message, counts, time.perf_counter() - clock, history)

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
        evidence = (f"scaled projected gradient {optimality:.2e} <= {target:g}" if optimality <= target else
                    f"L stalled at its rounding (scaled projected gradient {optimality:.2e})")
        if converged and confirm:
            # the scaled gradient can be small in a flat valley away from the optimum: confirm with
            # the KKT distance of the kkt module, and tighten the inner target if it disagrees
            distance = kkt_optimality(problem, p)
            converged = distance <= KKT_TOLERANCE
            evidence = f"KKT distance {distance:.2e} <= {KKT_TOLERANCE:g}"
            if not converged:
                counts["tightened"] += 1
                target = max(1e-3 * target, MIN_TARGET)
        if converged:
            return finish("converged", f"|c|_inf = {violation:.2e} <= {tol:g} and {evidence} after "
                          f"{counts['outer']} outer and {counts['gauss_newton']} Gauss-Newton iterations")
        if violation > tol and violation > 0.25 * previous_violation:
            mu *= mu_growth
            if mu >= 1e4 * mu0:
                verdict = _infeasibility(problem, p, c, J, lower, upper)
                if verdict:
                    return finish("infeasible", verdict)
        previous_violation = violation
        omega = max(target, 0.1 * omega)
    return finish("max_iterations", f"stopped after {max_outer} outer iterations with |c|_inf = "
                  f"{history[-1]:.3g} (target {tol:g}); raise max_outer")


def _strand_mode_start(problem: Problem, counts: dict, **options) -> tuple[np.ndarray, list[float]]:
    """A feasible start for per-element stiffness, from the solution with one stiffness multiplier S
    for the whole strand (supplement section V).

    Element mode is bilinear in stiffness and rest shape, and from p0 (where stiffness has no effect
    on c) Gauss-Newton crawls. The strand solution balances gravity; its forces depend on each
    element only through the products y = S (kbar - kappa*) (bend), z = S (mbar - m*) (twist) and
    S * strain (stretch). Keeping those products keeps c: each vertex gets the least multiplier its
    boxes allow, k_i = min(S, max(1, |y_i| / b_i, |z_i| / b_m,i)), with kbar - kappa* = y / k_i and
    mbar - m* = z / k_i (k_i = S gives back the strand's own rest shape, which is in the box); each
    edge keeps multiplier 1 and takes the strain S * strain through its rest length, or, where that
    rest length would leave its box, keeps the strand's edge (multiplier S, its rest length). So only
    the root, where the boxes bind, starts stiffened; the tail starts at its specified stiffness.
    (Clipping the root edge's rest length instead left |c|_inf = 25 on some groom strands; what
    remains, up to ~4e-2, is the 4d curvature's separate terms per frame, which the products do not
    keep where the two frames' curvatures differ.) The element solve's multipliers start as the
    least-squares multipliers at this point (kkt.least_squares_multipliers): from lam = 0 it first
    walked away from feasibility. On groom(30, 100) that took the Gauss-Newton steps per strand from
    26 to 16.5 and the factorizations from 136 to 64; on groom(10, 400) from 44 to 32 and 412 to 168.
    (The strand solve's own multipliers, the other candidate, were as good at 100 vertices but sent
    3 of 10 400-vertex strands to max_iterations; they were then inflated, see the module docstring,
    Start.) The element solve starts again from mu0: inheriting the strand solve's final penalty
    saved ~10% of the Gauss-Newton steps, but sent strand 27 of groom(40, 200, seed=0) crawling
    along a flat valley at large mu (497 steps against 19; strand 2200 of groom(10000, 100, seed=0)
    580 steps into max_gauss_newton, at ~1% per step, against 14).

    The strand solve stops at |c|_inf <= START_TOL: the spread above leaves up to ~4e-2 anyway, and
    the last decades cost the strand solve 4-6 Gauss-Newton steps (at mu up to 1e4) that the element
    solve did not need. Measured against tol = 1e-8 (same statuses, R to 7 digits), mean
    Gauss-Newton steps per strand: groom(150, 100, seed=2) 25.3 -> 21.8, groom(20, 200, seed=3)
    27.9 -> 24.0, groom(10, 400, seed=2) 31.7 -> 30.4, groom(40, 50, seed=4) 25.6 -> 21.4. (At 1e-3
    one strand of groom(10, 400, seed=0) needed 200 more steps in element mode.)
    It is capped at START_GAUSS_NEWTON steps (it usually needs 7-20; a rare slow one still gives a
    good start); its iterations count towards ``counts`` and its |c|_inf history is
    returned with the start; p0 (and no history) if it failed or is infeasible."""
    bounds, weights = dict(problem.options["bounds"] or {}), dict(problem.options["weights"] or {})
    stiffness_ix = np.concatenate([ix for b, ix in problem.blocks.items() if b.endswith("_stiffness")])
    bounds = {b: v for b, v in bounds.items() if not b.endswith("_stiffness")}
    bounds["strand_stiffness"] = (problem.layout.lower[stiffness_ix].max(),
                                  problem.layout.upper[stiffness_ix].min())
    weights = {b: v for b, v in weights.items() if not b.endswith("_stiffness")}
    if bounds["strand_stiffness"][0] > bounds["strand_stiffness"][1]:
        return problem.p0, []  # no common multiplier fits every element's box
    strand_problem = problem.with_options(stiffness="strand", bounds=bounds, weights=weights)
    result = solve_alm(strand_problem, start="p0", max_gauss_newton=START_GAUSS_NEWTON, confirm=False,
                       measure=False, **options)
    for key, value in result.iterations.items():
        counts[key] += value
    if result.status not in ("converged", "max_iterations"):
        return problem.p0, []
    return _spread_strand_solution(problem, strand_problem, result.p), result.history


def _spread_strand_solution(problem: Problem, strand_problem: Problem, strand_p) -> np.ndarray:
    """Element parameters with the same forces as the strand solution (see _strand_mode_start)."""
    layout, blocks = problem.layout, problem.blocks
    S = float(strand_p[strand_problem.blocks["strand_stiffness"]][0])
    p = problem.p0

    def excess(block):
        """(moment-like product, box half-width) of a rest block, per entry."""
        ix = blocks[block]
        change = S * (strand_p[strand_problem.blocks[block]] - layout.p0[ix])
        half = np.minimum(layout.upper[ix] - layout.p0[ix], layout.p0[ix] - layout.lower[ix])
        return change, np.maximum(half, 1e-300)

    n_inner = problem.n_vertices - 2
    need = {"bend_stiffness": np.ones(n_inner), "twist_stiffness": np.ones(n_inner)}
    products = {}
    for block, target in (("rest_curvature", "bend_stiffness"), ("rest_twist", "twist_stiffness")):
        if block in blocks:
            change, half = excess(block)
            products[block] = change
            per_vertex = (np.abs(change) / half).reshape(n_inner, -1).max(axis=1)
            # at most S: with S itself the strand's own rest shape, which is in the box, returns
            need[target] = np.minimum(np.maximum(need[target], per_vertex), max(S, 1.0))
    coupled = "twist_stiffness" not in blocks
    bend = np.maximum(need["bend_stiffness"], need["twist_stiffness"]) if coupled else need["bend_stiffness"]
    twist = bend if coupled else need["twist_stiffness"]
    multipliers = {"bend_stiffness": bend, "twist_stiffness": twist,
                   "stretch_stiffness": np.ones(problem.n_vertices - 1)}
    for block, k in multipliers.items():
        if block in blocks:
            p[blocks[block]] = np.clip(k, layout.lower[blocks[block]], layout.upper[blocks[block]])
    # the multipliers actually in force (a block not optimized keeps its specified value 1; a
    # coupled twist follows the bend multiplier)
    k_bend = p[blocks["bend_stiffness"]] if "bend_stiffness" in blocks else np.ones(n_inner)
    k_twist = p[blocks["twist_stiffness"]] if not coupled else k_bend
    if "rest_curvature" in blocks:
        ix = blocks["rest_curvature"]
        p[ix] = layout.p0[ix] + products["rest_curvature"] / np.repeat(k_bend, 2)
    if "rest_twist" in blocks:
        ix = blocks["rest_twist"]
        p[ix] = layout.p0[ix] + products["rest_twist"] / k_twist
    if "rest_length" in blocks:  # strain(u) = -u / (1 + u) at q*; keep S * strain with multiplier 1
        ix = blocks["rest_length"]
        u = strand_p[strand_problem.blocks["rest_length"]]
        strain = S * (-u / (1.0 + u))
        p[ix] = -strain / (1.0 + strain)
        if "stretch_stiffness" in blocks:  # where that leaves the box: the strand's own edge (S, u)
            outside = (p[ix] < layout.lower[ix]) | (p[ix] > layout.upper[ix])
            p[ix[outside]] = u[outside]
            p[blocks["stretch_stiffness"][outside]] = S
    return np.clip(p, layout.lower, layout.upper)


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
