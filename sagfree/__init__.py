"""sagfree: sag-free Discrete Elastic Rods (see README and DESIGN)."""
from sagfree import scenes
from sagfree.formulation import Problem, Strand

__version__ = "0.1.0"
__all__ = ["Problem", "Strand", "scenes", "__version__"]
