"""Trust-region reflective least squares in a box, over a Jacobian operator.

    minimize 1/2 |f(x)|^2    over lower <= x <= upper,

by the subspace trust-region reflective method of Branch, Coleman & Li (SIAM J. Sci. Comput. 21,
1999), step for step as scipy.optimize.least_squares(method="trf", tr_solver="lsmr") takes it
(scipy/optimize/_lsq/trf.py and common.py, BSD licence, whose helpers are ported here): Coleman-Li
scaling of the variables by their distance to the bound the gradient points at, a trust region in
those variables, the step in the two-dimensional subspace of the scaled gradient and a
Gauss-Newton direction, reflected at the first bound it hits or stepped back from it (iterates stay
strictly inside the box), the radius updated by the ratio of actual to predicted decrease.

What differs from scipy's, and why (solvers.least_sag, the one user, evaluates f by a static solve
and applies J by band solves):
- the Gauss-Newton direction comes from the caller (``Linearization.direction``: compiled
  conjugate gradients on the regularized normal equations, CGLS, which in exact arithmetic are
  LSQR's and LSMR's Krylov iterates), not from scipy's LSMR, whose Python loop of operator
  products was most of the least sag's time;
- the variables' scales (``x_scale``) are renewed by the caller every ``rescale_every``
  evaluations, where the minimization is (scipy's take them from the caller once, or from a
  matrix);
- the numeric helpers are compiled (numba) and shared with the least sag's compiled loop
  (solvers.least_sag_loop), which takes this loop's steps through the sag operator: the two give
  the same iterates bit for bit because every number either computes comes from the same kernel.
  So the 2-D trust region's Cholesky factor is written out, and its boundary minimum is the least
  of the points of all roots' real parts (numba's roots of the quartic come complex, real roots
  with rounding-sized imaginary parts), the 2-D QR is numba's LAPACK, and norms are sqrt(x . x).
"""
from __future__ import annotations

from typing import Callable, NamedTuple, Protocol

import numba
import numpy as np

#: Stopping tolerances of scipy's least_squares (ftol, xtol, gtol defaults).
FTOL, XTOL, GTOL = 1e-8, 1e-8, 1e-8


class Linearization(Protocol):
    """J at a point, as an operator."""

    def product(self, v: np.ndarray) -> np.ndarray:
        """J v."""

    def transposed_product(self, u: np.ndarray) -> np.ndarray:
        """J^T u."""

    def direction(self, d: np.ndarray, damping: np.ndarray, f: np.ndarray) -> np.ndarray:
        """An approximate minimizer of |J diag(d) p + f|^2 + |damping^(1/2) p|^2."""


class Minimized(NamedTuple):
    """Where ``reflective_least_squares`` ended: x, 1/2 |f(x)|^2, evaluations of new points, and the
    reason (scipy's status codes: 0 evaluations used up, 1 gtol, 2 ftol, 3 xtol, 4 both ftol and
    xtol, -1 the start could not be evaluated)."""
    x: np.ndarray
    cost: float
    evaluations: int
    status: int


