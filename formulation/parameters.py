"""Parameter layout: blocks, p0, bounds, regularizer weights and the map to physical values (DESIGN 4).

The optimized vector p is normalized and ordered along the strand, so that dc/dp is banded:
edge 0, vertex 1, edge 1, vertex 2, ..., vertex n-2, edge n-2, with each element's entries in the
order of BLOCKS; the single ``strand_stiffness`` of ``stiffness="strand"`` comes last.

| block               | per             | variable                       | p0       | default box              |
| rest_length         | edge            | u = lbar/l0 - 1                | 0        | [-0.05, 0.05]            |
| rest_curvature      | interior vertex | (k0, k1), 2 entries            | kappa(q*)| p0 +- THETA lv_i / L     |
| rest_twist          | interior vertex | mbar (rad)                     | m(q*)    | p0 +- PHI lv_i / L       |
| stretch_stiffness   | edge            | alpha = k E                    | 1        | [1, 100]                 |
| bend_stiffness      | interior vertex | beta = k E (and gamma = k G)   | 1        | [1, 100]                 |
| twist_stiffness     | interior vertex | gamma = k G (couple_twist off) | 1        | [1, 100]                 |
| strand_stiffness    | strand          | s: alpha, beta, gamma = s E,G  | 1        | [1, 100]                 |
| contact_force       | contact vertex  | g: 1 or 4 supports / D_i       | 0        | [0, CONTACT_MAX]         |

``contact_force`` exists when the Problem has bodies: per vertex resting on one (Problem, contacts),
the body's push in units of the vertex's force scale D_i (its weight plus its load), placed right
after that vertex's own entries so dc/dp stays banded: frictionless, one entry, along the outward
normal n; with a friction coefficient mu > 0, four, along the generators n + mu e of the friction
pyramid (e = +-t1, +-t2, contact.Contacts.directions), whose non-negative combinations are exactly
the forces with |f.t1| + |f.t2| <= mu f.n (inside Coulomb's cone |f_t| <= mu f_n). Either way c
stays linear in the supports and their box is a box. Its
weight is CONTACT_WEIGHT times the vertex's share of the length: a body carrying a vertex's weight
costs 1e-3 of what doubling one element's stiffness costs, so the regularizer prefers support by the
body to stiffening (a light weight rather than none keeps the QP Hessian definite).

Every physical slot of every stencil is either a constant or coefficient * p[index] (one entry of p),
which keeps dc/dp an exact, constant-structure sparse matrix.

Stiffness modes: ``element`` (per edge / per vertex multipliers, the paper's method), ``strand`` (one
multiplier s, supplement section V), ``fixed`` (rest shape only, the predecessor). With
``couple_twist=True`` (default) the bend multiplier also scales gamma and ``twist_stiffness`` is not a
separate block even when listed in ``optimize``.

Regularizer: R(p) = 1/2 sum_j w_b(j) a_j (p_j - p0_j)^2 with w_b the block's weight (``weights``,
default 1; a scalar or an array of the block's size) and a_j the element's share of the strand's
length: its edge length over L for edge blocks, its Voronoi length (l_{i-1} + l_i)/2 over L for
vertex blocks, 1 for the strand multiplier. So R of the same physical strand converges as the
resolution grows and a weight means the same at every n (a plain per-element sum grows like n).

User bounds: ``bounds={block: (lower, upper)}`` in the block's own variable (scalars or arrays of the
block's size; absolute values, so p0 must lie inside), plus ``curvature_budget`` (THETA, rad) and
``twist_budget`` (PHI, rad) to resize the default curvature and twist boxes.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numba
import numpy as np

#: the rest-shape blocks and the per-element stiffness blocks; BLOCKS is their order in p
REST_BLOCKS = ("rest_length", "rest_curvature", "rest_twist")
STIFFNESS_BLOCKS = ("stretch_stiffness", "bend_stiffness", "twist_stiffness")
BLOCKS = REST_BLOCKS + STIFFNESS_BLOCKS
#: the single multiplier of ``stiffness="strand"`` (last in p)
STRAND_BLOCK = "strand_stiffness"
STIFFNESS_MODES = ("element", "strand", "fixed")
BUDGETS = {"curvature_budget": 2.0, "twist_budget": 2.0}   # THETA, PHI in rad (DESIGN section 4)
RELATIVE_LENGTH_BOX = 0.05
STIFFNESS_BOX = (1.0, 100.0)
#: contact_force: weight relative to the other blocks and the largest support (in vertex weights)
CONTACT_BLOCK = "contact_force"
CONTACT_WEIGHT = 1e-3
CONTACT_MAX = 1e4
_EDGE_BLOCKS = {"rest_length": 1, "stretch_stiffness": 1}
_VERTEX_BLOCKS = {"rest_curvature": 2, "rest_twist": 1, "bend_stiffness": 1, "twist_stiffness": 1}


def _budget(name: str, value) -> float:
    """A curvature or twist budget (rad over the whole strand): positive and finite."""
    try:
        budget = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"bounds: {name} must be a number of radians, got {value!r}") from None
    if not (np.isfinite(budget) and budget >= 0):
        raise ValueError(f"bounds: {name} must be a non-negative number of radians (the total rest "
                         f"{'curvature' if name.startswith('curvature') else 'twist'} change allowed along "
                         f"the strand), got {value!r}")
    return budget


def check_user_bounds(bounds) -> None:
    """The parts of a ``bounds`` option that do not depend on the strand, checked once before a batch
    (a wrong one would fail every strand alike): known names, budgets, (lower, upper) pairs of
    finite numbers with lower <= upper where both are scalars."""
    for name, value in (bounds or {}).items():
        if name in BUDGETS:
            _budget(name, value)
            continue
        if name not in (*BLOCKS, STRAND_BLOCK, CONTACT_BLOCK):
            raise ValueError(f"bounds given for {name!r}, which is no parameter block; blocks: "
                             f"{', '.join((*BLOCKS, STRAND_BLOCK, CONTACT_BLOCK))}, or {' / '.join(BUDGETS)}")
        sides = [_block_values(name, what, side, (np.size(side),)) for what, side in
                 zip(("lower bound", "upper bound"), _pair(name, value))]
        if not all(np.all(np.isfinite(side)) for side in sides):
            raise ValueError(f"bounds of {name!r} must be finite, got {value!r}")
        if sides[0].size == sides[1].size == 1 and sides[0][0] > sides[1][0]:
            raise ValueError(f"bounds of {name!r}: lower bound {sides[0][0]:g} above upper bound {sides[1][0]:g}")


def _pair(name: str, value) -> tuple:
    """The (lower, upper) of a user's bounds of block ``name``."""
    try:
        lo, hi = value
    except (TypeError, ValueError):
        raise ValueError(f"bounds of {name!r} must be a pair (lower, upper), got {value!r}") from None
    return lo, hi


