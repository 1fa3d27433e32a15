"""Least-squares Lagrange multipliers of a nearly feasible point (the starts and the convergence test
of ``asc``)."""
from __future__ import annotations

import numpy as np

from sagfree.linalg.normal import NormalFactor, seminormal_least_squares

#: the shift added to A's diagonal (NormalFactor's ``shift``)
SHIFT = 1e-14


def least_squares_multipliers(regularizer_gradient, J, scale, p, lower, upper) -> np.ndarray:
    """lam minimizing the scaled Lagrangian gradient on the free variables F,
    ||(grad R + J^T lam)_F / sqrt(h_F)||_2 (a feasible p's multipliers), from the normal equations
    A lam = -J_F (grad R / h)_F with A = J_F diag(h_F)^-1 J_F^T (linalg.normal.NormalFactor, banded,
    with the strand multiplier's dense column added back by Woodbury), plus one step of the
    corrected semi-normal equations: lam += A^-1 (-J_F e_F), e = (grad R + J^T lam) / h. Normal
    equations square J's condition number; the correction brings the multipliers from ~1e-4 to ~1e-8
    (relative) of a QR least-squares solution.
    NaN if A is singular (J_F rank deficient); the caller then keeps its multipliers.
    Without a dense column, linalg.normal.seminormal_least_squares takes these steps in one compiled
    call (the same arithmetic); with one, NormalFactor adds it back by Woodbury.
    """
    free = (p > lower) & (p < upper)
    lam = seminormal_least_squares(J, regularizer_gradient, scale, free, SHIFT)  # one compiled call
    if lam is not None:
        return lam
    factor = NormalFactor(J, 1.0 / scale, free, shift=SHIFT)  # the strand multiplier's dense column
    if not factor.definite:
        return np.full(J.shape[0], np.nan)
    lam = np.zeros(J.shape[0])
    for _ in range(2):  # the solve, then the correction
        lam += factor.solve(-(J @ np.where(free, (regularizer_gradient + J.T @ lam) / scale, 0.0)))
    return lam
