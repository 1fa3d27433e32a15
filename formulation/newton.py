"""The Newton solve of the forward simulation (simulation.newton_solve) as one compiled call.

Every Newton step of the static solve and of each implicit-Euler step evaluates Phi (J), its
gradient and its Hessian band through the strand's stencils, factors the damped free block, and
searches along the length-keeping curve (simulation module docstring). Driven from Python, a step
is some twenty numpy and ctypes calls, ~0.4 ms on a 100-vertex strand, most of it outside the
stencils: the forward check of every report and the static solves of the infeasible strands' best
effort (solvers.least_sag) spent their time there. ``newton_kernel`` runs newton_solve's whole loop
as compiled code: the stencils through their C drivers at their addresses (at_rest.call_into), the
Hessian band as at_rest.hessian_band scatters it, the banded Cholesky of linalg.cholesky, the
line search along ``length_keeping_step``, the damping's rule, and the re-basing of the frames
(frames._transported). Same formulas in the same order, the energies summed pairwise as numpy sums
them (linalg.pairwise), the dot products through BLAS: the two loops agree to rounding
(tests/test_newton.py).

The contact penalty of bodies (contact.contact_penalty) is summed in the same way, each body's
distance by the compiled functions of the bodies module (``_contact``; a mesh through its search
tree, mesh_tree). It applies where the stencils are compiled, the bodies are spheres, capsules and
at most one mesh, and Phi has no friction (the lagged friction is numpy code): Problem.newton_kernels
is None elsewhere, and newton_solve takes its Python loop, with the same constants and messages
(``outcome_message``).
"""
from __future__ import annotations

import numba
import numpy as np

from sagfree.linalg import timing
from sagfree.linalg.band import quadratic_form
from sagfree.linalg.cholesky import factor_active, plain_solve
from sagfree.linalg.pairwise import pairwise_sum

from .at_rest import call_into, hessian_band
from .bodies import Capsule, Mesh, Sphere, _capsule_distance, _mesh_distance, _round
from .frames import _transported
from .parameters import evaluate_slots

#: Newton has converged when the scaled residual max |grad Phi / D| is below the solve's tol; ...
#: ... or, below the round-off floor, when a Newton step moves vertices by at most this many strand
#: lengths (and angles by this many rad) ...
STEP_TOLERANCE = 1e-10
#: ... or when the residual has not halved in STAGNATION_STEPS steps.
STAGNATION_STEPS = 3
#: Levenberg-Marquardt damping mu (1/s^2): smallest non-zero value, start of the static solve,
#: directions rejected in a row (line search failed, or K indefinite) before giving up.
MU_MIN = 1.0
MU_STATIC = 1e6
MAX_REJECTED = 40
#: Line search: Armijo constant and step halvings before mu is raised instead.
ARMIJO = 1e-4
MAX_HALVINGS = 4
#: Tangent turn (rad) above which the reference frames are re-based on the current iterate.
REBASE_ANGLE = np.radians(60.0)

EPS = float(np.finfo(float).eps)

#: Body kinds in contact_table (bodies.Sphere, Capsule, Mesh).
SPHERE, CAPSULE, MESH = range(3)

#: How a Newton solve ended: the residual within tol; at the round-off floor after a tiny step, or
#: stagnating there; a non-finite energy or force; out of steps; no acceptable step.
CONVERGED, TINY_STEP, STAGNATED, NON_FINITE, OUT_OF_STEPS, NO_STEP = range(6)


def outcome_message(outcome: int, residual: float, tol: float, floor: float, max_steps: int, mu: float) -> str:
    """The NewtonSolve message of a solve that ended with ``outcome`` at the scaled ``residual``."""
    if outcome == CONVERGED:
        return f"residual {residual:.2e} <= {tol:g}"
    if outcome in (TINY_STEP, STAGNATED):
        how = f"Newton step below {STEP_TOLERANCE:g}" if outcome == TINY_STEP else "stagnated"
        return f"residual {residual:.2e} at the round-off floor {floor:.1e} ({how})"
    if outcome == NON_FINITE:
        return "non-finite energy or force"
    if outcome == OUT_OF_STEPS:
        return f"no convergence in {max_steps} Newton steps (residual {residual:.2e})"
    return f"no acceptable step after {MAX_REJECTED} increases of mu to {mu:.3g} (residual {residual:.2e})"


