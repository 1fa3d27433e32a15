"""asc's start for a strand held by its root alone: the optimum, element by element.

At q* an element's forces depend on its parameters only through products of its multiplier and
its rest change (formulation.rest_change): z = k (kbar - kappa*, mbar - m*) for a vertex, whose
stresses are linear in z divided by lbar_{i-1} + lbar_i, and k u / (1 + u) for an edge. For a
strand held by its root alone the rest blocks' columns of dc/dp at p0 form a square system (the
root edge's rest length acts on no free DOF; a vertex's 5 kinematics move in only 3 directions,
benchmarks/study_vertex_decomposition.py), so the linear start's least rest change at unit
stiffness (alm.linear_start; one band LU of that square system, linalg.square) is the only one:
it fixes every vertex's z and every edge's stretch force, whatever the multipliers. The parameter
problem then falls apart into convex problems in one multiplier each:

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

The interior edges' rest lengths (the strain that holds gravity) scale their vertices' z through
the lbar sums, so the edges and vertices are coupled: each edge's choice adds the marginal cost of
its rest length on its two vertices' shares (their envelope derivative, a term a1 / b in its
share: least_scalar), and edges and vertices are swept until no multiplier moves (a few sweeps).
Near the root, where the vertices are stiffened, that cost lifts the first edges' multipliers
~1e-5 above 1; without it the start missed the KKT tolerance there and Gauss-Newton had to take
over. asc confirms the start (its KKT check) or polishes it. Against the linear start's
least multipliers that fit the boxes (rest_change.spread_rest_change), the optimum stiffens every
vertex a little where it trades stiffness for rest change. Applies to per-element stiffness with the
twist coupled to bend, every block optimized, no bodies, a clamped root and nothing else held
(``applies``); ``None`` elsewhere, where the system is not square, or where a box admits no
multiplier.

The same decomposition proves infeasibility (``unbalanceable``): an element whose box admits no
multiplier at the most favourable rest lengths the boxes allow cannot carry what the unique rest
change asks of it, whatever the other parameters are, so no p in the box balances the strand.
"""
from __future__ import annotations

import numba
import numpy as np

from sagfree.formulation.parameters import BLOCKS, CONTACT_BLOCK, REST_BLOCKS, number_ranges
from sagfree.formulation.problem import Problem
from sagfree.linalg.band import column_norms

#: coordinate-descent rounds for the root edge's rest length and the first vertex's multiplier
ROOT_STEPS = 100
#: sweeps over the edges and vertices coupled through the vertices' rest-length sums (statics_optimum)
SWEEPS = 20
#: Newton steps of least_multiplier_scalar (monotone from the left end; ~6 reach the rounding)
NEWTON_STEPS = 60
EPS = float(np.finfo(float).eps)
#: share of a box's width within which the start puts a value on the bound (onto_near_bound)
NEAR_BOUND = 1e-12
#: relative excess over its upper bound of a multiplier the balance needs that certifies infeasibility (unbalanceable)
CERTAIN_EXCESS = 1e-6
#: runs of elements an infeasibility certificate's message names
CERTIFICATE_NAMES = 6
#: share of a box's width within which optimum_gradient takes a value as held by that bound
ON_BOUND = 1e-9


def applies(problem: Problem) -> bool:
    """True where the module's decomposition can hold (module docstring, last sentence)."""
    return decomposable(problem) and problem.strand.tip is None and len(problem.strand.pins) == 0


def decomposable(problem: Problem) -> bool:
    """True where the element-by-element decomposition can hold whatever holds the strand besides its
    root (``applies``; solvers.reaction_start adds a pinned tip or pins): per-element stiffness with
    the twist coupled to bend, every block optimized, no bodies, a clamped root."""
    layout = problem.layout
    return (layout.stiffness == "element" and layout.couple_twist
            and set(layout.blocks) == set(BLOCKS) - {"twist_stiffness"} and CONTACT_BLOCK not in layout.blocks
            and problem.strand.root == "clamped")


