"""The input strand: groomed polyline, material, frames, attachments and loads (DESIGN sections 3 and 10)."""
from __future__ import annotations

import copy

import numba
import numpy as np

#: Root conditions: which leading DOFs are prescribed (DESIGN section 3).
ROOTS = ("clamped", "pinned")
#: Tip conditions: None (free), or the mirror image of a root condition on the last vertices.
TIPS = (None, "pinned", "clamped")
#: Largest turning angle accepted at a vertex (degrees). The curvature binormal 2 tan(phi/2) blows up
#: at 180 degrees; a groom with a sharper kink is almost surely a broken polyline.
MAX_TURNING_ANGLE_DEG = 170.0


class Strand:
    """One groomed strand, SI units.

    points: (n, 3) vertex positions in m, n >= 3, vertex 0 is the root.
    radius (m), youngs_modulus E (Pa), shear_modulus G (Pa), density (kg/m^3): positive, finite; the
        radius at most MAX_RADIUS_PER_EDGE times any edge length (a thin rod).
    theta: (n-1,) material angles of the edges (rad) relative to the Bishop reference frame;
        None = 0 (untwisted input). th = pi on alternate edges gives "flipped frames".
    root: "clamped" (x_0, x_1, th_0 prescribed) or "pinned" (x_0 prescribed).
    tip: None (free), "pinned" (x_{n-1} prescribed) or "clamped" (x_{n-2}, x_{n-1}, th_{n-2}
        prescribed): a cable held at both ends, a strand whose tip is tied down.
    pins: indices of further vertices whose positions are prescribed (their edges still turn about
        them), e.g. a strand held by a clip along the way.
    loads: (n, 3) external force on each vertex (N) in addition to gravity (wind, a hanging weight);
        None = no load. Forces on prescribed vertices are carried by the support.
    director: reference director a1 of the first edge; projected perpendicular to the first edge.
        None = "up" (minus gravity) projected, chosen by the Problem that knows gravity.
    """

    def __init__(self, points, radius=5e-5, youngs_modulus=1e9, shear_modulus=4e8, density=1300.0,
                 theta=None, root="clamped", director=None, tip=None, pins=(), loads=None):
        self.points = _validated_points(points)
        n = len(self.points)
        self.radius = _positive("radius", radius)
        _check_thin(self.points, self.radius)
        self.youngs_modulus = _positive("youngs_modulus", youngs_modulus)
        self.shear_modulus = _positive("shear_modulus", shear_modulus)
        self.density = _positive("density", density)
        if root not in ROOTS:
            raise ValueError(f"root must be one of {ROOTS}, got {root!r}")
        self.root = root
        if tip not in TIPS:
            raise ValueError(f"tip must be one of {TIPS}, got {tip!r}")
        self.tip = tip
        self.pins = _validated_pins(pins, n)
        self.loads = None if loads is None else _validated_loads(loads, n)
        if theta is None:
            self.theta = np.zeros(n - 1)
        else:
            self.theta = np.array(theta, dtype=float).reshape(-1)
            if self.theta.shape != (n - 1,):
                raise ValueError(f"theta must have one angle per edge ({n - 1}), got {self.theta.size}")
            bad = np.flatnonzero(~np.isfinite(self.theta))
            if bad.size:
                raise ValueError(f"theta of edge {bad[0]} is not finite ({self.theta[bad[0]]})")
        if director is None:
            self.director = None
        else:
            self.director = np.array(director, dtype=float).reshape(-1)
            if self.director.shape != (3,) or not np.all(np.isfinite(self.director)):
                raise ValueError(f"director must be a finite 3-vector, got {director!r}")

    @property
    def attachments(self) -> str:
        """How the strand is held and loaded, e.g. "root clamped, tip free, pins [], no loads"."""
        return (f"root {self.root}, tip {self.tip or 'free'}, pins {self.pins.tolist()}, "
                f"{'loads' if self.loads is not None else 'no loads'}")

    def attached(self, root=None, tip=None, pins=None) -> "Strand":
        """The same strand with the given attachments replacing its own (None keeps its own; ``tip``
        "free" frees the tip)."""
        return self.replaced(root=root or self.root, tip=self.tip if tip is None else (None if tip == "free" else tip),
                             pins=self.pins if pins is None else pins)

    def root_held(self) -> "Strand":
        """The same strand held by its root alone (tip free, no pins), sharing this strand's arrays,
        which are validated already: a solver's companion problem (solvers.reaction_start), which
        only reads them. ``attached(tip="free", pins=())`` validates the points again."""
        twin = copy.copy(self)
        twin.tip, twin.pins = None, np.zeros(0, dtype=int)
        return twin

    def replaced(self, **changes) -> "Strand":
        """The same strand with the given constructor arguments replacing its own (validated again)."""
        own = dict(points=self.points, radius=self.radius, youngs_modulus=self.youngs_modulus,
                   shear_modulus=self.shear_modulus, density=self.density, theta=self.theta, root=self.root,
                   director=self.director, tip=self.tip, pins=self.pins, loads=self.loads)
        unknown = sorted(set(changes) - set(own))
        if unknown:
            raise TypeError(f"Strand has no argument(s) {', '.join(unknown)}")
        return Strand(**{**own, **changes})

    @property
    def prescribed_vertices(self) -> np.ndarray:
        """Sorted indices of the vertices whose positions are prescribed (root, tip, pins)."""
        n = self.n_vertices
        held = {0, *self.pins}
        if self.root == "clamped":
            held.add(1)
        if self.tip is not None:
            held.add(n - 1)
        if self.tip == "clamped":
            held.add(n - 2)
        return np.array(sorted(held), dtype=int)

    @property
    def n_vertices(self) -> int:
        return len(self.points)

    @property
    def edge_lengths(self) -> np.ndarray:
        """Input edge lengths l0_j, m."""
        return np.linalg.norm(np.diff(self.points, axis=0), axis=1)

    @property
    def thickness(self) -> tuple[int, float]:
        """(edge, radius over its length) of the shortest edge: how far the strand is from a thin rod
        (refused above MAX_RADIUS_PER_EDGE; a batch warns above 1)."""
        return radius_per_edge(self.points, self.radius)

    @property
    def length(self) -> float:
        """Strand length L, m."""
        return float(self.edge_lengths.sum())

    @property
    def vertex_masses(self) -> np.ndarray:
        """Lumped masses m_i = rho pi r^2 (half of each adjacent input edge), kg."""
        half = 0.5 * self.density * np.pi * self.radius**2 * self.edge_lengths
        masses = np.zeros(self.n_vertices)
        masses[:-1] += half
        masses[1:] += half
        return masses

    def __repr__(self) -> str:
        return (f"Strand(n={self.n_vertices}, L={self.length:.4g} m, r={self.radius:.3g} m, "
                f"E={self.youngs_modulus:.3g} Pa, G={self.shear_modulus:.3g} Pa, root={self.root!r}"
                f"{f', tip={self.tip!r}' if self.tip else ''}{f', pins={self.pins.tolist()}' if self.pins.size else ''}"
                f"{', loads' if self.loads is not None else ''})")


