"""The `naive` baseline: no optimization (DESIGN section 6). At p0 its residual is gravity."""
from __future__ import annotations

import time

import numpy as np

from sagfree.contract.feasibility import judged_tolerance, raised_note
from sagfree.contract.optimality import KKT_TOL, TOL, kkt_optimality
from sagfree.contract.result import Result, make_result
from sagfree.formulation.problem import Problem


def solve_naive(problem: Problem, tol: float = TOL, kkt_tol: float = KKT_TOL, max_iterations: int = 0,
                max_seconds: float = np.inf, p_start=None) -> Result:
    """The Result of the specified parameters as they are (the rest shape is the groomed shape), or of
    ``p_start`` (clipped into the box) when given: a way to measure parameters from elsewhere.
    Common options only (contract.options); max_iterations and max_seconds have nothing to limit.
    Converged only if the point already is one by the common rule: |c|_inf <= tol and KKT distance
    <= kkt_tol (e.g. p0 without a load)."""
    start = time.perf_counter()
    p = problem.p0 if p_start is None else np.clip(np.asarray(p_start, dtype=float), problem.lower, problem.upper)
    residual = float(abs(problem.residual(p)).max(initial=0.0))
    held = judged_tolerance(problem, p, residual, tol)
    if residual <= held and (distance := kkt_optimality(problem, p)) <= kkt_tol:
        status = "converged"
        message = (f"already an equilibrium: |c|_inf = {residual:.2e}, KKT distance {distance:.2e}"
                   + raised_note(tol, held))
    elif residual <= held:
        status, message = "failed", f"in equilibrium but not optimal: KKT distance {distance:.2e} > {kkt_tol:g}"
    else:
        what = "naive parameters leave the gravity residual" if p_start is None else "p_start leaves the residual"
        status, message = "failed", f"{what} |c|_inf = {residual:.3g} unbalanced"
    return make_result(problem, p, "naive", status, message, {}, time.perf_counter() - start)