def statics_start(problem: Problem, change: np.ndarray) -> np.ndarray | None:
    """The optimum of the module docstring from the least rest change ``change`` at unit stiffness
    (alm.linear_start's step), or None where it does not apply."""
    if not applies(problem):
        return None
    layout = problem.layout
    if not square_rest_system(problem):
        return None  # the rest change is not the only one
    p = statics_optimum(np.ascontiguousarray(change, dtype=float), layout.p0, layout.weights, layout.lower,
                        layout.upper, *statics_indices(problem), problem.edge_lengths)
    return p if p.size else None


def unbalanceable(problem: Problem, change: np.ndarray) -> str | None:
    """Why no p in the box balances the strand, or None where some might (a certificate, not a test).

    Where the rest system is square (square_rest_system), every vertex's z and every edge's stretch
    force at unit stiffness are fixed by the least rest change ``change``, whatever the parameters
    (module docstring). So an edge whose interval of b = a + t is empty (edge_intervals) cannot
    carry its force inside its boxes, and a vertex whose needed multiplier at the smallest lbar-sum
    scale its two edges allow, needed x scale, exceeds its bend multiplier's upper bound by more than
    CERTAIN_EXCESS (the rounding of ``change`` is far below it) cannot keep its rest change inside
    its box. The message names those elements (the first few runs) and the bend bound that holds
    them: with every edge's interval non-empty, the rest lengths at their least scale and each
    multiplier at max(lower, needed x scale) balance the strand, so the certificate is exact both
    ways (up to CERTAIN_EXCESS). asc then goes straight to the best effort (alm.solve_alm): on long hair
    the augmented Lagrangian otherwise spent most of the solve finding the infeasibility itself.
    """
    if not square_rest_system(problem):
        return None
    layout = problem.layout
    lower, upper = layout.lower, layout.upper
    rate, multiplier, bend, rest = statics_indices(problem)
    low, high, least_multiplier = least_multipliers(change, layout.p0, layout.weights, lower, upper, rate, multiplier,
                                                    rest, problem.edge_lengths)
    empty = np.flatnonzero(~((low > 0.0) & (low <= high)))
    empty = empty[empty > 0]  # the root edge's rest length acts on no free DOF
    short = np.flatnonzero(least_multiplier > upper[bend] * (1.0 + CERTAIN_EXCESS))
    if empty.size == 0 and short.size == 0:
        return None
    parts = []
    numbers = layout.element_numbers(np.concatenate([bend[short], multiplier[empty]]))
    if short.size:
        one = short.size == 1
        parts.append(f"{short.size} {'vertex' if one else 'vertices'} "
                     f"({number_ranges(numbers['bend_stiffness'], CERTIFICATE_NAMES)}) {'needs' if one else 'need'} a "
                     f"bend_stiffness above its upper bound {upper[bend].max():.4g} to keep {'its' if one else 'their'} "
                     "rest change inside the rest_curvature and rest_twist box; an upper bound of "
                     f"{_rounded_up(least_multiplier[short].max())} holds {'it' if one else 'them'}")
    if empty.size:
        one = empty.size == 1
        parts.append(f"{empty.size} {'edge' if one else 'edges'} "
                     f"({number_ranges(numbers['stretch_stiffness'], CERTIFICATE_NAMES)}) cannot carry "
                     f"{'its' if one else 'their'} stretch force with stretch_stiffness and rest_length inside "
                     "their boxes")
    return "; ".join(parts)


def _rounded_up(x: float, digits: int = 4) -> str:
    """x rounded up to ``digits`` significant digits, as text: a bound a message suggests must not
    fall below what it is for."""
    if not np.isfinite(x) or x <= 0.0:
        return f"{x:g}"
    unit = 10.0 ** (np.floor(np.log10(x)) - digits + 1)
    return f"{np.ceil(x / unit) * unit:.{digits}g}"


def statics_indices(problem: Problem) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """statics_optimum's block indices into p: the rest lengths, stretch and bend multipliers, and
    (S, 3) each vertex's rest curvature and twist entries."""
    return problem.layout.by_structure("statics indices", _statics_indices)


def _statics_indices(layout) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    blocks = layout.blocks
    rest = np.column_stack([blocks["rest_curvature"].reshape(-1, 2), blocks["rest_twist"]])
    return blocks["rest_length"], blocks["stretch_stiffness"], blocks["bend_stiffness"], rest


