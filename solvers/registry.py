"""``sagfree.solve``: one entry point for our solver and every baseline (DESIGN section 10)."""
from __future__ import annotations

from importlib import import_module

from sagfree.formulation.problem import Problem

from .result import Result

#: solver name -> "module:function"; each function takes (problem, **options) and returns a Result.
SOLVERS = {
    "asc": "sagfree.solvers.alm:solve_alm",
    "naive": "sagfree.baselines.naive:solve_naive",
}


def solver_function(name: str):
    if name not in SOLVERS:
        raise ValueError(f"unknown solver {name!r}; available: {', '.join(SOLVERS)}")
    module, function = SOLVERS[name].split(":")
    return getattr(import_module(module), function)


def solve(problem: Problem, solver: str = "asc", **options) -> Result:
    """Solve one strand's problem with ``solver``; options go to the solver function."""
    return solver_function(solver)(problem, **options)