@numba.njit(cache=True)
def stagnated(residuals, count):  # pragma: no cover - compiled
    """The last STAGNATION_STEPS of the ``count`` residuals did not halve the one before them."""
    if count <= STAGNATION_STEPS:
        return False
    least = residuals[count - STAGNATION_STEPS]
    for k in range(count - STAGNATION_STEPS + 1, count):
        least = min(least, residuals[k])
    return least > 0.5 * residuals[count - STAGNATION_STEPS - 1]


@numba.njit(cache=True)
def length_keeping_step(q, free, alpha, d, anchor):  # pragma: no cover - compiled
    """q(alpha): q + alpha d on the DOFs ``free``, except that the edges past vertex ``anchor`` (the
    last prescribed one) turn instead of stretching. Each such edge e_j = x_{j+1} - x_j becomes

        e_j(alpha) = (|e_j| + alpha t_j . de_j) (e_j + alpha de_j) / |e_j + alpha de_j|      (t_j = e_j / |e_j|)

    (de_j the change d makes to it), and the free tail is rebuilt from x_anchor by summing them.
    The curve has the straight step's tangent at alpha = 0 (d q(alpha)/d alpha = d there, so
    Armijo's slope g . d holds), but a turn of an edge no longer lengthens it by alpha^2 |de_j
    perpendicular|^2 / (2 |e_j|). A hair's stretch stiffness is ~1e6 times its bending's, so along
    straight steps that second-order stretch held the Newton steps of a strand that falls far
    short: a long hair falling to hang took 40 times more steps. Vertices up to the anchor (a held
    tip or pin: a span between prescribed vertices cannot close by summing) step straight; where
    the step collapses an edge (a first-order length <= 0) the whole step is straight."""
    trial = q.copy()
    for k in range(free.size):
        trial[free[k]] += alpha * d[k]
    n_vertices = (q.size + 1) // 4
    if anchor >= n_vertices - 1:
        return trial
    edges = n_vertices - 1 - anchor
    turned, factor = np.empty((edges, 3)), np.empty(edges)
    for j in range(edges):
        a, b = 4 * (anchor + j), 4 * (anchor + j + 1)
        length = turned_length = along = 0.0
        for c in range(3):
            edge, moved = q[b + c] - q[a + c], trial[b + c] - trial[a + c]
            turned[j, c] = moved
            length += edge * edge
            turned_length += moved * moved
        length, turned_length = np.sqrt(length), np.sqrt(turned_length)
        for c in range(3):
            edge = q[b + c] - q[a + c]
            along += edge * (turned[j, c] - edge)
        kept = length + along / length
        if not (kept > 0.0 and turned_length > 0.0):
            return trial
        factor[j] = kept / turned_length
    summed = np.zeros(3)
    for j in range(edges):  # x_anchor + the running sum of the turned edges
        b = 4 * (anchor + j + 1)
        for c in range(3):
            summed[c] += turned[j, c] * factor[j]
            trial[b + c] = q[4 * anchor + c] + summed[c]
    return trial


@numba.njit(cache=True)
def _gathered(q, index):  # pragma: no cover - compiled
    """q[index] for a 2-D index (the stencils' DOFs), C-contiguous."""
    out = np.empty(index.shape)
    for s in range(index.shape[0]):
        for i in range(index.shape[1]):
            out[s, i] = q[index[s, i]]
    return out


@numba.njit(cache=True)
def _reference(tangents, a1, twist):  # pragma: no cover - compiled
    """rest_geometry.reference_data: (n-2, 13) t^{i-1}, a1^{i-1}, t^i, a1^i, reference twist."""
    out = np.empty((twist.size, 13))
    for i in range(twist.size):
        for c in range(3):
            out[i, c], out[i, 3 + c] = tangents[i, c], a1[i, c]
            out[i, 6 + c], out[i, 9 + c] = tangents[i + 1, c], a1[i + 1, c]
        out[i, 12] = twist[i]
    return out


