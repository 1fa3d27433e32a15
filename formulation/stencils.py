"""Compiled stencil functions: energies, gradients, parameter Jacobians and Hessians per stencil.

Everything the Problem evaluates comes from here: CasADi builds the expressions of the energies
module, differentiates them (gradient in the stencil DOFs, its Jacobian in the physical parameters,
the Hessian in the DOFs), and the compiled module evaluates them over all stencils of a strand (or of
many strands) at once.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import casadi as ca

from .compiled import BatchFunction, batch_functions
from .curvature import check_variant, material_curvature
from .energies import (EDGE_GEOMETRY, EDGE_PHYSICAL, TERMS, VERTEX_GEOMETRY, VERTEX_PHYSICAL,
                       bend_energy, stretch_energy, twist_energy)
from .kinematics import (EDGE_DOFS, EDGES_OF_STENCIL, REFERENCE_SIZE, VERTEX_DOFS, VertexKinematics, edge_length,
                         stencil_edges, vertex_kinematics, vertex_kinematics_of_edges)

#: the vertex kinematics k = (kappa4, m) through which the bend and twist energies see the DOFs
KINEMATICS_SIZE = 5


@dataclass(frozen=True)
class StencilFunctions:
    """Batch functions of one stencil kind (inputs: DOFs, [reference,] geometry, physical).

    energy -> E (J); gradient -> dE/dy; parameter_jacobian -> d(dE/dy)/d(physical);
    hessian -> d2E/dy2; geometry (DOFs[, reference] only) -> the stencil's measured shape (see the
    builders).
    """

    energy: BatchFunction
    gradient: BatchFunction
    parameter_jacobian: BatchFunction
    hessian: BatchFunction
    geometry: BatchFunction


@dataclass(frozen=True)
class FixedShapeFunctions:
    """Batch functions of the vertex stencil at a fixed shape y* (the input shape q*, where the
    residual and its parameter Jacobian are evaluated), through its kinematics k = (kappa4, m):

    kinematics (y, reference) -> k (5), dk/dy (5 x 11); gradient (k, geometry, physical) -> dE/dk;
    parameter_jacobian (k, geometry, physical) -> d(dE/dk)/d(physical) (5 x 7); hessian (k, geometry,
    physical) -> d2E/dk2 (5 x 5).

    The energy depends on the DOFs only through k, so by the chain rule
    dE/dy = (dk/dy)^T dE/dk and d(dE/dy)/d(physical) = (dk/dy)^T d(dE/dk)/d(physical): with k and
    dk/dy evaluated once per shape, a residual or Jacobian no longer differentiates the frames,
    transports and trigonometry of the kinematics, which halves the cost of both. Where dE/dk = 0
    (p0: the rest shape is q*'s own), d2E/dy2 = (dk/dy)^T d2E/dk2 dk/dy as well.
    """

    kinematics: BatchFunction
    gradient: BatchFunction
    parameter_jacobian: BatchFunction
    hessian: BatchFunction


def _derived(name: str, energy, y, inputs, hessian=None) -> list[ca.Function]:
    """The energy, gradient, parameter Jacobian and Hessian functions of a stencil's energy in its
    DOFs y; ``hessian``: the Hessian's expression where the stencil builds it its own way."""
    physical = inputs[-1]
    g = ca.gradient(energy, y)
    return [
        ca.Function(f"{name}_energy", inputs, [energy]),
        ca.Function(f"{name}_gradient", inputs, [ca.densify(g)]),
        ca.Function(f"{name}_parameter_jacobian", inputs, [ca.densify(ca.jacobian(g, physical))]),
        ca.Function(f"{name}_hessian", inputs,
                    [ca.densify(ca.hessian(energy, y)[0] if hessian is None else hessian)]),
    ]


def _vertex_hessian(variant: str, terms: tuple[str, ...], y, reference, geometry, physical):
    """d2E/dy2 of the vertex stencil through its edges: E depends on the 11 DOFs only through
    z = T y (kinematics.stencil_edges: two edge vectors and two angles), so d2E/dy2 = T^T (d2E/dz2) T.
    Differentiating in 8 variables instead of 11 takes 36% fewer instructions (7.9K instead of 12.4K
    per stencil, 4d curvature) in the Hessian that every stability evaluation and every implicit
    simulation step assembles; T's entries are 0 and +-1, so the product is sums and differences."""
    z = ca.SX.sym("z", 8)
    energy = _vertex_energy(variant, terms, vertex_kinematics_of_edges(z, reference), geometry, physical)
    T = EDGES_OF_STENCIL
    return ca.substitute(ca.mtimes(T.T, ca.mtimes(ca.hessian(energy, z)[0], T)), z, stencil_edges(y))


@lru_cache(maxsize=None)
def edge_stencil(with_stretch: bool = True) -> StencilFunctions:
    """Stretch stencil of edge j; geometry output: the edge length |x_{j+1} - x_j| (m)."""
    y = ca.SX.sym("y", EDGE_DOFS)
    geometry = ca.SX.sym("geometry", len(EDGE_GEOMETRY))
    physical = ca.SX.sym("physical", len(EDGE_PHYSICAL))
    energy = stretch_energy(y, geometry, physical) if with_stretch else ca.SX(0)
    functions = _derived("edge", energy, y, [y, geometry, physical])
    functions.append(ca.Function("edge_length", [y], [edge_length(y)]))
    return StencilFunctions(*batch_functions(functions))


@lru_cache(maxsize=None)
def vertex_stencil(variant: str = "4d", terms: tuple[str, ...] = ("bend", "twist")) -> StencilFunctions:
    """Bend + twist stencil of interior vertex i (terms chosen by ``terms``).

    geometry output: (material curvature of the variant, padded to 4 entries with zeros; twist m_i).
    """
    y = ca.SX.sym("y", VERTEX_DOFS)
    reference = ca.SX.sym("reference", REFERENCE_SIZE)
    geometry = ca.SX.sym("geometry", len(VERTEX_GEOMETRY))
    physical = ca.SX.sym("physical", len(VERTEX_PHYSICAL))
    kin = vertex_kinematics(y, reference)
    energy = _vertex_energy(variant, terms, kin, geometry, physical)
    functions = _derived("vertex", energy, y, [y, reference, geometry, physical],
                         _vertex_hessian(variant, terms, y, reference, geometry, physical))
    kappa = material_curvature(variant, kin)
    padded = ca.vertcat(kappa, ca.SX.zeros(4 - kappa.numel()))
    functions.append(ca.Function("vertex_geometry", [y, reference], [padded, kin.twist]))
    return StencilFunctions(*batch_functions(functions))


@lru_cache(maxsize=None)
def vertex_fixed_shape(variant: str = "4d", terms: tuple[str, ...] = ("bend", "twist")) -> FixedShapeFunctions:
    """The vertex stencil's derivatives at a fixed shape (FixedShapeFunctions), same energy terms."""
    y = ca.SX.sym("y", VERTEX_DOFS)
    reference = ca.SX.sym("reference", REFERENCE_SIZE)
    kin = vertex_kinematics(y, reference)
    k = ca.vertcat(kin.kappa4, kin.twist)
    kinematics = ca.Function("vertex_kinematics", [y, reference], [k, ca.densify(ca.jacobian(k, y))])
    k_sym = ca.SX.sym("k", KINEMATICS_SIZE)
    geometry = ca.SX.sym("geometry", len(VERTEX_GEOMETRY))
    physical = ca.SX.sym("physical", len(VERTEX_PHYSICAL))
    energy = _vertex_energy(variant, terms, VertexKinematics(kappa4=k_sym[0:4], twist=k_sym[4]), geometry,
                            physical)
    gradient = ca.gradient(energy, k_sym)
    functions = [kinematics,
                 ca.Function("vertex_kinematics_gradient", [k_sym, geometry, physical], [ca.densify(gradient)]),
                 ca.Function("vertex_kinematics_parameter_jacobian", [k_sym, geometry, physical],
                             [ca.densify(ca.jacobian(gradient, physical))]),
                 ca.Function("vertex_kinematics_hessian", [k_sym, geometry, physical],
                             [ca.densify(ca.hessian(energy, k_sym)[0])])]
    return FixedShapeFunctions(*batch_functions(functions))


@dataclass(frozen=True)
class ParameterHessianFunctions:
    """Second derivatives in the physical parameters at a fixed shape, weighted by a force direction:

    edge (y, geometry, physical, u) -> d2(u . dE/dy)/d(physical)^2 (2 x 2), u in the edge's DOFs;
    vertex (k, geometry, physical, u) -> d2(u . dE/dk)/d(physical)^2 (7 x 7), u in the kinematics k.

    lam^T c(p) sums such terms (Problem.constraint_hessian): the exact Hessian of the Lagrangian that
    asc's Newton-SQP phase needs (stiffness x rest-shape products, rest lengths in 1/lbar). Built and
    compiled apart from the other stencil functions, on first use.
    """

    edge: BatchFunction
    vertex: BatchFunction


@lru_cache(maxsize=None)
def parameter_hessians(variant: str = "4d", terms: tuple[str, ...] = TERMS) -> ParameterHessianFunctions:
    """The ParameterHessianFunctions of the energies ``terms`` with the curvature ``variant``."""
    y = ca.SX.sym("y", EDGE_DOFS)
    geometry = ca.SX.sym("geometry", len(EDGE_GEOMETRY))
    physical = ca.SX.sym("physical", len(EDGE_PHYSICAL))
    u = ca.SX.sym("u", EDGE_DOFS)
    energy = stretch_energy(y, geometry, physical) if "stretch" in terms else ca.SX(0)
    weighted = ca.dot(u, ca.gradient(energy, y))
    edge = ca.Function("edge_parameter_hessian", [y, geometry, physical, u],
                       [ca.densify(ca.hessian(weighted, physical)[0])])
    k = ca.SX.sym("k", KINEMATICS_SIZE)
    geometry = ca.SX.sym("geometry", len(VERTEX_GEOMETRY))
    physical = ca.SX.sym("physical", len(VERTEX_PHYSICAL))
    u = ca.SX.sym("u", KINEMATICS_SIZE)
    vertex_terms = tuple(t for t in ("bend", "twist") if t in terms)
    energy = _vertex_energy(variant, vertex_terms, VertexKinematics(kappa4=k[0:4], twist=k[4]), geometry, physical)
    weighted = ca.dot(u, ca.gradient(energy, k))
    vertex = ca.Function("vertex_parameter_hessian", [k, geometry, physical, u],
                         [ca.densify(ca.hessian(weighted, physical)[0])])
    return ParameterHessianFunctions(*batch_functions([edge, vertex]))


def _vertex_energy(variant: str, terms: tuple[str, ...], kin: VertexKinematics, geometry, physical):
    """Bend + twist energy of a vertex stencil (the chosen ``terms``), J."""
    check_variant(variant)
    unknown = set(terms) - set(TERMS)
    if unknown:
        raise ValueError(f"unknown energy terms {sorted(unknown)}; choose from {TERMS}")
    energy = ca.SX(0)
    if "bend" in terms:
        energy += bend_energy(variant, kin, geometry, physical)
    if "twist" in terms:
        energy += twist_energy(kin, geometry, physical)
    return energy
