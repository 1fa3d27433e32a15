"""Contact between a strand and rigid bodies: which vertices of q* rest on a body, and the contact
model of the forward simulation (DESIGN section 3; bodies module for the geometry).

At q*: a free vertex whose centreline lies within ``contact_distance`` of a body's surface inflated
by the strand radius, phi_b(x_i*) - r <= contact_distance, rests on body b (the nearest if several)
and gets unknowns of the equilibrium, the body's push along the outward normal n_i =
grad phi_b(x_i*) or, with friction, along the friction pyramid's generators (parameters.CONTACT_BLOCK,
non-negative). A free vertex with its
centreline inside a body, phi_b(x_i*) < 0, is an error. Default contact_distance: CONTACT_RADII
strand radii (a hair combed onto a scalp lies about one radius above it).

Simulation: every free vertex is kept out of every body by a penalty on the penetration of its
contact surface, psi_ib(x) = phi_b(x) - level_ib, with level_ib = phi_b(x_i*) for a vertex resting
on b at q* (its contact surface passes through its groomed position, so the groom's small gaps are
not forces) and r otherwise:

    E_contact = sum_ib k_i / 2 min(psi_ib(x_i), 0)^2,     k_i = E pi r^2 / lv_i,

the stretch stiffness of the strand's own length lv_i at the vertex (its Voronoi length): a vertex
sinks into a body as much as that piece of strand stretches under the same force (4e-8 of the
length for a hair carrying a dozen of its vertex weights), and Newton's systems keep the conditioning
the strand already has. The gradient k psi n and the Hessian k (n n^T + psi K) (K = d2 phi/dx2)
enter Newton's potential exactly. With friction, LaggedFriction adds IPC's lagged friction.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

#: default contact distance, in strand radii
CONTACT_RADII = 2.0


@dataclass
class Contacts:
    """The vertices of q* resting on bodies.

    vertices (K,) sorted; body (K,) index into ``bodies``; normals (K, 3) outward unit normals at x*;
    tangents (K, 2, 3) an orthonormal pair completing each normal; directions (K, width, 3) the
    directions of the contact's supports (parameters.CONTACT_BLOCK): the normal alone without
    friction, the friction pyramid's generators n + mu e (e = t1, -t1, t2, -t2) with it;
    curvature (K, 3, 3) d2 phi/dx2 there (1/m); levels (n, B) each vertex's contact level per body
    (m, the simulation's psi = phi - level); stiffness (n,) the penalty k_i (N/m).
    """

    bodies: tuple
    vertices: np.ndarray
    body: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    directions: np.ndarray
    curvature: np.ndarray
    levels: np.ndarray
    stiffness: np.ndarray

    @property
    def count(self) -> int:
        return int(self.vertices.size)


def find_contacts(points: np.ndarray, radius: float, bodies, held: np.ndarray, stiffness: np.ndarray,
                  contact_distance: float | None = None, friction: float = 0.0) -> Contacts:
    """Contacts of the groomed ``points`` (n, 3) with ``bodies``; ``held``: the prescribed vertices
    (never contacts, never checked); ``stiffness``: the penalty k_i per vertex (N/m). ValueError
    naming the vertex and the body if a free vertex's centreline is inside a body."""
    bodies = tuple(bodies)
    n = len(points)
    distance = CONTACT_RADII * radius if contact_distance is None else float(contact_distance)
    if not (np.isfinite(distance) and distance >= 0):
        raise ValueError(f"contact_distance must be a non-negative length (m), got {contact_distance!r}")
    if not bodies:  # most strands: nothing to find (and a groom builds thousands of Problems)
        empty = np.zeros((0, 3))
        return Contacts(bodies, np.zeros(0, int), np.zeros(0, int), empty, np.zeros((0, 2, 3)),
                        np.zeros((0, 1, 3)), np.zeros((0, 3, 3)), np.zeros((n, 0)),
                        np.asarray(stiffness, dtype=float))
    free = np.ones(n, dtype=bool)
    free[held] = False
    levels = np.full((n, len(bodies)), float(radius))
    gaps = np.full((n, len(bodies)), np.inf)
    evaluations = []
    for b, body in enumerate(bodies):
        phi, normal, curvature = body.evaluate(points)
        inside = np.flatnonzero(free & (phi < 0))
        if inside.size:
            i = int(inside[np.argmin(phi[inside])])
            raise ValueError(f"vertex {i} is inside {body.name} ({-phi[i]:.3g} m below its surface, the "
                             f"deepest of {inside.size} vertices inside): move the strand or the body")
        gaps[:, b] = np.where(free, phi - radius, np.inf)
        evaluations.append((phi, normal, curvature))
    nearest = np.argmin(gaps, axis=1) if bodies else np.zeros(n, dtype=int)
    vertices = np.flatnonzero(free & (gaps.min(axis=1, initial=np.inf) <= distance)) if bodies else np.zeros(0, int)
    body = nearest[vertices]
    normals, curvature = np.zeros((vertices.size, 3)), np.zeros((vertices.size, 3, 3))
    for k, (i, b) in enumerate(zip(vertices, body)):
        phi, normal, K = evaluations[b]
        normals[k], curvature[k] = normal[i], K[i]
        levels[i, b] = phi[i]
    tangents = tangent_pairs(normals)
    if friction > 0:
        sides = np.stack([tangents[:, 0], -tangents[:, 0], tangents[:, 1], -tangents[:, 1]], axis=1)
        directions = normals[:, None, :] + friction * sides
    else:
        directions = normals[:, None, :]
    return Contacts(bodies, vertices, body, normals, tangents, directions, curvature, levels,
                    np.asarray(stiffness, dtype=float))


@numba.njit(cache=True)
def tangent_pairs(normals: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """(K, 2, 3): t1 = unit(n x e) with e the axis least aligned with n (the first of equals), t2 =
    n x t1. Compiled, numpy's cross, norm and argmin bit for bit (a strand on a head has a few
    dozen contacts, and numpy's passes over such small arrays took a tenth of its Problem)."""
    out = np.empty((normals.shape[0], 2, 3))
    for k in range(normals.shape[0]):
        n0, n1, n2 = normals[k, 0], normals[k, 1], normals[k, 2]
        axis, least = 0, abs(n0)
        if abs(n1) < least:
            axis, least = 1, abs(n1)
        if abs(n2) < least:
            axis = 2
        e0, e1, e2 = (1.0 if axis == 0 else 0.0), (1.0 if axis == 1 else 0.0), (1.0 if axis == 2 else 0.0)
        t0, t1, t2 = n1 * e2 - n2 * e1, n2 * e0 - n0 * e2, n0 * e1 - n1 * e0
        norm = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        t0, t1, t2 = t0 / norm, t1 / norm, t2 / norm
        out[k, 0, 0], out[k, 0, 1], out[k, 0, 2] = t0, t1, t2
        out[k, 1, 0], out[k, 1, 1], out[k, 1, 2] = n1 * t2 - n2 * t1, n2 * t0 - n0 * t2, n0 * t1 - n1 * t0
    return out


def _penetrations(contacts: Contacts, x: np.ndarray, free: np.ndarray):
    """Per body: (touching, psi, n, K) at positions x, touching = the free vertices with psi < 0."""
    for b, body in enumerate(contacts.bodies):
        phi, n, K = body.evaluate(x)
        psi = phi - contacts.levels[:, b]
        yield free & (psi < 0), psi, n, K


def contact_penalty(contacts: Contacts, x: np.ndarray, free: np.ndarray):
    """(E_contact (J), gradient (n, 3) N, Hessian blocks (n, 3, 3) N/m) of the simulation's penalty at
    positions x (n, 3), on the vertices where ``free`` (module docstring)."""
    energy, gradient, hessian = 0.0, np.zeros_like(x), np.zeros((len(x), 3, 3))
    for touching, psi, n, K in _penetrations(contacts, x, free):
        if not touching.any():
            continue
        k, depth = contacts.stiffness[touching], psi[touching]
        energy += float(0.5 * np.sum(k * depth * depth))
        gradient[touching] += (k * depth)[:, None] * n[touching]
        hessian[touching] += k[:, None, None] * (n[touching][:, :, None] * n[touching][:, None, :]
                                                 + depth[:, None, None] * K[touching])
    return energy, gradient, hessian


#: the lagged friction's creep: a vertex held by static friction slides at most this many strand
#: lengths per second (its smoothing displacement eps = FRICTION_CREEP L dt, IPC's eps_v h), unless
#: that would make its friction spring 2 mu F / eps stiffer than the contact penalty k_i: then
#: eps = 2 mu F / k_i (stiffer springs only add rounding: Newton's residual stalled above its floor)
FRICTION_CREEP = 1e-6


@dataclass
class LaggedFriction:
    """Friction on the vertices touching a body at the start of a step (Li et al. 2020, "Incremental
    Potential Contact", section 5): normal force, tangent basis and position frozen there.

    vertices (m,); normal_force (m,) N; tangents (m, 2, 3); anchors (m, 3) m; smoothing eps (m,) m.
    Potential: sum_i mu F_i f0(|T_i (x_i - a_i)|) with IPC's f0 (C1 between static and sliding at
    eps): below eps the vertex is held by a spring of stiffness 2 mu F / eps, above it the friction
    force is mu F against the slip.
    """

    vertices: np.ndarray
    normal_force: np.ndarray
    tangents: np.ndarray
    anchors: np.ndarray
    eps: np.ndarray

    def evaluate(self, x: np.ndarray, mu: float):
        """(energy J, gradient (n, 3) N, Hessian blocks (n, 3, 3) N/m) at positions x (n, 3)."""
        gradient, hessian = np.zeros_like(x), np.zeros((len(x), 3, 3))
        if not self.vertices.size:
            return 0.0, gradient, hessian
        u = np.einsum("mkd,md->mk", self.tangents, x[self.vertices] - self.anchors)   # (m, 2)
        y = np.linalg.norm(u, axis=1)
        eps = self.eps
        inside = y < eps
        f0 = np.where(inside, -y**3 / (3 * eps**2) + y**2 / eps + eps / 3, y)
        over_y = np.where(inside, 2 / eps - y / eps**2, 1 / np.where(y > 0, y, 1.0))     # f1(y) / y
        slope = np.where(inside, 2 / eps - 2 * y / eps**2, 0.0)                           # f1'(y)
        weight = mu * self.normal_force
        gradient[self.vertices] = (weight * over_y)[:, None] * np.einsum("mkd,mk->md", self.tangents, u)
        safe = np.where(y > 0, y, 1.0)
        unit = u / safe[:, None]
        local = (over_y[:, None, None] * np.eye(2)
                 + ((slope - over_y) * (y > 0))[:, None, None] * unit[:, :, None] * unit[:, None, :])
        hessian[self.vertices] = weight[:, None, None] * np.einsum("mkd,mkl,mle->mde", self.tangents, local,
                                                                   self.tangents)
        return float(np.sum(weight * f0)), gradient, hessian


def lagged_friction(contacts: Contacts, x: np.ndarray, free: np.ndarray, creep: float, mu: float,
                    held_forces: np.ndarray | None = None) -> LaggedFriction:
    """The LaggedFriction of a step starting at positions x (n, 3): every free vertex inside a body's
    contact surface (psi < 0) with its penalty force k |psi| and the body's tangents there; with
    ``held_forces`` (n,) N, a vertex's normal force is at least that (the supports of p at q*, where
    the penalty is still zero). creep: FRICTION_CREEP L dt (m); eps as FRICTION_CREEP says."""
    force = np.zeros(len(x))
    normals = np.zeros((len(x), 3))
    for touching, psi, n, _ in _penetrations(contacts, x, free):
        pressed = touching & (contacts.stiffness * -psi > force)
        force[pressed] = contacts.stiffness[pressed] * -psi[pressed]
        normals[pressed] = n[pressed]
    if held_forces is not None:
        larger = held_forces > force
        force[larger] = held_forces[larger]
        normals[contacts.vertices[larger[contacts.vertices]]] = contacts.normals[larger[contacts.vertices]]
    vertices = np.flatnonzero(force > 0)
    eps = np.maximum(creep, 2 * mu * force[vertices] / contacts.stiffness[vertices])
    return LaggedFriction(vertices, force[vertices], tangent_pairs(normals[vertices]), x[vertices].copy(), eps)
