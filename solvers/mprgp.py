"""MPRGP: Dostal's modified proportioning with reduced gradient projections, for box QPs (DESIGN 5).

    minimize 1/2 x^T H x - b^T x   subject to   lower <= x <= upper,   H symmetric positive definite,

with H a bordered band (linalg.band). With g = H x - b and the free set F = {i: l_i < x_i < u_i}:

* free gradient phi_i = g_i on F, 0 elsewhere; chopped gradient beta_i = min(g_i, 0) at a lower bound,
  max(g_i, 0) at an upper bound; projected gradient g^P = phi + beta;
* reduced free gradient phi~_i = min((x_i - l_i)/abar, phi_i) for phi_i > 0, max((x_i - u_i)/abar,
  phi_i) for phi_i < 0, abar = 1.9 / ||H|| (Gershgorin bound);
* if beta^T beta <= Gamma^2 phi~^T phi ("proportional"): a preconditioned CG step in the face; when it
  would leave the box, an EXPANSION step: Dostal's step to the boundary followed by a projected
  gradient step of length abar on phi, with two additions that keep its decrease guarantee (each
  only moves to a point of lower f): the step to the boundary continues along the bent path
  P(x - t p) to its first minimizer, and the projected preconditioned step P(x - t M_F^-1 phi)
  (t = 1, 1/2, ...) replaces the gradient step when it is lower. Both activate many bounds at once,
  where the plain expansion activates one, which matters at the scaled condition numbers (~1e9) of
  the Gauss-Newton QPs. The bent path is searched breakpoint by breakpoint with O(w) updates
  (_projected_search);
* otherwise a PROPORTIONING step, which releases bound variables: Dostal's step along -beta, or,
  with the active-set Cholesky, the projected search along the Newton direction of the face enlarged
  by the variables beta would release, whichever is lower (so again at least Dostal's decrease).

Preconditioners of the CG steps: ``cholesky`` (the active-set Cholesky of linalg.cholesky: the exact
factor of H on the free set, so a CG step jumps to the face minimizer; refactored whenever the free
set changes, from the first changed variable on), ``jacobi`` (diag(H) on F) and ``none``. Iterations
of each kind and factorizations are counted where they happen. The whole loop is compiled (numba):
no Python per iteration.

Primal-dual active-set prelude (Hintermueller, Ito & Kunisch, SIAM J. Optim. 13, 2002), with the
active-set Cholesky only: minimize over the face of x0 exactly, guess the next active set as the
variables that x - g puts out of the box (scaled variables, so c = 1), repeat up to
``active_set_steps`` times or until the guess repeats (then the iterate is the solution). MPRGP starts
from the projected iterate with the lowest f, or x0 if none is lower, so its convergence guarantee is
kept. Each step costs one factorization but jumps many bounds at once, where MPRGP moves a front of
bounds one variable per proportioning step: it halves the factorizations of 400-vertex element QPs.
With the dense border of strand stiffness the guesses cycle, so the default
(``active_set_steps=None``) runs it only without a border.

Interior-point fallback (interior_point module): where the active set can only be walked (on
strand-stiffness QPs the binding rest-curvature bound moves one vertex per proportioning step as the
strand multiplier rises), MPRGP pays one factorization per step of the walk. So after WALKING
factorizations the QP goes to Mehrotra's interior-point method (from its own start, to a relative
duality gap of INTERIOR_GAP, then put on the bounds it identifies), and MPRGP goes on, with the
prelude, from the better of the two points (lower f) to the tolerance set by x0. WALKING = 20 is
the budget that balances strand QPs (fewer factorizations with a smaller budget) against element
QPs (more). Where the prelude ran, a walk first sends MPRGP back to x0 without the prelude, with
another WALKING factorizations, and only a second walk goes to the interior-point method: a
prelude's guess can lead into a walk that MPRGP from x0 (Gauss-Newton's warm start, the previous
step's active bounds) avoids, and at 2000 vertices the interior-point method's ~60 factorizations
cost more than the walk (one QP of a pinned groom strand: 84 factorizations, 6 from x0).
The measurements behind these choices are in benchmarks/RESULTS.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from sagfree.linalg.band import BorderedBand, gershgorin_bound, matvec
from sagfree.linalg.cholesky import factor_active, solve_factored
from sagfree.linalg.timing import LINEAR_ALGEBRA, timed

from .interior_point import interior_point

PRECONDITIONERS = {"none": 0, "jacobi": 1, "cholesky": 2}
STATUS = {0: "converged", 1: "max_iterations", 2: "not_positive_definite", 3: "non_finite",
          4: "walking"}  # 4: _mprgp's factorization budget ran out; solve_box_qp then takes the fallback
# layout of the counts array, filled inside the compiled loop
CG, EXPANSION, PROPORTIONING, FACTORIZATIONS, MATVECS, FACTORED_ROWS, ACTIVE_SET, INTERIOR = range(8)
ACTIVE_SET_STEPS = 3  # primal-dual active-set steps before MPRGP on a QP without border (see above)
WALKING = 20  # factorizations after which MPRGP hands the QP to the interior-point method (see above)
INTERIOR_GAP = 1e-10  # relative duality gap and dual residual at which the interior-point method stops


@dataclass
class QPResult:
    x: np.ndarray
    status: str
    cg: int
    expansion: int
    proportioning: int
    factorizations: int
    matvecs: int
    projected_gradient: float   # ||g^P||_2 at x
    factored_rows: int = 0      # band rows recomputed over all factorizations (partial ones count less)
    active_set: int = 0         # primal-dual active-set steps of the prelude
    interior: int = 0           # interior-point iterations of the fallback


@timed(LINEAR_ALGEBRA)
def solve_box_qp(hessian: BorderedBand, b: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                 x0: np.ndarray | None = None, rtol: float = 1e-10, atol: float = 0.0,
                 max_iterations: int = 10_000, preconditioner: str = "cholesky",
                 gamma: float = 1.0, active_set_steps: int | None = None) -> QPResult:
    """Solve the box QP from x0 (projected onto the box; default 0 projected).

    active_set_steps: primal-dual active-set steps before MPRGP (with the active-set Cholesky only);
    None takes ACTIVE_SET_STEPS for a QP without border and none with it. After WALKING
    factorizations, the interior-point fallback (module docstring); max_iterations counts MPRGP's
    iterations over both of its runs.

    The QP is first scaled symmetrically to a unit diagonal, x = S y with S = diag(H)^-1/2, so that
    the expansion step length abar = 1.9/||S H S|| and the stopping test do not depend on the units
    of the variables (in sagfree a rest-length entry carries ~1e16 times the curvature of a stiffness
    multiplier). Stops when ||g^P||_2 <= max(atol, rtol ||g^P(x0)||_2) in the scaled variables.
    """
    if preconditioner not in PRECONDITIONERS:
        raise ValueError(f"preconditioner must be one of {tuple(PRECONDITIONERS)}, got {preconditioner!r}")
    if active_set_steps is None:
        active_set_steps = ACTIVE_SET_STEPS if hessian.corner.shape[0] == 0 else 0
    counts = np.zeros(8, dtype=np.int64)
    x, status, pg = box_qp(hessian.band, hessian.border, hessian.corner, np.asarray(b, dtype=float),
                           np.asarray(lower, dtype=float), np.asarray(upper, dtype=float),
                           np.zeros(hessian.size) if x0 is None else np.asarray(x0, dtype=float), rtol, atol,
                           max_iterations, PRECONDITIONERS[preconditioner], gamma, active_set_steps, WALKING,
                           counts)
    return QPResult(x, STATUS[status], int(counts[CG]), int(counts[EXPANSION]),
                    int(counts[PROPORTIONING]), int(counts[FACTORIZATIONS]), int(counts[MATVECS]), pg,
                    int(counts[FACTORED_ROWS]), int(counts[ACTIVE_SET]), int(counts[INTERIOR]))


def on_previous_bounds(at_lower, at_upper, d_lower, d_upper) -> np.ndarray:
    """A box QP's warm start: the step onto the bounds the previous step's QP ended on (``at_lower``,
    ``at_upper``), 0 elsewhere; MPRGP then starts from that active set."""
    return np.where(at_lower, d_lower, np.where(at_upper, d_upper, 0.0))


@numba.njit(cache=True)
def box_qp(band, border, corner, b, lower, upper, x0, rtol, atol, max_iterations, precond, gamma,
           active_set_steps, walking, counts):  # pragma: no cover - compiled
    """(x, status code, ||g^P||_2) of ``solve_box_qp`` with the preconditioner's code, the
    active-set steps and the factorizations before the fallback (WALKING) given, its iterations
    added to ``counts`` (the CG, ... INTERIOR layout): the whole QP in one compiled call, also from
    asc's compiled Gauss-Newton loop (solvers.gauss_newton)."""
    n = x0.size
    nb = band.shape[1]
    s = np.empty(n)
    for j in range(n):
        diagonal = band[0, j] if j < nb else corner[j - nb, j - nb]
        if not diagonal > 0:
            return np.zeros(n), 2, np.nan
        s[j] = 1.0 / np.sqrt(diagonal)
    scaled_band, scaled_border, scaled_corner = _scale_symmetric(band, border, corner, s)
    sb, sl, su, y = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    for j in range(n):  # the scaled QP
        sb[j], sl[j], su[j] = s[j] * b[j], lower[j] / s[j], upper[j] / s[j]
        y[j] = min(max(x0[j] / s[j], sl[j]), su[j])
    start = y.copy()
    status, pg, tol = _mprgp(scaled_band, scaled_border, scaled_corner, sb, sl, su, y, rtol, atol, max_iterations,
                             precond, gamma, active_set_steps, walking, counts)
    if status == 4 and active_set_steps > 0 and precond == 2:  # walking after the prelude: from x0 without it
        y = start
        used = counts[CG] + counts[EXPANSION] + counts[PROPORTIONING]
        status, pg, tol = _mprgp(scaled_band, scaled_border, scaled_corner, sb, sl, su, y, rtol, atol,
                                 max(max_iterations - used, 0), precond, gamma, np.int64(0),
                                 counts[FACTORIZATIONS] + walking, counts)
    if status == 4:  # walking: the interior-point fallback (module docstring)
        z = np.empty_like(y)
        iterations, factorizations = interior_point(scaled_band, scaled_border, scaled_corner, sb, sl, su, z,
                                                    INTERIOR_GAP)
        counts[INTERIOR] += iterations
        counts[FACTORIZATIONS] += factorizations
        counts[FACTORED_ROWS] += factorizations * nb
        for j in range(n):
            z[j] = min(max(z[j], sl[j]), su[j])
        work = np.empty_like(y)
        if _objective(scaled_band, scaled_border, scaled_corner, sb, z, work) < _objective(
                scaled_band, scaled_border, scaled_corner, sb, y, work):
            y = z
        # on from the better point (with the prelude: the interior point's bounds are not all
        # identified), to the first call's tolerance
        used = counts[CG] + counts[EXPANSION] + counts[PROPORTIONING]
        status, pg, _ = _mprgp(scaled_band, scaled_border, scaled_corner, sb, sl, su, y, 0.0, tol,
                               max(max_iterations - used, 0), precond, gamma, active_set_steps,
                               np.iinfo(np.int64).max, counts)
    x = np.empty(n)
    for j in range(n):  # exactly on the bound, not one rounding off it
        x[j] = min(max(s[j] * y[j], lower[j]), upper[j])
    return x, status, pg


