"""Our solver ("asc"): augmented Lagrangian + Gauss-Newton + MPRGP + active-set Cholesky (DESIGN 5).

    minimize R(p) = 1/2 sum w_j (p_j - p0_j)^2   s.t.   c(p) = 0,   lower <= p <= upper.

Outer loop (augmented Lagrangian, PERMON SMALXE-style accounting):
    L(p, lam) = R(p) + lam^T c(p) + mu/2 |c(p)|^2;
    after each inner solve lam <- lam + mu c. When |c|_inf did not fall below a quarter of its
    previous value (the constraint stalls), the equality-constrained SQP step on the free variables
    is tried first and taken, with its multipliers, if it at least halves |c|_inf (_sqp_step);
    otherwise mu <- 10 mu. mu starts at ALGENCAN's scale-free value, floored at mu0
    (_initial_penalty). Gauss-Newton omits lam^T c'', so the usable range of mu narrows as the
    bending modes soften with n: mu0 = 100 is the floor that works from 25 to 800 vertices.
    Where the saddle system is a band (every problem without a strand multiplier), the outer
    iterations, Newton-SQP included, run as one compiled call (solvers.outer_loop) that hands back
    to this loop only for the infeasibility test (below); the loop here is the same arithmetic,
    for the rest.
Inner loop (primal): Gauss-Newton on L with the banded Hessian H = diag(w) + mu J^T J (damped,
    _Model.hessian); each step solves the box QP
    min g^T d + 1/2 d^T H d,  lower - p <= d <= upper - p  by MPRGP, preconditioned by the active-set
    Cholesky and warm-started with the previous step's active bounds, then a nonmonotone Armijo
    backtracking line search on L (memory NONMONOTONE) keeps p feasible. Where the full step d fails
    the Armijo test, its second-order correction is tried before any halving: p + d + e with
    e = -H_F^-1 mu J^T r on the QP's free variables, r = c(p + d) - c - J d the error of the
    linearization (gauss_newton.corrected_trial; one band Cholesky; counted as ``corrected`` when
    taken). Gauss-Newton's straight step leaves the curved valley of the bilinear products stiffness
    x (kbar - kappa*) along which the optimum trades (the Maratos effect), and the halvings crawled
    (on 25-vertex groom strands the correction took the Gauss-Newton steps from 6.2 to 3.9 per
    strand, to the same optima). On a strand held at both ends (a tip or pins, off bodies), once
    |c|_inf <= 1e-2 the Hessian also takes the constraints' curvature sum_r (lam + mu c)_r c_r''
    (the augmented Lagrangian's exact Hessian, shifted on its diagonal where it is not definite:
    gauss_newton.curved_hessian): there the internal forces are not fixed by statics, Gauss-Newton
    crawled along the curvature it omits, and long strands with a pinned tip ended max_iterations
    (benchmarks/RESULTS.md, 2026-12-05).
    The whole inner solve is one compiled call where the model is compiled (solvers.gauss_newton);
    _inner_solve_python is the same loop step for step, for the rest (no C compiler).
Start: per-element stiffness starts from the least rest-shape change that balances gravity,
    stiffened where it leaves the boxes (linear_start), with least-squares multipliers. For a strand
    held by its root alone that change is the only balancing one, and each element's multiplier is
    chosen as the optimum's (solvers.statics_start): the start is the optimum. A start with
    |c|_inf <= tol is confirmed at once by the KKT distance (below), before any multiplier
    estimate or outer iteration (``outer`` = 0): for a root-held groom strand that check is
    usually all that is left of its solve, and the start, the check and its Result's stability run
    as one compiled call (solvers.confirmed_start; the Python steps where it does not apply; the
    front end's solve makes that call and the stabilization's rounds one, frontend.whole_solve). Where
    the check fails, the outer loop polishes. With bodies,
    from p0: the same step with the supports (clipped at zero where it pulled) left the rest shape
    to stiffen (R 0.17 where the optimum is 8e-4 on a strand lying on a head), and the augmented
    Lagrangian then lost feasibility from it. A strand held at points besides its root (a pinned
    tip, pins) starts at the optimum over those points' reactions (solvers.reaction_start: the
    root-held decomposition with 3 more unknowns per point, searched by quasi-Newton), which asc
    confirms as it does a root-held start: from p0 or the linear start the augmented Lagrangian
    crawled at feasible non-KKT points or stopped at worse optima (groom strands pinned at their
    middle vertex, 400 vertices: 4 of 20 max_iterations; a pinned tip from 3000 vertices on).
    Where that search does not apply or finds no reaction the boxes admit, those strands start
    from p0: from the linear start asc ended at other KKT points or crawled more often there
    (horizontal(n=100, tip="pinned"): R 0.49 after stabilization against Ipopt's 6.8e-5; 17 of 60
    groom strands pinned at their middle vertex ended max_iterations, none from p0: benchmarks/
    RESULTS.md, 2026-12-05, twenty-sixth session). A clamped tip keeps the linear start, from which
    asc reaches the optimum there more closely (benchmarks/RESULTS.md, 2026-12-03). A default solve
    that ends max_iterations all the same begins again from the other start (p0 after the linear
    start or the reaction search, the linear start after p0) with what is left of max_iterations
    and max_seconds, and answers with that solve if it converges (its message says so; the counts
    and the time are both solves'): on longer strands held at two points, each start converges on
    some strands where the other crawls. The first
    inner solve is loose (omega0 = 1). An outer iteration whose inner solve took no step only
    tightens omega, by as many factors of 10 as it takes to fall below the current pi (one factor
    per outer iteration repeated the same test at the same p: 10.9 -> 6.4 outer iterations per
    groom strand, the same p): a multiplier update there adds mu c to lam without moving p, and the
    large multipliers it builds make Gauss-Newton (which omits lam^T c'') crawl. While no
    Gauss-Newton step has moved p at all (from p0, or from p0 raised onto a stabilization's floors),
    the same holds below gradient_tol: the SQP step is tried (taken if it halves |c|_inf, as below)
    and omega drops to a tenth of pi, so that the next inner solve steps. From p0 pi can meet
    gradient_tol where the Gauss-Newton step is far from small (the soft modes of a strand held at
    both ends), and the multiplier update lam = mu c that followed aims the next inner solve at
    c = -c(p0), into stiffening long strands held at both ends never left. The SQP step first keeps
    the optima that update reached where it worked (benchmarks/RESULTS.md, 2026-12-05, twenty-fifth
    session).
Scale: a rest-length entry moves c about 1e7 times more than a stiffness multiplier (the strain that
    holds gravity is ~1e-8), so gradients are compared in the scaled projected gradient
        pi(p, g) = ||P(p - g / h) - p||_inf,   h_j = w_j + ||J_{:,j}||^2,
    a Newton-like step length in the units of p that is the same for every block. The inner loop
    stops when pi of the gradient of L is below omega_k (tightening by 10 per outer iteration down to
    ``gradient_tol``) or when the model predicts no decrease above the rounding of L.
Converged: |c|_inf <= tol and pi of the gradient of the Lagrangian R + lam^T c is <= its target
    (gradient_tol), confirmed by the KKT distance of contract.optimality <= kkt_tol, the measure
    every solver's status uses. Past its confirmed start, the solve holds c to tol or, where
    larger, to c's rounding level at the point it starts from (contract.feasibility), which its
    message then says. Where pi is small but the distance is not
    (a flat valley along the bilinear fibres stiffness x (kbar - kappa*)), the target is tightened
    1000-fold (counted as ``tightened``) and the outer loop goes on.
Newton-SQP: Gauss-Newton omits lam^T c''. Where the internal forces are not fixed by statics (a tip
    or a pin held, so the supports' reactions are unknowns too), the feasible set's curvature is what
    the optimum trades along, and the inner solves crawl at a feasible p (5000 steps left the cable
    clamped at both ends 3e-5 above the optimum in R). So after NEWTON_AFTER outer iterations in a
    row whose inner solves stepped and ended at a feasible p whose KKT distance is still above
    kkt_tol, NEWTON_STEPS steps of SQP with the exact Hessian of the Lagrangian
    W = diag(w) + sum lam_r c_r'' (Problem.constraint_hessian_entries; the least-squares multipliers
    at the start, then each step's own; one band LU each, a second-order correction back to c = 0)
    are tried (counted as ``newton_sqp``), first with each step bounded: the QP of the step with the
    box (lower <= p + d <= upper) by primal-dual active-set rounds on the saddle system
    (outer_loop.bounded_newton_step), where the equality step on the working set, clipped to the box,
    reached other KKT points (horizontal(200, pins=[100]): R 3.3% above Ipopt's, which the bounded
    steps reach), then, if those fail, with the equality steps; their
    point is taken if it passes the convergence test without raising R above its start's plus the
    first-order cost of reaching c = 0 from there (_newton_sqp). A KKT point that raised R is kept
    all the same (the one with the least R, _newton_attempt), and it is the answer if the loop then
    ends without converging (a strand with a tight curvature budget crawled to max_outer above
    Newton's point in R). Once the attempts are used up, CRAWL_ROUNDS such outer iterations in a row
    end the solve (max_iterations, or that kept point): Gauss-Newton then crawls at the feasible p
    until max_outer, and no solve of the strands measured converged after such a run (benchmarks/
    RESULTS.md, 2026-12-05, twenty-sixth session). The same is
    tried where the constraint stalls near feasibility (|c|_inf <= NEWTON_NEAR) and the SQP step
    below fails: on strands of 1000 and more vertices that step (diagonal W) is useless, and the
    larger mu that followed made Gauss-Newton crawl along the soft modes at |c|_inf ~1e-8, within
    the rounding of c there (84 Gauss-Newton steps on groom(4, 2000, seed=1), 25 with Newton tried
    there, same optima to 4e-12 in R). At most NEWTON_ATTEMPTS per solve. (Tried sooner, Newton ends
    at other KKT points: from the linear start with R up to 2e-4 higher than Ipopt's; from
    |c|_inf = 6e-4 on a strand resting on a head, 1.2e-5 higher than where Gauss-Newton goes.
    Gauss-Newton on L brings p into the right basin first.) NEWTON_STEPS = 30: the halved steps of
    a long strand with a pinned tip converge in about 20. An attempt whose full steps fail is
    repeated at once with each step halved until the corrected point keeps |c|_inf within
    NEWTON_GROWTH of where the step started (_newton_trial): the full step can be far off where
    the reduced Hessian is indefinite; on horizontal(n=400, tip="pinned") it left |c|_inf 1.5e3,
    every attempt failed, and Gauss-Newton crawled into max_iterations (R 5.25e-4, KKT distance
    0.16), where the halved steps converge (R 3.52e-4). Halving every attempt instead doubled the
    Newton steps of 2000-vertex grooms and moved one to another KKT point (R +2.6e-5).
Stall: the rounding estimate of L can be too optimistic, and accepted steps that lower L by less than
    its rounding make no progress; STALL of them in a row end the inner loop, and on a feasible p the
    KKT distance decides convergence.
Crawl: an inner solve ends after INNER_STEPS Gauss-Newton steps and the outer loop decides (the SQP
    step, lam, mu); the infeasibility test still needs inner solves that reach the stationary point
    of |c|, which 30 steps allow. Near feasibility (|c|_inf <= CRAWL_NEAR tol) it ends sooner, once
    CRAWL_WINDOW steps in a row reduced neither |c|_inf nor pi by 10% (_crawls): on long strands
    the soft bending modes make Gauss-Newton crawl there, and what ends a crawl is the outer loop's
    SQP or Newton-SQP step, tried after one such round at a feasible p (NEWTON_AFTER = 1): the
    strands of groom(2, 2000, seed=0) took 20.5 Gauss-Newton steps instead of 123 (measurements
    in benchmarks/RESULTS.md, 2026-12-02).
Infeasible: for a strand held by its root alone whose rest system is square, the least rest change
    fixes what every element must carry, and where a vertex needs a bend multiplier above its box
    or an edge's boxes cannot carry its stretch force, no p in the box balances the strand
    (statics_start.unbalanceable, a certificate checked once at the start, exact up to a 1e-6
    margin on the multiplier): the best effort below starts at once, from the linear start and
    p0, and the message names those elements and the bend bound that would hold them. (On a
    2000-vertex long hair the augmented Lagrangian otherwise took three quarters of the solve to
    find out.)
    Elsewhere, once mu has reached 10^4 mu0 and either the best box-constrained Gauss-Newton step for
    |c|^2 alone reduces |c| by less than 1% (p is a stationary point of the constraint violation
    inside the box) or |c|_inf is still above STALLED_VIOLATION (the penalty crawls), the best effort
    takes over (least_residual): the parameters inside the box with the least residual
    force |c|^2 (each DOF's force over its weight: weighted least squares), then, among those with
    the same forces, the stiffest the boxes allow (rest_change.stiffest): at equal residual force
    stiffness is what reduces the sag, which is what a user sees (it halved the static sag of the
    least-R choice on some long-hair strands; measurements in benchmarks/RESULTS.md). If the least
    residual balances gravity after all, the augmented Lagrangian goes on from it. The message names
    the bounds that bind (the blocks and vertices whose relaxation would reduce |c|), so a user knows
    what to relax. Where neither holds (|c|_inf small, no certificate) and |c|_inf has not halved
    over STALLED_TESTS such tests (mu grown 10^5-fold meanwhile), the solve ends max_iterations
    at once, and a default solve takes its other start, where the penalty would crawl on for hundreds
    of Gauss-Newton steps; no converged held strand measured took more than 2 such tests
    (benchmarks/RESULTS.md, 2026-12-05, twenty-eighth session).
The measurements behind these choices are in benchmarks/RESULTS.md.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from sagfree.contract.feasibility import feasibility_tolerance, raised_note
from sagfree.contract.optimality import (KKT_TOL, TOL, gradient_scale, kkt_optimality, scaled_projected_gradient,
                                         working_set)
from sagfree.contract.result import Result, make_result, summed_iterations
from sagfree.formulation.jacobian import StrandJacobian
from sagfree.formulation.parameters import CONTACT_BLOCK, REST_BLOCKS, STIFFNESS_BLOCKS, STRAND_BLOCK
from sagfree.formulation.problem import Problem
from sagfree.formulation.rest_change import spread_rest_change, stiffest
from sagfree.linalg import lapack
from sagfree.linalg.band import BorderedBand, column_norms, gram
from sagfree.linalg.saddle import SaddleFactor, band_order, constrained_step
from sagfree.linalg.square import square_column_solve
from sagfree.linalg.timing import LINEAR_ALGEBRA, timed

from . import gauss_newton, outer_loop
from .gauss_newton import (ARMIJO, CRAWL, CRAWL_DROP, CRAWL_NEAR, CRAWL_WINDOW, CURVATURE_NEAR, DAMPING, INNER_STEPS,
                           MAX_ITERATIONS, MAX_SECONDS, NO_PROGRESS, NONMONOTONE, QP_FAILED, ROUNDING, STALL, TARGET,
                           InnerState)
from .least_residual import least_residual
from .mprgp import PRECONDITIONERS, on_previous_bounds, solve_box_qp
from .multipliers import least_squares_multipliers
from .outer_loop import (CRAWL_ROUNDS, MIN_TARGET, NEWTON_AFTER, NEWTON_ATTEMPTS, NEWTON_GROWTH, NEWTON_HALVINGS,
                         NEWTON_NEAR, NEWTON_STEPS, SQP_DECREASE, feasibility_cost)
from .confirmed_start import confirmed_start, corrected
from .reaction_start import applies as reaction_applies, reaction_start
from .statics_start import square_rest_system, statics_start, unbalanceable

STALLED_VIOLATION = 1e-3  # |c|_inf above which a penalty of 1e4 mu0 hands over to least_residual
#: infeasibility tests without a certificate over which |c|_inf must fall below STALLED_DROP of where it
#: was, or the solve ends (module docstring, Infeasible): no converged strand measured took more than 2
STALLED_TESTS, STALLED_DROP = 5, 0.5
#: how an infeasibility message tells the user to relax the bounds (API and command line)
RELAX = ("Relax those bounds (bounds={block: (lower, upper)}, or curvature_budget / twist_budget for the "
         "rest-shape boxes; command line: --bound BLOCK=LO,HI or --bound curvature_budget=VALUE)")


class _Model:
    """The regularizer's data, the merit function L and the Gauss-Newton Hessian of one problem."""

    def __init__(self, problem: Problem):
        self.w, self.p0 = problem.layout.weights, problem.layout.p0
        self.border = 1 if STRAND_BLOCK in problem.blocks else 0

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


