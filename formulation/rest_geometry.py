"""A strand's geometry at its input shape q*, what every Problem computes first: in one compiled call.

From the vertices x_i and edge angles th_j (DESIGN section 3):

    t^j = e^j / |e^j|,  a1^j the space-parallel transport of a1^0 along the edges (frames module),
    q* = (x_0, th_0, x_1, ...),  reference data (t^{i-1}, a1^{i-1}, t^i, a1^i, 0) per interior vertex,
    l0_j, kappa_i, m_i and the vertex kinematics k, dk/dy through the compiled stencil functions,

so that the strains, curvatures and twists of the energies vanish exactly at p0 (the same CasADi
expressions). In numpy these were ~15 calls of a few microseconds each around three CasADi batches
(~60 us of arithmetic): ``rest_geometry`` makes them one numba call that runs the batch drivers at
their addresses (at_rest.call_into), with the same arithmetic in the same order, so the numbers
are the numpy path's bit for bit (``rest_geometry_numpy``, used where the stencils are not compiled,
and by the test that compares the two).
"""
from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from . import dofs
from .at_rest import call_into
from .frames import Frames, _transport_along, bishop_frames


class RestGeometry(NamedTuple):
    """The strand at q*: ``frames`` (Bishop, reference twist 0), ``q_star`` (4n-1), the stencils'
    DOFs and reference data there (``edge_q`` (n-1, 6), ``vertex_q`` (n-2, 11), ``reference``
    (n-2, 13)), rest lengths ``l0`` (n-1,; m), curvatures ``kappa`` (n-2, 2 or 4) and twists
    ``twist`` (n-2,; rad), the stencils' geometry inputs ``edge_geometry`` (l0, r) and
    ``vertex_geometry`` (l_{i-1}, l_i, r, m_i, kappa_i), and the vertex kinematics ``kinematics``
    (n-2, 5) with ``kinematics_jacobian`` (dk/dy)^T (n-2, 11, 5)."""

    frames: Frames
    q_star: np.ndarray
    edge_q: np.ndarray
    vertex_q: np.ndarray
    reference: np.ndarray
    l0: np.ndarray
    kappa: np.ndarray
    twist: np.ndarray
    edge_geometry: np.ndarray
    vertex_geometry: np.ndarray
    kinematics: np.ndarray
    kinematics_jacobian: np.ndarray


def rest_geometry(points: np.ndarray, theta: np.ndarray, a1_first: np.ndarray, radius: float,
                  edge_functions, vertex_functions, vertex_fixed_functions) -> RestGeometry:
    """The RestGeometry of the strand with vertices ``points`` (n, 3), edge angles ``theta`` (n-1,)
    and first director ``a1_first`` (unit, perpendicular to the first edge), radius in metres;
    ``edge_functions`` / ``vertex_functions`` / ``vertex_fixed_functions``: the Problem's stencil
    functions (stencils module), whose geometry and kinematics it evaluates."""
    drivers = (edge_functions.geometry, vertex_functions.geometry, vertex_fixed_functions.kinematics)
    if not all(driver.compiled for driver in drivers):
        return rest_geometry_numpy(points, theta, a1_first, radius, edge_functions, vertex_functions,
                                   vertex_fixed_functions)
    n = len(points)
    kappa_size = drivers[1].out_sizes[0]
    (tangents, a1, q_star, edge_q, vertex_q, reference, l0, kappa, twist, edge_geometry, vertex_geometry, kinematics,
     jacobian) = _rest_geometry(np.ascontiguousarray(points, dtype=float), np.ascontiguousarray(theta, dtype=float),
                                np.ascontiguousarray(a1_first, dtype=float), float(radius),
                                dofs.edge_stencil_index(n), dofs.vertex_stencil_index(n), kappa_size,
                                *(driver.address for driver in drivers))
    return RestGeometry(Frames(tangents, a1, np.zeros(n - 2)), q_star, edge_q, vertex_q, reference, l0, kappa,
                        twist, edge_geometry, vertex_geometry, kinematics, jacobian)


