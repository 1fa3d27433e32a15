"""One options vocabulary for every solver (README, "Solver options").

Every solver function takes the problem and keyword options; its keyword parameters ARE its options
(``frontend.options`` reads them from the signature, so a default lives in one place). These common
names appear in every solver's signature and mean the same thing in each; a solver's other keyword
parameters are its own, documented in its docstring.
"""
from __future__ import annotations

#: name -> meaning, for every solver
COMMON = {
    "tol": "|c|_inf (unit-free) at or below which the strand is in equilibrium; `converged` needs it "
           "(default 1e-8)",
    "kkt_tol": "KKT distance (contract.optimality.kkt_optimality, in the units of p) at or below which a "
               "point in equilibrium is `converged` (default 1e-5)",
    "max_iterations": "limit on the solver's major iterations, each of which linearizes c once: asc and "
                      "penalty-gn Gauss-Newton steps, ipopt iterations, osqp SQP iterations (naive: none "
                      "to limit); reaching it ends with status `max_iterations`",
    "max_seconds": "wall-clock limit per strand in seconds, checked between major iterations; reaching "
                   "it ends with status `max_iterations`",
    "p_start": "starting parameters in the Problem's layout, clipped into the box (None: the solver's own "
               "start; naive evaluates it instead of p0)",
}
