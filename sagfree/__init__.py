"""sagfree: sag-free Discrete Elastic Rods (see README and DESIGN).

    strand = sagfree.Strand(points, radius=5e-5)        # or sagfree.scenes.horizontal()
    problem = sagfree.Problem(strand, stiffness="element")
    result = sagfree.solve(problem, solver="asc")
    results = sagfree.optimize(strands, solver="asc", jobs=None)
"""
from sagfree import scenes
from sagfree.formulation import Problem, Strand
from sagfree.solvers import SOLVERS, Result, SolverUnavailable, optimize, solve

__version__ = "0.1.0"
__all__ = ["Problem", "Strand", "Result", "SOLVERS", "SolverUnavailable", "solve", "optimize", "scenes",
           "__version__"]
