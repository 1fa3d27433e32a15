"""asc's start for a strand held by its root alone: the optimum, element by element.

At q* an element's forces depend on its parameters only through products of its multiplier and
its rest change (formulation.rest_change): z = k (kbar - kappa*, mbar - m*) for a vertex, whose
stresses are linear in z divided by lbar_{i-1} + lbar_i, and k u / (1 + u) for an edge. For a
strand held by its root alone the rest blocks' columns of dc/dp at p0 form a square system (the
root edge's rest length acts on no free DOF; a vertex's 5 kinematics move in only 3 directions,
benchmarks/study_vertex_decomposition.py), so the linear start's least rest change at unit
stiffness (alm.linear_start) is the only one: it fixes every vertex's z and every edge's stretch
force, whatever the multipliers. The parameter problem then falls apart into convex problems in one
multiplier each:

- an edge with stretch force -E pi r^2 t (t = -u at unit stiffness): u = -t / (a + t) for the
  multiplier a, and its share of R is w_u t^2 / (a + t)^2 + w_a (a - 1)^2 (halved), convex in
  b = a + t;
- a vertex: delta = z / k, and its share of R is sum_j w_j (z_j / k)^2 + w_k (k - 1)^2 (halved),
  convex in k (the twist modulus follows the bend multiplier);
- every box is an interval of the multiplier (delta = z / k and u inside their boxes);
- the root edge's rest length is free but for the first vertex's lbar_0 + lbar_1, a cheap stiffener
  there (asc moves it to its bound): chosen jointly with that vertex's multiplier.

The interior edges' rest lengths (~1e-8, the strain that holds gravity) scale their vertices' z
through the lbar sums: taken into account, but not in the edges' own choice, so the start is the
optimum to ~1e-10 in R; asc confirms it (its KKT check) or polishes it. Against the linear start's
least multipliers that fit the boxes (rest_change.spread_rest_change), the optimum stiffens every
vertex a little where it trades stiffness for rest change. Applies to per-element stiffness with the
twist coupled to bend, every block optimized, no bodies, a clamped root and nothing else held
(``applies``); ``None`` elsewhere, where the system is not square, or where a box admits no
multiplier.
"""
from __future__ import annotations

import numpy as np

from sagfree.formulation.parameters import BLOCKS, CONTACT_BLOCK, REST_BLOCKS
from sagfree.formulation.problem import Problem
from sagfree.linalg.band import column_norms

#: coordinate-descent rounds for the root edge's rest length and the first vertex's multiplier
ROOT_STEPS = 100
#: Newton steps of least_multiplier (monotone from the left end; ~6 reach the rounding)
NEWTON_STEPS = 60
EPS = float(np.finfo(float).eps)


def applies(problem: Problem) -> bool:
    """True where the module's decomposition can hold (module docstring, last sentence)."""
    layout, strand = problem.layout, problem.strand
    return (layout.stiffness == "element" and layout.couple_twist
            and set(layout.blocks) == set(BLOCKS) - {"twist_stiffness"} and CONTACT_BLOCK not in layout.blocks
            and strand.root == "clamped" and strand.tip is None and len(strand.pins) == 0)


def statics_start(problem: Problem, change: np.ndarray) -> np.ndarray | None:
    """The optimum of the module docstring from the least rest change ``change`` at unit stiffness
    (alm.linear_start's step), or None where it does not apply."""
    if not applies(problem):
        return None
    layout = problem.layout
    acting = column_norms(problem.strand_jacobian(layout.p0))[layout.block_mask(REST_BLOCKS)] > 0
    if int(acting.sum()) != int(problem.free.sum()):
        return None  # not square: the rest change is not the only one
    blocks, p0, w, lower, upper = layout.blocks, layout.p0, layout.weights, layout.lower, layout.upper
    rate, multiplier, bend = blocks["rest_length"], blocks["stretch_stiffness"], blocks["bend_stiffness"]
    rest = np.column_stack([blocks["rest_curvature"].reshape(-1, 2), blocks["rest_twist"]])
    p = p0.copy()
    # the acting edges (all but the root one): b = a + t
    t = -change[rate[1:]]
    iu, ia = rate[1:], multiplier[1:]
    low = lower[ia] + t
    for bound in (lower[iu], upper[iu]):  # u = -t / b inside [lower, upper]
        with np.errstate(divide="ignore", invalid="ignore"):
            side = np.where(bound != 0.0, -t / bound, 0.0)
        low = np.maximum(low, np.where(side > 0, side, 0.0))
    b = least_multiplier(w[iu] * t**2, w[ia], p0[ia] + t, low, upper[ia] + t)
    if b is None:
        return None
    p[ia], p[iu] = b - t, -t / b
    # the vertices, their z scaled by their lbar sums; the first one with the root edge's rest length
    lengths = problem.edge_lengths
    unit_sums = lengths[:-1] + lengths[1:]
    scale = (lengths[:-1] * (1 + p[rate[:-1]]) + lengths[1:] * (1 + p[rate[1:]])) / unit_sums
    unit_z = change[rest]  # z at unit stiffness and lbar = l0
    width = np.where(unit_z > 0, upper[rest] - p0[rest], lower[rest] - p0[rest])
    with np.errstate(divide="ignore", invalid="ignore"):
        needed = np.max(np.where(unit_z != 0.0, unit_z / width, 0.0), axis=1)  # multiplier per unit sum
    z = unit_z * scale[:, None]
    beta = least_multiplier(np.sum(w[rest] * z**2, axis=1), w[bend], p0[bend], np.maximum(lower[bend], needed * scale),
                            upper[bend])
    if beta is None:
        return None
    root = _root_rest_length(problem, float(np.sum(w[rest[0]] * unit_z[0] ** 2)), float(needed[0]),
                             float(lengths[1] * (1 + p[rate[1]])), float(unit_sums[0]))
    if root is None:
        return None
    p[rate[0]], scale[0], beta[0] = root
    p[bend] = beta
    p[rest] = p0[rest] + unit_z * scale[:, None] / beta[:, None]
    return np.clip(p, lower, upper)


