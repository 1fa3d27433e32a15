"""The forces and dc/dp at q* in one compiled call each (Problem.forces and Problem.strand_jacobian at
rest, which the solvers evaluate at every trial point).

At q* the vertex stencils see the DOFs through their kinematics k, fixed there
(stencils.FixedShapeFunctions), so

    f = f_ext - sum_e g_e - sum_v (dk/dy)_v^T dE_v/dk,          (scattered onto the stencils' DOFs)
    dc/dp = the edge Jacobians d g_e / d(physical) and (dk/dy)^T d(dE/dk)/d(physical), scaled and summed
            into the values of the strand's JacobianPattern,

with the physical parameters from p through the slot maps (parameters.SlotMap). In numpy that is
eight calls of a few microseconds each (two slot maps, two stencil batches, a stacked product, the
scatter): a 100-vertex strand's residual took 33 us and its dc/dp 52 us, 17 and 39 us through
this module (most of what is left: the two CasADi batches and the scatter). numba calls the CasADi
batch drivers at their addresses (compiled.BatchFunction.address, ``call_driver``). The sums run in the
order of the numpy form (np.bincount, edges then vertices); only the chain rule's products are
summed in another order than BLAS's, a rounding difference.

``hessian_band`` is d2E/dq2 at q* for a stressed p (the stability evaluation of every Result and of
the stabilization's checks): the stencils' full Hessians from their drivers, scattered into band
storage in the order of Problem.hessian_band's numpy sum, so the band is the same bit for bit.
"""
from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

from sagfree.linalg import timing
from sagfree.linalg.eigen import block_eigenpair
from sagfree.linalg.pairwise import pairwise_sum

from .jacobian import scatter_values
from .parameters import evaluate_slots


@intrinsic
def call_driver(typing_context, address, count, inputs, outputs):
    """driver(count, inputs, outputs) for the batch driver at the integer ``address``
    (compiled._DRIVER: void (long long, const double**, double**)); inputs and outputs are the
    addresses of the pointer arrays. Cacheable, unlike a function pointer baked into the code."""
    if not all(isinstance(t, types.Integer) for t in (address, count, inputs, outputs)):
        return None

    def codegen(context, builder, signature, args):
        byte_pointer = ir.IntType(8).as_pointer()
        driver_type = ir.FunctionType(ir.VoidType(), [ir.IntType(64), byte_pointer, byte_pointer])
        driver = builder.inttoptr(args[0], driver_type.as_pointer())
        count = context.cast(builder, args[1], signature.args[1], types.int64)
        builder.call(driver, [count, builder.inttoptr(args[2], byte_pointer), builder.inttoptr(args[3], byte_pointer)])
        return context.get_dummy_value()

    return types.void(address, count, inputs, outputs), codegen


@numba.njit(cache=True)
def _call(driver, count, inputs, out):  # pragma: no cover - compiled
    """The batch driver at address ``driver`` (compiled._DRIVER) on ``count`` stencils: the arrays
    of the tuple ``inputs`` in, one output."""
    call_into(driver, count, inputs, (out,))


@numba.njit(cache=True)
def call_into(driver, count, inputs, outputs):  # pragma: no cover - compiled
    """The batch driver at address ``driver`` on ``count`` stencils: the C-contiguous arrays of the
    tuple ``inputs`` in, those of ``outputs`` (a tuple of 2-D arrays, (count, entries) each, as
    compiled.BatchFunction allocates them) out."""
    pointers, out_pointers = np.empty(len(inputs), dtype=np.intp), np.empty(len(outputs), dtype=np.intp)
    k = 0
    for array in numba.literal_unroll(inputs):
        pointers[k] = array.ctypes.data
        k += 1
    for k in range(len(outputs)):
        out_pointers[k] = outputs[k].ctypes.data
    call_driver(driver, count, pointers.ctypes.data, out_pointers.ctypes.data)


@numba.njit(cache=True)
def _physical(p, edge_slots, vertex_slots):  # pragma: no cover - compiled
    """The edge and vertex stencils' physical parameters from p (two SlotMaps' ``arrays``)."""
    return (evaluate_slots(edge_slots[0], edge_slots[1], edge_slots[2], edge_slots[3], p),
            evaluate_slots(vertex_slots[0], vertex_slots[1], vertex_slots[2], vertex_slots[3], p))


