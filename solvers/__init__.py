"""Our solver (augmented Lagrangian + MPRGP + active-set Cholesky), the Result type and the batch runner."""
from .batch import optimize, solve_strand
from .registry import SOLVERS, SolverUnavailable, solve
from .result import Result

__all__ = ["solve", "optimize", "solve_strand", "Result", "SOLVERS", "SolverUnavailable"]
