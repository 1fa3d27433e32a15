"""The whole strand's constraint c(p) as one CasADi expression, for the nlpsol baselines (DESIGN 6).

    c(p) = D^-1 S (f_ext - sum_stencils scatter(grad_y E_s(y*_s, geometry_s, physical_s(p)))) + C p,
    physical_s(p) = constant_s + coefficient_s * p[index_s]          (SlotMap, parameters module),

(C p: the bodies' supports, Problem.contact_matrix, whose pattern is structure and whose normals
are data) built from the same per-stencil CasADi functions that the compiled evaluation uses (stencils module),
each mapped over the strand's stencils with ``Function.map``. The expression's structure depends only on
the strand size and the Problem's options (variant, energy terms, blocks, stiffness mode, root); every
number of one strand (q* stencil DOFs, reference frames, geometry, slot constants and coefficients,
gravity, row scales, p0, weights) enters as a parameter vector. So one symbolic NLP, and one Ipopt
instance, serves every strand of that structure (``SymbolicNLP.for_problem`` caches them).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp

from .parameters import SlotMap
from .problem import Problem


@dataclass(frozen=True)
class SymbolicNLP:
    """minimize 1/2 sum w (p - p0)^2 s.t. c(p) = 0: symbols and the layout of the data vector."""

    p: ca.MX            # decision variables (the Problem's normalized parameters)
    data: ca.MX         # every strand-specific number, see ``data_vector``
    objective: ca.MX    # R(p)
    constraint: ca.MX   # c(p), free rows in strand order
    pieces: tuple[tuple[str, int], ...]   # (name, size) of the data vector's parts, in order

    @staticmethod
    def for_problem(problem: Problem) -> "SymbolicNLP":
        return _cached(structure_key(problem), problem)

    def data_vector(self, problem: Problem) -> np.ndarray:
        """The strand's numbers in the order of ``pieces``."""
        values = _data_values(problem)
        return np.concatenate([values[name].ravel(order="F") for name, _ in self.pieces])


def structure_key(problem: Problem) -> tuple:
    """What fixes the expression: size, variant, terms, where each physical slot reads p, root."""
    layout = problem.layout
    return (problem.n_vertices, problem.curvature, problem.energies, layout.size,
            layout.edge_map.index.tobytes(), layout.vertex_map.index.tobytes(),
            problem.free.tobytes(), problem.contacts.vertices.tobytes())


_CACHE: dict[tuple, SymbolicNLP] = {}
_CACHE_SIZE = 16


def _cached(key, problem: Problem) -> SymbolicNLP:
    if key not in _CACHE:
        if len(_CACHE) >= _CACHE_SIZE:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = _build(problem)
    return _CACHE[key]


def _data_values(problem: Problem) -> dict[str, np.ndarray]:
    """Strand-specific arrays, stencil-major (one column per stencil after Fortran ravel)."""
    edge, vertex = problem.stencil_inputs(problem.p0, None, None)
    layout = problem.layout
    return {
        "edge_dofs": edge[0].T, "edge_geometry": edge[1].T,
        "edge_constant": layout.edge_map.constant.T, "edge_coefficient": layout.edge_map.coefficient.T,
        "vertex_dofs": vertex[0].T, "vertex_reference": vertex[1].T, "vertex_geometry": vertex[2].T,
        "vertex_constant": layout.vertex_map.constant.T,
        "vertex_coefficient": layout.vertex_map.coefficient.T,
        "gravity": problem.external_forces[problem.free],
        "inverse_scale": 1.0 / problem.row_scale[problem.free],
        "p0": layout.p0, "weights": layout.weights,
        "contact_normals": problem.contact_matrix().data,
    }


def _gather(slot_map: SlotMap, n_parameters: int) -> sp.csc_matrix:
    """0/1 matrix G with (G p)[k] = p[index[k]] (0 where the slot is constant), stencil-major."""
    index = slot_map.index.ravel()  # (stencil, slot) row-major = stencil-major
    rows = np.flatnonzero(index >= 0)
    return sp.csc_matrix((np.ones(rows.size), (rows, index[rows])), shape=(index.size, n_parameters))


def _scatter(stencil_index: np.ndarray, size: int, free: np.ndarray) -> sp.csc_matrix:
    """0/1 matrix that sums stencil-major per-stencil gradients into the free DOFs."""
    columns = np.arange(stencil_index.size)
    full = sp.csc_matrix((np.ones(columns.size), (stencil_index.ravel(), columns)),
                         shape=(size, stencil_index.size))
    return full[np.flatnonzero(free)]


def _casadi_sparse(matrix: sp.spmatrix) -> ca.DM:
    coo = sp.coo_matrix(matrix)
    sparsity = ca.Sparsity.triplet(coo.shape[0], coo.shape[1], coo.row.tolist(), coo.col.tolist())
    return ca.DM(sparsity, coo.data.tolist())


def _build(problem: Problem) -> SymbolicNLP:
    values = _data_values(problem)
    pieces = tuple((name, value.size) for name, value in values.items())
    data = ca.MX.sym("data", sum(size for _, size in pieces))
    parts, offset = {}, 0
    for (name, size), value in zip(pieces, values.values()):
        shape = value.shape if value.ndim == 2 else (value.size, 1)
        parts[name] = ca.reshape(data[offset:offset + size], shape[0], shape[1])
        offset += size

    layout = problem.layout
    p = ca.MX.sym("p", layout.size)
    n_edges, n_inner = problem.n_vertices - 1, problem.n_vertices - 2
    size = problem.q_star.size

    def physical(slot_map, prefix, count):
        gathered = ca.reshape(ca.mtimes(_casadi_sparse(_gather(slot_map, layout.size)), p),
                              slot_map.index.shape[1], count)
        return parts[f"{prefix}_constant"] + parts[f"{prefix}_coefficient"] * gathered

    # per-stencil gradients, (stencil DOFs x stencils)
    edge_gradient = problem.edge_functions.gradient.function.map(n_edges, "serial")(
        parts["edge_dofs"], parts["edge_geometry"], physical(layout.edge_map, "edge", n_edges))
    vertex_gradient = problem.vertex_functions.gradient.function.map(n_inner, "serial")(
        parts["vertex_dofs"], parts["vertex_reference"], parts["vertex_geometry"],
        physical(layout.vertex_map, "vertex", n_inner))
    elastic = (ca.mtimes(_casadi_sparse(_scatter(problem.edge_dofs, size, problem.free)),
                         ca.vec(edge_gradient))
               + ca.mtimes(_casadi_sparse(_scatter(problem.vertex_dofs, size, problem.free)),
                           ca.vec(vertex_gradient)))
    constraint = parts["inverse_scale"] * (parts["gravity"] - elastic)
    if problem.contacts.count:
        contact = problem.contact_matrix()
        pattern = ca.Sparsity(contact.shape[0], contact.shape[1], contact.indptr.tolist(), contact.indices.tolist())
        constraint = constraint + ca.mtimes(ca.MX(pattern, parts["contact_normals"]), p)
    difference = p - parts["p0"]
    objective = 0.5 * ca.sum1(parts["weights"] * difference * difference)
    return SymbolicNLP(p, data, objective, constraint, pieces)