def contact_table(bodies: tuple, contacts, free_vertices: np.ndarray):
    """``_contact``'s description of ``bodies`` with their contact.Contacts ``contacts``: (kinds
    (B,) of SPHERE, CAPSULE, MESH; parameters (B, 7): a sphere's centre and radius, a capsule's a, b
    and radius; the mesh's vertices, faces and search tree (bodies.Mesh.tree; empty arrays without a
    mesh); the contact levels (n, B), the penalty stiffness (n,), the free vertices), or None if a
    body is of another kind or there is more than one mesh (the Python loop evaluates them)."""
    kinds, parameters = np.zeros(len(bodies), np.int64), np.zeros((len(bodies), 7))
    meshes = [body for body in bodies if type(body) is Mesh]
    if len(meshes) > 1:
        return None
    mesh = (meshes[0].vertices, meshes[0].faces, *meshes[0].tree) if meshes else _NO_MESH
    for b, body in enumerate(bodies):
        if type(body) is Sphere:  # exactly: a subclass may measure the distance its own way
            kinds[b], parameters[b, :4] = SPHERE, (*body.center, body.radius)
        elif type(body) is Capsule:
            kinds[b], parameters[b] = CAPSULE, (*body.a, *body.b, body.radius)
        elif type(body) is Mesh:
            kinds[b] = MESH
        else:
            return None
    return (kinds, parameters, mesh, np.ascontiguousarray(contacts.levels, dtype=float),
            np.ascontiguousarray(contacts.stiffness, dtype=float), np.ascontiguousarray(free_vertices, dtype=np.bool_))


#: contact_table's mesh where there is none: empty arrays of its types
_NO_MESH = (np.zeros((0, 3)), np.zeros((0, 3), np.int64), *(np.zeros(shape, dtype) for shape, dtype in (
    ((0, 3), float), ((0, 3), float), (0, np.int64), (0, np.int64), ((0, 2), np.int64), (0, np.int64),
    ((0, 3), float), (0, float), ((0, 3), float))))


@numba.njit(cache=True, inline="always")
def _body_distance(x, kind, parameters, mesh):  # pragma: no cover - compiled
    """(phi, n, K) of one body at the points x (n, 3), as Body.evaluate gives them: a sphere
    (parameters: centre, radius), a capsule (a, b, radius) or the mesh (its vertices, faces and
    search tree)."""
    if kind == SPHERE:
        return _round(x - parameters[:3], parameters[3])
    if kind == MESH:
        return _mesh_distance(x, *mesh)
    return _capsule_distance(x, parameters[:3], parameters[3:6], parameters[6])


@numba.njit(cache=True)
def _contact(x, bodies):  # pragma: no cover - compiled
    """(energy (J), gradient (n, 3), Hessian blocks (n, 3, 3)) of contact.contact_penalty at the
    positions x, summed body by body as it sums them. bodies: ``contact_table``'s."""
    kinds, parameters, mesh, levels, stiffness, free = bodies
    n = x.shape[0]
    energy, gradient, hessian = 0.0, np.zeros((n, 3)), np.zeros((n, 3, 3))
    terms = np.empty(n)
    for b in range(kinds.size):
        phi, normal, K = _body_distance(x, kinds[b], parameters[b], mesh)
        count = 0
        for i in range(n):
            depth = phi[i] - levels[i, b]
            if not (free[i] and depth < 0.0):
                continue
            k = stiffness[i]
            terms[count] = k * depth * depth
            count += 1
            for c in range(3):
                gradient[i, c] += (k * depth) * normal[i, c]
                for e in range(3):
                    hessian[i, c, e] += k * (normal[i, c] * normal[i, e] + depth * K[i, c, e])
        if count:
            energy += 0.5 * pairwise_sum(terms[:count])
    return energy, gradient, hessian