def rest_geometry_numpy(points, theta, a1_first, radius, edge_functions, vertex_functions,
                        vertex_fixed_functions) -> RestGeometry:
    """``rest_geometry`` in numpy and the stencil functions' batch calls (CasADi's virtual machine
    where they are not compiled)."""
    n = len(points)
    frames = bishop_frames(points, a1_first)
    q_star = dofs.interleave(points, theta)
    edge_q, vertex_q = q_star[dofs.edge_stencil_index(n)], q_star[dofs.vertex_stencil_index(n)]
    reference = np.ascontiguousarray(reference_data(frames))
    (l0,) = edge_functions.geometry(edge_q)
    kappa, twist = vertex_functions.geometry(vertex_q, reference)
    edge_geometry = np.column_stack([l0, np.full(n - 1, radius)])
    vertex_geometry = np.column_stack([l0[:-1], l0[1:], np.full(n - 2, radius), twist, kappa])
    kinematics, jacobian = vertex_fixed_functions.kinematics(vertex_q, reference)
    return RestGeometry(frames, q_star, edge_q, vertex_q, reference, l0, kappa, twist, edge_geometry,
                        vertex_geometry, kinematics, np.ascontiguousarray(jacobian.transpose(0, 2, 1)))


def reference_data(frames: Frames) -> np.ndarray:
    """(n-2, 13) the vertex stencils' reference data: t^{i-1}, a1^{i-1}, t^i, a1^i, reference twist."""
    t, a1 = frames.tangents, frames.a1
    return np.column_stack([t[:-1], a1[:-1], t[1:], a1[1:], frames.reference_twist])


@numba.njit(cache=True)
def _rest_geometry(points, theta, a1_first, radius, edge_dofs, vertex_dofs, kappa_size, edge_geometry_driver,
                   vertex_geometry_driver, kinematics_driver):  # pragma: no cover - compiled
    """``rest_geometry``'s arrays: tangents, a1, q*, edge_q, vertex_q, reference, l0, kappa, m, edge
    geometry, vertex geometry, k and (dk/dy)^T. The drivers write
    column-major blocks: (dk/dy) (5 x 11) lands as its transpose in C order."""
    n = points.shape[0]
    edges, vertices = n - 1, n - 2
    tangents = np.empty((edges, 3))
    for j in range(edges):  # unit(edges(points)): the norm's sum in numpy's order
        e0, e1, e2 = points[j + 1, 0] - points[j, 0], points[j + 1, 1] - points[j, 1], points[j + 1, 2] - points[j, 2]
        norm = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        tangents[j, 0], tangents[j, 1], tangents[j, 2] = e0 / norm, e1 / norm, e2 / norm
    a1 = _transport_along(tangents, a1_first)
    q_star = np.empty(4 * n - 1)
    for i in range(n):
        q_star[4 * i], q_star[4 * i + 1], q_star[4 * i + 2] = points[i, 0], points[i, 1], points[i, 2]
        if i < edges:
            q_star[4 * i + 3] = theta[i]
    edge_q = np.empty(edge_dofs.shape)
    for s in range(edges):
        for k in range(edge_dofs.shape[1]):
            edge_q[s, k] = q_star[edge_dofs[s, k]]
    vertex_q = np.empty(vertex_dofs.shape)
    reference = np.zeros((vertices, 13))  # the last column: the reference twist, 0 for Bishop frames
    for s in range(vertices):
        for k in range(vertex_dofs.shape[1]):
            vertex_q[s, k] = q_star[vertex_dofs[s, k]]
        for k in range(3):
            reference[s, k], reference[s, 3 + k] = tangents[s, k], a1[s, k]
            reference[s, 6 + k], reference[s, 9 + k] = tangents[s + 1, k], a1[s + 1, k]
    # the drivers' outputs as (count, entries) blocks, as compiled.BatchFunction allocates them
    l0 = np.empty((edges, 1))
    call_into(edge_geometry_driver, edges, (edge_q,), (l0,))
    l0 = l0[:, 0]
    kappa, twist = np.empty((vertices, kappa_size)), np.empty((vertices, 1))
    if vertices:
        call_into(vertex_geometry_driver, vertices, (vertex_q, reference), (kappa, twist))
    twist = twist[:, 0]
    edge_geometry = np.empty((edges, 2))
    for j in range(edges):
        edge_geometry[j, 0], edge_geometry[j, 1] = l0[j], radius
    vertex_geometry = np.empty((vertices, 4 + kappa_size))
    for s in range(vertices):
        vertex_geometry[s, 0], vertex_geometry[s, 1], vertex_geometry[s, 2] = l0[s], l0[s + 1], radius
        vertex_geometry[s, 3] = twist[s]
        for k in range(kappa_size):
            vertex_geometry[s, 4 + k] = kappa[s, k]
    kinematics, jacobian = np.empty((vertices, 5)), np.empty((vertices, 5 * vertex_dofs.shape[1]))
    if vertices:
        call_into(kinematics_driver, vertices, (vertex_q, reference), (kinematics, jacobian))
    return (tangents, a1, q_star, edge_q, vertex_q, reference, l0, kappa, twist, edge_geometry, vertex_geometry,
            kinematics, jacobian.reshape(vertices, vertex_dofs.shape[1], 5))
