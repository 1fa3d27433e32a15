"""Derivative verification: CasADi AD vs hand-derived formulas S(7)-(19) vs finite differences (DESIGN 7).

Two tools in the spirit of ``scipy.optimize.check_grad`` and ``jax.test_util.check_grads``:

* ``gradient_error(problem, p, q, frames)``: one number, the relative error of the AD force against a
  central difference of the energy along random directions (frames re-transported for each perturbed
  state, because the energy expression transports them from ``frames``);
* ``jacobian_error(problem, p, block)``: the same for dc/dp along random directions in one block.

Central differences use Richardson extrapolation, D = (4 D(h/2) - D(h)) / 3, error O(h^4).
``verify()`` runs both, plus the comparison with the hand-derived module, for every energy term,
parameter block and curvature variant on a set of random strands (helices, random 3D curves,
strongly twisted and flipped frames), and returns the rows that ``sagfree check`` prints.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import dofs, hand_derived
from .curvature import VARIANTS
from .frames import transport_frames
from .bodies import Sphere
from .parameters import BLOCKS, CONTACT_BLOCK, STRAND_BLOCK
from .problem import Problem
from .strand import Strand

HAND_TOLERANCE = 1e-8   # AD vs closed form: both exact, only round-off differs
FD_TOLERANCE = 1e-6     # AD vs Richardson-extrapolated central differences
#: Which parameter blocks each energy term depends on (the other pairs are structurally zero and are
#: checked to be zero in both AD and closed form).
TERM_BLOCKS = {
    "stretch": ("rest_length", "stretch_stiffness", STRAND_BLOCK),
    "bend": ("rest_length", "rest_curvature", "bend_stiffness", STRAND_BLOCK),
    "twist": ("rest_length", "rest_twist", "bend_stiffness", "twist_stiffness", STRAND_BLOCK),
    "contact": (CONTACT_BLOCK,),  # the bodies' supports (_check_contact)
}


def richardson_derivative(fun, x: np.ndarray, direction: np.ndarray, step: float):
    """d/dt fun(x + t direction) at t = 0 by Richardson-extrapolated central differences."""
    def central(h):
        return (np.asarray(fun(x + h * direction)) - np.asarray(fun(x - h * direction))) / (2 * h)
    return (4 * central(step / 2) - central(step)) / 3


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    """||a - b||_inf / max(||a||_inf, ||b||_inf); 0 when both vanish."""
    scale = max(np.abs(a).max(initial=0.0), np.abs(b).max(initial=0.0))
    return 0.0 if scale == 0 else float(np.abs(a - b).max() / scale)


def _state_direction(problem: Problem, rng) -> np.ndarray:
    """Random DOF direction, positions scaled by the mean edge length (m), angles in rad."""
    v = rng.standard_normal(problem.q_star.size)
    v[dofs.position_index(problem.n_vertices)] *= problem.edge_lengths.mean()
    return v


def gradient_error(problem: Problem, p, q=None, frames=None, directions: int = 3, seed: int = 0,
                   step: float = 1e-4) -> float:
    """Largest relative error of grad E (AD) . v against d/dt E(q + t v) over random directions v,
    normalized by sum_i |g_i v_i|: unit-consistent across positions and angles, and fair to a
    direction along which the terms of g . v cancel."""
    rng = np.random.default_rng(seed)
    q = problem.q_star if q is None else q
    g = problem.elastic_gradient(p, q, frames)
    worst = 0.0
    for _ in range(directions):
        v = _state_direction(problem, rng)
        fd = richardson_derivative(lambda x: problem.energy(p, x, frames), q, v, step)
        scale = np.abs(g * v).sum()
        worst = max(worst, 0.0 if scale == 0 else abs(fd - g @ v) / scale)
    return worst


def jacobian_error(problem: Problem, p, block: str, directions: int = 3, seed: int = 0,
                   step: float = 1e-4) -> float:
    """Largest relative error of (dc/dp) v against d/dt c(p + t v), v random on ``block`` and scaled
    by the block's box width."""
    rng = np.random.default_rng(seed)
    J = problem.jacobian(p)
    ix = problem.blocks[block]
    width = (problem.upper - problem.lower)[ix]
    worst = 0.0
    for _ in range(directions):
        v = np.zeros(problem.n_parameters)
        v[ix] = rng.standard_normal(ix.size) * np.where(width > 0, width, 1.0)
        fd = richardson_derivative(problem.residual, p, v, step)
        worst = max(worst, _relative(J @ v, fd))
    return worst


