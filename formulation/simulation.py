"""Forward simulation of one strand: implicit Euler and the static equilibrium (DESIGN section 7).

Both minimize, by Newton's method, an incremental potential over the free DOFs (the root prescribes
x_0, th_0, x_1 when clamped, x_0 when pinned; a held tip and pins prescribe theirs, Strand):

    Phi(q) = E(q, p) - f_ext . q + 1/2 (q - y)^T W (q - y)                                    (J)

with f_ext gravity on the lumped masses plus the strand's loads, plus, with bodies, the contact
penalty of the contact module and, with friction, its lagged friction: normal forces, tangents and
anchors frozen at the start of each step (the static solve: at its start, as one step of 1 s),
the first step from q* pressing with the supports of p.

* implicit (backward) Euler with mass-proportional damping c (1/s): W = M (1/dt^2 + c/dt) and
  y = q_t + dt v_t / (1 + c dt); then grad Phi = 0 is M (v_{t+1} - v_t)/dt = f(q_{t+1}) - c M v_{t+1}
  with v_{t+1} = (q_{t+1} - q_t)/dt (S(7) is the inertia term at v = 0);
* the static equilibrium: W = 0, started from q*.

M is lumped: m_i = rho pi r^2 (l0_{i-1} + l0_i)/2 on the positions of vertex i, and the polar inertia
of edge j about its axis, rho pi r^4 l0_j / 2 (kg m^2), on th_j.

Reference frames (Bergou et al. 2010): during a time step the energy is evaluated with the frames of
the previous state, time-parallel transported to the new tangents inside the CasADi expression, so
Phi is one smooth function whose exact gradient and Hessian Newton uses; after the step the frames
are transported to the new state and the reference twist updated. When a tangent turns by more than
REBASE_ANGLE from its frame's tangent within one solve, the frames are re-based on the current
iterate (exact in value: the transported frame is the same), which keeps the transport far from its
singularity at opposite tangents during large static sags.

Newton (``newton_solve``; its whole loop is one compiled call, the newton module): the free block of
K = d2Phi/dq2 + mu M is banded (half bandwidth 10) and factored by the banded Cholesky of
sagfree.linalg in O(n); an Armijo backtracking line search on Phi takes the step, along a curve on
which the edges of the free tail turn instead of stretching (``length_keeping_step``). mu is a
Levenberg-Marquardt damping in the mass metric (1/s^2: mu M is the inertia of a pseudo time step
1/sqrt(mu)): it falls 16x when a full step decreased Phi by more than 0.75 of the quadratic model's
prediction, and rises 4x after a poorer or shortened step, or when the line search fails
(MAX_HALVINGS halvings; the direction is then recomputed); below MU_MIN it is 0, i.e. pure Newton
with quadratic convergence. The
implicit-Euler steps start at mu = 0 (their own inertia W keeps Newton in range). The static solve
starts at MU_STATIC: a pure Newton step from q* would move a drooping cantilever straight down,
stretch it, and crawl; the damped steps follow an overdamped motion from q* instead, which also makes
the equilibrium found the one q* relaxes into. Where K is not positive definite (compressed or
buckling states), mu rises 4x until the Cholesky succeeds: the mass metric is positive on every DOF,
so this always ends, and unlike a shift by diag(K) it does not let the stiff stretch terms freeze the
soft directions.

Convergence: the scaled residual max |grad Phi / D| (D: dofs.row_scales, the vertex weight) is at
most ``tol``; or it is below the round-off floor (``roundoff_floor``) and either the last Newton step
moved no vertex by more than STEP_TOLERANCE strand lengths and no angle by more than STEP_TOLERANCE
rad, or it stagnates. Coordinates are known to 1e-16 of their magnitude, and a hair's stretch
stiffness EA is ~1e10 times its vertex weight per metre: rounding alone leaves residuals of 1e-8 to
1e-6 on a 30-vertex strand, more on finer ones.
"""
from __future__ import annotations

import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sagfree.linalg import timing
from sagfree.linalg.band import add_vertex_blocks, quadratic_form
from sagfree.linalg.cholesky import band_cholesky, band_solve

