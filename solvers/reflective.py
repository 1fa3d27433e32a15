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
  matrix).
"""
from __future__ import annotations

from typing import Callable, NamedTuple, Protocol

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
    x = make_strictly_feasible(np.asarray(x0, dtype=float), lower, upper, rstep=1e-10)
    f = residuals(x)
    evaluations = 1
    if not np.all(np.isfinite(f)):
        return Minimized(x, np.inf, evaluations, -1)
    cost = 0.5 * float(f @ f)
    linear = linearize(x)
    g = linear.transposed_product(f)
    scale, since = _scales(column_norms(x)), 0
    v, dv = cl_scaling_vector(x, g, lower, upper)
    v[dv != 0] /= scale[dv != 0]
    held = v == 0  # lower == upper: a fixed variable never moves (scipy refuses such bounds)
    radius = float(np.linalg.norm(x[~held] / scale[~held] / v[~held] ** 0.5)) or 1.0
    status = None
    while True:
        v, dv = cl_scaling_vector(x, g, lower, upper)
        g_norm = float(np.linalg.norm(g * v, ord=np.inf))
        if g_norm < GTOL:
            status = 1
        if status is not None or evaluations >= max_evaluations:
            break
        if since >= rescale_every:
            scale, since = _scales(column_norms(x)), 0
        v[dv != 0] /= scale[dv != 0]
        d = v**0.5 * scale
        diag_h = g * dv * scale
        g_h = d * g
        jh = _Scaled(linear, d)
        a, b = build_quadratic_1d(jh, g_h, -g_h, diag=diag_h)
        regularization = -minimize_quadratic_1d(a, b, 0, radius / np.linalg.norm(g_h))[1] / radius**2
        gn_h = linear.direction(d, diag_h + regularization, f)
        subspace, _ = np.linalg.qr(np.vstack((g_h, gn_h)).T, mode="reduced")
        js = np.column_stack([jh.dot(column) for column in subspace.T])
        b_s = js.T @ js + (subspace.T * diag_h) @ subspace
        g_s = subspace.T @ g_h
        theta = max(0.995, 1 - g_norm)
        reduction = -1.0
        while reduction <= 0 and evaluations < max_evaluations:
            p_s, _ = solve_trust_region_2d(b_s, g_s, radius)
            p_h = subspace @ p_s
            step, step_h, predicted = select_step(x, jh, diag_h, g_h, d * p_h, p_h, d, radius, lower, upper, theta)
            trial = make_strictly_feasible(x + step, lower, upper)
            f_trial = residuals(trial)
            evaluations, since = evaluations + 1, since + 1
            step_h_norm = float(np.linalg.norm(step_h))
            if not np.all(np.isfinite(f_trial)):
                radius = 0.25 * step_h_norm
                continue
            trial_cost = 0.5 * float(f_trial @ f_trial)
            reduction = cost - trial_cost
            new_radius, ratio = update_tr_radius(radius, reduction, predicted, step_h_norm,
                                                 step_h_norm > 0.95 * radius)
            status = check_termination(reduction, cost, float(np.linalg.norm(step)), float(np.linalg.norm(x)),
                                       ratio, FTOL, XTOL)
            if status is not None:
                break
            radius = new_radius
        if reduction > 0:
            x, f, cost = trial, f_trial, trial_cost
            linear = linearize(x)
            g = linear.transposed_product(f)
    return Minimized(x, cost, evaluations, 0 if status is None else status)


def _scales(norms: np.ndarray) -> np.ndarray:
    """x_scale from the column norms (1 where a column vanishes)."""
    return 1.0 / np.where(norms > 0, norms, 1.0)


class _Scaled:
    """J diag(d) (scipy's right_multiplied_operator), products only."""

    def __init__(self, linear: Linearization, d: np.ndarray):
        self.linear, self.d = linear, d

    def dot(self, v: np.ndarray) -> np.ndarray:
        return self.linear.product(self.d * v)


def select_step(x, jh, diag_h, g_h, p, p_h, d, radius, lower, upper, theta):
    """(step, step in the scaled variables, predicted decrease): the best of the trust-region step
    (stepped back inside the box), its reflection at the first bound it hits, and the scaled
    gradient step (scipy's trf.select_step)."""
    if np.all((x + p >= lower) & (x + p <= upper)):
        return p, p_h, -evaluate_quadratic(jh, g_h, p_h, diag=diag_h)
    p_stride, hits = step_size_to_bound(x, p, lower, upper)
    r_h = np.copy(p_h)
    r_h[hits.astype(bool)] *= -1
    r = d * r_h
    p, p_h = p * p_stride, p_h * p_stride
    x_on_bound = x + p
    _, to_tr = intersect_trust_region(p_h, r_h, radius)
    to_bound, _ = step_size_to_bound(x_on_bound, r, lower, upper)
    r_stride = min(to_bound, to_tr)
    if r_stride > 0:
        r_stride_l = (1 - theta) * p_stride / r_stride
        r_stride_u = theta * to_bound if r_stride == to_bound else to_tr
    else:
        r_stride_l, r_stride_u = 0, -1
    if r_stride_l <= r_stride_u:
        a, b, c = build_quadratic_1d(jh, g_h, r_h, s0=p_h, diag=diag_h)
        r_stride, r_value = minimize_quadratic_1d(a, b, r_stride_l, r_stride_u, c=c)
        r_h = r_h * r_stride + p_h
        r = r_h * d
    else:
        r_value = np.inf
    p, p_h = p * theta, p_h * theta
    p_value = evaluate_quadratic(jh, g_h, p_h, diag=diag_h)
    ag_h = -g_h
    ag = d * ag_h
    to_tr = radius / np.linalg.norm(ag_h)
    to_bound, _ = step_size_to_bound(x, ag, lower, upper)
    ag_stride = theta * to_bound if to_bound < to_tr else to_tr
    a, b = build_quadratic_1d(jh, g_h, ag_h, diag=diag_h)
    ag_stride, ag_value = minimize_quadratic_1d(a, b, 0, ag_stride)
    ag_h, ag = ag_h * ag_stride, ag * ag_stride
    if p_value < r_value and p_value < ag_value:
        return p, p_h, -p_value
    if r_value < p_value and r_value < ag_value:
        return r, r_h, -r_value
    return ag, ag_h, -ag_value


def solve_trust_region_2d(b, g, radius):
    """(p, Newton step inside) minimizing 1/2 p^T B p + g^T p over |p| <= radius in two dimensions:
    the Newton step where B is definite and it fits, else the boundary's minimum from a quartic
    (scipy's common.solve_trust_region_2d)."""
    try:
        factor = np.linalg.cholesky(b)
        p = -np.linalg.solve(factor.T, np.linalg.solve(factor, g))
        if p @ p <= radius**2:
            return p, True
    except np.linalg.LinAlgError:
        pass
    a, bb, c = b[0, 0] * radius**2, b[0, 1] * radius**2, b[1, 1] * radius**2
    d, f = g[0] * radius, g[1] * radius
    t = np.roots(np.array([-bb + d, 2 * (a - c + f), 6 * bb, 2 * (-a + c + f), -bb - d]))
    t = np.real(t[np.isreal(t)])
    p = radius * np.vstack((2 * t / (1 + t**2), (1 - t**2) / (1 + t**2)))
    value = 0.5 * np.sum(p * b.dot(p), axis=0) + g @ p
    return p[:, np.argmin(value)], False


def update_tr_radius(radius, reduction, predicted, step_norm, bound_hit):
    """(radius, ratio of actual to predicted decrease) after a step (scipy's common.update_tr_radius)."""
    if predicted > 0:
        ratio = reduction / predicted
    elif predicted == reduction == 0:
        ratio = 1
    else:
        ratio = 0
    if ratio < 0.25:
        radius = 0.25 * step_norm
    elif ratio > 0.75 and bound_hit:
        radius *= 2.0
    return radius, ratio


def build_quadratic_1d(jh, g, s, diag=None, s0=None):
    """Coefficients of 1/2 (s0 + s t)^T (J^T J + diag) (s0 + s t) + g^T (s0 + s t) in t: (a, b), and
    c with s0 (scipy's common.build_quadratic_1d)."""
    v = jh.dot(s)
    a = v @ v
    if diag is not None:
        a += (s * diag) @ s
    a *= 0.5
    b = g @ s
    if s0 is None:
        return a, b
    u = jh.dot(s0)
    b += u @ v
    c = 0.5 * (u @ u) + g @ s0
    if diag is not None:
        b += (s0 * diag) @ s
        c += 0.5 * (s0 * diag) @ s0
    return a, b, c


def minimize_quadratic_1d(a, b, lower, upper, c=0):
    """(t, value) minimizing a t^2 + b t + c over [lower, upper]."""
    t = [lower, upper]
    if a != 0:
        extremum = -0.5 * b / a
        if lower < extremum < upper:
            t.append(extremum)
    t = np.asarray(t, dtype=float)
    y = t * (a * t + b) + c
    best = np.argmin(y)
    return t[best], y[best]


def evaluate_quadratic(jh, g, s, diag=None):
    """1/2 s^T (J^T J + diag) s + g^T s."""
    js = jh.dot(s)
    q = js @ js
    if diag is not None:
        q += (s * diag) @ s
    return 0.5 * q + s @ g


def intersect_trust_region(x, s, radius):
    """(t_neg, t_pos) with |x + s t| = radius."""
    a, b, c = s @ s, x @ s, x @ x - radius**2
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


def step_size_to_bound(x, s, lower, upper):
    """(t >= 0 at which x + s t first reaches a bound, which variables reach it: -1 lower, 1 upper)."""
    nonzero = np.nonzero(s)
    steps = np.full_like(x, np.inf)
    with np.errstate(over="ignore"):
        steps[nonzero] = np.maximum((lower - x)[nonzero] / s[nonzero], (upper - x)[nonzero] / s[nonzero])
    smallest = np.min(steps)
    return smallest, np.equal(steps, smallest) * np.sign(s).astype(int)


def make_strictly_feasible(x, lower, upper, rstep=0.0):
    """x with every entry within ``rstep`` (relative, at least absolute) of a bound, or past it,
    moved that far inside it; one ulp with rstep 0 (the midpoint where the bounds are closer)."""
    out = x.copy()
    if rstep == 0:
        at_lower, at_upper = x <= lower, x >= upper
        out[at_lower] = np.nextafter(lower[at_lower], upper[at_lower])
        out[at_upper] = np.nextafter(upper[at_upper], lower[at_upper])
    else:
        below, above = x - lower, upper - x
        at_upper = above <= np.minimum(below, rstep * np.maximum(1, np.abs(upper)))
        at_lower = (below <= np.minimum(above, rstep * np.maximum(1, np.abs(lower)))) & ~at_upper
        out[at_lower] = lower[at_lower] + rstep * np.maximum(1, np.abs(lower[at_lower]))
        out[at_upper] = upper[at_upper] - rstep * np.maximum(1, np.abs(upper[at_upper]))
    tight = (out < lower) | (out > upper)
    out[tight] = 0.5 * (lower[tight] + upper[tight])
    return out


def cl_scaling_vector(x, g, lower, upper):
    """Coleman-Li scaling (v, dv/dx): the distance to the bound the gradient points at (1 where
    that bound is infinite)."""
    v, dv = np.ones_like(x), np.zeros_like(x)
    mask = (g < 0) & np.isfinite(upper)
    v[mask], dv[mask] = upper[mask] - x[mask], -1
    mask = (g > 0) & np.isfinite(lower)
    v[mask], dv[mask] = x[mask] - lower[mask], 1
    return v, dv


def check_termination(reduction, cost, step_norm, x_norm, ratio, ftol, xtol):
    """scipy's status: 2 ftol, 3 xtol, 4 both, None to go on."""
    ftol_met = reduction < ftol * cost and ratio > 0.25
    xtol_met = step_norm < xtol * (xtol + x_norm)
    if ftol_met and xtol_met:
        return 4
    if ftol_met:
        return 2
    if xtol_met:
        return 3
    return None
