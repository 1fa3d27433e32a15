"""Elastic energies of one stencil as CasADi expressions (DESIGN section 3, S(9)-(11)).

Stencil inputs (named layouts, shared with the hand-derived formulas and the Problem's assembly):

* edge stencil j: DOFs (x_j, x_{j+1}); geometry EDGE_GEOMETRY; physical parameters EDGE_PHYSICAL.
* vertex stencil i: DOFs (x_{i-1}, th_{i-1}, x_i, th_i, x_{i+1}); reference data (kinematics module);
  geometry VERTEX_GEOMETRY; physical parameters VERTEX_PHYSICAL.

Physical parameters: ``u`` relative rest-length change (lbar = l0 (1 + u)), rest curvatures ``kbar0``,
``kbar1`` (dimensionless), rest twist ``mbar`` (rad), moduli ``alpha``, ``beta``, ``gamma`` in Pa that
already include the strand scale s and the stiffness multipliers.
"""
from __future__ import annotations

import casadi as ca

from .curvature import BEND_WEIGHT, material_curvature, rest_curvature
from .kinematics import VertexKinematics, edge_length

EDGE_GEOMETRY = ("l0", "radius")
EDGE_PHYSICAL = ("u", "alpha")
VERTEX_GEOMETRY = ("l0_prev", "l0_next", "radius", "twist_star", "kappa_star0", "kappa_star1",
                   "kappa_star2", "kappa_star3")
VERTEX_PHYSICAL = ("u_prev", "u_next", "kbar0", "kbar1", "mbar", "beta", "gamma")
TERMS = ("stretch", "bend", "twist")


def stretch_energy(y_edge, geometry, physical):
    """E = 1/2 alpha pi r^2 lbar (l/lbar - 1)^2, J; strain as ((l - l0)/l0 - u)/(1 + u) (S(9)).

    The strain form keeps the ~1e-8 strains that hold gravity free of the rounding of l - lbar.
    """
    l0, r = geometry[0], geometry[1]
    u, alpha = physical[0], physical[1]
    strain = ((edge_length(y_edge) - l0) / l0 - u) / (1 + u)
    return 0.5 * alpha * ca.pi * r**2 * l0 * (1 + u) * strain**2


def _rest_length_sum(geometry, physical):
    """lbar_{i-1} + lbar_i = l0_{i-1}(1 + u_{i-1}) + l0_i(1 + u_i), m."""
    return geometry[0] * (1 + physical[0]) + geometry[1] * (1 + physical[1])


def bend_energy(variant: str, kin: VertexKinematics, geometry, physical):
    """E = beta pi r^4 w / (lbar_{i-1} + lbar_i) |kappa - kbar|^2, J (S(10); w in curvature module)."""
    r, twist_star = geometry[2], geometry[3]
    kappa = material_curvature(variant, kin)
    kbar = rest_curvature(variant, physical[2:4], twist_star, geometry[4:8])
    beta = physical[5]
    return beta * ca.pi * r**4 * BEND_WEIGHT[variant] / _rest_length_sum(geometry, physical) \
        * ca.sumsqr(kappa - kbar)


def twist_energy(kin: VertexKinematics, geometry, physical):
    """E = gamma pi r^4 / (2 (lbar_{i-1} + lbar_i)) (m - mbar)^2, J (S(11))."""
    r, mbar, gamma = geometry[2], physical[4], physical[6]
    return gamma * ca.pi * r**4 / (2 * _rest_length_sum(geometry, physical)) * (kin.twist - mbar) ** 2