from . import dofs
from .contact import FRICTION_CREEP, LaggedFriction, contact_penalty, lagged_friction
from .frames import Frames, transport_frames, unit
from .newton import (ARMIJO, MAX_HALVINGS, MAX_REJECTED, MU_MIN, MU_STATIC, NO_STEP, NON_FINITE,
                     OUT_OF_STEPS, REBASE_ANGLE, STAGNATION_STEPS, STEP_TOLERANCE, CONVERGED, STAGNATED, TINY_STEP,
                     length_keeping_step, newton_kernel, outcome_message, stagnated)
from .newton import roundoff_floor as newton_roundoff_floor  # simulation.roundoff_floor wraps it
from .problem import Problem

#: Newton has converged when the scaled residual max |grad Phi / D| is below this (the other rules
#: and the loop's constants: the newton module, which runs the loop compiled).
RESIDUAL_TOLERANCE = 1e-8
#: Tolerance of sag_check: below the round-off floor, so that Newton always steps.
CHECK_TOLERANCE = 1e-12
#: push_check: the push (largest vertex displacement over L), the run's length (s) and time step (s).
#: 5 s is several periods of the slowest stable modes and ~20 e-foldings of the mildest saddle seen.
PUSH, PUSH_DURATION, PUSH_DT = 1e-3, 5.0, 1e-2


@dataclass
class NewtonSolve:
    """One Newton solve: scaled residual max |grad Phi / D| before each step, steps taken, outcome."""

    residuals: list[float] = field(default_factory=list)
    steps: int = 0
    line_search: int = 0    # steps the line search shortened (alpha < 1)
    rejected: int = 0       # directions whose line search failed (mu raised)
    indefinite: int = 0     # factorizations that failed: K not positive definite (mu raised)
    converged: bool = False
    message: str = ""
    substeps: int = 1       # a time step's sub-steps (simulate: more than one where a whole step failed)


@dataclass
class Equilibrium:
    """Static equilibrium found by Newton from q*.

    q: DOFs (4n-1); positions (n, 3), m; sag: max |x_i - x_i*| (m); relative_sag: sag / L;
    newton: the solve's residual history and outcome; time (s); frames: the reference frames q's
    energy is evaluated with (Problem.energy; re-based during the solve when tangents turned far).
    """

    q: np.ndarray
    positions: np.ndarray
    sag: float
    relative_sag: float
    newton: NewtonSolve
    time: float
    frames: Frames

    @property
    def converged(self) -> bool:
        return self.newton.converged

    def __repr__(self) -> str:
        return (f"Equilibrium(converged={self.converged}, sag={self.sag:.3g} m, relative_sag="
                f"{self.relative_sag:.3g}, newton_steps={self.newton.steps}, time={self.time:.3g} s)\n"
                f"  message: {self.newton.message}")


@dataclass
class Simulation:
    """Implicit-Euler trajectory from rest at q*.

    trajectory: (steps + 1, n, 3) positions, m; theta: (steps + 1, n - 1) material angles, rad;
    times: (steps + 1,) s; displacement: (steps + 1,) max |x_i(t) - x_i*| per frame, m;
    sag: its maximum over the run (m); relative_sag: sag / L; newton: one NewtonSolve per step;
    dt: time step (s); time: wall time (s).
    """

    trajectory: np.ndarray
    theta: np.ndarray
    times: np.ndarray
    displacement: np.ndarray
    sag: float
    relative_sag: float
    newton: list[NewtonSolve]
    dt: float
    time: float

    @property
    def converged(self) -> bool:
        """Every step ran and its Newton solve converged."""
        return len(self.times) == len(self.newton) + 1 and all(s.converged for s in self.newton)

    @property
    def newton_iterations(self) -> np.ndarray:
        return np.array([s.steps for s in self.newton])

    def __repr__(self) -> str:
        steps = self.newton_iterations
        return (f"Simulation(steps={len(self.times) - 1}, dt={self.dt:g} s, converged={self.converged}, "
                f"sag={self.sag:.3g} m, relative_sag={self.relative_sag:.3g}, "
                f"newton_per_step={steps.mean() if steps.size else 0:.2f}, time={self.time:.3g} s)")