def solve_alm(problem: Problem, tol: float = TOL, kkt_tol: float = KKT_TOL, max_iterations: int = 600,
              max_seconds: float = np.inf, p_start=None, gradient_tol: float = 1e-6, max_outer: int = 60,
              mu0: float = 100.0, mu_growth: float = 10.0, omega0: float = 1.0,
              preconditioner: str = "cholesky", qp_rtol: float = 1e-10, start: str = "auto") -> Result:
    """Solve ``problem`` with our augmented Lagrangian solver; see the module docstring.

    Common options (contract.options): tol, kkt_tol, max_iterations (Gauss-Newton steps),
    max_seconds (checked before each Gauss-Newton step), p_start (clipped into the box; overrides
    ``start``).
    asc's own: gradient_tol: target of the scaled projected gradient of the Lagrangian (the inner
    stopping test, before the KKT distance confirms). max_outer: augmented Lagrangian iterations.
    mu0, mu_growth, omega0: the penalty's floor and growth, the first inner target. preconditioner:
    "cholesky" (active-set Cholesky), "jacobi" or "none". qp_rtol: relative tolerance of the box
    QPs. start: "auto" starts per-element stiffness from linear_start, which for a strand held by
    its root alone is the optimum (solvers.statics_start), from the optimum over the held points'
    reactions for a pinned tip or pins (solvers.reaction_start; p0 where it finds none), from p0
    with bodies (module docstring, Start), and where that solve ends max_iterations, from the
    other start; "linear" the least rest change spread into the boxes without those last steps (the
    Gauss-Newton loop's own path, for comparisons and tests; p0 with bodies) and without the
    second start; "p0" from p0 alone.
    """
    if start not in ("auto", "linear", "p0"):
        raise ValueError(f"start must be 'auto', 'linear' or 'p0', got {start!r}")
    options = dict(tol=tol, kkt_tol=kkt_tol, max_iterations=max_iterations, gradient_tol=gradient_tol,
                   max_outer=max_outer, mu0=mu0, mu_growth=mu_growth, omega0=omega0, preconditioner=preconditioner,
                   qp_rtol=qp_rtol)
    clock = time.perf_counter()
    result = _solve_from(problem, p_start, start, max_seconds=max_seconds, **options)
    other = _other_start(problem) if p_start is None and start == "auto" else None
    seconds, steps = max_seconds - (time.perf_counter() - clock), max_iterations - result.iterations["gauss_newton"]
    if result.status != "max_iterations" or other is None or not seconds > 0 or steps <= 0:
        return result
    # the other start (module docstring, Start) with what is left of the budgets: its answer if it converges
    retry = _solve_from(problem, None, other, max_seconds=seconds, **{**options, "max_iterations": steps})
    counts = summed_iterations(result.iterations, retry.iterations)
    first, then = ("the linear start", "p0") if other == "p0" else ("p0", "the linear start")
    if retry.status == "converged":
        return dataclasses.replace(retry, iterations=counts, time=result.time + retry.time,
                                   history=result.history + retry.history,
                                   message=f"{retry.message}, from {then} ({first} ended max_iterations)")
    return dataclasses.replace(result, iterations=counts, time=result.time + retry.time,
                               message=f"{result.message}; from {then} too: {retry.message}")