def square_rest_system(problem: Problem) -> bool:
    """True where the module's decomposition applies (``applies``) and the rest blocks' columns of
    dc/dp at p0 that act on a free DOF are as many as the free DOFs (the module docstring's square
    system); checked once per strand (Problem.bound_independent)."""
    return applies(problem) and problem.bound_independent("square rest system", lambda: _square_rest_columns(problem))


def _square_rest_columns(problem: Problem) -> bool:
    acting = column_norms(problem.strand_jacobian(problem.layout.p0))[problem.layout.block_mask(REST_BLOCKS)] > 0
    return int(acting.sum()) == int(problem.free.sum())


@numba.njit(cache=True)
def statics_optimum(change, p0, w, lower, upper, rate, multiplier, bend, rest, lengths):  # pragma: no cover
    """The start of the module docstring in one compiled call (statics_start's arrays: the layout's
    p0, weights and box, the blocks' indices, rest (S, 3) the vertices' rest entries, the edge
    lengths l0); empty where a box admits no multiplier. Sweeps (at most SWEEPS): the edges, each
    with the marginal cost of its rest length on its two vertices' shares (``coupling``: 0 in the
    first sweep), then the vertices at the sums those edges give, until no edge multiplier moves."""
    p = p0.copy()
    edges, stencils = rate.size, bend.size
    t, edge_low, edge_high = edge_intervals(change, lower, upper, rate, multiplier)
    for e in range(1, edges):
        if not 0.0 < edge_low[e] <= edge_high[e]:
            return np.empty(0)
    unit_z, weighted, needed = vertex_needs(change, p0, w, lower, upper, rest)
    scale, beta, slope_cost, coupling = np.empty(stencils), np.empty(stencils), np.empty(stencils), np.zeros(edges)
    for sweep in range(SWEEPS):
        moved_most = 0.0
        for e in range(1, edges):
            iu, ia = rate[e], multiplier[e]
            b = least_scalar(w[iu] * t[e] * t[e], -2.0 * coupling[e] * t[e], w[ia], p0[ia] + t[e], edge_low[e],
                             edge_high[e])
            moved_most = max(moved_most, abs(b - t[e] - p[ia]) / max(1.0, abs(p[ia])))
            p[ia], p[iu] = b - t[e], -t[e] / b
        for v in range(1, stencils):  # the vertices, their z scaled by their lbar sums
            ib = bend[v]
            scale[v] = (lengths[v] * (1.0 + p[rate[v]]) + lengths[v + 1] * (1.0 + p[rate[v + 1]])) / (
                lengths[v] + lengths[v + 1])
            low = max(lower[ib], needed[v] * scale[v])
            if not 0.0 < low <= upper[ib]:
                return np.empty(0)
            beta[v] = least_multiplier_scalar(weighted[v] * scale[v] ** 2, w[ib], p0[ib], low, upper[ib])
        if not _root_vertex(p, w, lower, upper, p0, rate[0], bend[0], lengths, weighted[0], needed[0],
                            p[rate[1]], scale, beta):
            return np.empty(0)
        if sweep > 0 and moved_most <= 4.0 * EPS:
            break
        # d(share_v)/d(sum scale): the envelope of each vertex's choice; on its rest box beta = needed x scale
        for v in range(stencils):
            ib = bend[v]
            if _on_rest_box(beta[v], needed[v] * scale[v], lower[ib]):
                slope_cost[v] = w[ib] * needed[v] * (needed[v] * scale[v] - p0[ib])
            else:
                slope_cost[v] = weighted[v] * scale[v] / beta[v] ** 2
        for e in range(1, edges):  # edge e sits in the sums of vertices e - 1 and e
            coupling[e] = 0.0
            for v in (e - 1, e):
                if v < stencils:
                    coupling[e] += slope_cost[v] * lengths[e] / (lengths[v] + lengths[v + 1])
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
def optimum_gradient(change, p, p0, w, lower, upper, rate, multiplier, bend, rest, lengths):  # pragma: no cover
    """dR/d change at p = statics_optimum(change, ...) (its arrays): the derivative of the optimum's
    value, by the envelope theorem. A multiplier inside its box, or held by a bound of its own, stays
    where it is; one held by a bound that moves with the change follows it:

    - a vertex: at a free multiplier beta, delta_j = z_j s / beta (s its lbar-sum scale), so
      dR/dz_j = w_j z_j s^2 / beta^2; held at its rest box, beta = needed s with needed = z_* / width_*
      (the entry that binds) and delta_j = z_j / needed, so dR/dz_j = w_j z_j / needed^2 plus, for
      z_*, dR/dneeded / width_*; dR/ds is statics_optimum's slope cost either way;
    - an edge, t = -change at its rest length: a free b = a + t keeps b (du/dt = -1/b, da/dt = -1);
      a multiplier a on its bound keeps a (du/dt = -a / b^2); a rest length u on its bound keeps u
      (da/dt = -1/u - 1); u also scales its two vertices' sums.

    The root edge's rest length (free but for its box) stays. Exact between the changes at which a
    bound starts or stops binding, where R has kinks (central differences agree to ~1e-10 off them,
    benchmarks/RESULTS.md); at a kink, one side's derivative."""
    g = np.zeros(change.size)
    stencils, edges = bend.size, rate.size
    slope = np.zeros(stencils)
    for v in range(stencils):
        ib = bend[v]
        beta = p[ib]
        scale = (lengths[v] * (1.0 + p[rate[v]]) + lengths[v + 1] * (1.0 + p[rate[v + 1]])) / (
            lengths[v] + lengths[v + 1])
        needed, star, weighted = 0.0, -1, 0.0
        for j in range(3):
            i = rest[v, j]
            z = change[i]
            weighted += w[i] * z * z
            if z != 0.0:
                width = upper[i] - p0[i] if z > 0.0 else lower[i] - p0[i]
                if width != 0.0 and z / width > needed:
                    needed, star = z / width, j
        if star >= 0 and needed * scale >= beta * (1.0 - ON_BOUND) and beta > lower[ib]:  # held at its rest box
            slope[v] = w[ib] * needed * (needed * scale - p0[ib])
            by_needed = w[ib] * (needed * scale - p0[ib]) * scale
            for j in range(3):
                i = rest[v, j]
                g[i] += w[i] * change[i] / needed**2
                by_needed -= w[i] * change[i] ** 2 / needed**3
            i = rest[v, star]
            g[i] += by_needed / (upper[i] - p0[i] if change[i] > 0.0 else lower[i] - p0[i])
        else:
            slope[v] = weighted * scale / beta**2
            for j in range(3):
                i = rest[v, j]
                g[i] += w[i] * change[i] * scale**2 / beta**2
    for e in range(1, edges):
        iu, ia = rate[e], multiplier[e]
        a, u = p[ia], p[iu]
        b = a - change[iu]
        if min(upper[ia] - a, a - lower[ia]) <= ON_BOUND * (upper[ia] - lower[ia]):
            du, da = -a / b**2, 0.0
        elif min(upper[iu] - u, u - lower[iu]) <= ON_BOUND * (upper[iu] - lower[iu]):
            du, da = 0.0, -1.0 / u - 1.0
        else:
            du, da = -1.0 / b, -1.0
        by_t = w[iu] * (u - p0[iu]) * du + w[ia] * (a - p0[ia]) * da
        for v in (e - 1, e):  # edge e sits in the sums of vertices e - 1 and e
            if v < stencils:
                by_t += slope[v] * lengths[e] / (lengths[v] + lengths[v + 1]) * du
        g[iu] -= by_t  # t = -change
    return g


