"""Mehrotra's predictor-corrector interior-point method for the box QPs of mprgp (DESIGN 5).

    minimize 1/2 x^T H x - b^T x   subject to   lower <= x <= upper,   H a bordered band (linalg.band),

in the variables scaled to a unit diagonal (mprgp.solve_box_qp). MPRGP's fallback for a QP whose
active set it can only walk (on strand-stiffness QPs the binding curvature bound moves one vertex per
proportioning step as the strand multiplier S rises; mprgp's module docstring). An interior-point
method does not identify the active set bound by bound: where MPRGP needed 284 factorizations, 14
iterations reach the same minimizer (to a relative duality gap of 1e-10).

With slacks s_l = x - l, s_u = u - x (finite bounds only) and their multipliers z_l, z_u >= 0, the
KKT conditions H x - b - z_l + z_u = 0, s_l z_l = s_u z_u = 0 are followed along the central path
s z = sigma mu (Nocedal & Wright, Numerical Optimization, 2nd ed., algorithm 16.4, for bound
constraints): every iteration factors H + diag(z_l / s_l + z_u / s_u), a bordered band with the
pattern of H (linalg.cholesky.factor_active with every variable free, fixed ones l = u replaced by the
identity), and solves with it twice (affine predictor, then the corrector with sigma = (mu_aff / mu)^3).
The slacks stay positive (step to the boundary times 0.99).
"""
from __future__ import annotations

import numba
import numpy as np

from sagfree.linalg.band import matvec
from sagfree.linalg.cholesky import factor_active, solve_factored

MAX_ITERATIONS = 60
TO_BOUNDARY = 0.99  # fraction of the step to the boundary of the positive orthant


def compile_kernels() -> None:
    """Compile (or load from numba's cache) ``interior_point`` for the argument types solve_box_qp
    passes, on a 2-variable QP. Only a QP whose active set walks reaches it, so no warm-up strand
    does: without this its first compilation (~2.6 s) landed in the wall time of a timed batch
    (frontend.warm calls it before any)."""
    interior_point(np.array([[2.0, 2.0], [0.5, 0.0]]), np.zeros((0, 2)), np.zeros((0, 0)), np.ones(2),
                   np.zeros(2), np.ones(2), np.empty(2), 1e-10)