def zero_counts() -> dict[str, int]:
    """asc's Result.iterations before a solve: every kind it counts, at zero, in its order."""
    return dict(outer=0, gauss_newton=0, cg=0, expansion=0, proportioning=0, active_set=0, interior=0,
                factorizations=0, factored_rows=0, line_search=0, corrected=0, sqp=0, tightened=0, least_residual=0,
                newton_sqp=0, reaction_values=0)


def _other_start(problem: Problem) -> str | None:
    """The start a default solve (start "auto") that ended max_iterations tries next: p0 after the
    linear start or the reaction search, the linear start after p0 where it applies, else None."""
    first = _resolved_start(problem, "auto")
    if first != "p0" and (first != "reaction" or reaction_start(problem) is not None):
        return "p0"
    return "linear" if _resolved_start(problem, "linear") == "linear" else None


def _resolved_start(problem: Problem, start: str) -> str:
    """Where a solve with option ``start`` begins: "p0", "linear" (the least rest change spread into
    the boxes), "auto" (the same, at the statics optimum where it applies) or "reaction" (the optimum
    over the held points' reactions, solvers.reaction_start; p0 where that search finds none), by
    the rule of the module docstring (Start). The linear start needs per-element stiffness to spread
    into and no bodies (whose supports it would clip); "auto" begins at the reaction search where the
    strand is held at a point besides its root (a pinned tip, pins) and that applies, else at p0
    there."""
    if (start == "p0" or problem.layout.stiffness != "element" or CONTACT_BLOCK in problem.blocks
            or not any(b in problem.blocks for b in STIFFNESS_BLOCKS)):
        return "p0"
    if start == "auto" and (problem.strand.tip == "pinned" or len(problem.strand.pins)):
        return "reaction" if reaction_applies(problem) else "p0"
    return start


