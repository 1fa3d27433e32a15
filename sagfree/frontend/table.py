"""The solver table: every name ``sagfree.solve`` accepts, filled by plain imports (as qpsolvers
fills its table), above our method and the baselines, which never import each other.

A solver is a function ``(problem, **options) -> Result``; its keyword parameters are its options
(contract.options for the common ones). A solver whose plugin is missing stays in the table and
raises SolverUnavailable, naming what to install, before any strand is solved.
"""
from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field

from sagfree.baselines import ipopt, naive, osqp_sqp, penalty_gn
from sagfree.contract.result import Result
from sagfree.solvers import solve_alm


class SolverUnavailable(RuntimeError):
    """A known solver whose plugin or package is not installed."""


@dataclass(frozen=True)
class Solver:
    """One row of the table: the function, what it is, and whether it can run here.

    prepare(problem, **options): builds what the solver needs per problem structure (Ipopt's
    compiled instance) before a batch, so worker processes inherit it, calling ``announce()`` before
    a noticeable wait; precompile(problem, **options): starts that work in the background (a study
    starts it for all its solvers after its first warm-up); warm_options: options of
    the untimed warm-up solve (frontend.warm) that differ from the batch's; warm_paths: further
    option sets the warm-up strand is solved with, for code its own solve does not reach;
    uses_stiffness: its answer depends on the stiffness mode (naive and the predecessor keep p0's
    stiffness).
    """

    name: str
    function: Callable[..., Result]
    description: str
    available: Callable[[], bool] = field(default=lambda: True)
    requirement: str = ""
    prepare: Callable[..., None] | None = None
    precompile: Callable[..., None] | None = None
    warm_options: dict = field(default_factory=dict)
    warm_paths: tuple = ()
    uses_stiffness: bool = True

    @property
    def options(self) -> dict[str, object]:
        """Option name -> default, read from the function's keyword parameters."""
        parameters = list(inspect.signature(self.function).parameters.values())[1:]  # after the problem
        return {p.name: p.default for p in parameters}

    def check_available(self) -> None:
        if not self.available():
            raise SolverUnavailable(f"solver {self.name!r} is not available: it needs {self.requirement}")


SOLVERS: dict[str, Solver] = {s.name: s for s in (
    # the warm-up strand, held by its root alone, starts at its optimum: its Gauss-Newton path loads the rest
    Solver("asc", solve_alm, "ours: augmented Lagrangian + Gauss-Newton + MPRGP + active-set Cholesky",
           warm_paths=({"start": "linear"},)),
    Solver("ipopt", ipopt.solve_ipopt, "Ipopt through CasADi's nlpsol, exact Hessian, MUMPS",
           lambda: ipopt.available(),
           "CasADi's Ipopt plugin (casadi.has_nlpsol('ipopt') is False); the CasADi wheels on PyPI bundle it: "
           "pip install --force-reinstall 'casadi>=3.6'",
           # the warm-up strand is of another size: load Ipopt, compile nothing for it
           prepare=ipopt.prepare_ipopt, precompile=ipopt.precompile_ipopt, warm_options={"model": "casadi"}),
    Solver("osqp", osqp_sqp.solve_osqp, "SQP with OSQP subproblems", lambda: osqp_sqp.available(),
           "the osqp package (import osqp failed): pip install 'osqp>=1.0'"),
    Solver("penalty-gn", penalty_gn.solve_penalty_gn, "the predecessor: rest shape by penalty Gauss-Newton",
           uses_stiffness=False),
    Solver("naive", naive.solve_naive, "no optimization: the Result of p0 (or p_start)", uses_stiffness=False),
)}


def solver_entry(name: str) -> Solver:
    """The table row of ``name``: ValueError for an unknown name, SolverUnavailable when a plugin it
    needs is missing (so a batch can refuse before any work)."""
    if name not in SOLVERS:
        raise ValueError(f"unknown solver {name!r}; available: {', '.join(SOLVERS)}")
    entry = SOLVERS[name]
    entry.check_available()
    return entry
