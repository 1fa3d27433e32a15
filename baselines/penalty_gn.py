"""The `penalty-gn` baseline: the predecessor method (Takahashi & Batty, "Rest shape optimization for
sag-free discrete elastic rods", CGF; DESIGN section 6).

Rest shape only (rest lengths, curvatures, twists; stiffness stays as specified), and no hard
constraints: Gauss-Newton on

    F(p) = rho/2 f^T M^-1 f / (m g^2) + R(p) + kappa/2 sum_j (max(0, p_j - upper_j)^2 + max(0, lower_j - p_j)^2)

with f = S f(q*, p) the residual force on the free DOFs, M the lumped masses on positions and the
edge inertias rho_s pi r^4 l / 2 on the twist angles, m g^2 (strand mass times g^2) making the force
term unit-free, and quadratic penalties for the boxes. In terms of the unit-free residual
c = D^-1 S f (D: m_i g on positions, m_edge l g on angles) the force term is rho/2 sum_i mu_i c_i^2
with mu_i = D_i^2 / (M_i m g^2): the vertex's share of the strand mass on positions,
2 (m_edge / m) (l / r)^2 on angles.

The Gauss-Newton normal matrix rho J^T diag(mu) J + diag(w) + kappa diag(bound violated) is banded; it
is factored by the banded Cholesky of sagfree.linalg (with a relative Levenberg-Marquardt damping of
1e-13 of its diagonal, as in our solver) and an Armijo backtracking line search on F sets the step.

A minimizer of F is not an equilibrium: where the boxes bind (or gravity needs stiffness) the force
term is only traded off against the penalties, so a residual force remains and boxes may be violated.
The Result reports it as it is: status ``converged`` only by the common rule (|c|_inf <= tol and KKT
distance <= kkt_tol), otherwise ``failed`` with
the residual and the largest box violation in the message. Result.p is in the caller's Problem layout
(stiffness entries at p0) and is not clipped into the box.
"""
from __future__ import annotations

import time

import numpy as np

from sagfree.contract.feasibility import judged_tolerance, raised_note
from sagfree.contract.optimality import KKT_TOL, TOL, kkt_optimality
from sagfree.contract.result import Result, make_result
from sagfree.formulation import dofs
from sagfree.formulation.parameters import REST_BLOCKS
from sagfree.formulation.problem import Problem
from sagfree.linalg.band import gram
from sagfree.linalg.cholesky import band_cholesky, band_solve

ARMIJO = 1e-4
DAMPING = 1e-13


def force_weights(problem: Problem) -> np.ndarray:
    """mu_i = D_i^2 / (M_i m g^2) per free DOF (see the module docstring)."""
    strand, n = problem.strand, problem.n_vertices
    g = float(np.linalg.norm(problem.gravity)) or dofs.STANDARD_GRAVITY
    edge_mass = strand.density * np.pi * strand.radius**2 * problem.edge_lengths
    inertia = np.empty(dofs.dof_count(n))
    inertia[dofs.position_index(n)] = problem.masses[:, None]
    inertia[dofs.theta_index(n)] = 0.5 * edge_mass * strand.radius**2
    mu = problem.row_scale**2 / (inertia * edge_mass.sum() * g**2)
    return mu[problem.free]


def _objective(rest: Problem, p, c, mu, rho, kappa) -> float:
    over = np.maximum(p - rest.layout.upper, 0.0) + np.maximum(rest.layout.lower - p, 0.0)
    return 0.5 * rho * float(mu @ (c * c)) + rest.objective(p) + 0.5 * kappa * float(over @ over)


def _to_rest_layout(problem: Problem, rest: Problem, p: np.ndarray) -> np.ndarray:
    p_rest = rest.p0
    for block, ix in rest.blocks.items():
        if block in problem.blocks:
            p_rest[ix] = p[problem.blocks[block]]
    return p_rest


def _to_caller_layout(problem: Problem, rest: Problem, p_rest: np.ndarray) -> np.ndarray:
    p = problem.p0
    for block, ix in rest.blocks.items():
        if block in problem.blocks:
            p[problem.blocks[block]] = p_rest[ix]
    return p