@numba.njit(cache=True)
def _scale_symmetric(band, border, corner, s):  # pragma: no cover - compiled
    """(band, border, corner) of S H S, S = diag(s); the band's unused tail entries are copied."""
    w1, nb = band.shape
    m = corner.shape[0]
    scaled_band = band.copy()
    for k in range(w1):
        for j in range(nb - k):
            scaled_band[k, j] *= s[j + k] * s[j]
    scaled_border = np.empty_like(border)
    scaled_corner = np.empty_like(corner)
    for r in range(m):
        for j in range(nb):
            scaled_border[r, j] = border[r, j] * s[nb + r] * s[j]
        for c in range(m):
            scaled_corner[r, c] = corner[r, c] * s[nb + r] * s[nb + c]
    return scaled_band, scaled_border, scaled_corner


@numba.njit(cache=True)
def _gradients(x, g, lower, upper, abar, phi, beta, free):  # pragma: no cover - compiled
    """Fill phi, beta, free; return (||g^P||^2, beta.beta, phi~.phi)."""
    gp2 = 0.0
    bb = 0.0
    tp = 0.0
    for i in range(x.size):
        at_lower = x[i] <= lower[i]
        at_upper = x[i] >= upper[i]
        free[i] = not (at_lower or at_upper)
        if free[i]:
            phi[i] = g[i]
            beta[i] = 0.0
            if g[i] > 0:
                tp += min((x[i] - lower[i]) / abar, g[i]) * g[i]
            else:
                tp += max((x[i] - upper[i]) / abar, g[i]) * g[i]
        else:
            phi[i] = 0.0
            beta[i] = min(g[i], 0.0) if at_lower else max(g[i], 0.0)
            if at_lower and at_upper:  # fixed variable (lower == upper)
                beta[i] = 0.0
            bb += beta[i] * beta[i]
        gp2 += (phi[i] + beta[i]) ** 2
    return gp2, bb, tp