@numba.njit(cache=True, inline="always")
def _chain_rule(kinematics_jacobian, s, by_kinematics, first, column):  # pragma: no cover - compiled
    """column = (dk/dy)_s^T u with u_m = by_kinematics[first + m], summed over m in order (inlined:
    called, it cost 10 of dc/dp's 35 us at 100 vertices)."""
    column[:] = 0.0
    for m in range(kinematics_jacobian.shape[1]):
        factor = by_kinematics[first + m]
        for i in range(column.size):
            column[i] += kinematics_jacobian[s, m, i] * factor


@numba.njit(cache=True)
def forces(p, edge_slots, vertex_slots, edge_q, edge_geometry, kinematics, vertex_geometry, kinematics_jacobian,
           edge_dofs, vertex_dofs, external, edge_gradient, vertex_gradient, contact_index, contact_directions,
           contact_rows, contact_scale):  # pragma: no cover - compiled
    """f(q*, p), the bodies' supports included. edge_slots / vertex_slots: a SlotMap's (constant,
    linked, factor, source); kinematics_jacobian: dk/dy per vertex stencil (S, 5, 11); edge_gradient
    / vertex_gradient: the addresses of the drivers of the edge gradient and of the vertex kinematics
    gradient (compiled.BatchFunction.address); contact k (none: empty arrays) pushes its vertex's
    position DOFs contact_rows[k] with D_k sum_j g_kj d_kj (Problem.contact_forces), g_kj =
    p[contact_index[k, j]], d = contact_directions, D = contact_scale."""
    edge_physical, vertex_physical = _physical(p, edge_slots, vertex_slots)
    edges, edge_width = edge_q.shape
    vertices, kinematics_size, vertex_width = kinematics_jacobian.shape
    by_edge = np.empty((edges, edge_width))
    _call(edge_gradient, edges, (edge_q, edge_geometry, edge_physical), by_edge)
    by_kinematics = np.empty((vertices, kinematics_size))
    _call(vertex_gradient, vertices, (kinematics, vertex_geometry, vertex_physical), by_kinematics)
    size = external.size
    edge_sum, vertex_sum = np.zeros(size), np.zeros(size)
    for s in range(edges):
        for i in range(edge_width):
            edge_sum[edge_dofs[s, i]] += by_edge[s, i]
    column = np.empty(vertex_width)
    for s in range(vertices):  # (dk/dy)^T dE/dk
        _chain_rule(kinematics_jacobian, s, by_kinematics[s], np.int64(0), column)
        for i in range(vertex_width):
            vertex_sum[vertex_dofs[s, i]] += column[i]
    out = np.empty(size)
    for j in range(size):
        out[j] = external[j] - (edge_sum[j] + vertex_sum[j])
    for k in range(contact_index.shape[0]):
        for d in range(3):
            push = 0.0
            for j in range(contact_index.shape[1]):
                push += p[contact_index[k, j]] * contact_directions[k, j, d]
            out[contact_rows[k, d]] += push * contact_scale[k]
    return out


@numba.njit(cache=True)
def jacobian_values(p, edge_slots, vertex_slots, edge_q, edge_geometry, kinematics, vertex_geometry,
                    kinematics_jacobian, contact_jacobian, edge_jacobian, vertex_jacobian, target, source, scale,
                    size):  # pragma: no cover - compiled
    """The CSC values of dc/dp at q* on the strand's JacobianPattern (target, source, scale, size:
    its scatter; contact_jacobian: the supports' constant blocks, flattened); the other arguments as
    for ``forces``, with edge_jacobian / vertex_jacobian the drivers' addresses of the edge parameter Jacobian
    and of the vertex kinematics one."""
    edge_physical, vertex_physical = _physical(p, edge_slots, vertex_slots)
    edges, edge_width = edge_q.shape
    edge_columns = edge_physical.shape[1]
    vertices, kinematics_size, vertex_width = kinematics_jacobian.shape
    vertex_columns = vertex_physical.shape[1]
    by_edge = np.empty((edges, edge_width * edge_columns))  # CasADi's column-major blocks
    _call(edge_jacobian, edges, (edge_q, edge_geometry, edge_physical), by_edge)
    by_kinematics = np.empty((vertices, kinematics_size * vertex_columns))
    _call(vertex_jacobian, vertices, (kinematics, vertex_geometry, vertex_physical), by_kinematics)
    entries = np.empty(edges * edge_width * edge_columns + vertices * vertex_width * vertex_columns
                       + contact_jacobian.size)
    k = 0
    for s in range(edges):  # the stencil blocks row by row, as JacobianPattern.values ravels them
        for i in range(edge_width):
            for c in range(edge_columns):
                entries[k] = by_edge[s, c * edge_width + i]
                k += 1
    column = np.empty(vertex_width)
    for s in range(vertices):
        for c in range(vertex_columns):  # column c of (dk/dy)^T d(dE/dk)/d(physical)
            _chain_rule(kinematics_jacobian, s, by_kinematics[s], c * kinematics_size, column)
            for i in range(vertex_width):
                entries[k + i * vertex_columns + c] = column[i]
        k += vertex_width * vertex_columns
    for value in contact_jacobian:
        entries[k] = value
        k += 1
    return scatter_values(target, source, scale, entries, size)


