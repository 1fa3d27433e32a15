"""sagfree: sag-free Discrete Elastic Rods (see README and DESIGN).

    strand = sagfree.Strand(points, radius=5e-5)        # or sagfree.scenes.horizontal()
    problem = sagfree.Problem(strand, stiffness="element")
    result = sagfree.solve(problem, solver="asc")
    results = sagfree.optimize(strands, solver="asc", jobs=None)
    sim = sagfree.simulate(problem, result.p, steps=200, dt=1e-3)   # sim.sag, sim.relative_sag
    static = sagfree.equilibrium(problem, result.p)                  # static.sag from q*
"""
import importlib.util as _util

# The source tree keeps sagfree.formulation, .solvers, ... in folders beside sagfree/ (formulation/,
# solvers/, ...); only installing maps them into this namespace (pyproject.toml, package-dir).
if _util.find_spec("sagfree.formulation") is None:  # e.g. PYTHONPATH=. from a clone
    raise ImportError(f"sagfree is not installed (found {__path__[0]} without its subpackages, which live in "
                      "folders beside it in the source tree): run `pip install .` (or `pip install -e .`) "
                      "in the repository first")

# before any kernel is decorated: cached kernels recompile when a module they use changes
from sagfree.kernel_cache import register as _register_kernel_cache  # noqa: E402

_register_kernel_cache(__name__)

from sagfree import scenes  # noqa: E402
from sagfree.contract.result import Result  # noqa: E402
from sagfree.formulation import Problem, Strand  # noqa: E402
from sagfree.formulation.simulation import (Equilibrium, Push, Simulation, equilibrium,  # noqa: E402
                                            push_check, simulate)
from sagfree.frontend.batch import optimize  # noqa: E402
from sagfree.frontend.options import InvalidOption  # noqa: E402
from sagfree.frontend.solve import solve  # noqa: E402
from sagfree.frontend.table import SOLVERS, SolverUnavailable  # noqa: E402
from sagfree.scenes.catalog import load, save  # noqa: E402

__version__ = "0.1.0"
__all__ = ["Problem", "Strand", "Result", "SOLVERS", "SolverUnavailable", "InvalidOption", "solve", "optimize",
           "simulate", "equilibrium", "push_check", "Simulation", "Equilibrium", "Push", "load", "save", "scenes",
           "__version__"]