@numba.njit(cache=True)
def _feasible_step(x, d, lower, upper):  # pragma: no cover - compiled
    """Largest t with lower <= x - t d <= upper, and the index of the bound that blocks it."""
    largest, block = np.inf, -1
    for i in range(x.size):
        if d[i] > 0.0:
            t = (x[i] - lower[i]) / d[i]
        elif d[i] < 0.0:
            t = (x[i] - upper[i]) / d[i]
        else:
            continue
        if t < largest:
            largest, block = t, i
    return largest, block


@numba.njit(cache=True)
def _objective(band, border, corner, b, x, work):  # pragma: no cover - compiled
    """f(x) = 1/2 x^T H x - b^T x (work receives H x)."""
    matvec(band, border, corner, x, work)
    f = 0.0
    for i in range(x.size):
        f += x[i] * (0.5 * work[i] - b[i])
    return f


@numba.njit(cache=True)
def _column_times(band, border, corner, j, scale, out):  # pragma: no cover - compiled
    """out += scale * H e_j (O(w) for a band column, O(n) for a border column)."""
    w1, nb = band.shape
    m = corner.shape[0]
    if j < nb:
        out[j] += scale * band[0, j]
        for k in range(1, w1):
            if j + k < nb:
                out[j + k] += scale * band[k, j]
            if j - k >= 0:
                out[j - k] += scale * band[k, j - k]
        for r in range(m):
            out[nb + r] += scale * border[r, j]
    else:
        r = j - nb
        for i in range(nb):
            out[i] += scale * border[r, i]
        for c in range(m):
            out[nb + c] += scale * corner[c, r]