@numba.njit(cache=True)
def interior_point(band, border, corner, b, lower, upper, x, relative_gap):  # pragma: no cover
    """x <- an approximate minimizer, inside the box up to the rounding of the updates x + alpha dx
    (solve_box_qp clips it; x is only written), with the variables whose slack ended below their
    multiplier put on that bound (_snap_to_active_bounds).

    Stops when the duality gap s_l.z_l + s_u.z_u (which bounds f(x) - f* at a dual-feasible point)
    falls below ``relative_gap`` (|f(x)| + tiny) and the dual residual ||H x - b - z_l + z_u||_inf
    below ``relative_gap`` ||b||_inf, after MAX_ITERATIONS, or when a factorization breaks down (x is
    then the last iterate). The test is relative to |f|, not to the starting gap, which can stop far
    above the minimum with no bound identified. Returns (iterations, factorizations).
    """
    n = x.size
    nb = band.shape[1]
    m = corner.shape[0]
    has_l = np.isfinite(lower)
    has_u = np.isfinite(upper)
    inner = np.empty(n, dtype=np.bool_)  # not fixed (l < u)
    sl, su, zl, zu = np.ones(n), np.ones(n), np.zeros(n), np.zeros(n)
    count = 0
    for i in range(n):
        inner[i] = not (has_l[i] and has_u[i] and upper[i] <= lower[i])
        if not inner[i]:
            x[i] = lower[i]
        elif has_l[i] and has_u[i]:
            width = upper[i] - lower[i]
            x[i] = min(max(0.0, lower[i] + 0.1 * width), upper[i] - 0.1 * width)
        elif has_l[i]:
            x[i] = max(0.0, lower[i] + 1.0)
        elif has_u[i]:
            x[i] = min(0.0, upper[i] - 1.0)
        else:
            x[i] = 0.0
        if inner[i] and has_l[i]:
            sl[i], zl[i] = x[i] - lower[i], 1.0
            count += 1
        if inner[i] and has_u[i]:
            su[i], zu[i] = upper[i] - x[i], 1.0
            count += 1
    shifted = band.copy()
    shifted_corner = corner.copy()
    cols = np.empty((nb, band.shape[0]))
    lborder = np.empty_like(border)
    lcorner = np.empty_like(corner)
    hx = np.empty(n)
    rd = np.empty(n)
    rhs = np.empty(n)
    dx = np.empty(n)
    dx_aff = np.empty(n)
    dzl_aff = np.zeros(n)
    dzu_aff = np.zeros(n)
    dzl = np.zeros(n)
    dzu = np.zeros(n)
    target_l = np.zeros(n)  # right-hand sides of the linearized complementarity s z = sigma mu
    target_u = np.zeros(n)
    b_norm = 1e-300
    for i in range(n):
        b_norm = max(b_norm, abs(b[i]))
    factorizations = 0
    for iteration in range(MAX_ITERATIONS):
        matvec(band, border, corner, x, hx)
        residual, gap, f = 0.0, 0.0, 0.0
        for i in range(n):
            rd[i] = (hx[i] - b[i] - zl[i] + zu[i]) if inner[i] else 0.0
            residual = max(residual, abs(rd[i]))
            f += x[i] * (0.5 * hx[i] - b[i])
            if inner[i]:
                gap += (sl[i] * zl[i] if has_l[i] else 0.0) + (su[i] * zu[i] if has_u[i] else 0.0)
        mu = gap / max(count, 1)
        if gap <= relative_gap * (abs(f) + 1e-300) and residual <= relative_gap * b_norm:
            _snap_to_active_bounds(x, lower, upper, has_l, has_u, inner, sl, su, zl, zu)
            return iteration, factorizations
        # H + D on the inner variables (the identity on fixed ones, inside factor_active)
        for j in range(nb):
            shifted[0, j] = band[0, j] + _barrier(j, has_l, has_u, sl, su, zl, zu)
        for r in range(m):
            shifted_corner[r, r] = corner[r, r] + _barrier(nb + r, has_l, has_u, sl, su, zl, zu)
        factorizations += 1
        if not factor_active(shifted, border, shifted_corner, inner, cols, lborder, lcorner, np.int64(0), np.int64(0)):
            return iteration, factorizations
        # predictor (sigma = 0), then corrector with the second-order term dS_aff dZ_aff
        for corrector in range(2):
            sigma_mu = 0.0
            if corrector:
                alpha_p, alpha_d = _step_lengths(dx_aff, dzl_aff, dzu_aff, has_l, has_u, inner, sl, su, zl, zu)
                alpha_p, alpha_d = min(1.0, alpha_p), min(1.0, alpha_d)
                gap_aff = 0.0
                for i in range(n):
                    if inner[i] and has_l[i]:
                        gap_aff += (sl[i] + alpha_p * dx_aff[i]) * (zl[i] + alpha_d * dzl_aff[i])
                    if inner[i] and has_u[i]:
                        gap_aff += (su[i] - alpha_p * dx_aff[i]) * (zu[i] + alpha_d * dzu_aff[i])
                sigma_mu = (gap_aff / max(count, 1) / mu) ** 3 * mu
            for i in range(n):
                rhs[i] = 0.0
                if not inner[i]:
                    continue
                rhs[i] = -rd[i]
                if has_l[i]:  # s_l dz_l + z_l ds_l = sigma mu - s_l z_l - ds_l dz_l (affine, corrector only)
                    target_l[i] = sigma_mu - sl[i] * zl[i] - (dx_aff[i] * dzl_aff[i] if corrector else 0.0)
                    rhs[i] += target_l[i] / sl[i]
                if has_u[i]:  # ds_u = -dx
                    target_u[i] = sigma_mu - su[i] * zu[i] + (dx_aff[i] * dzu_aff[i] if corrector else 0.0)
                    rhs[i] -= target_u[i] / su[i]
            solve_factored(cols, lborder, lcorner, rhs, dx)
            for i in range(n):
                if not inner[i]:
                    dx[i] = 0.0
                    continue
                if has_l[i]:
                    dzl[i] = (target_l[i] - zl[i] * dx[i]) / sl[i]
                if has_u[i]:
                    dzu[i] = (target_u[i] + zu[i] * dx[i]) / su[i]
            if not corrector:
                for i in range(n):
                    dx_aff[i], dzl_aff[i], dzu_aff[i] = dx[i], dzl[i], dzu[i]
        alpha_p, alpha_d = _step_lengths(dx, dzl, dzu, has_l, has_u, inner, sl, su, zl, zu)
        alpha_p, alpha_d = min(1.0, TO_BOUNDARY * alpha_p), min(1.0, TO_BOUNDARY * alpha_d)
        for i in range(n):
            if not inner[i]:
                continue
            x[i] += alpha_p * dx[i]
            if has_l[i]:
                sl[i] += alpha_p * dx[i]
                zl[i] += alpha_d * dzl[i]
            if has_u[i]:
                su[i] -= alpha_p * dx[i]
                zu[i] += alpha_d * dzu[i]
    _snap_to_active_bounds(x, lower, upper, has_l, has_u, inner, sl, su, zl, zu)
    return MAX_ITERATIONS, factorizations


@numba.njit(cache=True)
def _snap_to_active_bounds(x, lower, upper, has_l, has_u, inner, sl, su, zl, zu):  # pragma: no cover
    """Put x on the bounds whose slack is below its multiplier (s < z): the active set the iterate
    points to. MPRGP, which the point is handed to, activates bounds one expansion at a time: from
    the interior point itself it can take hundreds of expansions."""
    for i in range(x.size):
        if inner[i] and has_l[i] and sl[i] < zl[i]:
            x[i] = lower[i]
        elif inner[i] and has_u[i] and su[i] < zu[i]:
            x[i] = upper[i]


@numba.njit(cache=True, inline="always")
def _barrier(i, has_l, has_u, sl, su, zl, zu):  # pragma: no cover - compiled
    """z_l / s_l + z_u / s_u of variable i (its finite bounds only)."""
    return (zl[i] / sl[i] if has_l[i] else 0.0) + (zu[i] / su[i] if has_u[i] else 0.0)


@numba.njit(cache=True)
def _step_lengths(dx, dzl, dzu, has_l, has_u, inner, sl, su, zl, zu):  # pragma: no cover - compiled
    """Largest primal and dual steps that keep s_l, s_u, z_l, z_u >= 0 (may exceed 1)."""
    primal, dual = np.inf, np.inf
    for i in range(dx.size):
        if not inner[i]:
            continue
        if has_l[i]:
            if dx[i] < 0.0:
                primal = min(primal, -sl[i] / dx[i])
            if dzl[i] < 0.0:
                dual = min(dual, -zl[i] / dzl[i])
        if has_u[i]:
            if dx[i] > 0.0:
                primal = min(primal, su[i] / dx[i])
            if dzu[i] < 0.0:
                dual = min(dual, -zu[i] / dzu[i])
    return primal, dual