#: A strand whose radius exceeds this many times one of its edge lengths is refused (_check_thin).
MAX_RADIUS_PER_EDGE = 10.0


def _check_thin(points: np.ndarray, radius: float) -> None:
    """DER models thin rods: refuse a radius above MAX_RADIUS_PER_EDGE edge lengths, naming the edge.

    Such a strand is almost always a unit mix-up (a cyHair thickness of 1 in a cm file is a 5 mm
    radius on 0.02 mm edges, 250x), and its optimization crawled to `max_iterations` (360
    Gauss-Newton steps for a 1 mm, 50-vertex strand of radius 5 mm). Radii of a few edge lengths (a
    2000-vertex hair, 1.4x) are kept: the model is coarse there but solvable.
    """
    worst, ratio = radius_per_edge(points, radius)
    if ratio > MAX_RADIUS_PER_EDGE:
        raise ValueError(
            f"radius {radius:g} m is {ratio:.3g} times the length of edge {worst} (vertices {worst}-"
            f"{worst + 1}, {radius / ratio:.3g} m): not a thin rod (sagfree refuses a radius above "
            f"{MAX_RADIUS_PER_EDGE:g} edge lengths); check the units of the radius or thickness, or resample "
            "the strand with fewer vertices")


def radius_per_edge(points: np.ndarray, radius: float) -> tuple[int, float]:
    """(shortest edge, radius over its length) of the polyline ``points`` (Strand.thickness); one
    compiled pass (a batch checks every strand before it starts, so numpy's five small calls per
    strand showed in a groom's start)."""
    edge, length = _shortest_edge(np.ascontiguousarray(points, dtype=float))
    with np.errstate(over="ignore", divide="ignore"):
        return edge, float(np.float64(radius) / length)


@numba.njit(cache=True)
def _shortest_edge(points):  # pragma: no cover - compiled
    """(index, length) of the first shortest edge, as np.argmin of np.linalg.norm(np.diff(points),
    axis=1) (the same sums; a NaN length is the minimum, as argmin takes it)."""
    edge, shortest = 0, np.inf
    for i in range(points.shape[0] - 1):
        dx, dy, dz = points[i + 1, 0] - points[i, 0], points[i + 1, 1] - points[i, 1], points[i + 1, 2] - points[i, 2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        if np.isnan(length):
            return i, length
        if length < shortest:
            edge, shortest = i, length
    return edge, shortest


class InvalidStrand:
    """A strand of an input file that failed validation, kept in its slot so that a batch can report
    it (status ``failed``, this message) and go on with the others. ``Problem`` refuses it."""

    def __init__(self, points, message: str):
        self.message = message
        try:
            self.points = np.array(points, dtype=float)
        except (TypeError, ValueError):
            self.points = np.zeros((0, 3))
        self.n_vertices = len(self.points)

    @property
    def length(self) -> float:
        """Polyline length (m) where computable, else NaN."""
        if self.points.ndim != 2 or self.points.shape[1] != 3 or len(self.points) < 2:
            return float("nan")
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())

    def __repr__(self) -> str:
        return f"InvalidStrand(n={self.n_vertices}, {self.message!r})"


