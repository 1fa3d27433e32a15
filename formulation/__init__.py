"""The DER model: frames, curvature variants, energies, parameters and the equilibrium problem."""
from .problem import Problem
from .strand import Strand

__all__ = ["Problem", "Strand"]