def _block_values(name: str, what: str, value, shape: tuple) -> np.ndarray:
    """A user's bound or weight of block ``name``: a scalar or one value per entry of the block."""
    try:
        values = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{what} of {name!r} must be numbers, got {value!r}") from None
    if values.ndim > 1 or values.size not in (1, shape[0]):
        raise ValueError(f"{what} of {name!r} must be a scalar or one value per entry of the block "
                         f"({shape[0]} entries here), got an array of shape {values.shape}")
    return np.broadcast_to(values.reshape(-1) if values.size == shape[0] else values.reshape(()), shape)


@numba.njit(cache=True)
def _consistent(lower, upper, p0, weights):  # pragma: no cover - compiled
    """True if every entry has finite bounds lower <= p0 <= upper and a finite weight >= 0 (NaN fails)."""
    for j in range(p0.size):
        if not (np.isfinite(lower[j]) and np.isfinite(upper[j]) and lower[j] <= p0[j] <= upper[j]
                and np.isfinite(weights[j]) and weights[j] >= 0.0):
            return False
    return True


@dataclass
class SlotMap:
    """physical[k, s] = constant[k, s] + coefficient[k, s] * p[index[k, s]] where index >= 0."""

    index: np.ndarray        # (stencils, slots) int, -1 = constant
    coefficient: np.ndarray  # (stencils, slots)
    constant: np.ndarray     # (stencils, slots)

    #: (flat positions of the linked slots, their entries of p, their coefficients): derived from
    #: index and coefficient alone, so maps of one structure may share them (_slot_map)
    links: tuple | None = None

    def __post_init__(self):
        if self.links is None:
            linked = np.flatnonzero(self.index.ravel() >= 0)
            self.links = (linked, self.index.ravel()[linked], self.coefficient.ravel()[linked])
        self._linked, self._source, self._factor = self.links

    @property
    def arrays(self) -> tuple:
        """(constant, linked, factor, source): ``evaluate_slots``'s arguments before p (compiled
        callers, formulation.at_rest)."""
        return self.constant, self._linked, self._factor, self._source

    def evaluate(self, p: np.ndarray) -> np.ndarray:
        return evaluate_slots(*self.arrays, p)