class IncrementalPotential:
    """Phi(q) of the module docstring for one Problem and parameter vector p.

    ``inertia``: None (static) or (W, y) with W the per-DOF weight (kg/s^2, kg m^2/s^2) and y the
    inertial target (4n-1).
    """

    def __init__(self, problem: Problem, p: np.ndarray, frames: Frames, inertia=None, scales=None,
                 friction: LaggedFriction | None = None):
        self.problem, self.p, self.frames = problem, np.asarray(p, dtype=float), frames
        self.friction = friction if problem.friction > 0 else None
        self.weight, self.target = inertia if inertia is not None else (None, None)
        self.scales = newton_scales(problem, self.p) if scales is None else scales

    def _contact(self, q: np.ndarray):
        """The contact penalty (contact module) at q: (energy, gradient (n, 3), Hessian blocks)."""
        return contact_penalty(self.problem.contacts, dofs.positions(q), self.problem.free_vertices)

    def value(self, q: np.ndarray) -> float:
        phi = self.problem.energy(self.p, q, self.frames) - self.problem.external_forces @ q
        if self.problem.bodies:
            phi += self._contact(q)[0]
        if self.friction is not None:
            phi += self.friction.evaluate(dofs.positions(q), self.problem.friction)[0]
        if self.weight is not None:
            d = q - self.target
            phi += 0.5 * d @ (self.weight * d)
        return float(phi)

    def gradient(self, q: np.ndarray) -> np.ndarray:
        g = self.problem.elastic_gradient(self.p, q, self.frames) - self.problem.external_forces
        if self.problem.bodies:
            g[dofs.position_index(self.problem.n_vertices)] += self._contact(q)[1]
        if self.friction is not None:
            g[dofs.position_index(self.problem.n_vertices)] += self.friction.evaluate(
                dofs.positions(q), self.problem.friction)[1]
        if self.weight is not None:
            g += self.weight * (q - self.target)
        return g

    def hessian_band(self, q: np.ndarray) -> np.ndarray:
        band = self.problem.static_hessian_band(self.p, q, self.frames)
        if self.friction is not None:
            add_vertex_blocks(band, self.friction.evaluate(dofs.positions(q), self.problem.friction)[2])
        if self.weight is not None:
            band[0] += self.weight
        return band