@numba.njit(cache=True)
def raveled_blocks(by_stencil, rows, columns, entries, k):  # pragma: no cover - compiled
    """Copy CasADi's column-major (rows x columns) blocks into ``entries`` from k on, each block in C
    order (as ``ravel`` of compiled.BatchFunction's (N, rows, columns) output); returns the next k."""
    for s in range(by_stencil.shape[0]):
        for i in range(rows):
            for j in range(columns):
                entries[k] = by_stencil[s, j * rows + i]
                k += 1
    return k


@numba.njit(cache=True)
def hessian_band(p, edge_slots, vertex_slots, edge_q, edge_geometry, vertex_q, reference, vertex_geometry,
                 edge_hessian, vertex_hessian, target, source, ones, rows, columns):  # pragma: no cover
    """d2E/dq2 at q* in lower band storage (rows x columns = 4n-1), as Problem.hessian_band sums it: the
    edge and vertex stencils' full Hessians (edge_hessian / vertex_hessian: their drivers'
    addresses) scattered by the strand's band plan (target, source, ones: Problem._band_plan)."""
    edge_physical, vertex_physical = _physical(p, edge_slots, vertex_slots)
    edges, edge_width = edge_q.shape
    vertices, vertex_width = vertex_q.shape
    by_edge = np.empty((edges, edge_width * edge_width))
    _call(edge_hessian, edges, (edge_q, edge_geometry, edge_physical), by_edge)
    by_vertex = np.empty((vertices, vertex_width * vertex_width))
    _call(vertex_hessian, vertices, (vertex_q, reference, vertex_geometry, vertex_physical), by_vertex)
    entries = np.empty(by_edge.size + by_vertex.size)
    k = raveled_blocks(by_edge, edge_width, edge_width, entries, np.int64(0))
    raveled_blocks(by_vertex, vertex_width, vertex_width, entries, k)
    return scatter_values(target, source, ones, entries, rows * columns).reshape(rows, columns)


@numba.njit(cache=True)
def stability(p, hessian_args, eigen_args, scale, free_index, clock, clock_id, seconds):  # pragma: no cover
    """Problem.stability(p, vector=True) at q* off p0 in compiled code, from Problem.stability_kernels:
    (lambda, v) of the stressed Hessian band (``hessian_band``) and its mass-scaled free block's
    smallest eigenpair (linalg.eigen.block_eigenpair), v[free] = mode * s. seconds[0] and [1]
    accumulate the band's and the eigenpair's seconds on the clock (address, id)."""
    buffer = np.zeros(2, dtype=np.int64)
    start = timing.clock_seconds(clock, clock_id, buffer)
    band = hessian_band(p, *hessian_args)
    now = timing.clock_seconds(clock, clock_id, buffer)
    value, free_mode = block_eigenpair(band, *eigen_args)
    mode = np.zeros(hessian_args[-1])
    for k in range(free_index.size):
        mode[free_index[k]] = free_mode[k] * scale[k]
    seconds[0] += now - start
    seconds[1] += timing.clock_seconds(clock, clock_id, buffer) - now
    return value, mode