@numba.njit(cache=True)
def evaluate_slots(constant, linked, factor, source, p):  # pragma: no cover - compiled
    """SlotMap.evaluate in one compiled call (it runs for every residual and Jacobian)."""
    out = constant.copy()
    flat = out.ravel()
    for k in range(linked.size):
        flat[linked[k]] += factor[k] * p[source[k]]
    return out


@dataclass(frozen=True)
class _LayoutStructure:
    """What a ParameterLayout's shape alone fixes: each block's entries in p (read-only arrays), the
    size of p and the entry of p behind each physical slot of each stencil (-1: a constant)."""

    blocks: dict
    size: int
    edge_index: np.ndarray    # (n - 1, 2)
    vertex_index: np.ndarray  # (n - 2, 7)
    defaults: tuple           # _default_recipe's arrays: how _default_values fills p0, the box and shares
    slot_coefficients: dict = field(default_factory=dict, compare=False)  # _slot_map's, by stencil kind
    derived: dict = field(default_factory=dict, compare=False)  # ParameterLayout.by_structure's

    @functools.cached_property
    def owners(self) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
        """(block names, each entry's block number (-1: none), its place in its block): what
        ParameterLayout.locate and element_numbers read, made once per structure (read-only)."""
        owner, within = np.full(self.size, -1), np.zeros(self.size, dtype=int)
        for number, ix in enumerate(self.blocks.values()):
            owner[ix], within[ix] = number, np.arange(ix.size)
        owner.flags.writeable = within.flags.writeable = False
        return tuple(self.blocks), owner, within


def _concatenated(blocks: dict, names) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """ParameterLayout.concatenated_blocks' arrays, read-only."""
    present = tuple(name for name in names if name in blocks)
    parts = [blocks[name] for name in present]
    offsets = np.zeros(len(parts) + 1, dtype=np.int64)
    offsets[1:] = np.cumsum([part.size for part in parts])
    index = np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)
    index.flags.writeable = offsets.flags.writeable = False
    return present, index, offsets