def solve_penalty_gn(problem: Problem, tol: float = TOL, kkt_tol: float = KKT_TOL, max_iterations: int = 200,
                     max_seconds: float = np.inf, p_start=None, force_weight: float = 1e6,
                     box_weight: float = 1e6, rtol: float = 1e-12) -> Result:
    """Minimize the predecessor's penalty objective over the rest shape from p0 (module docstring).

    Common options (contract.options): max_iterations counts Gauss-Newton steps; max_seconds is
    checked before each; p_start gives the rest-shape entries of the start (the caller's layout; not
    clipped, as the boxes are penalties here).
    penalty-gn's own: force_weight: rho; box_weight: kappa; rtol: stops when a step changes F by less
    than rtol |F|."""
    clock = time.perf_counter()
    rest = problem.with_options(stiffness="fixed",
                                optimize=tuple(b for b in REST_BLOCKS if b in problem.options["optimize"]))
    if rest.n_parameters == 0:
        raise ValueError("penalty-gn optimizes the rest shape only, and the problem optimizes none of "
                         f"{REST_BLOCKS}")
    lower, upper, w = rest.layout.lower, rest.layout.upper, rest.layout.weights
    mu = force_weights(rest)
    p = rest.p0 if p_start is None else _to_rest_layout(problem, rest, np.asarray(p_start, dtype=float))
    c = rest.residual(p)
    value = _objective(rest, p, c, mu, force_weight, box_weight)
    counts = dict(gauss_newton=0, line_search=0)
    history = [float(np.abs(c).max(initial=0.0))]
    reason = f"reached max_iterations = {max_iterations}"
    while counts["gauss_newton"] < max_iterations:
        if time.perf_counter() - clock >= max_seconds:
            reason = f"reached max_seconds = {max_seconds:g}"
            break
        counts["gauss_newton"] += 1
        J = rest.jacobian(p)
        violated = (p > upper) | (p < lower)
        over = np.maximum(p - upper, 0.0) - np.maximum(lower - p, 0.0)
        gradient = force_weight * (J.T @ (mu * c)) + w * (p - rest.layout.p0) + box_weight * over
        weighted = J.multiply(np.sqrt(mu)[:, None]).tocsc()
        hessian = gram(weighted, w + box_weight * violated, force_weight, 0).band
        hessian[0] *= 1.0 + DAMPING
        factor = band_cholesky(hessian)
        if factor is None:
            reason = "the Gauss-Newton matrix lost positive definiteness"
            break
        step = band_solve(factor, -gradient)
        slope, alpha = float(gradient @ step), 1.0
        for _ in range(40):
            counts["line_search"] += 1
            trial = p + alpha * step
            c_trial = rest.residual(trial)
            trial_value = _objective(rest, trial, c_trial, mu, force_weight, box_weight)
            if trial_value <= value + ARMIJO * alpha * slope:
                break
            alpha *= 0.5
        else:
            reason = "the line search found no decrease"
            break
        decrease = value - trial_value
        p, c, value = trial, c_trial, trial_value
        history.append(float(np.abs(c).max(initial=0.0)))
        if decrease <= rtol * abs(value):
            reason = f"converged to a minimizer of the penalty objective (F = {value:.6g})"
            break
    residual = history[-1]
    violation = float(np.max(np.maximum(p - upper, 0.0) + np.maximum(lower - p, 0.0), initial=0.0))
    p = _to_caller_layout(problem, rest, p)
    held = judged_tolerance(problem, p, residual, tol)
    status = "converged" if residual <= held and kkt_optimality(problem, p) <= kkt_tol else "failed"
    message = (f"penalty Gauss-Newton {reason} after {counts['gauss_newton']} iterations; "
               f"|c|_inf = {residual:.3g}" + (raised_note(tol, held) if status == "converged" else
                                              f" (target {held:g}): the rest shape alone, with penalized "
                                              "boxes, leaves this residual force or is not optimal")
               + f"; largest box violation {violation:.3g}")
    return make_result(problem, p, "penalty-gn", status, message, counts, time.perf_counter() - clock, history)