def reflective_least_squares(residuals: Callable[[np.ndarray], np.ndarray],
                             linearize: Callable[[np.ndarray], Linearization],
                             column_norms: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, lower: np.ndarray,
                             upper: np.ndarray, max_evaluations: int, rescale_every: int) -> Minimized:
    """Minimize 1/2 |f|^2 in the box from x0 (module docstring). residuals(x): f(x) (non-finite
    entries where f cannot be evaluated there: the radius shrinks); linearize(x): J at an accepted
    point x; column_norms(x): J's column norms there (the scales x_scale = 1 / norms, renewed every
    ``rescale_every`` evaluations)."""
    x = make_strictly_feasible(np.asarray(x0, dtype=float), lower, upper, 1e-10)
    f = residuals(x)
    evaluations = 1
    if not np.all(np.isfinite(f)):
        return Minimized(x, np.inf, evaluations, -1)
    cost = 0.5 * float(f @ f)
    linear = linearize(x)
    g = linear.transposed_product(f)
    scale, since = scales_of(column_norms(x)), 0
    v, dv = cl_scaling_vector(x, g, lower, upper)
    scaled_variables(v, dv, g, scale)
    radius = first_radius(x, v, scale)
    status = 0
    while True:
        v, dv = cl_scaling_vector(x, g, lower, upper)
        g_norm = gradient_norm(g, v)
        if g_norm < GTOL:
            status = 1
        if status or evaluations >= max_evaluations:
            break
        if since >= rescale_every:
            scale, since = scales_of(column_norms(x)), 0
        d, diag_h, g_h = scaled_variables(v, dv, g, scale)
        a, b = quadratic_1d(linear.product(d * -g_h), g_h, -g_h, diag_h)
        regularization = -minimize_quadratic_1d(a, b, 0.0, radius / norm(g_h))[1] / radius**2
        gn_h = linear.direction(d, diag_h + regularization, f)
        basis = subspace_basis(g_h, gn_h)
        b_s, g_s = subspace_model(linear.product(d * basis[0]), linear.product(d * basis[1]), basis, diag_h, g_h)
        theta = max(0.995, 1 - g_norm)
        reduction = -1.0
        while reduction <= 0 and evaluations < max_evaluations:
            p_s, _ = solve_trust_region_2d(b_s, g_s, radius)
            p_h = in_subspace(basis, p_s)
            step, step_h, predicted = select_step(x, linear, diag_h, g_h, d * p_h, p_h, d, radius, lower, upper, theta)
            trial = make_strictly_feasible(x + step, lower, upper)
            f_trial = residuals(trial)
            evaluations, since = evaluations + 1, since + 1
            step_h_norm = norm(step_h)
            if not np.all(np.isfinite(f_trial)):
                radius = 0.25 * step_h_norm
                continue
            trial_cost = 0.5 * float(f_trial @ f_trial)
            reduction = cost - trial_cost
            new_radius, ratio = update_tr_radius(radius, reduction, predicted, step_h_norm,
                                                 step_h_norm > 0.95 * radius)
            status = check_termination(reduction, cost, norm(step), norm(x), ratio, FTOL, XTOL)
            if status:
                break
            radius = new_radius
        if reduction > 0:
            x, f, cost = trial, f_trial, trial_cost
            linear = linearize(x)
            g = linear.transposed_product(f)
    return Minimized(x, cost, evaluations, status)


@numba.njit(cache=True)
def scales_of(norms):  # pragma: no cover - compiled
    """x_scale from the column norms (1 where a column vanishes)."""
    out = np.empty(norms.size)
    for j in range(norms.size):
        out[j] = 1.0 / norms[j] if norms[j] > 0 else 1.0
    return out


def select_step(x, linear, diag_h, g_h, p, p_h, d, radius, lower, upper, theta):
    """(step, step in the scaled variables, predicted decrease): the best of the trust-region step
    (stepped back inside the box), its reflection at the first bound it hits, and the scaled
    gradient step (scipy's trf.select_step); J diag(d) applied as ``linear.product(d * s)``."""
    if inside(x, p, lower, upper):
        return p, p_h, -quadratic_value(linear.product(d * p_h), g_h, p_h, diag_h)
    p, p_h, r_h, r, r_stride_l, r_stride_u = reflection(x, p, p_h, d, radius, lower, upper, theta)
    if r_stride_l <= r_stride_u:
        a, b, c = quadratic_1d_from(linear.product(d * r_h), linear.product(d * p_h), g_h, r_h, p_h, diag_h)
        r_stride, r_value = minimize_quadratic_1d(a, b, r_stride_l, r_stride_u, c)
        r_h = r_h * r_stride + p_h
        r = r_h * d
    else:
        r_value = np.inf
    p, p_h = p * theta, p_h * theta
    p_value = quadratic_value(linear.product(d * p_h), g_h, p_h, diag_h)
    ag_h, ag, ag_stride = gradient_step(x, g_h, d, radius, lower, upper, theta)
    a, b = quadratic_1d(linear.product(d * ag_h), g_h, ag_h, diag_h)
    return least_of_three(p, p_h, p_value, r, r_h, r_value, ag, ag_h, a, b, ag_stride)


@numba.njit(cache=True)
def least_of_three(p, p_h, p_value, r, r_h, r_value, ag, ag_h, a, b, ag_stride):  # pragma: no cover - compiled
    """select_step's choice among the trust-region step, its reflection and the scaled gradient
    step, each (step, scaled step, model value), the gradient's first taken to its best stride
    along a t^2 + b t up to ``ag_stride``: (step, scaled step, predicted decrease)."""
    ag_stride, ag_value = minimize_quadratic_1d(a, b, 0.0, ag_stride)
    ag_h, ag = ag_h * ag_stride, ag * ag_stride
    if p_value < r_value and p_value < ag_value:
        return p, p_h, -p_value
    if r_value < p_value and r_value < ag_value:
        return r, r_h, -r_value
    return ag, ag_h, -ag_value