@functools.lru_cache(maxsize=16)
def _layout_structure(n_vertices: int, active: tuple, strand_level: bool, couple_twist: bool, contacts: bytes,
                      contact_width: int) -> _LayoutStructure:
    """The _LayoutStructure of a layout, shared by the strands of a groom (their layouts differ only
    in values: building it was 0.1 of a 100-vertex Problem's 0.53 ms). ``contacts``: the bytes of the
    int contact vertex array."""
    n_edges, n_inner = n_vertices - 1, n_vertices - 2
    contacts = np.frombuffer(contacts, dtype=int)
    # ---- positions of each block's entries in p, along the strand ----
    # order: [edge 0][vertex 1][edge 1] ... [vertex n-2][edge n-2], blocks in BLOCKS order
    edge_widths = {b: w for b, w in _EDGE_BLOCKS.items() if b in active}
    vertex_widths = {b: w for b, w in _VERTEX_BLOCKS.items() if b in active}
    stride = sum(edge_widths.values()) + sum(vertex_widths.values())
    blocks = {}
    for widths, count, start in ((edge_widths, n_edges, 0), (vertex_widths, n_inner, sum(edge_widths.values()))):
        for b, w in widths.items():
            first = start + stride * np.arange(count)
            blocks[b] = (first[:, None] + np.arange(w)).ravel()
            start += w
    blocks = {b: blocks[b] for b in BLOCKS if b in blocks}
    size = stride * n_edges - sum(vertex_widths.values()) * (n_edges - n_inner)
    if contacts.size:
        # contact of vertex i right after vertex i's entries (after edge i - 1's if it has none;
        # the tip's after the last edge): shift every later entry by the contacts before it
        vertex_width = sum(vertex_widths.values())
        after = np.where(contacts <= n_inner, sum(edge_widths.values()) + stride * (contacts - 1) + vertex_width, size)
        for b, ix in blocks.items():
            blocks[b] = ix + contact_width * np.searchsorted(after, ix, side="right")
        blocks[CONTACT_BLOCK] = ((after + contact_width * np.arange(contacts.size))[:, None]
                                 + np.arange(contact_width)).ravel()
        size += contact_width * contacts.size
    size += int(strand_level)
    if strand_level:
        blocks[STRAND_BLOCK] = np.array([size - 1])

    def slot(n, block, element_index):
        if block in blocks:
            return blocks[block][element_index]
        if strand_level and block in STIFFNESS_BLOCKS:
            return np.full(n, size - 1)
        return np.full(n, -1)

    edges_all, inner = np.arange(n_edges), np.arange(n_inner)
    curvature_rows = lambda k: 2 * inner + k if "rest_curvature" in blocks else None  # noqa: E731
    twist_block = "twist_stiffness" if "twist_stiffness" in blocks else (
        "bend_stiffness" if couple_twist else "twist_stiffness")
    edge_index = np.stack([slot(n_edges, "rest_length", edges_all), slot(n_edges, "stretch_stiffness", edges_all)],
                          axis=1)
    vertex_index = np.stack([
        slot(n_inner, "rest_length", inner), slot(n_inner, "rest_length", inner + 1),
        slot(n_inner, "rest_curvature", curvature_rows(0)), slot(n_inner, "rest_curvature", curvature_rows(1)),
        slot(n_inner, "rest_twist", inner), slot(n_inner, "bend_stiffness", inner), slot(n_inner, twist_block, inner),
    ], axis=1)
    defaults = _default_recipe(blocks, contact_width)
    for array in (*blocks.values(), edge_index, vertex_index, *defaults):
        array.flags.writeable = False  # shared by every layout of this shape
    return _LayoutStructure(blocks, size, edge_index, vertex_index, defaults)


#: how an entry of p gets its share of the strand (_default_recipe): none (1), its edge's, its
#: vertex's Voronoi length, its contact vertex's half edges
_NO_SHARE, _EDGE_SHARE, _VERTEX_SHARE, _CONTACT_SHARE = 0, 1, 2, 3
#: ... and its p0 and default box: a stiffness multiplier, a rest length, a rest curvature, a rest
#: twist, a contact force
_STIFFNESS, _REST_LENGTH, _REST_CURVATURE, _REST_TWIST, _CONTACT = 0, 1, 2, 3, 4


def _default_recipe(blocks: dict, contact_width: int) -> tuple[np.ndarray, ...]:
    """(entry, share kind, element, default kind, value index) per entry of the blocks, in block
    order: what ParameterLayout's defaults do to each (``_default_values``). element: the edge,
    vertex or contact whose share the entry takes; value index: its place in the rest curvatures
    (flattened) or twists at q*."""
    parts = []
    for b, ix in blocks.items():
        k = np.arange(ix.size)
        if b in _EDGE_BLOCKS:
            share, element = _EDGE_SHARE, k
        elif b in _VERTEX_BLOCKS:
            share, element = _VERTEX_SHARE, k // _VERTEX_BLOCKS[b]
        elif b == CONTACT_BLOCK:
            share, element = _CONTACT_SHARE, k // contact_width
        else:
            share, element = _NO_SHARE, k
        default = {"rest_length": _REST_LENGTH, "rest_curvature": _REST_CURVATURE, "rest_twist": _REST_TWIST,
                   CONTACT_BLOCK: _CONTACT}.get(b, _STIFFNESS)
        parts.append((ix, np.full(ix.size, share), element, np.full(ix.size, default), k))
    return tuple(np.concatenate([part[a] for part in parts]).astype(np.int64) if parts else np.zeros(0, dtype=np.int64)
                 for a in range(5))


