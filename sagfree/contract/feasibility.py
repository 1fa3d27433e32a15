"""The equilibrium tolerance a solution is held to: ``tol``, or c's own rounding level where that is larger.

A solver's status is ``converged`` only if |c|_inf <= tol (contract.optimality). No point stored in
floating point can place c closer to zero than the rounding of its own entries allows: moving each
p_j by its rounding, eps |p_j|, moves c_r by up to

    rounding_r(p) = eps sum_j |dc_r/dp_j| |p_j|,

and c's rows are forces over each vertex's weight, which shrinks as the vertices multiply: on
root-held groom strands max_r rounding_r grows as n^2, past the default tol = 1e-8 at 5000
vertices. Where ROUNDING_MULTIPLE times it exceeds ``tol``, that is the tolerance: below it a
solver started at the exact optimum can only crawl (benchmarks/RESULTS.md, 2026-12-05). Every
solver's status applies the same rule, and its message says when the tolerance was raised.
"""
from __future__ import annotations

import numpy as np

from sagfree.formulation.problem import Problem

#: The multiple of c's rounding level a feasible point may leave: moving the exact optimum of a
#: groom strand by one ulp per entry moved c by up to 1.8 times it.
ROUNDING_MULTIPLE = 4.0


def rounding_level(problem: Problem, p: np.ndarray, J=None) -> float:
    """max_r eps sum_j |dc_r/dp_j| |p_j| (module docstring), with J = dc/dp at p if given."""
    J = problem.strand_jacobian(p) if J is None else J
    indptr, indices, values = J.csc()
    columns = np.repeat(np.arange(indptr.size - 1), np.diff(indptr))
    rows = np.bincount(indices, weights=np.abs(values) * np.abs(np.asarray(p, dtype=float))[columns],
                       minlength=J.shape[0])
    return float(np.finfo(float).eps * rows.max(initial=0.0))


def feasibility_tolerance(problem: Problem, p: np.ndarray, tol: float, J=None) -> float:
    """The |c|_inf that p is held to: max(tol, ROUNDING_MULTIPLE x rounding_level(p))."""
    return max(float(tol), ROUNDING_MULTIPLE * rounding_level(problem, p, J))


def judged_tolerance(problem: Problem, p: np.ndarray, violation: float, tol: float) -> float:
    """The tolerance that |c(p)|_inf = ``violation`` is judged by: ``tol`` where it meets it (nothing
    evaluated), else feasibility_tolerance (one dc/dp at p)."""
    return float(tol) if violation <= tol else feasibility_tolerance(problem, p, tol)


def raised_note(tol: float, used: float) -> str:
    """The message's note where the tolerance ``used`` is above the requested ``tol``, else ''."""
    if used <= tol:
        return ""
    return (f"; tol {tol:g} raised to {used:.2g}: {ROUNDING_MULTIPLE:g} x the rounding level of c on this strand "
            "(contract.feasibility)")