#: per-Problem constants of newton_scales and roundoff_floor (forgotten with their Problem)
_FIXED_SCALES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_ROUNDOFF_GEOMETRY: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def newton_scales(problem: Problem, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Per free DOF: the residual scale D, the Levenberg-Marquardt metric M and the step tolerance
    (STEP_TOLERANCE L on positions, STEP_TOLERANCE rad on angles); and the round-off floor."""
    return (*_fixed_scales(problem), roundoff_floor(problem, p))


def _fixed_scales(problem: Problem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The p-independent part of ``newton_scales`` (D, M, the step tolerance), made once per
    Problem (a strand's best effort runs hundreds of static solves); do not modify."""
    known = _FIXED_SCALES.get(problem)
    if known is None:
        free = problem.free_index
        limit = np.full(problem.q_star.size, STEP_TOLERANCE * problem.strand.length)
        limit[dofs.theta_index(problem.n_vertices)] = STEP_TOLERANCE
        known = _FIXED_SCALES[problem] = (problem.row_scale[free], generalized_masses(problem)[free], limit[free])
    return known


def roundoff_floor(problem: Problem, p: np.ndarray) -> float:
    """Scaled residual that rounding alone leaves in the stretch forces (dimensionless).

    Coordinates are known to eps X, X = max |x*| + L bounding where a vertex can go, so each edge
    length to 2 eps X, and the stretch force of edge j to 2 eps X alpha_j pi r^2 / l0_j (N); summed
    over the edges at each vertex and divided by its weight D_i. About 1e-6 for `horizontal` (30
    vertices, 10 cm), growing like n^2 (4e-4 for a 400-vertex groom strand).
    """
    squared_radius, reach, weight = _roundoff_geometry(problem)
    modulus = np.ascontiguousarray(problem.layout.edge_map.evaluate(problem.check_parameters(p))[:, 1])
    return float(newton_roundoff_floor(modulus, squared_radius, problem.edge_lengths, reach, weight))


def static_solve_constants(problem: Problem) -> tuple:
    """What a compiled caller of newton.newton_kernel needs besides Problem.newton_kernels to take
    ``equilibrium``'s static solves itself (solvers.least_sag_loop): (D, M and the step tolerance
    of ``newton_scales``, (r^2, X, D on the x rows, l0): ``roundoff_floor``'s geometry for
    newton.roundoff_floor, the last prescribed vertex: the anchor of length_keeping_step)."""
    squared_radius, reach, weight = _roundoff_geometry(problem)
    return (*_fixed_scales(problem), (float(squared_radius), reach, np.ascontiguousarray(weight, dtype=float),
                                      np.ascontiguousarray(problem.edge_lengths, dtype=float)),
            int(problem.strand.prescribed_vertices.max()))


def _roundoff_geometry(problem: Problem) -> tuple[np.ndarray, float, np.ndarray]:
    """(r^2, X, D on each vertex's x row) of ``roundoff_floor``, made once per Problem."""
    known = _ROUNDOFF_GEOMETRY.get(problem)
    if known is None:
        strand = problem.strand
        known = _ROUNDOFF_GEOMETRY[problem] = (
            strand.radius**2, float(np.abs(strand.points).max() + strand.length),
            problem.row_scale[dofs.position_index(problem.n_vertices)[:, 0]])
    return known


def generalized_masses(problem: Problem) -> np.ndarray:
    """Lumped mass per DOF (4n-1): m_i (kg) on positions, rho pi r^4 l0_j / 2 (kg m^2) on th_j
    (Problem.dof_masses)."""
    return problem.dof_masses


def _max_turn(frames: Frames, q: np.ndarray) -> float:
    """Largest angle (rad) between the tangents of q and those of the frames."""
    tangents = unit(np.diff(dofs.positions(q), axis=0))
    cosine = np.clip(np.sum(tangents * frames.tangents, axis=1), -1.0, 1.0)
    return float(np.arccos(cosine.min()))


def newton_solve(potential: IncrementalPotential, q: np.ndarray, tol: float = RESIDUAL_TOLERANCE,
                 max_steps: int = 50, mu: float = 0.0) -> tuple[np.ndarray, NewtonSolve]:
    """Minimize Phi over the free DOFs from q (prescribed DOFs stay as given); module docstring.

    mu: initial Levenberg-Marquardt damping (1/s^2). Returns the final q and the solve's record;
    re-bases ``potential.frames`` when tangents turn far. One compiled call where the stencils are
    compiled and Phi has no friction (newton.newton_kernel: Problem.newton_kernels), else this loop
    in Python.
    """
    problem = potential.problem
    scale, metric, step_limit, floor = potential.scales
    anchor = int(problem.strand.prescribed_vertices.max())  # the tail past it turns (length_keeping_step)
    kernels = problem.newton_kernels
    if kernels is not None and potential.friction is None:
        return _compiled_newton_solve(potential, kernels, q, tol, max_steps, mu, anchor)
    free = problem.free_index
    q = np.array(q, dtype=float)
    record = NewtonSolve()
    phi = potential.value(q)
    tiny_step = False
    while True:
        g = potential.gradient(q)[free]
        residual = float(np.max(np.abs(g / scale)))
        record.residuals.append(residual)
        if not np.isfinite(residual) or not np.isfinite(phi):
            return q, _ended(record, NON_FINITE, tol, floor, max_steps, mu)
        if residual <= tol:
            return q, _ended(record, CONVERGED, tol, floor, max_steps, mu)
        recent = np.array(record.residuals[-STAGNATION_STEPS - 1:])  # all that stagnated reads
        if residual <= floor and (tiny_step or stagnated(recent, recent.size)):
            return q, _ended(record, TINY_STEP if tiny_step else STAGNATED, tol, floor, max_steps, mu)
        if record.steps == max_steps:
            return q, _ended(record, OUT_OF_STEPS, tol, floor, max_steps, mu)
        band = problem.free_band(potential.hessian_band(q))
        for _ in range(MAX_REJECTED):
            damped = band.copy()
            damped[0] += mu * metric
            factor = band_cholesky(damped)
            if factor is None:
                record.indefinite += 1
                mu = max(4.0 * mu, MU_MIN)
                continue
            d = -band_solve(factor, g)
            alpha, trial, phi_trial = _line_search(potential, q, free, phi, g @ d, d, anchor)
            if trial is not None:
                break
            record.rejected += 1
            mu = max(4.0 * mu, MU_MIN)
        else:
            return q, _ended(record, NO_STEP, tol, floor, max_steps, mu)
        if alpha == 1.0:  # the quadratic model held over the full step: how well?
            predicted = -(g @ d + 0.5 * quadratic_form(band, d))
            resolvable = predicted > 1e3 * np.finfo(float).eps * max(abs(phi), abs(phi_trial))
            ratio = (phi - phi_trial) / predicted if resolvable else 1.0
        else:
            ratio = 0.0
        q, phi = trial, phi_trial
        record.steps += 1
        record.line_search += alpha < 1.0
        tiny_step = bool(np.all(np.abs(alpha * d) <= step_limit))
        if ratio > 0.75:
            mu = mu / 16.0 if mu > 16.0 * MU_MIN else 0.0
        elif ratio < 0.25:
            mu = max(4.0 * mu, MU_MIN)
        if _max_turn(potential.frames, q) > REBASE_ANGLE:
            potential.frames = transport_frames(potential.frames, dofs.positions(q))
            phi = potential.value(q)


def _ended(record: NewtonSolve, outcome: int, tol: float, floor: float, max_steps: int, mu: float) -> NewtonSolve:
    """``record`` of a solve that ended with ``outcome`` (newton module), its message and verdict set."""
    record.converged = outcome in (CONVERGED, TINY_STEP, STAGNATED)
    record.message = outcome_message(outcome, record.residuals[-1], tol, floor, max_steps, mu)
    return record


def _compiled_newton_solve(potential: IncrementalPotential, kernels: tuple, q: np.ndarray, tol: float,
                           max_steps: int, mu: float, anchor: int) -> tuple[np.ndarray, NewtonSolve]:
    """newton_solve's loop in one compiled call (newton.newton_kernel), for a Phi without friction;
    the same q, record and re-based frames to rounding."""
    slots, strand, drivers, plan, gather, free, external, bodies = kernels
    scale, metric, step_limit, floor = potential.scales
    weight, target = (potential.weight, potential.target) if potential.weight is not None else (_EMPTY, _EMPTY)
    frames = potential.frames
    residuals, counts, seconds = np.empty(max_steps + 1), np.zeros(5, dtype=np.int64), np.zeros(2)
    q, outcome, mu, tangents, a1, twist = newton_kernel(
        np.array(q, dtype=float), float(mu), *(np.array(a, dtype=float) for a in (frames.tangents, frames.a1,
                                                                                   frames.reference_twist)),
        np.array(potential.p, dtype=float), slots, strand, drivers, plan, gather, free, external, bodies,
        *(np.ascontiguousarray(a, dtype=float) for a in (weight, target, scale, metric, step_limit)), float(floor),
        anchor, float(tol), int(max_steps), residuals, counts, *timing.CLOCK, seconds)
    timing.add(timing.MODEL, seconds[0])
    timing.add(timing.LINEAR_ALGEBRA, seconds[1])
    potential.frames = Frames(tangents, a1, twist)  # re-based, or the same values
    record = NewtonSolve(residuals[:counts[0]].tolist(), int(counts[1]), int(counts[2]), int(counts[3]),
                         int(counts[4]))
    return q, _ended(record, outcome, tol, floor, max_steps, mu)


_EMPTY = np.empty(0)


def _line_search(potential: IncrementalPotential, q, free, phi, slope, d, anchor: int):
    """Armijo backtracking from q along the curve of d (``length_keeping_step``; on the DOFs ``free``):
    the first alpha = 1, 1/2, ... (at most MAX_HALVINGS halvings) with Phi(q(alpha)) <= Phi(q) +
    ARMIJO alpha slope, or with a change of Phi below rounding. Returns (alpha, q(alpha), Phi there),
    or (0, None, None)."""
    alpha = 1.0
    for _ in range(MAX_HALVINGS + 1):
        trial = length_keeping_step(q, free, alpha, d, anchor)
        with np.errstate(all="ignore"):
            phi_trial = potential.value(trial)
        unresolvable = -alpha * slope <= 1e3 * np.finfo(float).eps * max(abs(phi), abs(phi_trial))
        if np.isfinite(phi_trial) and (phi_trial <= phi + ARMIJO * alpha * slope or unresolvable):
            return alpha, trial, phi_trial
        alpha *= 0.5
    return 0.0, None, None


def _displacement(problem: Problem, q: np.ndarray) -> float:
    """max_i |x_i - x_i*|, m."""
    return float(np.max(np.linalg.norm(dofs.positions(q) - problem.strand.points, axis=1)))


def equilibrium(problem: Problem, p, tol: float = RESIDUAL_TOLERANCE, max_steps: int = 2000,
                start: Equilibrium | None = None) -> Equilibrium:
    """Static equilibrium that q* relaxes into (damped Newton from q*, module docstring), with its sag.

    start: continue from another equilibrium of the same strand (its q and frames, Newton damped
    from MU_MIN), e.g. that of nearby parameters: the branch followed as p changes (solvers.least_sag).
    """
    clock = time.perf_counter()
    p = problem.check_parameters(p)
    q, frames, mu = (problem.q_star, problem.frames, MU_STATIC) if start is None else (start.q, start.frames, MU_MIN)
    potential = IncrementalPotential(problem, p, frames, friction=_friction(problem, p, q, 1.0, True))
    q, record = newton_solve(potential, q, tol, max_steps, mu=mu)
    sag = _displacement(problem, q)
    return Equilibrium(q, dofs.positions(q), sag, sag / problem.strand.length, record,
                       time.perf_counter() - clock, potential.frames)


def _friction(problem: Problem, p: np.ndarray, q: np.ndarray, dt: float, first: bool) -> LaggedFriction | None:
    """The lagged friction of a step of ``dt`` s from q (None without friction): on the first step
    (from q* or a state near it, where the penalty pushes nothing yet) the resting vertices press
    with the normal forces of p's supports (contact module)."""
    if not problem.friction > 0 or not problem.contacts.count:
        return None
    held = None
    if first:
        held = np.zeros(problem.n_vertices)
        held[problem.contacts.vertices] = problem.normal_forces(p)
    return lagged_friction(problem.contacts, dofs.positions(q), problem.free_vertices,
                           FRICTION_CREEP * problem.strand.length * dt, problem.friction, held)


def simulate(problem: Problem, p, steps: int = 200, dt: float = 1e-3, damping: float = 0.0,
             root_motion: Callable[[float], np.ndarray] | None = None, tol: float = RESIDUAL_TOLERANCE,
             max_newton: int = 50, start: np.ndarray | None = None) -> Simulation:
    """Implicit-Euler run of ``steps`` steps of ``dt`` seconds from rest at q* (module docstring).

    damping: mass-proportional damping rate c, 1/s (0: none). root_motion: translation (m, 3-vector)
    of the root vertices at time t (s); None keeps the root where q* has it (a held tip and pins stay). start: the
    state at t = 0 (4n-1; at rest; None: q*), e.g. a pushed q*. A step whose Newton solve does not
    converge is taken again as two half steps, each split again where it fails, down to
    dt / 2^SUBSTEP_HALVINGS (``_advanced``): a strand released far from equilibrium (a least-sag
    answer that snaps into its rest, 0.25 L in 10 ms) moves farther in one step than Newton reaches
    from the inertial target, and the run diverged at its second step where sub-steps follow the
    motion. The run stops at a step that fails even so, or whose state is not finite; ``converged``
    tells whether every step's Newton converged.
    """
    if steps < 0 or not dt > 0 or not damping >= 0:
        raise ValueError(f"need steps >= 0, dt > 0 and damping >= 0; got {steps}, {dt}, {damping}")
    clock = time.perf_counter()
    p = problem.check_parameters(p)
    n = problem.n_vertices
    stepper = _Stepper(problem, p, damping, root_motion, newton_scales(problem, p), tol, max_newton)
    q = problem.q_star.copy() if start is None else np.asarray(start, dtype=float).copy()
    if q.shape != problem.q_star.shape:
        raise ValueError(f"start must have {problem.q_star.size} entries (4n-1), got {q.size}")
    v, frames = np.zeros_like(problem.q_star), problem.frames
    states, solves = [q], []
    for step in range(1, steps + 1):
        q_next, v, frames, record = _advanced(stepper, q, v, frames, step * dt, dt, step == 1, SUBSTEP_HALVINGS)
        solves.append(record)
        if not record.converged or not np.all(np.isfinite(q_next)):
            break
        q = q_next
        states.append(q)
    states = np.array(states)
    positions = states[:, dofs.position_index(n)]
    displacement = np.max(np.linalg.norm(positions - problem.strand.points, axis=2), axis=1)
    sag = float(displacement.max())
    return Simulation(positions, states[:, dofs.theta_index(n)], dt * np.arange(len(states)), displacement,
                      sag, sag / problem.strand.length, solves, dt, time.perf_counter() - clock)


#: Halvings of a time step whose Newton solve fails (``simulate``): sub-steps down to dt / 32.
SUBSTEP_HALVINGS = 5


@dataclass
class _Stepper:
    """What every time step of one ``simulate`` run shares."""

    problem: Problem
    p: np.ndarray
    damping: float
    root_motion: Callable[[float], np.ndarray] | None
    scales: tuple
    tol: float
    max_newton: int

    def __post_init__(self):
        self.masses = generalized_masses(self.problem)
        self.root = dofs.position_index(self.problem.n_vertices)[:2 if self.problem.strand.root == "clamped"
                                                                 else 1].ravel()

    def step(self, q, v, frames: Frames, end: float, dt: float, first: bool):
        """(q, frames Newton ended with, record) of one implicit-Euler step of dt from (q, v) to time ``end``."""
        problem, damping = self.problem, self.damping
        weight = self.masses * (1.0 / dt**2 + damping / dt)
        target = q + dt * v / (1.0 + damping * dt)
        if self.root_motion is not None:
            target[self.root] = problem.q_star[self.root] + np.tile(np.asarray(self.root_motion(end), float),
                                                                    len(self.root) // 3)
        potential = IncrementalPotential(problem, self.p, frames, (weight, target), self.scales,
                                         _friction(problem, self.p, q, dt, first))
        q_next, record = newton_solve(potential, target, self.tol, self.max_newton)
        return q_next, potential.frames, record


def _advanced(stepper: _Stepper, q, v, frames: Frames, end: float, dt: float, first: bool, halvings: int):
    """(q, v, frames, record) after dt from (q, v, frames), ending at time ``end``: one step, or where
    its Newton solve fails and ``halvings`` remain, two half steps (``_in_halves``; the record counts
    the failed step's Newton steps too). Where even those fail, the failed whole step's state and
    record."""
    q_next, used, record = stepper.step(q, v, frames, end, dt, first)
    if not record.converged and halvings > 0:
        halves = _in_halves(stepper, q, v, frames, end, dt, first, halvings - 1)
        if halves is not None:
            q_end, v_end, frames_end, first_half, second_half = halves
            parts = (record, first_half, second_half)
            return q_end, v_end, frames_end, NewtonSolve(
                first_half.residuals + second_half.residuals,
                *(sum(getattr(part, name) for part in parts) for name in ("steps", "line_search", "rejected",
                                                                            "indefinite")),
                True, second_half.message, first_half.substeps + second_half.substeps)
    return q_next, (q_next - q) / dt, _transported(used, q_next), record


def _in_halves(stepper: _Stepper, q, v, frames: Frames, end: float, dt: float, first: bool, halvings: int):
    """(q, v, frames, first half's record, second half's) after two steps of dt / 2, each split again
    where it fails (``_advanced`` with ``halvings``); None where they fail."""
    q_half, v_half, frames_half, first_half = _advanced(stepper, q, v, frames, end - 0.5 * dt, 0.5 * dt, first,
                                                        halvings)
    if not (first_half.converged and np.all(np.isfinite(q_half))):
        return None
    q_end, v_end, frames_end, second_half = _advanced(stepper, q_half, v_half, frames_half, end, 0.5 * dt, False,
                                                      halvings)
    return (q_end, v_end, frames_end, first_half, second_half) if second_half.converged else None


def _transported(frames: Frames, q: np.ndarray) -> Frames:
    """The frames carried to q's tangents (as they were where q is not finite: the run stops there)."""
    return transport_frames(frames, dofs.positions(q)) if np.all(np.isfinite(q)) else frames


@dataclass
class Push:
    """A pushed strand: q* moved by ``push`` L along its softest mode, then simulated.

    push: the push, max vertex displacement over L; eigenvalue: the mode's (s^-2); deviation: max
    vertex displacement from q* over L at the end of the run; peak: its maximum over the run;
    holds: it came back within its push (deviation <= push) and every Newton solve converged.
    """

    push: float
    eigenvalue: float
    deviation: float
    peak: float
    holds: bool
    simulation: Simulation


def push_check(problem: Problem, p, push: float = PUSH, duration: float = PUSH_DURATION,
               dt: float = PUSH_DT) -> Push:
    """Push the rest state along its softest mode (``Problem.stability``'s eigenvector, scaled so that
    the largest vertex displacement is ``push`` L) and integrate ``duration`` seconds of implicit
    Euler from rest there: a stable rest state swings back (implicit Euler only damps), a saddle
    point grows like exp(sqrt(-lambda) t) and leaves. A run from q* alone cannot see a saddle: it
    leaves only once rounding has grown, seconds later.
    """
    p = problem.check_parameters(p)
    eigenvalue, mode = problem.stability(p, vector=True)
    length = problem.strand.length
    reach = float(np.max(np.linalg.norm(dofs.positions(mode), axis=1)))
    if reach > 1e-12 * np.abs(mode).max():
        scale = push * length / reach
    else:  # a pure twist mode: push the angles by ``push`` rad
        scale = push / np.abs(mode).max()
    run = simulate(problem, p, steps=int(round(duration / dt)), dt=dt, start=problem.q_star + scale * mode)
    deviation = float(run.displacement[-1]) / length
    return Push(push, eigenvalue, deviation, run.relative_sag, bool(run.converged and deviation <= push), run)


@dataclass
class SagCheck:
    """Forward check of one strand's parameters (``sagfree simulate``, studies): an implicit-Euler run
    from rest at q*, the static equilibrium from q*, and a push along the softest mode (push_check).

    sag: max vertex displacement over the run (m); relative_sag: over L; static_sag: the static
    equilibrium's displacement over L (NaN if it did not converge); converged: both solvers
    converged; newton: mean Newton steps per time step; push: the pushed run's displacement at its
    end over L (NaN if not pushed); holds: it came back within its push (push_check); message: what
    went wrong, if anything.
    """

    sag: float
    relative_sag: float
    static_sag: float
    converged: bool
    newton: float
    time: float
    message: str = ""
    push: float = float("nan")
    holds: bool = False

    def sags(self, threshold: float) -> bool:
        """Whether the strand moves by more than ``threshold`` strand lengths (or was not checked)."""
        worst = max(self.relative_sag, self.static_sag)
        return not (self.converged and worst <= threshold)


def sag_check(problem: Problem, p, steps: int = 200, dt: float = 1e-3, damping: float = 0.0,
              tol: float = CHECK_TOLERANCE, push: bool = True) -> SagCheck:
    """Run ``simulate`` and ``equilibrium`` on ``p`` (and ``push_check`` with its defaults, unless
    ``push`` is False) and summarize them as a SagCheck.

    The default ``tol`` lies below the round-off floor, so Newton takes at least one step at every
    time step even where q* already satisfies RESIDUAL_TOLERANCE: the check shows what a simulator
    does that has no such tolerance.
    """
    start = time.perf_counter()
    run = simulate(problem, p, steps, dt, damping, tol=tol)
    static = equilibrium(problem, p, tol=tol)
    pushed = push_check(problem, p) if push else None
    problems = []
    if not run.converged:
        failed = next((k for k, s in enumerate(run.newton) if not s.converged), len(run.newton))
        detail = run.newton[failed].message if failed < len(run.newton) else "non-finite state"
        problems.append(f"time step {failed + 1}: {detail}")
    if not static.converged:
        problems.append(f"static solve: {static.newton.message}")
    if pushed is not None and not pushed.holds:
        problems.append(f"pushed by {pushed.push:g} L along its softest mode ({pushed.eigenvalue:.3g} s^-2), it "
                        f"ends {pushed.deviation:.3g} L away")
    return SagCheck(run.sag, run.relative_sag, static.relative_sag if static.converged else float("nan"),
                    run.converged and static.converged,
                    float(run.newton_iterations.mean()) if run.newton else 0.0,
                    time.perf_counter() - start, "; ".join(problems),
                    pushed.deviation if pushed else float("nan"), bool(pushed and pushed.holds))
