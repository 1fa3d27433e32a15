"""The `naive` baseline: p0, no optimization (DESIGN section 6). Its residual is gravity."""
from __future__ import annotations

import time

from sagfree.formulation.problem import Problem
from sagfree.solvers.result import Result, make_result


def solve_naive(problem: Problem) -> Result:
    """The specified parameters as they are: the rest shape is the groomed shape."""
    start = time.perf_counter()
    p = problem.p0
    residual = float(abs(problem.residual(p)).max(initial=0.0))
    status = "converged" if residual == 0.0 else "failed"
    message = ("p0 is already an equilibrium (no load)" if status == "converged" else
               f"naive parameters leave the gravity residual |c|_inf = {residual:.3g} unbalanced")
    return make_result(problem, p, "naive", status, message, {}, time.perf_counter() - start)