@numba.njit(cache=True)
def unstressed_form(v, p0, edge_slots, vertex_slots, edge_q, edge_geometry, kinematics, vertex_geometry,
                    kinematics_jacobian, edge_dofs, vertex_dofs, edge_hessian, vertex_hessian):  # pragma: no cover
    """v^T H(p0) v at q* summed over the stencils without assembling H (Problem._unstressed_form):
    the edge stencils' v_s^T H_s v_s, and the vertex stencils' u^T d2E/dk2 u with u = dk/dy v_s
    (dE/dk = 0 at p0); edge_hessian / vertex_hessian: the drivers of the edge Hessian and of the
    vertex kinematics Hessian (compiled.BatchFunction.address). Summed stencil by stencil, in
    another order than numpy's pairwise sums: its caller only bounds an eigenvalue with it."""
    edge_physical, vertex_physical = _physical(p0, edge_slots, vertex_slots)
    edges, edge_width = edge_q.shape
    by_edge = np.empty((edges, edge_width * edge_width))
    _call(edge_hessian, edges, (edge_q, edge_geometry, edge_physical), by_edge)
    total = 0.0
    for s in range(edges):
        for j in range(edge_width):
            vj = v[edge_dofs[s, j]]
            for i in range(edge_width):
                total += v[edge_dofs[s, i]] * by_edge[s, j * edge_width + i] * vj
    vertices, kinematics_size, vertex_width = kinematics_jacobian.shape
    by_vertex = np.empty((vertices, kinematics_size * kinematics_size))
    _call(vertex_hessian, vertices, (kinematics, vertex_geometry, vertex_physical), by_vertex)
    motion = np.empty(kinematics_size)
    for s in range(vertices):
        for m in range(kinematics_size):
            u = 0.0
            for i in range(vertex_width):
                u += kinematics_jacobian[s, m, i] * v[vertex_dofs[s, i]]
            motion[m] = u
        for n in range(kinematics_size):
            for m in range(kinematics_size):
                total += motion[m] * by_vertex[s, n * kinematics_size + m] * motion[n]
    return total


@numba.njit(cache=True)
def stiffening_gradient(v, p, vertex_slots, edge_q, edge_geometry, kinematics, vertex_geometry, kinematics_jacobian,
                        edge_dofs, vertex_dofs, edge_hessian, vertex_hessian, youngs, shear, stretch_index,
                        bend_index, twist_index, strand_index, couple_twist):  # pragma: no cover - compiled
    """Problem.stiffening_gradient in one compiled call: v_s^T G_s v_s per element, G_s the Hessian
    of its energy at unit multiplier with its rest shape at q*: the edge stencils' full Hessians at
    zero rest strain and modulus E, the vertex stencils' u^T d2E/dk2 u (u = dk/dy v_s, as in
    ``unstressed_form``) at kbar = kappa*, mbar = m* with moduli (E, 0) for bending and (0, G) for
    twisting; into the multipliers' entries of p (the ``*_index`` arrays, empty where the layout
    has no such block): stretch, bend (plus twist where ``couple_twist``), twist, and the strand's
    one multiplier the sum of all (bend, twist, stretch; numpy's pairwise sums). The numpy form's
    numbers bit for bit. edge_hessian / vertex_hessian: the drivers of the edge Hessian and of the
    vertex kinematics Hessian."""
    gradient = np.zeros(p.size)
    edges, edge_width = edge_q.shape
    edge_physical = np.zeros((edges, 2))
    edge_physical[:, 1] = youngs
    by_edge = np.empty((edges, edge_width * edge_width))
    _call(edge_hessian, edges, (edge_q, edge_geometry, edge_physical), by_edge)
    stretch = np.zeros(edges)
    for s in range(edges):
        for j in range(edge_width):
            vj = v[edge_dofs[s, j]]
            for i in range(edge_width):
                stretch[s] += v[edge_dofs[s, i]] * by_edge[s, j * edge_width + i] * vj
    vertices, kinematics_size, vertex_width = kinematics_jacobian.shape
    motion = np.zeros((vertices, kinematics_size))
    for s in range(vertices):
        for m in range(kinematics_size):
            for i in range(vertex_width):
                motion[s, m] += kinematics_jacobian[s, m, i] * v[vertex_dofs[s, i]]
    unstressed = evaluate_slots(vertex_slots[0], vertex_slots[1], vertex_slots[2], vertex_slots[3], p)
    for s in range(vertices):  # kbar = kappa* (the 4d map adds the rotated pair), mbar = m*
        unstressed[s, 2], unstressed[s, 3], unstressed[s, 4] = (vertex_geometry[s, 4], vertex_geometry[s, 5],
                                                                 vertex_geometry[s, 3])
    forms = np.zeros((2, vertices))  # bend, twist
    by_vertex = np.empty((vertices, kinematics_size * kinematics_size))
    for term in range(2):
        unstressed[:, 5] = youngs if term == 0 else 0.0
        unstressed[:, 6] = shear if term == 1 else 0.0
        _call(vertex_hessian, vertices, (kinematics, vertex_geometry, unstressed), by_vertex)
        for s in range(vertices):
            for n in range(kinematics_size):
                for m in range(kinematics_size):
                    forms[term, s] += motion[s, m] * by_vertex[s, n * kinematics_size + m] * motion[s, n]
    for k in range(stretch_index.size):
        gradient[stretch_index[k]] = stretch[k]
    for k in range(twist_index.size):
        gradient[twist_index[k]] = forms[1, k]
    for k in range(bend_index.size):
        gradient[bend_index[k]] = forms[0, k] + (forms[1, k] if couple_twist else 0.0)
    if strand_index.size:
        gradient[strand_index[0]] = pairwise_sum(forms[0]) + pairwise_sum(forms[1]) + pairwise_sum(stretch)
    return gradient