@numba.njit(cache=True)
def least_multipliers(change, p0, w, lower, upper, rate, multiplier, rest, lengths):  # pragma: no cover - compiled
    """(low, high, least): each edge's interval [low, high] of b (edge_intervals; the element can
    carry its force only where 0 < low <= high), and each vertex's least bend multiplier that keeps
    its rest change in its box, needed x its smallest lbar-sum scale: the sum lbar_v + lbar_v+1 over
    l_v + l_v+1 at the smallest rest lengths u = -t / b its two edges allow (the root edge's: its
    box). With every edge's interval non-empty, every vertex at max(lower, least) <= its upper
    bound balances the strand (``unbalanceable``)."""
    t, low, high = edge_intervals(change, lower, upper, rate, multiplier)
    _, _, needed = vertex_needs(change, p0, w, lower, upper, rest)
    edges = rate.size
    least_u = np.zeros(edges)
    for e in range(edges):  # -t / 0 is -inf or +inf, as numpy divides (an empty interval)
        if t[e] != 0.0:
            side = low[e] if t[e] > 0.0 else high[e]
            least_u[e] = -t[e] / side if side != 0.0 else -np.sign(t[e]) * np.inf
    least_u[0] = lower[rate[0]]
    least = np.empty(needed.size)
    for v in range(needed.size):
        sums = lengths[v] * (1.0 + least_u[v]) + lengths[v + 1] * (1.0 + least_u[v + 1])
        least[v] = needed[v] * (sums / (lengths[v] + lengths[v + 1]))
    return low, high, least


