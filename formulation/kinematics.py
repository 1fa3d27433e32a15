"""Symbolic (CasADi) kinematics of one DER vertex stencil (DESIGN section 3, S(1)-(4)).

A vertex stencil is the 11 consecutive DOFs y = (x_{i-1}, th_{i-1}, x_i, th_i, x_{i+1}) of the
interleaved DOF vector q. Its reference frames are time-parallel transported from given reference
frames (those of q* for the equilibrium problem, those of the previous state in a simulation), so the
expressions below are exact functions of y whose AD gradients are the true DER gradients.

Stencil reference data (13 numbers per interior vertex, REFERENCE_SIZE): t^{i-1}, a1^{i-1}, t^i, a1^i
of the reference state, then its reference twist rt_i.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

VERTEX_DOFS = 11
EDGE_DOFS = 6
REFERENCE_SIZE = 13


def transport(t_from, t_to, v):
    """Parallel transport P(t_from -> t_to) v = c v + b x v + b (b.v)/(1+c), b = t_from x t_to."""
    b = ca.cross(t_from, t_to)
    c = ca.dot(t_from, t_to)
    return c * v + ca.cross(b, v) + b * ca.dot(b, v) / (1 + c)


def rotate2(angle, v):
    """R(a) v with R(a) = [[cos a, sin a], [-sin a, cos a]] (DESIGN section 3)."""
    c, s = ca.cos(angle), ca.sin(angle)
    return ca.vertcat(c * v[0] + s * v[1], -s * v[0] + c * v[1])


@dataclass
class VertexKinematics:
    """Curvature binormal, the four frame curvatures S(1)-(4) and the twist of one vertex stencil."""

    kappa4: ca.SX   # (kb.d2^{i-1}, -kb.d1^{i-1}, kb.d2^i, -kb.d1^i), dimensionless
    twist: ca.SX    # m_i = th_i - th_{i-1} + reference twist, rad


def vertex_kinematics(y, reference) -> VertexKinematics:
    """Kinematics of the vertex stencil ``y`` (11) given its reference data (13)."""
    return vertex_kinematics_of_edges(stencil_edges(y), reference)


def stencil_edges(y):
    """z = (e_{i-1}, th_{i-1}, e_i, th_i) (8) of the vertex stencil y (11), e_{i-1} = x_i - x_{i-1}
    and e_i = x_{i+1} - x_i: the stencil's energy depends on y only through z (it is invariant
    under translation), and z = T y with the constant ``EDGES_OF_STENCIL`` T."""
    x0, th0, x1, th1, x2 = y[0:3], y[3], y[4:7], y[7], y[8:11]
    return ca.vertcat(x1 - x0, th0, x2 - x1, th1)


def _edges_of_stencil() -> ca.DM:
    T = ca.DM(8, VERTEX_DOFS)
    for k in range(3):
        T[k, k], T[k, 4 + k] = -1, 1          # e_{i-1} = x_i - x_{i-1}
        T[4 + k, 4 + k], T[4 + k, 8 + k] = -1, 1  # e_i = x_{i+1} - x_i
    T[3, 3] = T[7, 7] = 1
    return T


#: T (8 x 11, entries 0 and +-1) with stencil_edges(y) = T y
EDGES_OF_STENCIL = _edges_of_stencil()


def vertex_kinematics_of_edges(z, reference) -> VertexKinematics:
    """Kinematics of the vertex stencil from its edges and angles z = stencil_edges(y) (8)."""
    e0, th0, e1, th1 = z[0:3], z[3], z[4:7], z[7]
    t0, t1 = e0 / ca.norm_2(e0), e1 / ca.norm_2(e1)
    a1_0 = transport(reference[0:3], t0, reference[3:6])
    a1_1 = transport(reference[6:9], t1, reference[9:12])
    a2_0, a2_1 = ca.cross(t0, a1_0), ca.cross(t1, a1_1)
    d1_0 = ca.cos(th0) * a1_0 + ca.sin(th0) * a2_0
    d2_0 = -ca.sin(th0) * a1_0 + ca.cos(th0) * a2_0
    d1_1 = ca.cos(th1) * a1_1 + ca.sin(th1) * a2_1
    d2_1 = -ca.sin(th1) * a1_1 + ca.cos(th1) * a2_1
    kb = 2 * ca.cross(t0, t1) / (1 + ca.dot(t0, t1))
    # reference twist, incremental from the reference state's value (never wraps at +-pi)
    rt_ref = reference[12]
    u = transport(t0, t1, a1_0)
    u = ca.cos(rt_ref) * u + ca.sin(rt_ref) * ca.cross(t1, u)
    rt = rt_ref + ca.atan2(ca.dot(ca.cross(u, a1_1), t1), ca.dot(u, a1_1))
    kappa4 = ca.vertcat(ca.dot(kb, d2_0), -ca.dot(kb, d1_0), ca.dot(kb, d2_1), -ca.dot(kb, d1_1))
    return VertexKinematics(kappa4=kappa4, twist=th1 - th0 + rt)


def edge_length(y_edge):
    """Length |x_{j+1} - x_j| of the edge stencil y_edge = (x_j, x_{j+1}), m."""
    return ca.norm_2(y_edge[3:6] - y_edge[0:3])