@numba.njit(cache=True)
def _default_values(entry, share_kind, element, default_kind, value_index, size, lengths, total, rest_curvature,
                    rest_twist, curvature_budget, twist_budget, contacts):  # pragma: no cover - compiled
    """(p0, lower, upper, share, weights) of ParameterLayout's defaults, from its structure's
    _default_recipe (lengths: l0; total: their numpy sum; rest_curvature flattened): each entry's
    share of the strand's length (module docstring) and its default box, with the arithmetic of
    numpy's block-by-block version (voronoi = 0.5 (l_{i-1} + l_i), then / total)."""
    p0, lower, upper, share = np.zeros(size), np.zeros(size), np.zeros(size), np.ones(size)
    for e in range(entry.size):
        j, i = entry[e], element[e]
        if share_kind[e] == _EDGE_SHARE:
            share[j] = lengths[i] / total
        elif share_kind[e] == _VERTEX_SHARE:
            share[j] = 0.5 * (lengths[i] + lengths[i + 1]) / total
        elif share_kind[e] == _CONTACT_SHARE:  # the vertex's half edges (the tip has one)
            vertex = contacts[i]
            share[j] = 0.5 * (lengths[vertex - 1] + (lengths[vertex] if vertex < lengths.size else 0.0)) / total
    weights = share.copy()
    for e in range(entry.size):
        j, kind = entry[e], default_kind[e]
        if kind == _STIFFNESS:
            p0[j], lower[j], upper[j] = 1.0, STIFFNESS_BOX[0], STIFFNESS_BOX[1]
        elif kind == _REST_LENGTH:
            p0[j], lower[j], upper[j] = 0.0, -RELATIVE_LENGTH_BOX, RELATIVE_LENGTH_BOX
        elif kind == _REST_CURVATURE:
            value, half = rest_curvature[value_index[e]], curvature_budget * share[j]
            p0[j], lower[j], upper[j] = value, value + -half, value + half
        elif kind == _REST_TWIST:
            value, half = rest_twist[value_index[e]], twist_budget * share[j]
            p0[j], lower[j], upper[j] = value, value + -half, value + half
        else:  # a contact force
            p0[j], lower[j], upper[j] = 0.0, 0.0, CONTACT_MAX
            weights[j] *= CONTACT_WEIGHT
    return p0, lower, upper, share, weights


def _slot_map(index: np.ndarray, constants: list, coefficients: list, known: dict | None = None) -> SlotMap:
    """The SlotMap of one stencil kind: slot s of a stencil is coefficients[s] * p[index] where
    index >= 0, else constants[s] (a scalar or one value per stencil). ``known``: a cache of the
    coefficient arrays by coefficients (the layout structure's: the strands of a groom share them)."""
    key = tuple(float(c) for c in coefficients)
    parts = None if known is None else known.get(key)
    if parts is None:
        linked = index >= 0
        coefficient = np.where(linked, np.asarray(key), 0.0)
        links = SlotMap(index, coefficient, np.zeros(index.shape)).links
        for array in (coefficient, *links):
            array.flags.writeable = False
        parts = (linked, coefficient, [slot for slot in range(index.shape[1]) if not linked[:, slot].all()], links)
        if known is not None:
            known[key] = parts
    linked, coefficient, constant_slots, links = parts
    constant = np.zeros(index.shape)
    for slot in constant_slots:  # the slots some stencil holds constant
        constant[:, slot] = constants[slot]
    if constant_slots:
        constant[linked] = 0.0
    return SlotMap(index, coefficient, constant, links)