def _solve_from(problem: Problem, p_start, start: str, tol: float, kkt_tol: float, max_iterations: int,
                max_seconds: float, gradient_tol: float, max_outer: int, mu0: float, mu_growth: float,
                omega0: float, preconditioner: str, qp_rtol: float) -> Result:
    """solve_alm from ``p_start`` or, if None, from the start named by ``start``."""
    clock = time.perf_counter()
    if preconditioner not in PRECONDITIONERS:
        raise ValueError(f"preconditioner must be one of {tuple(PRECONDITIONERS)}, got {preconditioner!r}")
    history: list[float] = []
    requested = tol  # raised below to c's rounding level where that is larger (contract.feasibility)
    lower, upper = problem.layout.lower, problem.layout.upper
    model = _Model(problem)
    counts = zero_counts()
    attempts = feasible_rounds = 0
    tested: list[float] = []  # |c|_inf at each infeasibility test without a certificate (_stalled_message)
    # the start, its KKT distance and its Result's stability (whose seconds make_result's time
    # leaves out) from one compiled call (solvers.confirmed_start)
    confirmed, measured = None, 0.0
    kept = None  # Newton-SQP's KKT point that raised R, (p, c, distance): the answer if the loop ends short

    def done(violation, distance):  # the converged message: with the tolerance raised only where it took that
        held = requested if violation <= requested else tol
        return converged_message(violation, distance, held, kkt_tol, counts["outer"],
                                 counts["gauss_newton"]) + raised_note(requested, held)

    def finish(status, message):
        if kept is not None and status != "converged":  # module docstring, Newton-SQP
            violation = float(np.abs(kept[1]).max(initial=0.0))
            history.append(violation)
            message = (f"{done(violation, kept[2])}; Newton-SQP's KKT point, kept: the augmented Lagrangian ended "
                       f"{status} above it")
            return make_result(problem, kept[0], "asc", "converged", message, counts,
                               time.perf_counter() - clock - measured, history)
        if status != "converged":  # its targets are the raised tolerance
            message += raised_note(requested, tol)
        return make_result(problem, p, "asc", status, message, counts, time.perf_counter() - clock - measured,
                           history)

    def converged_at(violation, distance):
        return finish("converged", done(violation, distance))

    reaction = None
    if p_start is None:
        p_start = problem.p0
        resolved = _resolved_start(problem, start)
        reaction = reaction_start(problem, counts) if resolved == "reaction" else None
        if reaction is not None:  # held at points besides the root: the optimum over their reactions
            p_start, history = reaction, [start_violation(problem)]
        elif resolved not in ("p0", "reaction"):
            confirmed = confirmed_start(problem, tol, kkt_tol) if start == "auto" else None
            linear = confirmed.p if confirmed is not None else linear_start(problem, optimal=start == "auto")
            if linear is not None:
                p_start, history = linear, [start_violation(problem, confirmed)]
    if confirmed is not None and confirmed.violation <= tol and confirmed.distance <= kkt_tol:
        # the start is the optimum, confirmed (the common case): its p is inside the box already
        p, measured = confirmed.p, confirmed.stability_seconds
        history.append(confirmed.violation)
        return converged_at(confirmed.violation, confirmed.distance)
    p = np.clip(np.asarray(p_start, dtype=float), lower, upper)
    target = gradient_tol  # inner target; tightened when the KKT distance disagrees
    c, J = problem.residual(p), problem.strand_jacobian(p)
    violation = float(np.abs(c).max(initial=0.0))
    tol = feasibility_tolerance(problem, p, tol, J)
    if violation <= tol and (confirmed is None or confirmed.distance <= kkt_tol):
        # another start at the optimum, or the confirmed start within c's rounding: confirmed at once
        distance = kkt_optimality(problem, p) if confirmed is None else confirmed.distance
        if distance <= kkt_tol:
            history.append(violation)
            return converged_at(violation, distance)
        # the reaction search's end at a kink of its Phi: a few SQP steps to the KKT point (confirmed_start)
        fixed = corrected(problem, p, requested, kkt_tol, counts) if reaction is not None else None
        if fixed is not None:
            p, violation, distance = fixed
            history.append(violation)
            return converged_at(violation, distance)
    change = problem.remembered("least rest change") if start == "auto" and history else None
    certificate = unbalanceable(problem, change) if change is not None else None
    if certificate:  # no p in the box balances the strand: the best effort at once (module docstring, Infeasible)
        history.append(violation)
        p, c, J, verdict = _best_effort(problem, [p, problem.p0], counts, qp_rtol, tol, history,
                                        certificate=certified(certificate))
        if verdict:
            return finish("infeasible", verdict)
        violation = history.pop()  # within tol after all: the loop goes on from there (and records it)
    mu, omega = _initial_penalty(mu0, problem.objective(p), c), omega0
    scale = gradient_scale(model.w, J)
    lam = np.zeros(int(problem.free.sum()))
    if history:  # started from the linear start: its least-squares multipliers (linear_start)
        estimate = least_squares_multipliers(model.w * (p - model.p0), J, scale, p, lower, upper)
        lam = estimate if np.all(np.isfinite(estimate)) else lam
    history = history + [violation]
    previous_violation = np.inf
    at_lower, at_upper = p <= lower, p >= upper
    nearby = None  # the last SQP step's factorization while p is its point (kkt_optimality)
    compiled = gauss_newton.available(problem)
    compiled_outer = outer_loop.available(problem)

    while counts["outer"] < max_outer:
        event = None
        if compiled_outer:
            # the outer iterations in one compiled call, up to an event (solvers.outer_loop)
            stop = outer_loop.outer_iterations(
                problem, model, p, c, J, scale, lam, at_lower, at_upper, mu, omega, target, previous_violation,
                feasible_rounds, attempts, nearby, tol, kkt_tol, gradient_tol, max_outer, max_iterations,
                clock + max_seconds, mu0, mu_growth, qp_rtol, preconditioner, counts, history, kept)
            (p, c, J, scale, lam, at_lower, at_upper, mu, omega, target, previous_violation, feasible_rounds,
             attempts, nearby) = (stop.p, stop.c, stop.J, stop.scale, stop.lam, stop.at_lower, stop.at_upper, stop.mu,
                                  stop.omega, stop.target, stop.previous_violation, stop.feasible_rounds,
                                  stop.attempts, stop.nearby)
            kept = stop.kept
            violation, distance, converged, stalls = stop.violation, stop.distance, stop.converged, stop.stalls
            event = stop.event
            if event == outer_loop.OUT_OF_OUTER:
                break
            if event == outer_loop.INNER_STOPPED:
                return finish(*_inner_stop(stop.reason, stop.qp_status, max_iterations, clock, counts, history))
            # the rest of this iteration (convergence, the infeasibility test) is below
        else:
            counts["outer"] += 1
            # ---- inner: Gauss-Newton on the augmented Lagrangian (compiled where it can be) ----
            steps_before = counts["gauss_newton"]
            state = InnerState(p, c, J, scale, at_lower, at_upper)
            inner = gauss_newton.inner_solve if compiled else _inner_solve_python
            reason, qp_status, optimality, stalled, moved = inner(
                problem, model, state, lam, mu, omega, tol, max_iterations, clock + max_seconds, qp_rtol,
                preconditioner, counts, history)
            p, c, J, scale, at_lower, at_upper = state.p, state.c, state.J, state.scale, state.at_lower, state.at_upper
            nearby = None if moved else nearby
            if reason in (MAX_ITERATIONS, MAX_SECONDS, QP_FAILED):
                return finish(*_inner_stop(reason, qp_status, max_iterations, clock, counts, history))

            # ---- outer: multipliers, penalty, convergence ----
            violation = float(np.abs(c).max(initial=0.0))
            unmoved = not counts["gauss_newton"] and 0.1 * optimality < omega
            if counts["gauss_newton"] == steps_before and violation > tol and (omega > target or unmoved):
                # the inner target was met without a step (the loose first one, from p0): a multiplier
                # update there only adds mu c to lam, which grew |lam| to ~1e3 in four such rounds
                # before the first step and made Gauss-Newton crawl; tighten the target instead, at once
                # as far as the next inner solves would stop without a step again (same p, lam and mu).
                # While no Gauss-Newton step has moved p, below gradient_tol too (module docstring, Start)
                if omega > target:
                    omega = max(target, 0.1 * omega)
                    while omega > target and optimality <= omega:
                        omega = max(target, 0.1 * omega)
                else:
                    sqp = _sqp_step(problem, model, p, c, J, SQP_DECREASE * violation, tol)
                    if sqp is not None:
                        p, c, J, scale, lam, nearby = _taken(problem, model, sqp, counts, history)
                    omega = 0.1 * optimality
                continue
            lam = lam + mu * c
            regularizer_gradient = model.w * (p - model.p0)
            optimality = scaled_projected_gradient(p, regularizer_gradient + J.T @ lam, scale, lower, upper)
            if violation <= tol and optimality > gradient_tol:
                # the first-order update may lag behind a feasible p: try the least-squares multipliers
                estimate = least_squares_multipliers(regularizer_gradient, J, scale, p, lower, upper)
                kkt = scaled_projected_gradient(p, regularizer_gradient + J.T @ estimate, scale, lower, upper)
                if kkt < optimality:
                    lam, optimality = estimate, kkt
            # a stalled inner loop on a feasible p: only the KKT distance can tell (below)
            converged = violation <= tol and (optimality <= gradient_tol or stalled >= STALL)
            if converged:
                # the scaled gradient can be small in a flat valley away from the optimum: confirm with
                # the KKT distance of contract.optimality, and tighten the inner target if it disagrees
                # where the inner loop reached it (the distance decides once the target is below rounding)
                distance = kkt_optimality(problem, p, nearby=nearby)
                converged = distance <= kkt_tol
                if not converged and (optimality <= target or stalled >= STALL):
                    counts["tightened"] += 1
                    target = max(1e-3 * target, MIN_TARGET)
            crawled = violation <= tol and counts["gauss_newton"] > steps_before
            feasible_rounds = feasible_rounds + 1 if crawled else 0
            stalls = violation > tol and violation > 0.25 * previous_violation
            if stalls:  # before growing mu, try the constrained step (SQP)
                sqp = _sqp_step(problem, model, p, c, J, SQP_DECREASE * violation, tol)
                if sqp is not None:
                    p, c, J, scale, lam, nearby = _taken(problem, model, sqp, counts, history)
                    previous_violation = violation
                    continue
        # Newton-SQP where Gauss-Newton crawls at a feasible p or the SQP step failed near it (module
        # docstring; the compiled loop took it already)
        if (event is None and not converged and attempts < NEWTON_ATTEMPTS
                and (feasible_rounds >= NEWTON_AFTER or (stalls and violation <= NEWTON_NEAR))):
            attempts, feasible_rounds = attempts + 1, 0
            newton, kept = _newton_attempt(problem, model, p, counts, tol, kkt_tol, kept)
            if newton is not None:
                p, c, distance = newton
                violation = float(np.abs(c).max(initial=0.0))
                history.append(violation)
                converged = True
        if converged:
            return converged_at(violation, distance)
        if attempts >= NEWTON_ATTEMPTS and feasible_rounds >= CRAWL_ROUNDS:  # the compiled loop's CRAWLED
            return finish("max_iterations", _crawl_message(problem, p, violation, counts["outer"], tol, kkt_tol))
        if stalls:
            if event is None:  # the compiled loop grew it already
                mu *= mu_growth
            if mu >= 1e4 * mu0:
                verdict = _infeasibility(problem, p, c, J, lower, upper)
                if verdict or violation > STALLED_VIOLATION:
                    p, c, J, verdict = _best_effort(problem, [p, problem.p0], counts, qp_rtol, tol, history,
                                                    fallback=verdict)
                    if verdict:
                        return finish("infeasible", verdict)
                    # the least residual balances gravity after all: go on from there
                    nearby, scale = None, gradient_scale(model.w, J)
                    estimate = least_squares_multipliers(model.w * (p - model.p0), J, scale, p, lower, upper)
                    lam = estimate if np.all(np.isfinite(estimate)) else np.zeros_like(lam)
                    mu = _initial_penalty(mu0, problem.objective(p), c)
                else:  # no certificate, |c| small: stalled where the violation no longer falls (module docstring)
                    tested.append(violation)
                    if len(tested) > STALLED_TESTS and violation > STALLED_DROP * tested[-1 - STALLED_TESTS]:
                        return finish("max_iterations", _stalled_message(tested, counts["outer"], mu_growth))
        previous_violation = violation
        omega = max(target, 0.1 * omega)
    return finish("max_iterations", _max_outer_message(problem, p, history[-1], max_outer, tol, kkt_tol))