@numba.njit(cache=True)
def edge_intervals(change, lower, upper, rate, multiplier):  # pragma: no cover - compiled
    """(t, low, high) per edge (statics_optimum's arrays): t = -u the stretch at unit stiffness of the
    least rest change, and the interval [low, high] of b = a + t (a the edge's multiplier, u = -t / b
    its rest length) that keeps both inside their boxes; the root edge's entries stay 0 (its rest
    length acts on no free DOF)."""
    edges = rate.size
    t, edge_low, edge_high = np.zeros(edges), np.zeros(edges), np.zeros(edges)
    for e in range(1, edges):
        iu, ia = rate[e], multiplier[e]
        t[e] = -change[iu]
        low = lower[ia] + t[e]
        for bound in (lower[iu], upper[iu]):
            if bound != 0.0 and -t[e] / bound > 0.0:
                low = max(low, -t[e] / bound)
        edge_low[e], edge_high[e] = low, upper[ia] + t[e]
    return t, edge_low, edge_high


@numba.njit(cache=True)
def vertex_needs(change, p0, w, lower, upper, rest):  # pragma: no cover - compiled
    """(z, weighted, needed) per vertex (statics_optimum's arrays): its rest change z at unit stiffness
    (S, 3), its share's weight sum_j w_j z_j^2, and the least multiplier per unit lbar-sum scale that
    keeps z / k inside the rest box (inf where a box has no room on z's side)."""
    stencils = rest.shape[0]
    unit_z, weighted, needed = np.empty((stencils, 3)), np.zeros(stencils), np.zeros(stencils)
    for v in range(stencils):
        for j in range(3):
            i = rest[v, j]
            z = change[i]
            unit_z[v, j] = z
            weighted[v] += w[i] * z * z
            if z != 0.0:
                width = upper[i] - p0[i] if z > 0.0 else lower[i] - p0[i]
                needed[v] = max(needed[v], z / width if width != 0.0 else np.inf)
    return unit_z, weighted, needed


@numba.njit(cache=True)
def _root_vertex(p, w, lower, upper, p0, iu, ib, lengths, weighted, needed, u1, scale, beta):  # pragma: no cover
    """The first vertex's multiplier beta[0] and the root edge's rest length p[iu] (its sum scale
    into scale[0]) by coordinate descent, each step in closed form (module docstring); False where
    a box admits no multiplier."""
    unit = lengths[0] + lengths[1]
    base, slope = (lengths[0] + lengths[1] * (1.0 + u1)) / unit, lengths[0] / unit  # sum scale: base + slope u0
    u0 = p0[iu]
    for _ in range(ROOT_STEPS):
        sum_scale = base + slope * u0
        low = max(lower[ib], needed * sum_scale)
        if not 0.0 < low <= upper[ib]:
            return False
        beta[0] = least_multiplier_scalar(weighted * sum_scale**2, w[ib], p0[ib], low, upper[ib])
        on_rest_box = _on_rest_box(beta[0], needed * sum_scale, lower[ib])
        # each step keeps the vertex's rest change delta = z (base + slope u0) / beta inside its box,
        # beta >= needed (base + slope u0), and beta inside its own (a floor may hold it above needed)
        if on_rest_box:
            # beta = needed x scale: 1/2 wu u0^2 + 1/2 a / needed^2 + 1/2 wb (needed (base + slope u0) - 1)^2
            numerator = -w[ib] * needed * slope * (needed * base - p0[ib])
            denominator = w[iu] + w[ib] * (needed * slope) ** 2
            least = max(lower[iu], (lower[ib] / needed - base) / slope)
            most = min(upper[iu], (upper[ib] / needed - base) / slope)
        else:  # beta fixed: 1/2 wu u0^2 + 1/2 a (base + slope u0)^2 / beta^2
            numerator = -weighted * slope * base / beta[0] ** 2
            denominator = w[iu] + weighted * slope**2 / beta[0] ** 2
            least, most = lower[iu], upper[iu]
            if needed > 0.0:
                most = min(most, (beta[0] / needed - base) / slope)
        if denominator == 0.0:  # the share does not depend on u0: keep it
            break
        moved = min(max(numerator / denominator, least), most)
        done = abs(moved - u0) <= 4.0 * EPS * (upper[iu] - lower[iu])
        u0 = moved
        if on_rest_box:
            beta[0] = needed * (base + slope * u0)
        if done:
            break
    p[iu] = u0
    scale[0] = base + slope * u0
    return True


