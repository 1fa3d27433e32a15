"""``sagfree.solve``: one entry point for our solver and every baseline (DESIGN section 10)."""
from __future__ import annotations

from importlib import import_module

from sagfree.formulation.problem import Problem

from .result import Result

#: solver name -> "module:function"; each function takes (problem, **options) and returns a Result.
SOLVERS = {
    "asc": "sagfree.solvers.alm:solve_alm",
    "ipopt": "sagfree.baselines.ipopt:solve_ipopt",
    "osqp": "sagfree.baselines.osqp_sqp:solve_osqp",
    "penalty-gn": "sagfree.baselines.penalty_gn:solve_penalty_gn",
    "naive": "sagfree.baselines.naive:solve_naive",
}
#: solvers that need a component that may be missing: name -> ("module:available", what to install)
REQUIREMENTS = {
    "ipopt": ("sagfree.baselines.ipopt:available",
              "CasADi's Ipopt plugin (casadi.has_nlpsol('ipopt') is False); the CasADi wheels on PyPI "
              "bundle it: pip install --force-reinstall 'casadi>=3.6'"),
    "osqp": ("sagfree.baselines.osqp_sqp:available",
             "the osqp package (import osqp failed): pip install 'osqp>=1.0'"),
}


class SolverUnavailable(RuntimeError):
    """A known solver whose plugin or package is not installed."""


def _load(reference: str):
    module, name = reference.split(":")
    return getattr(import_module(module), name)


def solver_function(name: str):
    """The solver function of ``name``; ValueError for an unknown name, SolverUnavailable when a
    plugin it needs is missing (so a batch can refuse before any work)."""
    if name not in SOLVERS:
        raise ValueError(f"unknown solver {name!r}; available: {', '.join(SOLVERS)}")
    if name in REQUIREMENTS:
        check, remedy = REQUIREMENTS[name]
        if not _load(check)():
            raise SolverUnavailable(f"solver {name!r} is not available: it needs {remedy}")
    return _load(SOLVERS[name])


def solve(problem: Problem, solver: str = "asc", **options) -> Result:
    """Solve one strand's problem with ``solver``; options go to the solver function."""
    return solver_function(solver)(problem, **options)