class ParameterLayout:
    """Which parameters are optimized, where they sit in p, their p0, box and weights."""

    def __init__(self, n_vertices: int, edge_lengths: np.ndarray, rest_curvature0: np.ndarray,
                 rest_twist0: np.ndarray, youngs_modulus: float, shear_modulus: float,
                 optimize=BLOCKS, stiffness="element", couple_twist=True, bounds=None, weights=None,
                 contacts=(), contact_width: int = 1):
        """contacts: sorted indices of the vertices (1..n-1) with contact_width contact_force entries."""
        unknown = set(optimize) - set(BLOCKS)
        if unknown:
            raise ValueError(f"unknown parameter blocks {sorted(unknown)}; choose from {BLOCKS}")
        if stiffness not in STIFFNESS_MODES:
            raise ValueError(f"stiffness must be one of {STIFFNESS_MODES}, got {stiffness!r}")
        self.stiffness, self.couple_twist = stiffness, couple_twist
        n_inner = n_vertices - 2
        active = tuple(b for b in BLOCKS if b in optimize and
                       not (b in STIFFNESS_BLOCKS and stiffness != "element") and
                       not (b == "twist_stiffness" and couple_twist))
        strand_level = stiffness == "strand" and any(b in optimize for b in STIFFNESS_BLOCKS)
        self.contacts = np.asarray(contacts, dtype=int)
        structure = _layout_structure(n_vertices, active, strand_level, couple_twist, self.contacts.tobytes(),
                                      int(contact_width))
        self.blocks, self.size = dict(structure.blocks), structure.size
        self._structure = structure

        # ---- p0, default box, weights: each element's share of the strand's length (regularizer,
        # module docstring), rest shapes at q* with their budgets' boxes, multipliers at 1 ----
        lengths = np.asarray(edge_lengths, dtype=float)
        budgets = dict(BUDGETS)
        bounds = dict(bounds or {})
        for key in BUDGETS:
            if key in bounds:
                budgets[key] = _budget(key, bounds.pop(key))
        self.p0, self.lower, self.upper, self.share, self.weights = _default_values(
            *structure.defaults, self.size, lengths, float(lengths.sum()),
            np.ascontiguousarray(rest_curvature0, dtype=float).reshape(-1), np.ascontiguousarray(rest_twist0, dtype=float),
            float(budgets["curvature_budget"]), float(budgets["twist_budget"]), self.contacts)
        self._apply_user(bounds, weights)
        self.validate()

        # ---- physical slot maps (layouts of energies.EDGE_PHYSICAL / VERTEX_PHYSICAL) ----
        E, G = youngs_modulus, shear_modulus
        kappa0 = np.asarray(rest_curvature0, dtype=float).reshape(n_inner, 2)
        known = structure.slot_coefficients
        self.edge_map = _slot_map(structure.edge_index, [0.0, E], [1.0, E], known.setdefault("edge", {}))
        self.vertex_map = _slot_map(structure.vertex_index, [0.0, 0.0, kappa0[:, 0], kappa0[:, 1], rest_twist0, E, G],
                                    [1.0, 1.0, 1.0, 1.0, 1.0, E, G], known.setdefault("vertex", {}))

    def _apply_user(self, bounds: dict, weights) -> None:
        for name, value in (bounds or {}).items():
            ix = self._block_index(name, "bounds")
            lo, hi = _pair(name, value)
            self.lower[ix] = _block_values(name, "lower bound", lo, ix.shape)
            self.upper[ix] = _block_values(name, "upper bound", hi, ix.shape)
        for name, value in (weights or {}).items():
            ix = self._block_index(name, "weights")
            self.weights[ix] = self.share[ix] * _block_values(name, "weight", value, ix.shape)

    def _block_index(self, name: str, what: str) -> np.ndarray:
        if name not in self.blocks:
            known = sorted(self.blocks) + (sorted(BUDGETS) if what == "bounds" else [])
            raise ValueError(f"{what} given for {name!r}, which is not an optimized block here; "
                             f"optimized blocks: {known}")
        return self.blocks[name]

    def validate(self) -> None:
        """Raise a ValueError naming the block and entry of any inconsistent bound or weight."""
        if _consistent(self.lower, self.upper, self.p0, self.weights):
            return  # one compiled pass over p; the loop below only names the first bad entry
        for name, ix in self.blocks.items():
            lo, hi, p0, w = self.lower[ix], self.upper[ix], self.p0[ix], self.weights[ix]
            checks = [
                (~np.isfinite(lo) | ~np.isfinite(hi), "a non-finite bound"),
                (lo > hi, "lower bound above upper bound"),
                ((p0 < lo) | (p0 > hi), "p0 outside its bounds"),
                (~np.isfinite(w) | (w < 0), "a negative or non-finite weight"),
            ]
            for bad, what in checks:
                if np.any(bad):
                    k = int(np.flatnonzero(bad)[0])
                    raise ValueError(f"block {name!r}, entry {k}: {what} (lower {lo[k]:.6g}, "
                                     f"upper {hi[k]:.6g}, p0 {p0[k]:.6g}, weight {w[k]:.6g})")

    # ---- regularizer R(p) = 1/2 sum_j w_b(j) a_j (p_j - p0_j)^2 (DESIGN section 4) ----
    def regularizer(self, p: np.ndarray) -> float:
        d = p - self.p0
        return 0.5 * float(np.sum(self.weights * d * d))

    def regularizer_gradient(self, p: np.ndarray) -> np.ndarray:
        return self.weights * (p - self.p0)

    def block_mask(self, names) -> np.ndarray:
        """Boolean mask over p of the entries of the named blocks (those not optimized are skipped)."""
        mask = np.zeros(self.size, dtype=bool)
        for name in names:
            if name in self.blocks:
                mask[self.blocks[name]] = True
        return mask

    def by_structure(self, key, build):
        """``build(self)``, made once per ``key`` (hashable) for the layouts of one structure (the
        strands of a groom of one size and set of blocks): for what depends only on the blocks'
        entries. Not copied: readers must not write into it."""
        derived = self._structure.derived
        if key not in derived:
            derived[key] = build(self)
        return derived[key]

    def concatenated_blocks(self, names) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
        """(the named blocks present, their entries' indices in p concatenated in that order, the
        offset of each block in them: len + 1 entries), shared by the layouts of one structure (every
        Result's summaries ask for the same few)."""
        names = tuple(names)
        return self.by_structure(("concatenated", names), lambda layout: _concatenated(layout.blocks, names))

    def locate(self, index: int) -> tuple[str, str]:
        """(block, element) of entry ``index`` of p, e.g. ("bend_stiffness", "vertex 3")."""
        names, owner, within = self._structure.owners
        if not 0 <= index < self.size or owner[index] < 0:
            raise IndexError(f"p has no entry {index}")
        block = names[owner[index]]
        if block == STRAND_BLOCK:
            return block, "strand"
        number = int(self._element_numbers(block, within[index:index + 1])[0])
        return block, f"{'edge' if block in _EDGE_BLOCKS else 'vertex'} {number}"

    def element_numbers(self, indices) -> dict[str, np.ndarray]:
        """The entries ``indices`` of p by block (in BLOCKS order), each as the number of the edge or
        vertex that ``locate`` names (0 for the strand multiplier): ``locate`` for many entries at
        once, without a Python step per entry (a stabilized strand's note names dozens of floors)."""
        names, owner, within = self._structure.owners
        indices = np.asarray(indices, dtype=int).reshape(-1)
        bad = (indices < 0) | (indices >= self.size)
        bad[~bad] = owner[indices[~bad]] < 0
        if bad.any():
            raise IndexError(f"p has no entry {int(indices[bad][0])}")
        return {names[number]: self._element_numbers(names[number], within[indices[owner[indices] == number]])
                for number in np.unique(owner[indices])}

    def _element_numbers(self, block: str, within: np.ndarray) -> np.ndarray:
        """The edge or vertex number of the entries ``within`` block (their places in it)."""
        if block == STRAND_BLOCK:
            return np.zeros_like(within)
        if block == CONTACT_BLOCK:
            return self.contacts[within * self.contacts.size // self.blocks[block].size]
        if block in _EDGE_BLOCKS:
            return within
        return within // _VERTEX_BLOCKS[block] + 1


def number_ranges(numbers, most: int | None = None) -> str:
    """'1-4, 7' from the element numbers [1, 2, 3, 4, 7] (any order, repeats ignored; the first
    ``most`` runs and "and more" where there are more; a few dozen per message: plain Python beats
    numpy's calls). Messages name elements with it (a stabilized strand's floors, an infeasible
    strand's vertices)."""
    runs: list[list[int]] = []
    for number in sorted(set(np.asarray(numbers).tolist())):
        if runs and number == runs[-1][1] + 1:
            runs[-1][1] = number
        else:
            runs.append([number, number])
    more = most is not None and len(runs) > most
    listed = ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in runs[:most])
    return listed + (" and more" if more else "")
