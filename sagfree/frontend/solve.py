"""``sagfree.solve``: one strand's Problem with any solver of the table (DESIGN section 10)."""
from __future__ import annotations

from sagfree.contract.result import Result
from sagfree.formulation.problem import Problem

from .options import check_options
from .stabilize import solve_stabilized
from .table import solver_entry
from .warm import warm_up


def solve(problem: Problem, solver: str = "asc", **options) -> Result:
    """Solve one strand's problem with ``solver`` (a name of SOLVERS); ``options`` are checked against
    the solver's (frontend.options) before it runs. With ``problem.stabilize`` (the default) the
    solution is a stable rest state (frontend.stabilize). The process's first solve with a solver is
    preceded by an untimed warm-up (frontend.warm)."""
    entry = solver_entry(solver)
    options = check_options(solver, options)
    warm_up(solver, options, problem.options)  # compiling / loading never counts in Result.time
    return solve_stabilized(entry.function, problem, options)