def _stalled_message(tested: list[float], outer: int, mu_growth: float) -> str:
    """The message of a solve ended where |c|_inf stalled over STALLED_TESTS infeasibility tests
    without a certificate (module docstring, Infeasible)."""
    return (f"stopped after {outer} outer iterations: |c|_inf = {tested[-1]:.3g} fell by only "
            f"{1.0 - tested[-1] / tested[-1 - STALLED_TESTS]:.1%} over the last {STALLED_TESTS} infeasibility tests "
            f"while the penalty grew {mu_growth ** STALLED_TESTS:.3g}-fold, and no certificate says the boxes cannot "
            "balance the strand: the augmented Lagrangian is stuck at a point that is not in equilibrium; another "
            "solver may find one (solver='ipopt'; command line: --solver ipopt)")


def _inner_stop(reason: int, qp_status: str, max_iterations: int, clock: float, counts: dict,
                history: list) -> tuple[str, str]:
    """(status, message) of a solve whose inner solve stopped at a limit or failed (``reason``)."""
    if reason == MAX_ITERATIONS:
        return "max_iterations", (f"stopped after {max_iterations} Gauss-Newton steps with |c|_inf = "
                                  f"{history[-1]:.3g}; raise max_iterations (command line: --option max_iterations=N)")
    if reason == MAX_SECONDS:
        return "max_iterations", (f"stopped after {time.perf_counter() - clock:.3g} s (max_seconds) and "
                                  f"{counts['gauss_newton']} Gauss-Newton steps with |c|_inf = {history[-1]:.3g}")
    return "failed", f"the Gauss-Newton QP failed ({qp_status}) at step {counts['gauss_newton']}"


def _crawl_message(problem: Problem, p, violation: float, outer: int, tol: float, kkt_tol: float) -> str:
    """The message of a solve whose Gauss-Newton steps crawled at a feasible p for CRAWL_ROUNDS outer
    iterations after its last Newton-SQP attempt (module docstring, Newton-SQP)."""
    return (f"stopped after {outer} outer iterations at a feasible point (|c|_inf = {violation:.3g} <= {tol:.3g}) "
            f"whose KKT distance {kkt_optimality(problem, p):.3g} stays above {kkt_tol:g}: Gauss-Newton crawled "
            f"there for {CRAWL_ROUNDS} outer iterations after the last Newton-SQP attempt; loosen kkt_tol to accept "
            "it (command line: --option kkt_tol=X)")


def _max_outer_message(problem: Problem, p, violation: float, max_outer: int, tol: float, kkt_tol: float) -> str:
    """The message of a solve that ran out of outer iterations: at a feasible p (in equilibrium,
    as some strands with a held tip end) what is left is its KKT distance, which the message gives
    so a user can judge the answer; elsewhere |c|_inf."""
    if violation <= tol:
        return (f"stopped after {max_outer} outer iterations at a feasible point (|c|_inf = {violation:.3g} <= "
                f"{tol:.3g}) whose KKT distance {kkt_optimality(problem, p):.3g} stays above {kkt_tol:g}; raise "
                "max_outer or kkt_tol (command line: --option max_outer=N or --option kkt_tol=X)")
    return (f"stopped after {max_outer} outer iterations with |c|_inf = {violation:.3g} (target {tol:.3g}); raise "
            "max_outer (command line: --option max_outer=N)")