@numba.njit(cache=True)
def constraint_hessian_entries(p, lam, edge_slots, vertex_slots, edge_q, edge_geometry, kinematics, vertex_geometry,
                               kinematics_jacobian, edge_dofs, vertex_dofs, free_index, row_scale, size, edge_hessian,
                               vertex_hessian, edge_index, edge_coefficient, vertex_index,
                               vertex_coefficient):  # pragma: no cover - compiled
    """Problem.constraint_hessian_entries in one compiled call (Problem.curvature_kernels gives the
    arguments after p and lam): mu = lam / D on the free DOFs (``size`` of them in all), per
    stencil the Hessian of u . dE/dk in the physical parameters (edge_hessian / vertex_hessian: the
    addresses of stencils.parameter_hessians' drivers) with u = mu on an edge's DOFs and
    u = (dk/dy) mu_y on a vertex's, then ``slot_pair_entries``."""
    mu = np.zeros(size)
    for r in range(free_index.size):
        mu[free_index[r]] = lam[r] / row_scale[r]
    edge_physical, vertex_physical = _physical(p, edge_slots, vertex_slots)
    edges, edge_width = edge_dofs.shape
    vertices, kinematics_size, vertex_width = kinematics_jacobian.shape
    edge_u = np.empty((edges, edge_width))
    for s in range(edges):
        for i in range(edge_width):
            edge_u[s, i] = mu[edge_dofs[s, i]]
    vertex_u = np.zeros((vertices, kinematics_size))
    for s in range(vertices):
        for j in range(kinematics_size):
            for i in range(vertex_width):
                vertex_u[s, j] += kinematics_jacobian[s, j, i] * mu[vertex_dofs[s, i]]
    edge_size, vertex_size = edge_physical.shape[1], vertex_physical.shape[1]
    edge_blocks = np.empty((edges, edge_size * edge_size))
    _call(edge_hessian, edges, (edge_q, edge_geometry, edge_physical, edge_u), edge_blocks)
    vertex_blocks = np.empty((vertices, vertex_size * vertex_size))
    _call(vertex_hessian, vertices, (kinematics, vertex_geometry, vertex_physical, vertex_u), vertex_blocks)
    # the drivers write each block column by column (compiled._shaped)
    return slot_pair_entries(
        edge_index, edge_coefficient,
        np.ascontiguousarray(edge_blocks.reshape(edges, edge_size, edge_size).transpose((0, 2, 1))),
        vertex_index, vertex_coefficient,
        np.ascontiguousarray(vertex_blocks.reshape(vertices, vertex_size, vertex_size).transpose((0, 2, 1))))


@numba.njit(cache=True)
def slot_pair_entries(edge_index, edge_coefficient, edge_blocks, vertex_index, vertex_coefficient,
                      vertex_blocks):  # pragma: no cover - compiled
    """(rows, columns, values) of -c_a c_b B[s, a, b] for every stencil s and pair of linked slots
    (a, b) (index >= 0), the edge stencils' then the vertex stencils' (Problem.constraint_hessian_entries)."""
    count = _linked_pairs(edge_index) + _linked_pairs(vertex_index)
    rows, cols, values = np.empty(count, np.int64), np.empty(count, np.int64), np.empty(count)
    k = _fill_pairs(edge_index, edge_coefficient, edge_blocks, rows, cols, values, np.int64(0))
    _fill_pairs(vertex_index, vertex_coefficient, vertex_blocks, rows, cols, values, k)
    return rows, cols, values


@numba.njit(cache=True)
def _linked_pairs(index):  # pragma: no cover - compiled
    count = 0
    for s in range(index.shape[0]):
        linked = 0
        for a in range(index.shape[1]):
            linked += index[s, a] >= 0
        count += linked * linked
    return count


@numba.njit(cache=True)
def _fill_pairs(index, coefficient, blocks, rows, cols, values, k):  # pragma: no cover - compiled
    for s in range(index.shape[0]):
        for a in range(index.shape[1]):
            if index[s, a] < 0:
                continue
            for b in range(index.shape[1]):
                if index[s, b] < 0:
                    continue
                rows[k], cols[k] = index[s, a], index[s, b]
                values[k] = -(coefficient[s, a] * coefficient[s, b] * blocks[s, a, b])
                k += 1
    return k