def verification_strands(seed: int = 0, n: int = 12) -> dict[str, Strand]:
    """Random strands for verification: a helix, a random smooth 3D curve, a strongly twisted curve
    (random material angles, about 1 rad per edge), flipped frames on a curved strand, a pinned
    root, and a strand held at both ends and in the middle with random loads; all with edges of about 5 mm."""
    rng = np.random.default_rng(seed)

    def random_curve():
        direction, points = np.array([1.0, 0.0, 0.0]), [np.zeros(3)]
        for _ in range(n - 1):
            direction = direction + 0.5 * rng.standard_normal(3)
            direction /= np.linalg.norm(direction)
            points.append(points[-1] + 0.005 * rng.uniform(0.7, 1.3) * direction)
        return np.array(points)

    phi = np.linspace(0, 2.5 * np.pi, n)
    helix = np.column_stack([0.004 * phi, 0.01 * np.cos(phi), 0.01 * np.sin(phi)])
    return {
        "helix": Strand(helix),
        "random-curve": Strand(random_curve()),
        "twisted": Strand(random_curve(), theta=np.cumsum(rng.uniform(-1.5, 1.5, n - 1))),
        "flipped": Strand(random_curve(), theta=np.where(np.arange(n - 1) % 2 == 1, np.pi, 0.0)),
        "pinned": Strand(random_curve(), root="pinned", theta=rng.uniform(-3, 3, n - 1)),
        "held": Strand(random_curve(), tip="clamped", pins=[n // 2], loads=1e-6 * rng.standard_normal((n, 3))),
    }


def perturbed_parameters(problem: Problem, rng, fraction: float = 0.3) -> np.ndarray:
    """p0 moved a ``fraction`` of the way to random points of the box (a generic, non-p0 state)."""
    target = problem.lower + rng.uniform(size=problem.n_parameters) * (problem.upper - problem.lower)
    return problem.p0 + fraction * (target - problem.p0)


@dataclass
class CheckRow:
    """One line of the verification table: max errors over all verification strands."""

    term: str
    quantity: str       # "force" or a parameter block
    variant: str
    hand_error: float   # AD vs hand-derived
    fd_error: float     # AD vs finite differences
    structural_zero: bool = False

    @property
    def passed(self) -> bool:
        return self.hand_error <= HAND_TOLERANCE and self.fd_error <= FD_TOLERANCE


def _problems(strand: Strand, term: str, variant: str):
    """The three parameterizations that together contain every block."""
    for options in (dict(stiffness="element"), dict(stiffness="element", couple_twist=False),
                    dict(stiffness="strand")):
        yield Problem(strand, curvature=variant, energies=(term,), optimize=BLOCKS, **options)


def verify(variants=VARIANTS, seed: int = 0, n: int = 12) -> list[CheckRow]:
    """Verification table rows: every energy term x (force, each parameter block) x variant."""
    rows = []
    strands = verification_strands(seed, n)
    for term in ("stretch", "bend", "twist"):
        depends_on_variant = term == "bend"  # stretch and twist do not involve the curvature
        for variant in (variants if depends_on_variant else variants[:1]):
            label = variant if depends_on_variant else "any"
            errors: dict[str, list[float]] = {}
            for k, strand in enumerate(strands.values()):
                rng = np.random.default_rng([seed, k])
                for problem in _problems(strand, term, variant):
                    _check_problem(problem, term, rng, errors)
            for quantity, (hand, fd, zero) in errors.items():
                rows.append(CheckRow(term, quantity, label, hand, fd, zero))
    errors = {}
    for k, strand in enumerate(strands.values()):
        _check_contact(strand, variants[0], np.random.default_rng([seed, k, 1]), errors)
    rows.extend(CheckRow("contact", quantity, "any", hand, fd, zero) for quantity, (hand, fd, zero) in errors.items())
    return rows


def _check_contact(strand: Strand, variant: str, rng, errors) -> None:
    """The supports' columns of dc/dp (a small sphere touching the middle vertex on the outside of its
    bend), frictionless and with friction 0.4: AD (Problem.strand_jacobian) against the hand formula
    n_i = (x_i - c) / |x_i - c| (and the pyramid's generators n_i + mu e) on vertex i's rows, and
    against finite differences."""
    x = strand.points
    i = strand.n_vertices // 2 + 1
    inward = 0.5 * (x[i - 1] + x[i + 1]) - x[i]
    inward -= inward @ (x[i + 1] - x[i - 1]) / np.sum((x[i + 1] - x[i - 1]) ** 2) * (x[i + 1] - x[i - 1])
    if np.linalg.norm(inward) < 1e-12 * strand.length:  # straight there: any perpendicular
        inward = np.cross(x[i + 1] - x[i - 1], rng.standard_normal(3))
    radius = 0.3 * float(np.min(strand.edge_lengths))
    center = x[i] - (radius + strand.radius) * inward / np.linalg.norm(inward)
    for friction in (0.0, 0.4):
        problem = Problem(strand, curvature=variant, bodies=[Sphere(center, radius)], contact_distance=1e-9,
                          friction=friction)
        p = perturbed_parameters(problem, rng)
        block = problem.blocks[CONTACT_BLOCK]
        J_ad = problem.jacobian(p).toarray()[:, block]
        J_hand = np.zeros_like(J_ad)
        free_row = np.cumsum(problem.free) - 1
        width = block.size // problem.contacts.count
        frame_error = 0.0
        for k, vertex in enumerate(problem.contacts.vertices):
            normal = strand.points[vertex] - center
            normal /= np.linalg.norm(normal)
            # frictionless: the normal; with friction: n + mu e for e = t1, -t1, t2, -t2 (the tangents
            # are a convention of the contact module, taken from it; their orthonormality counts in
            # the hand error)
            t1, t2 = problem.contacts.tangents[k]
            frame_error = max(frame_error, abs(t1 @ normal) + abs(t2 @ normal) + abs(t1 @ t2),
                              abs(t1 @ t1 - 1) + abs(t2 @ t2 - 1))
            generators = [normal] if width == 1 else [normal + friction * e for e in (t1, -t1, t2, -t2)]
            rows = free_row[dofs.position_index(strand.n_vertices)[vertex]]
            for j, generator in enumerate(generators):
                J_hand[rows, k * width + j] = generator
        _record(errors, CONTACT_BLOCK + (" (friction)" if friction else ""),
                max(_relative(J_ad, J_hand), frame_error),
                jacobian_error(problem, p, CONTACT_BLOCK, seed=int(rng.integers(1 << 31))), False)


def _record(errors, quantity, hand, fd, zero):
    old = errors.get(quantity, (0.0, 0.0, True))
    errors[quantity] = (max(old[0], hand), max(old[1], fd), old[2] and zero)


def _check_problem(problem: Problem, term: str, rng, errors) -> None:
    p = perturbed_parameters(problem, rng)
    # forces at q* and at a moved state whose frames are transported there (nonzero reference twist)
    q = problem.q_star + 0.05 * _state_direction(problem, rng)
    moved = transport_frames(problem.frames, dofs.positions(q))
    for state, frames in ((None, None), (q, moved)):
        ad = problem.elastic_gradient(p, state, frames)
        hand = hand_derived.gradient(problem, p, term, state, frames)
        fd = gradient_error(problem, p, state, frames, seed=int(rng.integers(1 << 31)))
        _record(errors, "force", _relative(ad, hand), fd, False)
    J_ad = problem.jacobian(p).toarray()
    J_hand = hand_derived.parameter_jacobian(problem, p, term)[problem.free]
    J_hand /= problem.row_scale[problem.free, None]
    for block, ix in problem.blocks.items():
        zero = block not in TERM_BLOCKS[term]
        hand = _relative(J_ad[:, ix], J_hand[:, ix])
        if zero:  # structurally zero: both must vanish exactly
            fd = float(np.abs(J_ad[:, ix]).max(initial=0.0) + np.abs(J_hand[:, ix]).max(initial=0.0))
            hand = fd
        else:
            fd = jacobian_error(problem, p, block, seed=int(rng.integers(1 << 31)))
        _record(errors, block, hand, fd, zero)