@numba.njit(cache=True)
def _phi(q, reference, strand, physical, drivers, external, bodies, weight, target):  # pragma: no cover
    """Phi(q) (simulation.IncrementalPotential.value): E by the energy drivers, summed as numpy sums
    them, less f_ext . q, plus the bodies' contact penalty, plus the inertia's 1/2 (q - y)^T W (q - y)
    where W is not empty."""
    edge_geometry, vertex_geometry, edge_dofs, vertex_dofs = strand
    edges, vertices = edge_dofs.shape[0], vertex_dofs.shape[0]
    by_edge, by_vertex = np.empty((edges, 1)), np.empty((vertices, 1))
    call_into(drivers[0], edges, (_gathered(q, edge_dofs), edge_geometry, physical[0]), (by_edge,))
    call_into(drivers[3], vertices, (_gathered(q, vertex_dofs), reference, vertex_geometry, physical[1]), (by_vertex,))
    phi = (pairwise_sum(by_edge.ravel()) + pairwise_sum(by_vertex.ravel())) - np.dot(external, q)
    if bodies[0].size:
        phi += _contact(_positions(q), bodies)[0]
    if weight.size:
        d = q - target
        phi += 0.5 * np.dot(d, weight * d)
    return phi


@numba.njit(cache=True)
def _gradient(q, reference, strand, physical, drivers, external, pushed, weight, target,
              free):  # pragma: no cover - compiled
    """grad Phi on the free DOFs (IncrementalPotential.gradient): the stencils' gradients summed onto
    the DOFs edges first, then vertices (np.bincount's order), less f_ext, plus the contact
    penalty's ``pushed`` (n, 3; none if empty) on the positions, plus W (q - y)."""
    edge_geometry, vertex_geometry, edge_dofs, vertex_dofs = strand
    edges, edge_width = edge_dofs.shape
    vertices, vertex_width = vertex_dofs.shape
    by_edge, by_vertex = np.empty((edges, edge_width)), np.empty((vertices, vertex_width))
    call_into(drivers[1], edges, (_gathered(q, edge_dofs), edge_geometry, physical[0]), (by_edge,))
    call_into(drivers[4], vertices, (_gathered(q, vertex_dofs), reference, vertex_geometry, physical[1]),
              (by_vertex,))
    edge_sum, vertex_sum = np.zeros(q.size), np.zeros(q.size)
    for s in range(edges):
        for i in range(edge_width):
            edge_sum[edge_dofs[s, i]] += by_edge[s, i]
    for s in range(vertices):
        for i in range(vertex_width):
            vertex_sum[vertex_dofs[s, i]] += by_vertex[s, i]
    g = np.empty(free.size)
    for k in range(free.size):
        j = free[k]
        value = (edge_sum[j] + vertex_sum[j]) - external[j]
        if pushed.shape[0] and j % 4 != 3:
            value += pushed[j // 4, j % 4]
        if weight.size:
            value += weight[j] * (q[j] - target[j])
        g[k] = value
    return g


@numba.njit(cache=True)
def _free_band(q, reference, p, slots, strand, drivers, plan, gather, blocks, weight):  # pragma: no cover
    """The free block of d2Phi/dq2 in lower band storage: at_rest.hessian_band at q with the current
    reference, plus the contact penalty's ``blocks`` (n, 3, 3; none if empty) on the positions
    (linalg.band.add_vertex_blocks), plus W on the diagonal, gathered as Problem.free_band gathers
    it."""
    edge_geometry, vertex_geometry, edge_dofs, vertex_dofs = strand
    target, source, ones, rows = plan
    band = hessian_band(p, slots[0], slots[1], _gathered(q, edge_dofs), edge_geometry, _gathered(q, vertex_dofs),
                        reference, vertex_geometry, drivers[2], drivers[5], target, source, ones, rows, q.size)
    if blocks.shape[0]:
        for k in range(3):
            for j in range(3 - k):
                for i in range(blocks.shape[0]):
                    band[k, 4 * i + j] += blocks[i, j + k, j]
    if weight.size:
        for j in range(q.size):
            band[0, j] += weight[j]
    gather_target, gather_source, size = gather
    flat, out = band.ravel(), np.zeros(rows * size)
    for k in range(gather_target.size):
        out[gather_target[k]] = flat[gather_source[k]]
    return out.reshape(rows, size)


@numba.njit(cache=True)
def _turned_too_far(q, tangents):  # pragma: no cover - compiled
    """Whether a tangent of q turned by more than REBASE_ANGLE from its frame's (simulation._max_turn)."""
    least = 1.0
    for j in range(tangents.shape[0]):
        a, b = 4 * j, 4 * (j + 1)
        e0, e1, e2 = q[b] - q[a], q[b + 1] - q[a + 1], q[b + 2] - q[a + 2]
        norm = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        cosine = (e0 / norm) * tangents[j, 0] + (e1 / norm) * tangents[j, 1] + (e2 / norm) * tangents[j, 2]
        least = min(least, max(cosine, -1.0))
    return np.arccos(least) > REBASE_ANGLE


@numba.njit(cache=True)
def _positions(q):  # pragma: no cover - compiled
    """dofs.positions: (n, 3) vertex positions of q."""
    n = (q.size + 1) // 4
    out = np.empty((n, 3))
    for i in range(n):
        for c in range(3):
            out[i, c] = q[4 * i + c]
    return out


@numba.njit(cache=True)
def roundoff_floor(modulus, squared_radius, edge_lengths, reach, weight):  # pragma: no cover - compiled
    """simulation.roundoff_floor from the edges' Young's moduli (Pa): 2 eps X max_i (sum over the
    edges at vertex i of E_j pi r^2 / l0_j) / D_i, X the reach and D the vertices' weights."""
    at_vertex = np.zeros(modulus.size + 1)
    for j in range(modulus.size):
        at_vertex[j] += modulus[j] * np.pi * squared_radius / edge_lengths[j]
    for j in range(modulus.size):
        at_vertex[j + 1] += modulus[j] * np.pi * squared_radius / edge_lengths[j]
    largest = -np.inf
    for i in range(at_vertex.size):
        largest = max(largest, at_vertex[i] / weight[i])
    return 2.0 * EPS * reach * largest


@numba.njit(cache=True)
def newton_kernel(q, mu, tangents, a1, twist, p, slots, strand, drivers, plan, gather, free, external, bodies, weight,
                  target, scale, metric, step_limit, floor, anchor, tol, max_steps, residuals, counts, clock, clock_id,
                  seconds):  # pragma: no cover - compiled
    """simulation.newton_solve from q (copied) with damping mu, frames (tangents, a1, twist): returns
    (q, outcome, mu, tangents, a1, twist), the frames re-based where tangents turned far.
    residuals (max_steps + 1) receives the scaled residual before each step; counts the number of
    residuals, steps, shortened line searches, rejected directions and failed factorizations (a
    NewtonSolve's fields). The arguments after p are Problem.newton_kernels' and the potential's
    (W and y, empty for the static solve) and scales (simulation.newton_scales). seconds[0] and [1]
    accumulate the model evaluation's and the linear algebra's seconds on the clock (address, id)."""
    buffer = np.zeros(2, dtype=np.int64)
    q = q.copy()
    physical = (evaluate_slots(slots[0][0], slots[0][1], slots[0][2], slots[0][3], p),
                evaluate_slots(slots[1][0], slots[1][1], slots[1][2], slots[1][3], p))
    reference = _reference(tangents, a1, twist)
    before = timing.clock_seconds(clock, clock_id, buffer)
    phi = _phi(q, reference, strand, physical, drivers, external, bodies, weight, target)
    seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - before
    rows, size = plan[3], free.size
    no_border, no_corner, everything = np.zeros((0, size)), np.zeros((0, 0)), np.ones(size, dtype=np.bool_)
    factor, d = np.empty((size, rows)), np.empty(size)
    tiny_step = False
    counts[:] = 0
    while True:
        before = timing.clock_seconds(clock, clock_id, buffer)
        pushed, blocks = np.zeros((0, 3)), np.zeros((0, 3, 3))
        if bodies[0].size:  # the contact penalty at q, for the gradient and the band
            _, pushed, blocks = _contact(_positions(q), bodies)
        g = _gradient(q, reference, strand, physical, drivers, external, pushed, weight, target, free)
        seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - before
        residual = 0.0
        for k in range(size):  # np.max: NaN if any entry is NaN
            value = abs(g[k] / scale[k])
            if value != value:
                residual = value
                break
            residual = max(residual, value)
        residuals[counts[0]] = residual
        counts[0] += 1
        if not (np.isfinite(residual) and np.isfinite(phi)):
            return q, NON_FINITE, mu, tangents, a1, twist
        if residual <= tol:
            return q, CONVERGED, mu, tangents, a1, twist
        if residual <= floor and (tiny_step or stagnated(residuals, counts[0])):
            return q, TINY_STEP if tiny_step else STAGNATED, mu, tangents, a1, twist
        if counts[1] == max_steps:
            return q, OUT_OF_STEPS, mu, tangents, a1, twist
        before = timing.clock_seconds(clock, clock_id, buffer)
        band = _free_band(q, reference, p, slots, strand, drivers, plan, gather, blocks, weight)
        seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - before
        accepted, alpha, phi_trial, trial = False, 0.0, 0.0, q
        for _ in range(MAX_REJECTED):
            damped = band.copy()
            for j in range(size):
                damped[0, j] += mu * metric[j]
            before = timing.clock_seconds(clock, clock_id, buffer)
            factored = factor_active(damped, no_border, no_corner, everything, factor, no_border, no_corner,
                                     np.int64(0), np.int64(0))
            if factored:
                plain_solve(factor, g, d)
            seconds[1] += timing.clock_seconds(clock, clock_id, buffer) - before
            if not factored:
                counts[4] += 1
                mu = max(4.0 * mu, MU_MIN)
                continue
            for k in range(size):
                d[k] = -d[k]
            slope = np.dot(g, d)
            alpha = 1.0
            for _ in range(MAX_HALVINGS + 1):  # Armijo along length_keeping_step (simulation._line_search)
                trial = length_keeping_step(q, free, alpha, d, anchor)
                before = timing.clock_seconds(clock, clock_id, buffer)
                phi_trial = _phi(trial, reference, strand, physical, drivers, external, bodies, weight, target)
                seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - before
                unresolvable = -alpha * slope <= 1e3 * EPS * max(abs(phi), abs(phi_trial))
                if np.isfinite(phi_trial) and (phi_trial <= phi + ARMIJO * alpha * slope or unresolvable):
                    accepted = True
                    break
                alpha *= 0.5
            if accepted:
                break
            counts[3] += 1
            mu = max(4.0 * mu, MU_MIN)
        if not accepted:
            return q, NO_STEP, mu, tangents, a1, twist
        if alpha == 1.0:  # the quadratic model held over the full step: how well?
            predicted = -(np.dot(g, d) + 0.5 * quadratic_form(band, d))
            resolvable = predicted > 1e3 * EPS * max(abs(phi), abs(phi_trial))
            ratio = (phi - phi_trial) / predicted if resolvable else 1.0
        else:
            ratio = 0.0
        q, phi = trial, phi_trial
        counts[1] += 1
        if alpha < 1.0:
            counts[2] += 1
        tiny_step = True
        for k in range(size):
            tiny_step = tiny_step and abs(alpha * d[k]) <= step_limit[k]
        if ratio > 0.75:
            mu = mu / 16.0 if mu > 16.0 * MU_MIN else 0.0
        elif ratio < 0.25:
            mu = max(4.0 * mu, MU_MIN)
        if _turned_too_far(q, tangents):
            tangents, a1, twist = _transported(_positions(q), tangents, a1, twist)
            reference = _reference(tangents, a1, twist)
            before = timing.clock_seconds(clock, clock_id, buffer)
            phi = _phi(q, reference, strand, physical, drivers, external, bodies, weight, target)
            seconds[0] += timing.clock_seconds(clock, clock_id, buffer) - before
