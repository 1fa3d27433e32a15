"""sagfree: sag-free Discrete Elastic Rods (see README and DESIGN).

    strand = sagfree.Strand(points, radius=5e-5)        # or sagfree.scenes.horizontal()
    problem = sagfree.Problem(strand, stiffness="element")
    result = sagfree.solve(problem, solver="asc")
    results = sagfree.optimize(strands, solver="asc", jobs=None)
    sim = sagfree.simulate(problem, result.p, steps=200, dt=1e-3)   # sim.sag, sim.relative_sag
    static = sagfree.equilibrium(problem, result.p)                  # static.sag from q*
"""
from sagfree import scenes
from sagfree.formulation import Problem, Strand
from sagfree.formulation.simulation import Equilibrium, Simulation, equilibrium, simulate
from sagfree.scenes.catalog import load, save
from sagfree.solvers import SOLVERS, Result, SolverUnavailable, optimize, solve

__version__ = "0.1.0"
__all__ = ["Problem", "Strand", "Result", "SOLVERS", "SolverUnavailable", "solve", "optimize", "simulate",
           "equilibrium", "Simulation", "Equilibrium", "load", "save", "scenes", "__version__"]