def converged_message(violation: float, distance: float, tol: float, kkt_tol: float, outer: int,
                      gauss_newton: int) -> str:
    """The message of a converged asc solve (also of the stabilization's compiled re-solves,
    frontend.stabilize)."""
    return (f"|c|_inf = {violation:.2e} <= {tol:.3g} and KKT distance {distance:.2e} <= {kkt_tol:g} after {outer} "
            f"outer and {gauss_newton} Gauss-Newton iterations")


def _inner_solve_python(problem: Problem, model: _Model, state: InnerState, lam, mu: float, omega: float,
                        tol: float, max_iterations: int, deadline: float, qp_rtol: float, preconditioner: str,
                        counts: dict, history: list) -> tuple[int, str, float, int, bool]:
    """solvers.gauss_newton.inner_solve in Python, step for step (the same p, bit for bit): for
    problems whose model the compiled loop cannot evaluate (stencils not compiled, bodies)."""
    lower, upper = problem.layout.lower, problem.layout.upper
    p, c, J, scale = state.p, state.c, state.J, state.scale
    recent: list[float] = []
    stalled, moved = 0, False
    steps_before = counts["gauss_newton"]
    progress: list[tuple[float, float]] = []  # (|c|_inf, pi) before each step of this inner solve
    reason, qp_status = TARGET, ""
    curved = gauss_newton.curvature_applies(problem, model.border)
    while True:
        gradient = model.w * (p - model.p0) + J.T @ (lam + mu * c)
        optimality = scaled_projected_gradient(p, gradient, scale, lower, upper)
        if optimality <= omega:
            reason = TARGET
            break
        if counts["gauss_newton"] - steps_before >= INNER_STEPS:
            reason = CRAWL  # a crawling inner solve: let the outer loop (SQP step or mu) decide
            break
        progress.append((float(np.abs(c).max(initial=0.0)), optimality))
        if progress[-1][0] <= CRAWL_NEAR * tol and _crawls(progress):
            reason = CRAWL  # the same, detected sooner near feasibility (module docstring, Crawl)
            break
        if counts["gauss_newton"] >= max_iterations:
            reason = MAX_ITERATIONS
            break
        if time.perf_counter() >= deadline:
            reason = MAX_SECONDS
            break
        counts["gauss_newton"] += 1
        # warm start: the bounds active in the previous step's QP are active again
        d_lower, d_upper = lower - p, upper - p
        start_step = on_previous_bounds(state.at_lower, state.at_upper, d_lower, d_upper)
        curvature = (problem.constraint_hessian_entries(p, lam + mu * c)  # gauss_newton.curved_hessian
                     if curved and progress[-1][0] <= CURVATURE_NEAR else None)
        for damping in DAMPING:  # escalate only if rounding breaks the factorization
            hessian = model.hessian(J, mu, damping)
            if curvature is not None:
                exact = gauss_newton.curved_hessian(hessian.band, *curvature)
                hessian = BorderedBand(exact, hessian.border, hessian.corner) if exact.size else hessian
            qp = solve_box_qp(hessian, -gradient, d_lower, d_upper, x0=start_step, rtol=qp_rtol,
                              preconditioner=preconditioner)
            if qp.status != "not_positive_definite":
                break
        state.at_lower, state.at_upper = qp.x <= d_lower, qp.x >= d_upper
        for key in ("cg", "expansion", "proportioning", "active_set", "interior", "factorizations",
                    "factored_rows"):
            counts[key] += getattr(qp, key)
        if qp.status not in ("converged", "max_iterations"):
            reason, qp_status = QP_FAILED, qp.status
            break
        step, slope = qp.x, float(gradient @ qp.x)
        merit = model.merit(p, c, lam, mu)
        recent.append(merit)
        reference = max(recent[-NONMONOTONE:])
        rounding = ROUNDING * (abs(merit) + model.merit_scale(p, c, lam, mu))
        if -slope <= rounding:
            reason = NO_PROGRESS  # the model predicts no decrease above the rounding of L
            break
        alpha, accepted, corrected = 1.0, False, False
        for _ in range(40):
            counts["line_search"] += 1
            trial = np.clip(p + alpha * step, lower, upper)
            c_trial = problem.residual(trial)
            merit_trial = model.merit(trial, c_trial, lam, mu)
            if merit_trial <= reference + ARMIJO * alpha * slope + rounding:
                accepted = np.all(np.isfinite(c_trial))
                break
            if not corrected:  # the full step failed: its second-order correction before any halving
                corrected = True
                candidate = _corrected_trial(hessian, state, J, p, step, c, c_trial, mu, lower, upper)
                if candidate.size:
                    counts["line_search"] += 1
                    c_candidate = problem.residual(candidate)
                    merit_candidate = model.merit(candidate, c_candidate, lam, mu)
                    if merit_candidate <= reference + ARMIJO * slope + rounding:
                        trial, c_trial, merit_trial = candidate, c_candidate, merit_candidate
                        accepted = np.all(np.isfinite(c_trial))
                        counts["corrected"] += 1
                        break
            alpha *= 0.5
        if not accepted:
            reason = NO_PROGRESS  # no descent left at this accuracy: let the outer loop decide
            break
        stalled = stalled + 1 if merit_trial > merit - rounding else 0
        p, c, moved = trial, c_trial, True
        J = problem.strand_jacobian(p)
        scale = gradient_scale(model.w, J)
        history.append(float(np.abs(c).max(initial=0.0)))
        if stalled >= STALL:
            reason = NO_PROGRESS  # L no longer decreases above its rounding: let the outer loop decide
            break
    state.p, state.c, state.J, state.scale = p, c, J, scale
    return reason, qp_status, optimality, stalled, moved


@timed(LINEAR_ALGEBRA)
def _corrected_trial(hessian, state: InnerState, J: StrandJacobian, p, step, c, c_trial, mu, lower, upper) -> np.ndarray:
    """gauss_newton.corrected_trial (the same kernel as the compiled loop's) for the Python loop."""
    indptr, indices, data = J.csc()
    return gauss_newton.corrected_trial(hessian.band, hessian.border, hessian.corner, state.at_lower, state.at_upper,
                                        indptr, indices, data, p, step, c, np.ascontiguousarray(c_trial), float(mu),
                                        lower, upper)