@numba.njit(cache=True)
def inside(x, p, lower, upper):  # pragma: no cover - compiled
    """Whether x + p is in the box."""
    for j in range(x.size):
        if not (lower[j] <= x[j] + p[j] <= upper[j]):
            return False
    return True


@numba.njit(cache=True)
def reflection(x, p, p_h, d, radius, lower, upper, theta):  # pragma: no cover - compiled
    """select_step's trust-region step cut at the first bound it reaches (p, p_h), its reflection
    there (r_h, r = d r_h) and the reflected leg's stride bounds (lower, upper; lower > upper: none)."""
    p_stride, hits = step_size_to_bound(x, p, lower, upper)
    r_h = p_h.copy()
    for j in range(r_h.size):
        if hits[j] != 0:
            r_h[j] *= -1
    r = d * r_h
    p, p_h = p * p_stride, p_h * p_stride
    _, to_tr = intersect_trust_region(p_h, r_h, radius)
    to_bound, _ = step_size_to_bound(x + p, r, lower, upper)
    r_stride = min(to_bound, to_tr)
    if r_stride > 0:
        r_stride_l = (1 - theta) * p_stride / r_stride
        r_stride_u = theta * to_bound if r_stride == to_bound else to_tr
    else:
        r_stride_l, r_stride_u = 0.0, -1.0
    return p, p_h, r_h, r, r_stride_l, r_stride_u


@numba.njit(cache=True)
def gradient_step(x, g_h, d, radius, lower, upper, theta):  # pragma: no cover - compiled
    """select_step's scaled gradient direction (ag_h, ag = d ag_h) and its largest stride, inside
    the trust region and theta of the way to the box."""
    ag_h = -g_h
    ag = d * ag_h
    to_tr = radius / norm(ag_h)
    to_bound, _ = step_size_to_bound(x, ag, lower, upper)
    return ag_h, ag, theta * to_bound if to_bound < to_tr else to_tr


@numba.njit(cache=True)
def solve_trust_region_2d(b, g, radius):  # pragma: no cover - compiled
    """(p, Newton step inside) minimizing 1/2 p^T B p + g^T p over |p| <= radius in two dimensions:
    the Newton step where B is definite and it fits, else the boundary's minimum (scipy's
    common.solve_trust_region_2d). The Cholesky factor is written out; the boundary's candidates
    are the real parts of all roots of scipy's quartic in t = tan(phi / 2): each is a point on the
    circle, the stationary ones among them (numba's eigenvalues come complex, real roots with
    rounding-sized imaginary parts), and the least of them is the minimum."""
    if b[0, 0] > 0:
        l00 = np.sqrt(b[0, 0])
        l10 = b[1, 0] / l00
        pivot = b[1, 1] - l10 * l10
        if pivot > 0:
            l11 = np.sqrt(pivot)
            y0 = g[0] / l00
            y1 = (g[1] - l10 * y0) / l11
            p1 = y1 / l11
            p = np.array([-(y0 - l10 * p1) / l00, -p1])
            if p[0] * p[0] + p[1] * p[1] <= radius**2:
                return p, True
    a, bb, c = b[0, 0] * radius**2, b[0, 1] * radius**2, b[1, 1] * radius**2
    d, f = g[0] * radius, g[1] * radius
    coefficients = np.array([-bb + d, 2 * (a - c + f), 6 * bb, 2 * (-a + c + f), -bb - d], dtype=np.complex128)
    best, best_value = np.zeros(2), np.inf
    for root in np.roots(coefficients):
        t = root.real
        p = np.array([radius * 2 * t / (1 + t**2), radius * (1 - t**2) / (1 + t**2)])
        value = 0.5 * (p[0] * (b[0, 0] * p[0] + b[0, 1] * p[1]) + p[1] * (b[1, 0] * p[0] + b[1, 1] * p[1])) \
            + (g[0] * p[0] + g[1] * p[1])
        if value < best_value:
            best, best_value = p, value
    return best, False


