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
from .kinematics import EDGE_DOFS, REFERENCE_SIZE, VERTEX_DOFS, edge_length, vertex_kinematics


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


def _derived(name: str, energy, y, inputs) -> list[ca.Function]:
    physical = inputs[-1]
    g = ca.gradient(energy, y)
    return [
        ca.Function(f"{name}_energy", inputs, [energy]),
        ca.Function(f"{name}_gradient", inputs, [ca.densify(g)]),
        ca.Function(f"{name}_parameter_jacobian", inputs, [ca.densify(ca.jacobian(g, physical))]),
        ca.Function(f"{name}_hessian", inputs, [ca.densify(ca.hessian(energy, y)[0])]),
    ]


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
    check_variant(variant)
    unknown = set(terms) - set(TERMS)
    if unknown:
        raise ValueError(f"unknown energy terms {sorted(unknown)}; choose from {TERMS}")
    y = ca.SX.sym("y", VERTEX_DOFS)
    reference = ca.SX.sym("reference", REFERENCE_SIZE)
    geometry = ca.SX.sym("geometry", len(VERTEX_GEOMETRY))
    physical = ca.SX.sym("physical", len(VERTEX_PHYSICAL))
    kin = vertex_kinematics(y, reference)
    energy = ca.SX(0)
    if "bend" in terms:
        energy += bend_energy(variant, kin, geometry, physical)
    if "twist" in terms:
        energy += twist_energy(kin, geometry, physical)
    functions = _derived("vertex", energy, y, [y, reference, geometry, physical])
    kappa = material_curvature(variant, kin)
    padded = ca.vertcat(kappa, ca.SX.zeros(4 - kappa.numel()))
    functions.append(ca.Function("vertex_geometry", [y, reference], [padded, kin.twist]))
    return StencilFunctions(*batch_functions(functions))
