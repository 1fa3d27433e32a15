"""The best effort of every solver on a strand the boxes cannot balance (DESIGN section 4).

A strand whose solver ends ``infeasible`` with a residual force left (no p in the box balances
gravity at q*) will rest elsewhere, at the static equilibrium q* relaxes into. Whatever the solver,
its answer is then moved to the least static sag the box allows (solvers.least_sag, from the
solver's own best effort), so a comparison of solvers compares the same best effort, and its time
counts in the solver's. The Result's stability is measured where the strand rests, and the message
gives the sag next to naive's. An ``infeasible`` strand with no residual force (balanced but not
stabilizable inside the boxes) rests at q* and is left as it is.
"""
from __future__ import annotations

import time

from sagfree.contract.result import Result, make_result
from sagfree.formulation.problem import Problem
from sagfree.solvers.least_sag import least_sag


def with_least_sag(problem: Problem, result: Result) -> Result:
    """``result`` (infeasible, with a residual force) moved to the least static sag of its box."""
    clock = time.perf_counter()
    effort = least_sag(problem, result.p)
    naive = effort.naive
    counts = {**result.iterations, "least_sag": effort.evaluations}
    if effort.rest.converged:
        note = (f"; then the least static sag inside the box: {effort.rest.relative_sag:.3g} L (naive: "
                f"{naive.relative_sag:.3g} L" + (f"; {effort.start.relative_sag:.3g} L before"
                                                 if effort.start.converged else "") + ")")
    else:
        note = f"; the static solve did not converge ({effort.rest.newton.message}), sag unknown"
    rest = effort.rest if effort.rest.converged else None
    out = make_result(problem, effort.p, result.solver, "infeasible", result.message + note, counts,
                      result.time + time.perf_counter() - clock, result.history, result.floors, rest,
                      setup_time=result.setup_time)
    if rest is not None and out.min_eigenvalue < problem.stability_margin:
        out.message += (f"; where it rests, its smallest eigenvalue {out.min_eigenvalue:.3g} s^-2 is below the "
                        f"margin {problem.stability_margin:.3g} s^-2")
    return out