@numba.njit(cache=True)
def update_tr_radius(radius, reduction, predicted, step_norm, bound_hit):  # pragma: no cover - compiled
    """(radius, ratio of actual to predicted decrease) after a step (scipy's common.update_tr_radius)."""
    if predicted > 0:
        ratio = reduction / predicted
    elif predicted == reduction == 0:
        ratio = 1.0
    else:
        ratio = 0.0
    if ratio < 0.25:
        radius = 0.25 * step_norm
    elif ratio > 0.75 and bound_hit:
        radius *= 2.0
    return radius, ratio


@numba.njit(cache=True)
def quadratic_1d(js, g, s, diag):  # pragma: no cover - compiled
    """(a, b) of 1/2 (s t)^T (J^T J + diag) (s t) + g^T (s t) = a t^2 + b t, with js = J s (scipy's
    common.build_quadratic_1d)."""
    return 0.5 * (np.dot(js, js) + np.dot(s * diag, s)), np.dot(g, s)


@numba.njit(cache=True)
def quadratic_1d_from(js, js0, g, s, s0, diag):  # pragma: no cover - compiled
    """(a, b, c) of the same along s0 + s t (``quadratic_1d``), with js0 = J s0."""
    a, b = quadratic_1d(js, g, s, diag)
    b += np.dot(js0, js) + np.dot(s0 * diag, s)
    c = 0.5 * np.dot(js0, js0) + np.dot(g, s0) + 0.5 * np.dot(s0 * diag, s0)
    return a, b, c


@numba.njit(cache=True)
def quadratic_value(js, g, s, diag):  # pragma: no cover - compiled
    """1/2 s^T (J^T J + diag) s + g^T s, with js = J s."""
    return 0.5 * (np.dot(js, js) + np.dot(s * diag, s)) + np.dot(s, g)


@numba.njit(cache=True)
def minimize_quadratic_1d(a, b, lower, upper, c=0.0):  # pragma: no cover - compiled
    """(t, value) minimizing a t^2 + b t + c over [lower, upper] (the first of equal values: lower,
    upper, the extremum)."""
    best, best_value = lower, lower * (a * lower + b) + c
    value = upper * (a * upper + b) + c
    if value < best_value:
        best, best_value = upper, value
    if a != 0:
        extremum = -0.5 * b / a
        if lower < extremum < upper:
            value = extremum * (a * extremum + b) + c
            if value < best_value:
                best, best_value = extremum, value
    return best, best_value


@numba.njit(cache=True)
def intersect_trust_region(x, s, radius):  # pragma: no cover - compiled
    """(t_neg, t_pos) with |x + s t| = radius."""
    a, b, c = np.dot(s, s), np.dot(x, s), np.dot(x, x) - radius**2
    if a == 0:
        raise ValueError("`s` is zero.")
    if c > 0:
        raise ValueError("`x` is not within the trust region.")
    d = np.sqrt(b * b - a * c)
    q = -(b + np.copysign(d, b))
    if q == 0:  # x on the boundary and s tangent to it: a double root at 0 (scipy divides by zero)
        return 0.0, 0.0
    t1, t2 = q / a, c / q
    return (t1, t2) if t1 < t2 else (t2, t1)


@numba.njit(cache=True)
def step_size_to_bound(x, s, lower, upper):  # pragma: no cover - compiled
    """(t >= 0 at which x + s t first reaches a bound, which variables reach it: -1 lower, 1 upper)."""
    steps = np.full(x.size, np.inf)
    for j in range(x.size):
        if s[j] != 0:
            steps[j] = max((lower[j] - x[j]) / s[j], (upper[j] - x[j]) / s[j])
    smallest = np.min(steps)
    hits = np.zeros(x.size, dtype=np.int64)
    for j in range(x.size):
        if steps[j] == smallest:
            hits[j] = 1 if s[j] > 0 else (-1 if s[j] < 0 else 0)
    return smallest, hits


@numba.njit(cache=True)
def make_strictly_feasible(x, lower, upper, rstep=0.0):  # pragma: no cover - compiled
    """x with every entry within ``rstep`` (relative, at least absolute) of a bound, or past it,
    moved that far inside it; one ulp with rstep 0 (the midpoint where the bounds are closer)."""
    out = x.copy()
    for j in range(x.size):
        if rstep == 0:
            if x[j] <= lower[j]:
                out[j] = np.nextafter(lower[j], upper[j])
            elif x[j] >= upper[j]:
                out[j] = np.nextafter(upper[j], lower[j])
        else:
            below, above = x[j] - lower[j], upper[j] - x[j]
            if above <= min(below, rstep * max(1.0, abs(upper[j]))):
                out[j] = upper[j] - rstep * max(1.0, abs(upper[j]))
            elif below <= min(above, rstep * max(1.0, abs(lower[j]))):
                out[j] = lower[j] + rstep * max(1.0, abs(lower[j]))
        if out[j] < lower[j] or out[j] > upper[j]:
            out[j] = 0.5 * (lower[j] + upper[j])
    return out