def _newton_sqp(problem: Problem, model: _Model, p, counts: dict, tol: float, kkt_tol: float, halvings: int = 0,
                bounded: bool = False):
    """(p, c, KKT distance, raised) after at most NEWTON_STEPS exact-Hessian SQP steps from the
    feasible or nearly feasible p (module docstring, Newton-SQP), each bounded where ``bounded``
    (_bounded_newton_step: the step below with the box kept), or None unless they end at a point
    with |c|_inf <= tol and KKT distance <= kkt_tol. raised: R there is above R(p) plus rounding plus
    max(0, lam^T c(p)), the first-order change of R from p to c = 0 with p's least-squares
    multipliers: from an infeasible p, reaching c = 0 may cost R, and without that allowance a
    feasible point above R(p) was rejected where Gauss-Newton then crawled above it.

    Each step solves [[W_F, J_F^T], [J_F, 0]] [d_F; lam] = -[grad R_F; c] with W = diag(w) +
    sum lam_r c_r''(p) on the working set F of contract.optimality (the variables farther than 1e-6
    of their box's width from its bounds, or, where that system is singular, those not on a bound;
    linalg.saddle.SaddleFactor with the curvature, a band LU); lam is the least-squares multipliers
    at the start and then the previous step's own, as in textbook SQP (Nocedal & Wright, section
    18.1). A trial point that leaves |c|_inf > tol gets the
    least diag(w)-norm correction back to c = 0 (the same J), and with ``halvings`` > 0 the step is
    shortened as _newton_trial says. (The correction with the step's own factors, i.e. in the metric
    W, saved a factorization per step but left 2 of 6 strands of groom(6, 2000) at max_iterations;
    refining the plain system with those factors cost as much as its band LU at 2000 vertices.)
    Against least-squares multipliers at every step and every variable strictly inside its box
    (stiffness multipliers a hair above 1 then enlarge the system), a 2000-vertex strand's
    Newton-SQP phase takes a quarter less time for as many steps (benchmarks/RESULTS.md).
    """
    lower, upper = problem.layout.lower, problem.layout.upper
    start_objective = problem.objective(p)
    x, lam = p.copy(), None
    for _ in range(NEWTON_STEPS):
        J = problem.strand_jacobian(x)
        c, gradient = problem.residual(x), model.w * (x - model.p0)
        free = working_set(x, lower, upper)
        if lam is None:  # the first step's; each later one takes the previous step's
            lam = least_squares_multipliers(gradient, J, gradient_scale(model.w, J), x, lower, upper)
            if not np.all(np.isfinite(lam)):
                return None
            start_objective += feasibility_cost(lam, c)
        curvature = problem.constraint_hessian_entries(x, lam)
        direction = _newton_direction(J, model.w, free, curvature, gradient, c, x, lower, upper, bounded)
        if direction is None:  # too few free directions (as in kkt_optimality): free those near a bound
            free = (x > lower) & (x < upper)
            direction = _newton_direction(J, model.w, free, curvature, gradient, c, x, lower, upper, bounded)
        if direction is None:
            return None
        step, lam, free = direction
        if not np.all(np.isfinite(step)):
            return None
        counts["newton_sqp"] += 1
        trial, c_trial = _newton_trial(problem, model.w, J, x, step, c, free, tol, halvings)
        if trial is None or not np.all(np.isfinite(c_trial)):
            return None
        x = trial
        if np.abs(c_trial).max(initial=0.0) <= tol:
            distance = kkt_optimality(problem, x)
            if distance <= kkt_tol:
                return x, c_trial, distance, not problem.objective(x) <= start_objective * (1.0 + 1e-9) + 1e-15
    return None


def _newton_attempt(problem: Problem, model: _Model, p, counts: dict, tol: float, kkt_tol: float, kept):
    """(point, kept): an attempt of Newton-SQP from p (module docstring), its bounded steps, then, if
    they fail, its full equality steps and then its halved ones; point = (p, c, KKT distance) where
    one ends at a KKT point without raising R, else None. kept: the KKT point with the least R that
    raised it, of this attempt and the earlier ``kept``."""
    for halvings, bounded in ((0, True), (0, False), (NEWTON_HALVINGS, False)):
        newton = _newton_sqp(problem, model, p, counts, tol, kkt_tol, halvings, bounded)
        if newton is not None and not newton[3]:
            return newton[:3], kept
        if newton is not None and (kept is None or problem.objective(newton[0]) < problem.objective(kept[0])):
            kept = newton[:3]
    return None, kept


def _newton_direction(J: StrandJacobian, w, free, curvature, gradient, c, x, lower, upper, bounded: bool):
    """(d, lam, free) of one Newton-SQP step from x (outer_loop._newton_direction): the bounded step
    where ``bounded`` (_bounded_newton_step), else the equality step on ``free``; None where its
    system is singular."""
    if bounded:
        return _bounded_newton_step(J, w, free, curvature, gradient, c, x, lower, upper)
    factor = SaddleFactor(J, w, free, curvature)
    if factor.singular:
        return None
    step, lam = factor.solve(gradient, c)
    return step, lam, free


@timed(LINEAR_ALGEBRA)
def _bounded_newton_step(J: StrandJacobian, w, free, curvature, gradient, c, x, lower, upper):
    """(d, lam, free) of outer_loop.bounded_newton_step (the compiled loop's kernel, so both loops
    take the same steps), or None where its first system is singular or the saddle system is not a
    band (then Newton-SQP goes on with its equality steps)."""
    indptr, indices, values = J.csc()
    position = band_order(indptr, indices, c.size)
    if position is None:
        return None
    rows, columns, entries = curvature
    found, step, lam, free = outer_loop.bounded_newton_step(
        lapack.DGBTRF, lapack.DGBTRS, indptr, indices, values, w, np.ascontiguousarray(free), position, rows, columns,
        entries, np.ascontiguousarray(gradient, dtype=float), np.ascontiguousarray(c, dtype=float), x, lower, upper)
    return (step, lam, free) if found else None


def _newton_trial(problem: Problem, w, J, x, step, c, free, tol: float, halvings: int):
    """(trial point, its c) of the Newton-SQP step from x: x + t step with the least diag(w)-norm
    correction back to c = 0 where it leaves |c|_inf > tol, t = 1 halved (at most ``halvings``
    times, the last trial kept) until the corrected point's |c|_inf is at most NEWTON_GROWTH times
    max(tol, |c(x)|_inf); (None, None) if the correction's system is singular.
    """
    lower, upper = problem.layout.lower, problem.layout.upper
    bound = NEWTON_GROWTH * max(tol, float(np.abs(c).max(initial=0.0)))
    correction_factor = None
    fraction = 1.0
    for _ in range(halvings + 1):
        trial = np.clip(x + fraction * step, lower, upper)
        c_trial = problem.residual(trial)
        if not np.abs(c_trial).max(initial=0.0) <= tol:
            correction_factor = correction_factor or SaddleFactor(J, w, free)
            if correction_factor.singular:
                return None, None
            trial = np.clip(trial + correction_factor.solve(np.zeros_like(x), c_trial)[0], lower, upper)
            c_trial = problem.residual(trial)
        if np.abs(c_trial).max(initial=0.0) <= bound:
            break
        fraction *= 0.5
    return trial, c_trial


def _sqp_step(problem: Problem, model: _Model, p, c, J, bound: float, tol: float):
    """(p, c, lam, factorization) after the equality-constrained SQP step from p, or None if it
    leaves |c|_inf > bound. The factorization (at p) serves the KKT confirmation at the new p.

    The step d minimizes the regularizer's quadratic model on the linearized constraint over the
    free variables F (kkt_optimality's first working set: farther than 1e-6 of their box's width
    from its bounds; linalg.saddle.SaddleFactor, one band LU):
        [[W_F, J_F^T], [J_F, 0]] [d_F; lam] = -[grad R_F; c],
    and lam, the multipliers of that step, replace the first-order update lam + mu c. solve_alm
    tries it where it would otherwise grow mu because |c|_inf stalled: near the solution the
    first-order update converges slowly along the soft bending modes, and the inner solves it forces
    at large mu crawl (hundreds of Gauss-Newton steps where this takes two SQP steps). Wherever
    the step leaves |c|_inf above ``tol`` (the curvature of c, the stiffness x rest-shape products),
    a second-order correction follows: the least W-norm step back to c = 0 from the trial point
    with the same J and the same factors (two triangular solves and a residual), kept where it
    lowers |c|_inf. (Applied only where the step failed its bound, half of the groom strands took
    a second SQP step and its band LU instead: |c|_inf 3e-4 -> 1e-7 -> 1e-12.) With the same F,
    the KKT confirmation at the new point refines this factorization instead of factoring its own
    (SaddleFactor.solve_nearby: one or two corrections where a band LU costs ~0.2 ms; the
    variables strictly inside their boxes differ from its set on nearly every groom strand, by
    stiffness multipliers a hair above 1). On 2000-vertex strands the step is rejected (|d|_inf
    ~0.5, |c|_inf ~1e5 after it, even at a sixteenth of it) and solve_alm tries Newton-SQP instead.
    """
    free = working_set(p, problem.layout.lower, problem.layout.upper)
    factor = SaddleFactor(J, model.w, free)
    if factor.singular:
        return None
    step, lam = factor.solve(model.w * (p - model.p0), c)
    trial = np.clip(p + step, problem.layout.lower, problem.layout.upper)
    c_trial = problem.residual(trial)
    violation = np.abs(c_trial).max(initial=0.0)
    if not violation <= tol:
        # second-order correction: the least W-norm step back to c = 0 with the same J and factors,
        # kept where it lowers |c|_inf
        correction, _ = factor.solve(np.zeros_like(p), c_trial)
        corrected = np.clip(trial + correction, problem.layout.lower, problem.layout.upper)
        c_corrected = problem.residual(corrected)
        if np.abs(c_corrected).max(initial=0.0) < violation or not violation <= bound:
            trial, c_trial = corrected, c_corrected
    if not np.abs(c_trial).max(initial=0.0) <= bound:  # also rejects NaN
        return None
    return trial, c_trial, lam, factor


