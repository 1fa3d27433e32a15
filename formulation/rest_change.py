"""Rest-shape changes carried by stiffness: the element parameters with the same forces at q*.

At q* a vertex's elastic forces depend on its element's parameters only through the products

    y = k_bend (kbar - kappa*)      (bend, S(10)),
    z = k_twist (mbar - m*)         (twist, S(11)),
    k_stretch * strain(u),  strain(u) = ((l - l0)/l0 - u) / (1 + u) = -u / (1 + u) at l = l0  (S(9)),

so a rest change found at unit stiffness can be moved into the boxes by raising the multiplier k
and dividing the change by it, without changing c. ``asc`` starts per-element stiffness this way
(solvers.alm, the linear start; ``spread_rest_change``), and the stabilization raises stiffness
this way (``restiffen``; frontend.stabilize).
"""
from __future__ import annotations

import numba
import numpy as np

from .parameters import STRAND_BLOCK
from .problem import Problem


def rest_strain(u: np.ndarray) -> np.ndarray:
    """Stretch strain at q* of the relative rest-length change u (parameters module): -u / (1 + u).
    The map is its own inverse: the u with strain s is rest_strain(s)."""
    return -u / (1.0 + u)


def spread_rest_change(problem: Problem, change: np.ndarray) -> np.ndarray:
    """Parameters whose forces at q* equal those of p0 + ``change`` at unit stiffness, with the least
    multiplier per element that brings its rest change into its box: k_i = max(1, |y_i| / b_i,
    |z_i| / b_m,i) with b the box half-widths (the twist follows the bend multiplier when
    ``couple_twist``); clipped into the box where even the largest multiplier does not suffice.

    ``change`` has the Problem's layout; only its rest blocks are read.
    """
    layout, blocks = problem.layout, problem.blocks
    p0, lower, upper = layout.p0, layout.lower, layout.upper
    half = np.maximum(np.minimum(upper - p0, p0 - lower), 1e-300)  # box half-widths around p0
    p = p0.copy()
    n_inner = problem.n_vertices - 2
    need = {"bend_stiffness": np.ones(n_inner), "twist_stiffness": np.ones(n_inner)}
    for block, target in (("rest_curvature", "bend_stiffness"), ("rest_twist", "twist_stiffness")):
        if block in blocks:
            ix = blocks[block]
            need[target] = np.maximum(1.0, (np.abs(change[ix]) / half[ix]).reshape(n_inner, -1).max(axis=1))
    coupled = layout.couple_twist  # the twist follows the bend multiplier
    bend = np.maximum(need["bend_stiffness"], need["twist_stiffness"]) if coupled else need["bend_stiffness"]
    for block, k in (("bend_stiffness", bend), ("twist_stiffness", need["twist_stiffness"])):
        if block in blocks:
            p[blocks[block]] = np.clip(k, lower[blocks[block]], upper[blocks[block]])
    # the multipliers in force (a block not optimized keeps its specified value 1)
    k_bend = p[blocks["bend_stiffness"]] if "bend_stiffness" in blocks else np.ones(n_inner)
    k_twist = k_bend if coupled else (p[blocks["twist_stiffness"]] if "twist_stiffness" in blocks
                                      else np.ones(n_inner))
    if "rest_curvature" in blocks:
        ix = blocks["rest_curvature"]
        p[ix] = p0[ix] + change[ix] / np.repeat(k_bend, ix.size // n_inner)
    if "rest_twist" in blocks:
        ix = blocks["rest_twist"]
        p[ix] = p0[ix] + change[ix] / k_twist
    if "rest_length" in blocks:  # keep k * strain
        ix = blocks["rest_length"]
        u = change[ix]
        k = np.ones(ix.size)
        if "stretch_stiffness" in blocks:
            k = np.clip(np.maximum(1.0, np.abs(u) / half[ix]), lower[blocks["stretch_stiffness"]],
                        upper[blocks["stretch_stiffness"]])
            p[blocks["stretch_stiffness"]] = k
        p[ix] = rest_strain(rest_strain(u) / k)
    return np.clip(p, lower, upper)


def restiffen(problem: Problem, p: np.ndarray, stiffness: np.ndarray) -> np.ndarray:
    """p with its stiffness multipliers replaced by those of ``stiffness`` (same layout; only the
    stiffness entries are read) and each element's rest shape moved to keep its forces at q*:
    kbar' - kappa* = (kbar - kappa*) k / k', the same for the rest twist, strain' = strain k / k'.
    Where the matching rest block is not optimized the forces change with k.
    """
    layout, blocks = problem.layout, problem.blocks
    p0 = layout.p0
    old, new = np.asarray(p, dtype=float), p.copy()
    n_inner = problem.n_vertices - 2

    def ratio(block: str, count: int) -> np.ndarray:
        """k / k' per element of a block of ``count`` elements (1 where the block is not optimized)."""
        if STRAND_BLOCK in blocks:
            ix = blocks[STRAND_BLOCK]
            return np.full(count, old[ix][0] / stiffness[ix][0])
        if block in blocks:
            ix = blocks[block]
            new[ix] = stiffness[ix]
            return old[ix] / stiffness[ix]
        return np.ones(count)

    bend = ratio("bend_stiffness", n_inner)
    twist = bend if layout.couple_twist and "twist_stiffness" not in blocks else ratio("twist_stiffness", n_inner)
    stretch = ratio("stretch_stiffness", problem.n_vertices - 1)
    if STRAND_BLOCK in blocks:
        new[blocks[STRAND_BLOCK]] = stiffness[blocks[STRAND_BLOCK]]
    if "rest_curvature" in blocks:
        ix = blocks["rest_curvature"]
        new[ix] = p0[ix] + (old[ix] - p0[ix]) * np.repeat(bend, 2)
    if "rest_twist" in blocks:
        ix = blocks["rest_twist"]
        new[ix] = p0[ix] + (old[ix] - p0[ix]) * twist
    if "rest_length" in blocks:
        ix = blocks["rest_length"]
        new[ix] = rest_strain(rest_strain(old[ix]) * stretch)
    return new


@numba.njit(cache=True)
def restiffened_elements(p, stiffness, p0, rate, multiplier, bend, rest):  # pragma: no cover - compiled
    """``restiffen`` in one compiled call, with its bits, for per-element stiffness with the twist
    coupled to bend and every block optimized (solvers.statics_start.applies; its block indices:
    rest lengths ``rate``, stretch and bend multipliers, (S, 3) each vertex's rest curvature and
    twist entries): the multipliers of ``stiffness``, the rest changes scaled by k / k'."""
    new = p.copy()
    for e in range(rate.size):
        ia, iu = multiplier[e], rate[e]
        new[ia] = stiffness[ia]
        strain = -p[iu] / (1.0 + p[iu]) * (p[ia] / stiffness[ia])
        new[iu] = -strain / (1.0 + strain)
    for v in range(bend.size):
        ib = bend[v]
        new[ib] = stiffness[ib]
        ratio = p[ib] / stiffness[ib]
        for j in range(3):
            i = rest[v, j]
            new[i] = p0[i] + (p[i] - p0[i]) * ratio
    return new


def stiffest(problem: Problem, p: np.ndarray) -> np.ndarray:
    """p restiffened to the upper bounds of its bend, twist and strand multipliers: the same forces at
    q* (``restiffen``; the rest shape moves toward q*, so it stays in its box), with the stiffest
    strand the boxes allow. Where gravity cannot be balanced, the same residual force then deflects
    the strand least (the best effort of solvers.alm)."""
    stiffness = problem.layout.block_mask(("bend_stiffness", "twist_stiffness", STRAND_BLOCK))
    return restiffen(problem, p, np.where(stiffness, problem.layout.upper, p))