@numba.njit(cache=True, inline="always")
def _on_rest_box(beta, least, lower):  # pragma: no cover - compiled
    """True where a vertex's multiplier beta is held at ``least`` = needed x its sum scale, the
    least that keeps its rest change in its box, rather than at its own lower bound or inside."""
    return beta <= least * (1.0 + 1e-15) and least >= lower


@numba.njit(cache=True)
def least_scalar(a2, a1, weight, centre, low, high):  # pragma: no cover - compiled
    """argmin over x in [low, high] (0 < low <= high) of F(x) = a2 / x^2 + a1 / x + weight (x - centre)^2
    (an edge's share with the marginal cost of its rest length on its vertices, a1): Newton on F'
    kept inside a bracket of its sign change (bisection where it leaves it), the endpoints compared
    where F' does not change sign or F might not be convex; least_multiplier_scalar where a1 = 0."""
    if a1 == 0.0:
        return least_multiplier_scalar(a2, weight, centre, low, high)
    lo, hi = low, high
    if _share_slope(lo, a2, a1, weight, centre) >= 0.0:
        x = lo
    elif _share_slope(hi, a2, a1, weight, centre) <= 0.0:
        x = hi
    else:
        x = lo
        for _ in range(4 * NEWTON_STEPS):
            slope = _share_slope(x, a2, a1, weight, centre)
            if slope < 0.0:
                lo = x
            else:
                hi = x
            curvature = 6.0 * a2 / x**4 + 2.0 * a1 / x**3 + 2.0 * weight
            moved = x - slope / curvature if curvature > 0.0 else 0.5 * (lo + hi)
            if not lo <= moved <= hi:
                moved = 0.5 * (lo + hi)
            if abs(moved - x) <= 4.0 * EPS * x:
                x = moved
                break
            x = moved
    best, value = x, _share(x, a2, a1, weight, centre)
    for end in (low, high):
        end_value = _share(end, a2, a1, weight, centre)
        if end_value < value:
            best, value = end, end_value
    return best


@numba.njit(cache=True, inline="always")
def _share(x, a2, a1, weight, centre):  # pragma: no cover - compiled
    """least_scalar's F(x)."""
    return a2 / x**2 + a1 / x + weight * (x - centre) ** 2


@numba.njit(cache=True, inline="always")
def _share_slope(x, a2, a1, weight, centre):  # pragma: no cover - compiled
    """least_scalar's F'(x)."""
    return -2.0 * a2 / x**3 - a1 / x**2 + 2.0 * weight * (x - centre)


@numba.njit(cache=True)
def onto_near_bound(x, low, high):  # pragma: no cover - compiled
    """x, or the bound it is within NEAR_BOUND of the box's width from: a multiplier or a rest change
    at its box's edge up to rounding is ON the bound, as a solver's projection puts it, so a KKT
    measure that counts every value strictly inside as free sees the active bound there (without
    it, tests/test_solver's measured 1.9e-4 on groom(6, 40, seed=11)[5], the contract's 1.6e-12)."""
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