def _positive(name: str, value) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be positive and finite, got {value!r}")
    return v


def _validated_pins(pins, n: int) -> np.ndarray:
    """Sorted unique vertex indices in 0..n-1; the error names the offending entry."""
    values = np.array(pins if pins is not None else (), dtype=float).reshape(-1)
    for value in values:
        if not (np.isfinite(value) and value == int(value) and 0 <= value < n):
            raise ValueError(f"pins must be vertex indices in 0..{n - 1}, got {value:g}")
    return np.unique(values.astype(int))


def _validated_loads(loads, n: int) -> np.ndarray:
    """Loads as a float (n, 3) array in N; the error names the offending vertex."""
    try:
        f = np.array(loads, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"loads must be an (n, 3) array of forces in N: {exc}") from None
    if f.shape != (n, 3):
        raise ValueError(f"loads must have one force (N) per vertex, shape ({n}, 3), got {f.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(f), axis=1))
    if bad.size:
        raise ValueError(f"load on vertex {bad[0]} is not finite ({f[bad[0]].tolist()})")
    return f


#: An edge longer than this many times the strand's median edge is a misplaced point (_check_outliers).
MAX_EDGE_PER_MEDIAN = 1e6


def _check_outliers(x: np.ndarray, lengths: np.ndarray) -> None:
    """Refuse a vertex far off the polyline (a corrupt file, a 1e30 sentinel), naming it.

    Such a point makes its two edges (one at an end) MAX_EDGE_PER_MEDIAN times longer than the
    median edge; a groomed strand's edges differ by far less (resampled hair: a few times). Without
    this check every ordinary edge looks like a duplicate vertex next to the huge coordinate.
    """
    median = float(np.median(lengths))
    huge = lengths > MAX_EDGE_PER_MEDIAN * median if median > 0 else np.zeros(len(lengths), dtype=bool)
    if not huge.any():
        return
    j = int(np.flatnonzero(huge)[0])
    if j + 1 < len(huge) and huge[j + 1]:
        vertex = j + 1  # both its edges are huge
    elif j == 0 and len(huge) > 1:
        vertex = 0
    elif j == len(huge) - 1:
        vertex = j + 1
    else:
        raise ValueError(f"edge {j} (vertices {j} and {j + 1}) is {lengths[j] / median:.3g} times the strand's "
                         f"median edge ({median:.3g} m): the strand jumps between {x[j].tolist()} and "
                         f"{x[j + 1].tolist()} (points are in metres)")
    raise ValueError(f"vertex {vertex} at {x[vertex].tolist()} is {lengths[j]:.3g} m away from its neighbour, "
                     f"{lengths[j] / median:.3g} times the strand's median edge ({median:.3g} m): a misplaced or "
                     "corrupt point (points are in metres)")


def _validated_points(points) -> np.ndarray:
    """Points as a float (n, 3) array; errors name the offending vertex or edge."""
    try:
        x = np.array(points, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"points must be an (n, 3) array of numbers: {exc}") from None
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {x.shape}")
    if len(x) < 3:
        raise ValueError(f"a strand needs at least 3 vertices, got {len(x)}")
    bad = np.flatnonzero(~np.all(np.isfinite(x), axis=1))
    if bad.size:
        raise ValueError(f"vertex {bad[0]} has a non-finite coordinate {x[bad[0]].tolist()}")
    with np.errstate(over="ignore", invalid="ignore"):
        e = np.diff(x, axis=0)
        lengths = np.linalg.norm(e, axis=1)
    huge = np.flatnonzero(~np.isfinite(lengths))
    if huge.size:
        j = huge[0]
        vertex = j if np.abs(x[j]).max() >= np.abs(x[j + 1]).max() else j + 1
        raise ValueError(f"vertex {vertex} at {x[vertex].tolist()} is too far out: edge {j} (vertices {j} and "
                         f"{j + 1}) has a length beyond double precision (points are in metres)")
    _check_outliers(x, lengths)
    # zero length relative to where the edge is (a 1e-13 m edge at 1 m from the origin is a duplicate)
    scale = np.maximum(np.abs(x[:-1]).max(axis=1), np.abs(x[1:]).max(axis=1))
    short = np.flatnonzero(lengths <= 1e-12 * np.maximum(scale, np.median(lengths)))
    if short.size:
        j = short[0]
        raise ValueError(f"edge {j} (vertices {j} and {j + 1}) has zero length: duplicate vertex "
                         f"{x[j].tolist()}; remove the duplicate")
    t = e / lengths[:, None]
    cos_turn = np.sum(t[:-1] * t[1:], axis=1)
    kinked = np.flatnonzero(cos_turn < np.cos(np.radians(MAX_TURNING_ANGLE_DEG)))
    if kinked.size:
        i = kinked[0] + 1
        angle = np.degrees(np.arccos(np.clip(cos_turn[i - 1], -1, 1)))
        raise ValueError(f"vertex {i} turns by {angle:.1f} degrees (more than "
                         f"{MAX_TURNING_ANGLE_DEG:.0f}): the polyline folds back on itself there")
    return x
