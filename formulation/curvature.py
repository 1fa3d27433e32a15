"""The three material-curvature variants and their rest-curvature maps (DESIGN section 3).

Every variant is written in terms of the four frame curvatures kappa4 of S(1)-(4) and the vertex twist
m_i. For any configuration (kappa_2, kappa_3) = R(m_i)(kappa_0, kappa_1): the space-parallel transport
from edge i-1 to edge i rotates about kb, so kb . P d = kb . d, and the material frame of edge i is the
transported frame of edge i-1 rotated by m_i about t^i.

* ``4d`` (Bergou 2008, S(1)-(4)): kappa = kappa4.
  Rest curvature kbar = (k0, k1, R(m*_i)(k0, k1)), m*_i the twist of the input shape; for untwisted
  input this is the supplement's kbar_0 = kbar_2, kbar_1 = kbar_3.
* ``2d-average`` (Bergou 2010, S(5)-(6)): kappa = ((kappa_0 + kappa_2)/2, (kappa_1 + kappa_3)/2)
  = (I + R(m_i))/2 (kappa_0, kappa_1); zero for flipped frames (m_i = pi), supplement Fig. 2b.
* ``2d-slerp`` (Gornowicz & Borac 2015): kb evaluated on the vertex frame spherically interpolated
  halfway between the two material frames, i.e. the frame of edge i-1 transported to the vertex
  tangent and rotated by m_i/2: kappa = R(m_i/2)(kappa_0, kappa_1). Unit frames, so flipped frames
  bend correctly; unlike the original method, its gradient here is exact (CasADi AD).
  Rest curvature for both 2D variants: kbar = (k0, k1).

The bending energy is E = s beta pi r^4 w / (lbar_{i-1} + lbar_i) sum_k (kappa_k - kbar_k)^2 with
w = 1/8 for 4d (four entries) and w = 1/4 for the 2D variants (two entries), so all variants agree
when the two edge frames agree (S(10)).
"""
from __future__ import annotations

import casadi as ca

from .kinematics import VertexKinematics, rotate2

VARIANTS = ("4d", "2d-average", "2d-slerp")
BEND_WEIGHT = {"4d": 1 / 8, "2d-average": 1 / 4, "2d-slerp": 1 / 4}
CURVATURE_SIZE = {"4d": 4, "2d-average": 2, "2d-slerp": 2}


def check_variant(variant: str) -> None:
    if variant not in VARIANTS:
        raise ValueError(f"unknown curvature variant {variant!r}; choose one of {VARIANTS}")


def material_curvature(variant: str, kin: VertexKinematics):
    """Material curvature vector of the variant (4 or 2 entries), dimensionless."""
    check_variant(variant)
    k = kin.kappa4
    if variant == "4d":
        return k
    if variant == "2d-average":
        return 0.5 * (k[0:2] + k[2:4])
    return rotate2(0.5 * kin.twist, k[0:2])


def rest_curvature(variant: str, k01, twist_star, kappa_star):
    """Rest curvature vector of the variant from the two optimized values (k0, k1).

    4d: (k0, k1, R(m*)(k0, k1)), written as (k0, k1, kappa*_{2,3} + R(m*)((k0, k1) - kappa*_{0,1}))
    with kappa* the input shape's curvatures: the same map (kappa*_{2,3} = R(m*) kappa*_{0,1} holds
    identically), but exact to the last bit at p0, so c(p0) is gravity without rounding residue.
    """
    check_variant(variant)
    if variant == "4d":
        return ca.vertcat(k01, kappa_star[2:4] + rotate2(twist_star, k01 - kappa_star[0:2]))
    return k01