@numba.njit(cache=True)
def cl_scaling_vector(x, g, lower, upper):  # pragma: no cover - compiled
    """Coleman-Li scaling (v, dv/dx): the distance to the bound the gradient points at (1 where
    that bound is infinite)."""
    v, dv = np.ones(x.size), np.zeros(x.size)
    for j in range(x.size):
        if g[j] > 0 and np.isfinite(lower[j]):
            v[j], dv[j] = x[j] - lower[j], 1.0
        elif g[j] < 0 and np.isfinite(upper[j]):
            v[j], dv[j] = upper[j] - x[j], -1.0
    return v, dv


@numba.njit(cache=True)
def check_termination(reduction, cost, step_norm, x_norm, ratio, ftol, xtol):  # pragma: no cover - compiled
    """scipy's status: 2 ftol, 3 xtol, 4 both, 0 to go on."""
    ftol_met = reduction < ftol * cost and ratio > 0.25
    xtol_met = step_norm < xtol * (xtol + x_norm)
    if ftol_met and xtol_met:
        return 4
    if ftol_met:
        return 2
    if xtol_met:
        return 3
    return 0


@numba.njit(cache=True)
def gradient_norm(g, v):  # pragma: no cover - compiled
    """|g v|_inf: the scaled gradient that gtol tests."""
    out = 0.0
    for j in range(g.size):
        out = max(out, abs(g[j] * v[j]))
    return out


@numba.njit(cache=True)
def scaled_variables(v, dv, g, scale):  # pragma: no cover - compiled
    """(d, diag_h, g_h) from Coleman-Li's (v, dv) (``cl_scaling_vector``) and the variables' scales:
    v divided by x_scale where dv is non-zero (in place), d = v^1/2 x_scale, diag_h = g dv x_scale,
    g_h = d g (scipy's trf)."""
    for j in range(v.size):
        if dv[j] != 0:
            v[j] /= scale[j]
    d = np.sqrt(v) * scale
    return d, g * dv * scale, d * g


@numba.njit(cache=True)
def first_radius(x, v, scale):  # pragma: no cover - compiled
    """The first trust radius |x / x_scale / v^1/2| over the variables that can move (v > 0; v
    after ``scaled_variables``), 1 where that is 0."""
    total = 0.0
    for j in range(x.size):
        if v[j] != 0:
            ratio = x[j] / scale[j] / np.sqrt(v[j])
            total += ratio * ratio
    return np.sqrt(total) if total > 0 else 1.0


@numba.njit(cache=True)
def subspace_basis(g_h, gn_h):  # pragma: no cover - compiled
    """An orthonormal basis of the span of g_h and gn_h (reduced QR), as the rows of a (2, n) array."""
    stacked = np.empty((g_h.size, 2))
    stacked[:, 0], stacked[:, 1] = g_h, gn_h
    return np.ascontiguousarray(np.linalg.qr(stacked)[0].T)


@numba.njit(cache=True)
def subspace_model(js0, js1, basis, diag_h, g_h):  # pragma: no cover - compiled
    """(B_s, g_s) of the quadratic model in the subspace of ``basis`` (rows S^T): B_s = J_s^T J_s +
    S^T diag_h S with J_s = [js0 js1] the Jacobian times the basis vectors, g_s = S^T g_h."""
    b = np.empty((2, 2))
    images = (js0, js1)
    for i in range(2):
        for k in range(2):
            b[i, k] = np.dot(images[i], images[k]) + np.dot(basis[i] * diag_h, basis[k])
    return b, np.array([np.dot(basis[0], g_h), np.dot(basis[1], g_h)])


@numba.njit(cache=True)
def norm(x):  # pragma: no cover - compiled
    """|x| (2-norm), as both loops take it."""
    return np.sqrt(np.dot(x, x))


@numba.njit(cache=True)
def in_subspace(basis, coordinates):  # pragma: no cover - compiled
    """The vector of the two ``coordinates`` in the subspace of ``basis`` (``subspace_basis``)."""
    return basis[0] * coordinates[0] + basis[1] * coordinates[1]