@numba.njit(cache=True)
def _path_gradient(band, border, corner, g0, x0, p, lower, upper, t, j):  # pragma: no cover
    """g_j at x(t) = P(x0 - t p): g0_j + sum_i H_ji (x_i(t) - x0_i), over row j's band and border."""
    w1, nb = band.shape
    m = corner.shape[0]
    s = g0[j]
    if j < nb:
        for i in range(max(0, j - w1 + 1), min(nb, j + w1)):
            k = abs(i - j)
            h = band[k, min(i, j)]
            if h != 0.0:
                s += h * (min(max(x0[i] - t * p[i], lower[i]), upper[i]) - x0[i])
        for r in range(m):
            i = nb + r
            s += border[r, j] * (min(max(x0[i] - t * p[i], lower[i]), upper[i]) - x0[i])
    else:
        r = j - nb
        for i in range(nb):
            s += border[r, i] * (min(max(x0[i] - t * p[i], lower[i]), upper[i]) - x0[i])
        for c in range(m):
            i = nb + c
            s += corner[r, c] * (min(max(x0[i] - t * p[i], lower[i]), upper[i]) - x0[i])
    return s


@numba.njit(cache=True)
def _projected_search(band, border, corner, x, g, p, lower, upper, d, hd):  # pragma: no cover
    """Move x to the first minimizer of f along the projected path P(x - t p), t >= 0.

    The path bends at the breakpoints where a component reaches its bound; between them f is a
    quadratic in t whose slope and curvature are updated in O(w) per breakpoint (Nocedal & Wright,
    section 16.7's Cauchy point search): zeroing component j of the direction d changes H d by one
    column of H, and g_j at the breakpoint needs one row of H. Two matvec-sized passes plus a sort:
    O(n log n) per search, where recomputing H d per segment would be O(n) per bound hit.
    """
    n = x.size
    breaks = np.full(n, np.inf)
    for i in range(n):
        if p[i] > 0.0:
            breaks[i] = max((x[i] - lower[i]) / p[i], 0.0)
        elif p[i] < 0.0:
            breaks[i] = max((x[i] - upper[i]) / p[i], 0.0)
    order = np.argsort(breaks)
    for i in range(n):
        d[i] = p[i]
    matvec(band, border, corner, d, hd)
    slope = 0.0       # g(x(t)) . d: minus the derivative of f along the path
    curvature = 0.0   # d . H d
    for i in range(n):
        slope += g[i] * d[i]
        curvature += d[i] * hd[i]
    t = 0.0
    final = 0.0
    for k in range(n + 1):
        if slope <= 0.0 or curvature <= 0.0:
            final = t
            break
        stop = breaks[order[k]] if k < n else np.inf
        if t + slope / curvature <= stop:
            final = t + slope / curvature
            break
        slope -= (stop - t) * curvature
        t = stop
        j = order[k]
        delta = d[j]
        gj = _path_gradient(band, border, corner, g, x, p, lower, upper, t, j)
        slope -= delta * gj
        curvature += delta * (delta * (band[0, j] if j < band.shape[1] else
                                       corner[j - band.shape[1], j - band.shape[1]]) - 2.0 * hd[j])
        _column_times(band, border, corner, j, -delta, hd)
        d[j] = 0.0
    for i in range(n):
        x[i] = min(max(x[i] - final * p[i], lower[i]), upper[i])