def _taken(problem: Problem, model: _Model, sqp: tuple, counts: dict, history: list) -> tuple:
    """(p, c, dc/dp, gradient scale, lam, factorization) after the SQP step ``sqp`` (_sqp_step's
    answer), counted and recorded."""
    p, c, lam, nearby = sqp
    counts["sqp"] += 1
    history.append(float(np.abs(c).max(initial=0.0)))
    J = problem.strand_jacobian(p)
    return p, c, J, gradient_scale(model.w, J), lam, nearby


def _crawls(progress: list[tuple[float, float]]) -> bool:
    """True if neither |c|_inf nor the scaled projected gradient fell by CRAWL_DROP over the last
    CRAWL_WINDOW Gauss-Newton steps of an inner solve (module docstring, Crawl)."""
    if len(progress) <= CRAWL_WINDOW:
        return False
    (violation, optimality), (old_violation, old_optimality) = progress[-1], progress[-1 - CRAWL_WINDOW]
    return violation > CRAWL_DROP * old_violation and optimality > CRAWL_DROP * old_optimality


def start_violation(problem: Problem, confirmed=None) -> float:
    """|c(p0)|_inf, the first entry of the history of a solve from the linear start (also of the
    stabilization's compiled re-solves, frontend.stabilize): measured by ``confirmed`` (a
    solvers.confirmed_start.ConfirmedStart or None) where it evaluated p0."""
    if confirmed is not None and not np.isnan(confirmed.start_violation):
        return confirmed.start_violation
    return float(np.abs(problem.residual(problem.p0)).max(initial=0.0))


def _initial_penalty(mu0: float, objective: float, c: np.ndarray) -> float:
    """mu at the start: ALGENCAN's scale-free choice (Birgin & Martinez, "Practical Augmented
    Lagrangian Methods for Constrained Optimization", SIAM 2014), floored at mu0,

        mu = max(mu0, min(10 max(1, |R(p)|) / max(1, |c(p)|^2 / 2), 1e8)),

    so that the penalty term weighs about ten times the regularizer. From p0 (R = 0) it is mu0. From
    the linear start R is 1 to 1e4 (the root's stiffening) at |c|_inf ~1e-3, and with mu0 alone the
    first inner solve there gave up feasibility for R (|c|_inf back up to ~1).
    """
    return max(mu0, min(10.0 * max(1.0, abs(objective)) / max(1.0, 0.5 * float(c @ c)), 1e8))


def linear_start(problem: Problem, optimal: bool = True) -> np.ndarray | None:
    """A nearly feasible start for per-element stiffness: the least rest-shape change that balances
    gravity, spread into the boxes by stiffening where it does not fit (None if the linear system is
    singular; the solve then starts from p0).

    At p0 the rest shape is the groomed shape and the stiffness multipliers are 1; c is linear in the
    rest curvatures and twists there, and the rest lengths move by the strain that holds gravity
    (~1e-8). So one equality-constrained least-squares step on the rest blocks R,

        minimize sum_R w_j d_j^2   s.t.   c(p0) + J_R d = 0     (linalg.saddle.constrained_step),

    nearly balances gravity with no box; formulation.rest_change.spread_rest_change then stiffens
    each element just enough to bring its change into its box, keeping c. Only the root, where the
    boxes bind, starts stiffened, at |c|_inf ~1e-4 to 1e-3 with R within a few percent of the
    optimum; a start from the strand-stiffness solution (supplement section V) cost more than half of
    a strand's Gauss-Newton steps. For a strand held by its root alone that step is the only rest
    change that balances gravity (the unique solution of a square band system, _least_rest_change),
    and with ``optimal`` each element's multiplier is then chosen as the optimum's
    (solvers.statics_start): the start is the optimum, which solve_alm only confirms.
    """
    change = problem.bound_independent("least rest change", lambda: _least_rest_change(problem))
    if change is None:
        return None
    optimum = statics_start(problem, change) if optimal else None  # held by its root alone: the optimum
    return optimum if optimum is not None else spread_rest_change(problem, change)


def _least_rest_change(problem: Problem) -> np.ndarray | None:
    """linear_start's step d (None where its system is singular): where the rest columns that act
    are square (statics_start.square_rest_system) d is the unique solution of J_R d = -c(p0), one
    band LU of J_R (linalg.square); elsewhere the saddle system of the least diag(w)-norm change."""
    layout = problem.layout
    J, c, rest = problem.strand_jacobian(layout.p0), problem.residual(layout.p0), layout.block_mask(REST_BLOCKS)
    if square_rest_system(problem):
        change = square_column_solve(J, rest & (column_norms(J) > 0), -c)
        if change is not None:
            return change
    step = constrained_step(J, layout.weights, np.zeros(problem.n_parameters), c, rest)
    return step[0] if step is not None and np.all(np.isfinite(step[0])) else None


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
            f"balance gravity). Binding: {details or 'none identified'}. {RELAX}")


def certified(certificate: str) -> str:
    """The infeasibility message of a strand statics_start.unbalanceable certifies."""
    return f"infeasible within bounds: no parameters inside the box balance gravity, {certificate}. {RELAX}"


def _best_effort(problem: Problem, starts: list[np.ndarray], counts: dict, qp_rtol: float, tol: float,
                 history: list, certificate: str | None = None, fallback: str | None = None):
    """(p, c, J, message) after the best effort from ``starts`` (least_residual; its |c|_inf appended
    to ``history``): where it leaves |c|_inf > tol, p the stiffest among the least-residual points
    (rest_change.stiffest) and the ``infeasible`` message (the ``certificate``'s, else the bounds
    that bind there, else ``fallback``) with what the best effort did; else the least-residual
    point, c and J there, and None (it balances gravity after all)."""
    lower, upper = problem.layout.lower, problem.layout.upper
    p = least_residual(problem, starts, counts, qp_rtol)
    c, J = problem.residual(p), problem.strand_jacobian(p)
    history.append(float(np.abs(c).max(initial=0.0)))
    if history[-1] <= tol:
        return p, c, J, None
    verdict = certificate or _infeasibility(problem, p, c, J, lower, upper) or fallback or (
        f"infeasible within bounds: |c|_inf stalls at {history[-1]:.3g} (a local minimum of the residual inside "
        "the box)")
    return (stiffest(problem, p), c, J,
            verdict + "; best effort: the least residual force the box allows, at the largest stiffness it allows")