def _root_rest_length(problem: Problem, a: float, needed: float, others: float, unit: float):
    """(u0, the first vertex's sum scale, its multiplier) minimizing the root edge's rest-length
    term plus the first vertex's share of R, by coordinate descent: for a fixed multiplier (free or
    on its box, where it moves with the sum) the share is quadratic in u0, and for a fixed u0 the
    multiplier is ``least_multiplier``'s. ``others``: the rest of the first vertex's lbar sum
    (lbar_1), ``unit``: l0_0 + l0_1, a: sum w_j z_j^2 at the unit sum, needed: its multiplier per
    unit sum that keeps the rest shape in its box."""
    layout = problem.layout
    w, lower, upper, p0 = layout.weights, layout.lower, layout.upper, layout.p0
    iu, ib = layout.blocks["rest_length"][0], layout.blocks["bend_stiffness"][0]
    l0 = problem.edge_lengths[0]
    wu, wb = w[iu], w[ib]
    base, slope = (l0 + others) / unit, l0 / unit  # the sum scale is base + slope u0
    u0 = p0[iu]
    for _ in range(ROOT_STEPS):
        scale = base + slope * u0
        low = max(lower[ib], needed * scale)
        if not 0 < low <= upper[ib]:
            return None
        beta = _least_multiplier_scalar(a * scale**2, wb, p0[ib], low, upper[ib])
        if beta <= low * (1 + 1e-15) and needed * scale >= lower[ib]:  # on the box: beta = needed x scale
            # 1/2 wu u0^2 + 1/2 a / needed^2 + 1/2 wb (needed (base + slope u0) - 1)^2
            numerator, denominator = -wb * needed * slope * (needed * base - p0[ib]), wu + wb * (needed * slope) ** 2
        else:  # 1/2 wu u0^2 + 1/2 a (base + slope u0)^2 / beta^2
            numerator, denominator = -a * slope * base / beta**2, wu + a * slope**2 / beta**2
        if denominator == 0.0:  # the share does not depend on u0: keep it
            break
        u_new = numerator / denominator
        u_new = min(max(u_new, lower[iu]), upper[iu])
        if abs(u_new - u0) <= 4 * EPS * (upper[iu] - lower[iu]):
            u0 = u_new
            break
        u0 = u_new
    scale = base + slope * u0
    return u0, scale, beta


def _least_multiplier_scalar(a: float, weight: float, centre: float, low: float, high: float) -> float:
    """``least_multiplier`` for one multiplier, in plain floats (the root's coordinate descent)."""
    x = low
    for _ in range(NEWTON_STEPS):
        curvature = 6.0 * a / x**4 + 2.0 * weight
        if curvature == 0.0:  # no rest change and no weight: any multiplier, the lowest
            return x
        moved = min(max(x - (-2.0 * a / x**3 + 2.0 * weight * (x - centre)) / curvature, low), high)
        if abs(moved - x) <= 4 * EPS * x:
            return moved
        x = moved
    return x


def least_multiplier(a, weight, centre, low, high):
    """argmin over x in [low, high] of a / x^2 + weight (x - centre)^2, elementwise (convex for x > 0:
    its derivative is increasing and concave, so Newton from the left end converges monotonically);
    None where an interval is empty or not positive."""
    a, weight, centre = (np.asarray(v, dtype=float) for v in (a, weight, centre))
    low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
    if np.any(~(low <= high)) or np.any(~(low > 0)):
        return None
    slope = lambda x: -2.0 * a / x**3 + 2.0 * weight * (x - centre)  # noqa: E731
    x = low.copy()
    for _ in range(NEWTON_STEPS):
        curvature = 6.0 * a / x**4 + 2.0 * weight  # 0 only with no rest change and no weight: keep the lowest
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(curvature > 0.0, slope(x) / curvature, 0.0)
        moved = np.maximum(np.minimum(x - step, high), low)
        if np.all(np.abs(moved - x) <= 4 * EPS * x):
            return moved
        x = moved
    return x