@numba.njit(cache=True)
def _mprgp(band, border, corner, b, lower, upper, x, rtol, atol, max_iterations, precond, gamma,
           active_set_steps, max_factorizations, counts):  # pragma: no cover - compiled
    n = x.size
    nb = band.shape[1]
    lb = np.empty((nb, band.shape[0]))  # factor columns (linalg.cholesky.factor_active)
    lborder = np.empty_like(border)
    lcorner = np.empty_like(corner)
    g = np.empty(n)
    hp = np.empty(n)
    phi = np.empty(n)
    beta = np.empty(n)
    z = np.empty(n)
    p = np.empty(n)
    trial = np.empty(n)
    best = np.empty(n)
    direction = np.empty(n)
    free = np.empty(n, dtype=np.bool_)
    released = np.empty(n, dtype=np.bool_)
    factored_free = np.zeros(n, dtype=np.bool_)
    factor_valid = np.zeros(1, dtype=np.bool_)  # lb, lborder, lcorner hold the factor of factored_free
    diag = np.empty(n)
    for j in range(nb):
        diag[j] = band[0, j]
    for r in range(corner.shape[0]):
        diag[nb + r] = corner[r, r]
    abar = 1.9 / max(gershgorin_bound(band, border, corner), 1e-300)

    matvec(band, border, corner, x, g)
    counts[MATVECS] += 1
    for i in range(n):
        g[i] -= b[i]
    gp2, bb, tp = _gradients(x, g, lower, upper, abar, phi, beta, free)
    if not np.isfinite(gp2):
        return 3, np.sqrt(gp2), 0.0
    tol = max(atol, rtol * np.sqrt(gp2))

    def precondition(mask, rhs):
        """z = M^-1 rhs on the variables of mask (0 elsewhere)."""
        if precond == 2:
            start = n if factor_valid[0] else 0  # first variable whose freedom changed
            for i in range(start):
                if mask[i] != factored_free[i]:
                    start = i
                    break
            border_start = start
            for i in range(max(start, nb), n):
                if mask[i] != factored_free[i]:
                    border_start = 0
            if start < n:
                counts[FACTORIZATIONS] += 1
                counts[FACTORED_ROWS] += nb - max(0, min(start, nb) - (band.shape[0] - 1))
                factor_valid[0] = factor_active(band, border, corner, mask, lb, lborder, lcorner,
                                                min(start, nb), min(border_start, nb))
                if not factor_valid[0]:
                    return False  # the QP stops (not positive definite)
                for i in range(n):
                    factored_free[i] = mask[i]
            solve_factored(lb, lborder, lcorner, rhs, z)
            for i in range(n):
                if not mask[i]:
                    z[i] = 0.0
        elif precond == 1:
            for i in range(n):
                z[i] = rhs[i] / diag[i] if mask[i] else 0.0
        else:
            for i in range(n):
                z[i] = rhs[i] if mask[i] else 0.0
        return True

    def restart_at_best():
        """x <- best after an expansion or proportioning step: gradient, sets and the new
        preconditioned direction p; returns (gp2, bb, tp, factorization succeeded)."""
        for i in range(n):
            x[i] = best[i]
        matvec(band, border, corner, x, g)
        counts[MATVECS] += 1
        for i in range(n):
            g[i] -= b[i]
        gp2, bb, tp = _gradients(x, g, lower, upper, abar, phi, beta, free)
        ok = precondition(free, phi)
        for i in range(n):
            p[i] = z[i]
        return gp2, bb, tp, ok

    def active_set_prelude():
        """Primal-dual active-set steps from x (module docstring): best <- the lowest projected
        iterate, or x if none is lower. False if a factorization broke down. f(y) = y.(g - b) / 2
        with g = H y - b saves a product wherever g is at hand."""
        f_best = 0.0
        for i in range(n):
            f_best += 0.5 * x[i] * (g[i] - b[i])
            best[i] = x[i]
            trial[i] = x[i]
        for step in range(active_set_steps):
            counts[ACTIVE_SET] += 1
            # the guess: x's own bounds first, then the variables that trial - g puts out of the box;
            # direction = their bounds (0 on the guessed free set, ``released``)
            for i in range(n):
                v = trial[i] - g[i] if step > 0 else trial[i]
                released[i] = lower[i] < v < upper[i]
                direction[i] = 0.0 if released[i] else (lower[i] if v <= lower[i] else upper[i])
            # the minimizer of the guessed face: H_FF x_F = b_F - H_FA x_A
            matvec(band, border, corner, direction, hp)
            counts[MATVECS] += 1
            for i in range(n):
                phi[i] = b[i] - hp[i]
            if not precondition(released, phi):
                return False
            repeated = True  # the same guess as the last step: trial is the QP's solution
            for i in range(n):
                v = z[i] if released[i] else direction[i]
                repeated = repeated and v == trial[i]
                trial[i] = v
            if repeated:
                break  # g and f of trial are known from the last step
            matvec(band, border, corner, trial, g)
            counts[MATVECS] += 1
            inside = True
            f_trial = 0.0
            for i in range(n):
                g[i] -= b[i]
                p[i] = min(max(trial[i], lower[i]), upper[i])
                inside = inside and p[i] == trial[i]
                f_trial += 0.5 * trial[i] * (g[i] - b[i])
            if not inside:
                f_trial = _objective(band, border, corner, b, p, hp)
                counts[MATVECS] += 1
            if f_trial < f_best:
                f_best = f_trial
                for i in range(n):
                    best[i] = p[i]
        return True

    if precond == 2 and active_set_steps > 0 and gp2 > tol * tol:
        if not active_set_prelude():
            return 2, np.sqrt(gp2), tol
        gp2, bb, tp, ok = restart_at_best()
    else:
        ok = precondition(free, phi)
        for i in range(n):
            p[i] = z[i]
    if not ok:
        return 2, np.sqrt(gp2), tol

    for _ in range(max_iterations):
        if gp2 <= tol * tol:
            return 0, np.sqrt(gp2), tol
        if counts[FACTORIZATIONS] >= max_factorizations:
            return 4, np.sqrt(gp2), tol
        if bb <= gamma * gamma * tp:
            matvec(band, border, corner, p, hp)
            counts[MATVECS] += 1
            php = 0.0
            gp = 0.0
            for i in range(n):
                php += p[i] * hp[i]
                gp += g[i] * p[i]
            if not php > 0.0:
                return 2, np.sqrt(gp2), tol
            acg = gp / php
            afeas, block = _feasible_step(x, p, lower, upper)
            if acg <= afeas:  # conjugate gradient step in the face
                counts[CG] += 1
                for i in range(n):
                    x[i] -= acg * p[i]
                    g[i] -= acg * hp[i]
                gp2, bb, tp = _gradients(x, g, lower, upper, abar, phi, beta, free)
                if not precondition(free, phi):
                    return 2, np.sqrt(gp2), tol
                zhp = 0.0
                for i in range(n):
                    zhp += z[i] * hp[i]
                cg_beta = zhp / php
                for i in range(n):
                    p[i] = z[i] - cg_beta * p[i]
            else:  # expansion step
                counts[EXPANSION] += 1
                # (a) projected search along p: past the first blocking bound, follow the bent
                # path P(x - t p) segment by segment to its first minimizer, activating every
                # bound met on the way (one expansion instead of one per bound)
                _projected_search(band, border, corner, x, g, p, lower, upper, direction, hp)
                matvec(band, border, corner, x, g)
                counts[MATVECS] += 2
                for i in range(n):
                    g[i] -= b[i]
                _gradients(x, g, lower, upper, abar, phi, beta, free)
                # (b) Dostal's projected free-gradient step of fixed length abar
                for i in range(n):
                    trial[i] = min(max(x[i] - abar * phi[i], lower[i]), upper[i])
                f_best = _objective(band, border, corner, b, trial, hp)
                counts[MATVECS] += 1
                for i in range(n):
                    best[i] = trial[i]
                # (c) the preconditioned (with the active-set Cholesky: Newton) step of the face,
                # projected, backtracked along the projection arc; kept only if it beats (b), so
                # the expansion decreases f at least as much as Dostal's step
                if precond != 0:
                    if not precondition(free, phi):
                        return 2, np.sqrt(gp2), tol
                    t = 1.0
                    for _arc in range(12):
                        for i in range(n):
                            trial[i] = min(max(x[i] - t * z[i], lower[i]), upper[i])
                        f_trial = _objective(band, border, corner, b, trial, hp)
                        counts[MATVECS] += 1
                        if f_trial < f_best:
                            f_best = f_trial
                            for i in range(n):
                                best[i] = trial[i]
                            break
                        t *= 0.5
                gp2, bb, tp, ok = restart_at_best()
                if not ok:
                    return 2, np.sqrt(gp2), tol
        else:  # proportioning step: release variables along the chopped gradient
            counts[PROPORTIONING] += 1
            matvec(band, border, corner, beta, hp)
            counts[MATVECS] += 1
            bhb = 0.0
            for i in range(n):
                bhb += beta[i] * hp[i]
            a = bb / bhb if bhb > 0.0 else np.inf
            for i in range(n):  # stay inside a narrow box
                if beta[i] < 0.0:
                    a = min(a, (x[i] - upper[i]) / beta[i])
                elif beta[i] > 0.0:
                    a = min(a, (x[i] - lower[i]) / beta[i])
            for i in range(n):
                best[i] = min(max(x[i] - a * beta[i], lower[i]), upper[i])
            f_best = _objective(band, border, corner, b, best, hp)
            counts[MATVECS] += 1
            if precond == 2:
                for i in range(n):
                    released[i] = free[i] or beta[i] != 0.0
                    trial[i] = phi[i] + beta[i]
                if not precondition(released, trial):
                    return 2, np.sqrt(gp2), tol
                for i in range(n):
                    trial[i] = x[i]
                _projected_search(band, border, corner, trial, g, z, lower, upper, direction, hp)
                counts[MATVECS] += 2
                if _objective(band, border, corner, b, trial, hp) < f_best:
                    for i in range(n):
                        best[i] = trial[i]
            gp2, bb, tp, ok = restart_at_best()
            if not ok:
                return 2, np.sqrt(gp2), tol
        if not np.isfinite(gp2):
            return 3, np.sqrt(gp2), tol
    return (0 if gp2 <= tol * tol else 1), np.sqrt(gp2), tol
