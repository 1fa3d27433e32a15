"""asc's start for a strand held by its root alone: the optimum, element by element.

At q* an element's forces depend on its parameters only through products of its multiplier and
its rest change (formulation.rest_change): z = k (kbar - kappa*, mbar - m*) for a vertex, whose
stresses are linear in z divided by lbar_{i-1} + lbar_i, and k u / (1 + u) for an edge. For a
strand held by its root alone the rest blocks' columns of dc/dp at p0 form a square system (the
root edge's rest length acts on no free DOF; a vertex's 5 kinematics move in only 3 directions,
benchmarks/study_vertex_decomposition.py), so the linear start's least rest change at unit
stiffness (alm.linear_start; one band LU of that square system, linalg.square) is the only one: it fixes every vertex's z and every edge's stretch
force, whatever the multipliers. The parameter problem then falls apart into convex problems in one
multiplier each:

- an edge with stretch force -E pi r^2 t (t = -u at unit stiffness): u = -t / (a + t) for the
  multiplier a, and its share of R is w_u t^2 / (a + t)^2 + w_a (a - 1)^2 (halved), convex in
  b = a + t;
- a vertex: delta = z / k, and its share of R is sum_j w_j (z_j / k)^2 + w_k (k - 1)^2 (halved),
  convex in k (the twist modulus follows the bend multiplier);
- every box is an interval of the multiplier (delta = z / k and u inside their boxes);
- the root edge's rest length is free but for the first vertex's lbar_0 + lbar_1, a cheap stiffener
  there (asc moves it to its bound): chosen jointly with that vertex's multiplier by coordinate
  descent, each step kept where the vertex's rest change stays inside its box (a stiffness floor
  can hold the multiplier above what the box needs, and a free step of the rest length then
  carried the change out of it).

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

import numba
import numpy as np

from sagfree.formulation.parameters import BLOCKS, CONTACT_BLOCK, REST_BLOCKS
from sagfree.formulation.problem import Problem
from sagfree.linalg.band import column_norms

#: coordinate-descent rounds for the root edge's rest length and the first vertex's multiplier
ROOT_STEPS = 100
#: Newton steps of least_multiplier_scalar (monotone from the left end; ~6 reach the rounding)
NEWTON_STEPS = 60
EPS = float(np.finfo(float).eps)
#: share of a box's width within which the start puts a value on the bound (onto_near_bound)
NEAR_BOUND = 1e-12


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
    if not square_rest_system(problem):
        return None  # the rest change is not the only one
    blocks = layout.blocks
    rest = np.column_stack([blocks["rest_curvature"].reshape(-1, 2), blocks["rest_twist"]])
    p = _optimum(np.ascontiguousarray(change, dtype=float), layout.p0, layout.weights, layout.lower, layout.upper,
                 blocks["rest_length"], blocks["stretch_stiffness"], blocks["bend_stiffness"], rest,
                 problem.edge_lengths)
    return p if p.size else None


def square_rest_system(problem: Problem) -> bool:
    """True where the module's decomposition applies (``applies``) and the rest blocks' columns of
    dc/dp at p0 that act on a free DOF are as many as the free DOFs (the module docstring's square
    system); checked once per strand (Problem.bound_independent)."""
    return applies(problem) and problem.bound_independent("square rest system", lambda: _square_rest_columns(problem))


def _square_rest_columns(problem: Problem) -> bool:
    acting = column_norms(problem.strand_jacobian(problem.layout.p0))[problem.layout.block_mask(REST_BLOCKS)] > 0
    return int(acting.sum()) == int(problem.free.sum())


@numba.njit(cache=True)
def _optimum(change, p0, w, lower, upper, rate, multiplier, bend, rest, lengths):  # pragma: no cover - compiled
    """The start of the module docstring in one compiled call (statics_start's arrays: the layout's
    p0, weights and box, the blocks' indices, rest (S, 3) the vertices' rest entries, the edge
    lengths l0); empty where a box admits no multiplier."""
    p = p0.copy()
    for e in range(1, rate.size):  # the acting edges: b = a + t, u = -t / b
        iu, ia = rate[e], multiplier[e]
        t = -change[iu]
        low = lower[ia] + t
        for bound in (lower[iu], upper[iu]):
            if bound != 0.0 and -t / bound > 0.0:
                low = max(low, -t / bound)
        high = upper[ia] + t
        if not 0.0 < low <= high:
            return np.empty(0)
        b = least_multiplier_scalar(w[iu] * t * t, w[ia], p0[ia] + t, low, high)
        p[ia] = onto_near_bound(b - t, lower[ia], upper[ia])
        if p[ia] + t > 0.0:
            b = p[ia] + t
        p[iu] = -t / b
    stencils = bend.size
    unit_z, scale, needed, beta = np.empty((stencils, 3)), np.empty(stencils), np.empty(stencils), np.empty(stencils)
    for v in range(stencils):  # the vertices, their z scaled by their lbar sums
        unit = lengths[v] + lengths[v + 1]
        scale[v] = (lengths[v] * (1.0 + p[rate[v]]) + lengths[v + 1] * (1.0 + p[rate[v + 1]])) / unit
        needed[v], a = 0.0, 0.0
        for j in range(3):
            i = rest[v, j]
            z = change[i]
            unit_z[v, j] = z
            a += w[i] * (z * scale[v]) ** 2
            if z != 0.0:  # the multiplier per unit sum that keeps z / k in its box
                width = upper[i] - p0[i] if z > 0.0 else lower[i] - p0[i]
                needed[v] = max(needed[v], z / width if width != 0.0 else np.inf)
        ib = bend[v]
        low = max(lower[ib], needed[v] * scale[v])
        if not 0.0 < low <= upper[ib]:
            return np.empty(0)
        beta[v] = least_multiplier_scalar(a, w[ib], p0[ib], low, upper[ib])
    # the first vertex with the root edge's rest length (coordinate descent, each step in closed form)
    iu, ib = rate[0], bend[0]
    a = 0.0
    for j in range(3):
        a += w[rest[0, j]] * unit_z[0, j] ** 2
    unit = lengths[0] + lengths[1]
    base, slope = (lengths[0] + lengths[1] * (1.0 + p[rate[1]])) / unit, lengths[0] / unit  # sum scale: base + slope u0
    u0 = p0[iu]
    for _ in range(ROOT_STEPS):
        sum_scale = base + slope * u0
        low = max(lower[ib], needed[0] * sum_scale)
        if not 0.0 < low <= upper[ib]:
            return np.empty(0)
        beta[0] = least_multiplier_scalar(a * sum_scale**2, w[ib], p0[ib], low, upper[ib])
        on_rest_box = beta[0] <= low * (1.0 + 1e-15) and needed[0] * sum_scale >= lower[ib]
        # each step keeps the vertex's rest change delta = z (base + slope u0) / beta inside its box,
        # beta >= needed (base + slope u0), and beta inside its own (a floor may hold it above needed)
        if on_rest_box:
            # beta = needed x scale: 1/2 wu u0^2 + 1/2 a / needed^2 + 1/2 wb (needed (base + slope u0) - 1)^2
            numerator = -w[ib] * needed[0] * slope * (needed[0] * base - p0[ib])
            denominator = w[iu] + w[ib] * (needed[0] * slope) ** 2
            least = max(lower[iu], (lower[ib] / needed[0] - base) / slope)
            most = min(upper[iu], (upper[ib] / needed[0] - base) / slope)
        else:  # beta fixed: 1/2 wu u0^2 + 1/2 a (base + slope u0)^2 / beta^2
            numerator = -a * slope * base / beta[0] ** 2
            denominator = w[iu] + a * slope**2 / beta[0] ** 2
            least, most = lower[iu], upper[iu]
            if needed[0] > 0.0:
                most = min(most, (beta[0] / needed[0] - base) / slope)
        if denominator == 0.0:  # the share does not depend on u0: keep it
            break
        moved = min(max(numerator / denominator, least), most)
        done = abs(moved - u0) <= 4.0 * EPS * (upper[iu] - lower[iu])
        u0 = moved
        if on_rest_box:
            beta[0] = needed[0] * (base + slope * u0)
        if done:
            break
    p[iu] = u0
    scale[0] = base + slope * u0
    for v in range(stencils):
        ib = bend[v]
        if needed[v] * scale[v] <= lower[ib]:  # not held up by the rest box: a bound keeps delta inside it
            beta[v] = onto_near_bound(beta[v], lower[ib], upper[ib])
        p[ib] = beta[v]
        for j in range(3):
            i = rest[v, j]
            p[i] = onto_near_bound(p0[i] + unit_z[v, j] * scale[v] / beta[v], lower[i], upper[i])
    for k in range(p.size):
        p[k] = min(max(p[k], lower[k]), upper[k])
    return p


@numba.njit(cache=True)
def onto_near_bound(x, low, high):  # pragma: no cover - compiled
    """x, or the bound it is within NEAR_BOUND of the box's width from: a multiplier whose optimum
    sits a rounding-sized hair inside its box (an edge's is 1 + ~t^2, 3e-13 above its bound) or a
    rest change at its box's edge up to rounding is ON the bound, as a solver's projection puts it,
    so every KKT measure sees an active bound there rather than a free variable whose tiny reduced
    gradient the decomposition does not zero (the edges' choice leaves out their rest lengths'
    effect on the vertices)."""
    width = high - low
    if x - low <= NEAR_BOUND * width:
        return low
    if high - x <= NEAR_BOUND * width:
        return high
    return x


@numba.njit(cache=True)
def least_multiplier_scalar(a, weight, centre, low, high):  # pragma: no cover - compiled
    """argmin over x in [low, high] (0 < low <= high) of a / x^2 + weight (x - centre)^2: convex for
    x > 0, its derivative increasing and concave, so Newton from the left end converges
    monotonically; with neither a nor weight, the lowest x."""
    x = low
    for _ in range(NEWTON_STEPS):
        curvature = 6.0 * a / x**4 + 2.0 * weight
        if curvature == 0.0:
            return x
        moved = min(max(x - (-2.0 * a / x**3 + 2.0 * weight * (x - centre)) / curvature, low), high)
        if abs(moved - x) <= 4.0 * EPS * x:
            return moved
        x = moved
    return x
