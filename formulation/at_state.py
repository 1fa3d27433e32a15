"""dc/dp and the static Hessian at a state q away from q*, in one compiled call: the least sag's
linearizations (solvers.least_sag_loop), where the strand rests in equilibrium q_s(p) instead of at q*.

Away from q* the vertex stencils see q through the frames of that state (their reference data, as
in Problem.energy), so their parameter Jacobians come straight from the stencil functions, with no
kinematics chain rule as at q* (at_rest). The blocks are scattered into the values of the strand's
JacobianPattern in the order of Problem.strand_jacobian(p, q, frames), the bodies' supports' entries
zero (they act at q* only): the same values bit for bit. The Hessian's free block is the static
solve's (newton._free_band, with the bodies' contact penalty), Problem.free_band of
Problem.static_hessian_band(p, q, frames).
"""
from __future__ import annotations

import numba
import numpy as np

from .at_rest import _call, _physical, raveled_blocks
from .jacobian import scatter_values
from .newton import _contact, _free_band, _gathered, _positions, _reference


@numba.njit(cache=True)
def jacobian_values(p, edge_slots, vertex_slots, edge_q, edge_geometry, vertex_q, reference, vertex_geometry,
                    contact_entries, edge_jacobian, vertex_jacobian, target, source, scale,
                    size):  # pragma: no cover - compiled
    """The CSC values of dc/dp at the state whose stencil DOFs are edge_q and vertex_q (the vertex
    stencils' frames in ``reference``): edge_jacobian / vertex_jacobian the addresses of the edge and
    vertex parameter-Jacobian drivers (compiled.BatchFunction.address), contact_entries the number
    of the supports' (zero) entries, (target, source, scale, size) the pattern's scatter_plan."""
    edge_physical, vertex_physical = _physical(p, edge_slots, vertex_slots)
    edges, edge_width = edge_q.shape
    vertices, vertex_width = vertex_q.shape
    edge_columns, vertex_columns = edge_physical.shape[1], vertex_physical.shape[1]
    by_edge = np.empty((edges, edge_width * edge_columns))
    _call(edge_jacobian, edges, (edge_q, edge_geometry, edge_physical), by_edge)
    by_vertex = np.empty((vertices, vertex_width * vertex_columns))
    _call(vertex_jacobian, vertices, (vertex_q, reference, vertex_geometry, vertex_physical), by_vertex)
    entries = np.zeros(by_edge.size + by_vertex.size + contact_entries)
    k = raveled_blocks(by_edge, edge_width, edge_columns, entries, np.int64(0))
    raveled_blocks(by_vertex, vertex_width, vertex_columns, entries, k)
    return scatter_values(target, source, scale, entries, size)


@numba.njit(cache=True, inline="always")
def linearization(p, q, tangents, a1, twist, newton, jacobian):  # pragma: no cover - compiled
    """(the free block of d2E/dq2 plus the contact penalty's curvature, in lower band storage; the
    CSC values of dc/dp) at the state q with the frames (tangents, a1, twist). newton:
    Problem.newton_kernels; jacobian: Problem.state_jacobian_kernels."""
    slots, strand, drivers, plan, gather, _, _, bodies = newton
    edge_geometry, vertex_geometry, edge_dofs, vertex_dofs = strand
    blocks = np.zeros((0, 3, 3))
    if bodies[0].size:
        blocks = _contact(_positions(q), bodies)[2]
    reference = _reference(tangents, a1, twist)
    band = _free_band(q, reference, p, slots, strand, drivers, plan, gather, blocks, np.empty(0))
    (edge_slots, vertex_slots), _, _, contact_entries, (edge_driver, vertex_driver), scatter, _ = jacobian
    values = jacobian_values(p, edge_slots, vertex_slots, _gathered(q, edge_dofs), edge_geometry,
                             _gathered(q, vertex_dofs), reference, vertex_geometry, contact_entries, edge_driver,
                             vertex_driver, scatter[0], scatter[1], scatter[2], scatter[3])
    return band, values
