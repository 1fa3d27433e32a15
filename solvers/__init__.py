"""Our method, ``asc``: augmented Lagrangian + Gauss-Newton + MPRGP + active-set Cholesky (DESIGN 5).

Modules: ``alm`` (the outer and Gauss-Newton loops, ``solve_alm``), ``gauss_newton`` (its inner
solve compiled), ``mprgp`` (the box QPs), ``interior_point`` (their fallback where the active set
walks), ``multipliers`` (least-squares multipliers), ``least_sag`` (the best effort on strands the
boxes cannot balance, which the front end applies to every solver's). The banded kernels they use
are in ``sagfree.linalg``; the Result they return and the optimality measure are in
``sagfree.contract``.
"""
from .alm import solve_alm

__all__ = ["solve_alm"]
