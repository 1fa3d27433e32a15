"""Hand-derived DER gradients and parameter Jacobians, supplement S(9)-S(19) (DESIGN section 7).

This is the INDEPENDENT verification path: plain numpy, no CasADi. The Problem differentiates the
energies of the ``energies`` module by CasADi AD; here the same quantities are written in closed form,
so that verification can compare AD, these formulas and finite differences.

Closed forms used (vertex stencil i = (x_{i-1}, th_{i-1}, x_i, th_i, x_{i+1}), edges e0 = e^{i-1},
e1 = e^i, tangents t0, t1, chi = 1 + t0.t1, [a]x v = a x v):

* dt/de = (I - t t^T) / |e|;
* kb = 2 t0 x t1 / chi, dkb/de0 = -(2 [t1]x + kb (t0 + t1)^T) / (chi |e0|),
  dkb/de1 = (2 [t0]x - kb (t0 + t1)^T) / (chi |e1|);
  d/dx_{i-1} = -d/de0, d/dx_i = d/de0 - d/de1, d/dx_{i+1} = d/de1;
* kappa4 = (kb.d2^{i-1}, -kb.d1^{i-1}, kb.d2^i, -kb.d1^i) (S(1)-(4)) depends on positions only
  through kb: the reference directors are time-parallel transported (delta a = -(a.delta t) t) and
  kb is perpendicular to both tangents. d/dth_{i-1} (kappa_0, kappa_1) = (kappa_1, -kappa_0), and
  the same for (kappa_2, kappa_3) with th_i;
* twist m_i = th_i - th_{i-1} + reference twist: dm/dth_i = 1, dm/dth_{i-1} = -1 and the holonomy
  gradient of the reference twist dm/de0 = kb / (2 |e0|), dm/de1 = kb / (2 |e1|) (Bergou et al.
  2010), so dm/dx_{i-1} = -kb / (2 |e0|), dm/dx_{i+1} = +kb / (2 |e1|). The sign holds for this
  project's transport and signed-angle conventions (frames module): checked against AD and central
  finite differences with re-transported frames (the opposite sign gives a relative error of 2);
* 2D variants by the chain rule: 2d-average kappa = (kappa_{0:2} + kappa_{2:4}) / 2, 2d-slerp
  kappa = R(m/2) kappa_{0:2} with d/dm R(a/2) v = (k_1, -k_0) / 2 for k = R(a/2) v.

Parameters enter through the physical slots of ``energies`` (u, alpha per edge; u_prev, u_next, kbar0,
kbar1, mbar, beta, gamma per interior vertex), generalized from the supplement: rest lengths as
lbar = l0 (1 + u), so d/du = l0 d/dlbar; rest curvature through the variant's rest map (S(15) with
kbar_{2,3} = R(m*_i)(k0, k1) for 4d); moduli and multipliers through the SlotMap coefficients, e.g.
d/d(bend multiplier) = E d/d(beta).

The formulas assume CURRENT reference frames: ``frames`` must belong to ``q`` (time-parallel transported
to it). q = None means the input shape q* with the Problem's frames; q without frames transports the
Problem's frames to q.
"""
from __future__ import annotations

import numpy as np

from . import dofs
from .curvature import BEND_WEIGHT, check_variant
from .energies import TERMS
from .frames import Frames, transport_frames


def gradient(problem, p, term: str, q=None, frames: Frames | None = None) -> np.ndarray:
    """grad_q E_term (4n-1), N on positions and N m on angles, from the closed forms S(9) (stretch),
    S(10) (bend, the Problem's curvature variant) and S(11) (twist)."""
    index, grad, _, _ = _stencil_terms(problem, p, term, q, frames)
    g = np.zeros(problem.q_star.size)
    np.add.at(g, index, grad)
    return g


def parameter_jacobian(problem, p, term: str, q=None, frames: Frames | None = None) -> np.ndarray:
    """d f_term / d p, dense (4n-1, n_parameters), f_term = -grad_q E_term, from S(12)-(19).

    Units: the force's (N or N m) per unit of each normalized parameter. S(12)/(14)/(17) give the
    rest-length columns (times l0), S(15)/(18) rest curvature and twist, S(13)/(16)/(19) the moduli
    (times the SlotMap coefficient E or G).
    """
    index, _, dfdphys, slots = _stencil_terms(problem, p, term, q, frames)
    jac = np.zeros((problem.q_star.size, problem.n_parameters))
    linked = np.broadcast_to(slots.index[:, None, :] >= 0, dfdphys.shape)
    rows = np.broadcast_to(index[:, :, None], dfdphys.shape)[linked]
    cols = np.broadcast_to(slots.index[:, None, :], dfdphys.shape)[linked]
    np.add.at(jac, (rows, cols), (slots.coefficient[:, None, :] * dfdphys)[linked])
    return jac


# ---- per-stencil closed forms ----

def _stencil_terms(problem, p, term, q, frames):
    """(DOF index (K, W), grad E per stencil (K, W), d f/d physical (K, W, slots), SlotMap)."""
    if term not in TERMS:
        raise ValueError(f"unknown energy term {term!r}; choose from {TERMS}")
    p = np.asarray(p, dtype=float).reshape(-1)
    if q is None:
        q = problem.q_star
        frames = problem.frames if frames is None else frames
    else:
        q = np.asarray(q, dtype=float).reshape(-1)
        frames = transport_frames(problem.frames, dofs.positions(q)) if frames is None else frames
    n, r = problem.n_vertices, problem.strand.radius
    l0 = problem.edge_lengths
    if term == "stretch":
        slots = problem.layout.edge_map
        u, alpha = slots.evaluate(p).T
        e = np.diff(dofs.positions(q), axis=0)
        length = np.sqrt(e[:, 0] ** 2 + e[:, 1] ** 2 + e[:, 2] ** 2)
        t = e / length[:, None]
        strain = ((length - l0) / l0 - u) / (1 + u)          # l / lbar - 1, S(9)
        pull = np.concatenate([-t, t], axis=1)                # d l / d(x_j, x_{j+1})
        unit = (np.pi * r**2 * strain)[:, None] * pull        # grad E per unit alpha
        dfdphys = np.stack([(alpha * np.pi * r**2 * (1 + strain) / (1 + u))[:, None] * pull,  # S(12) l0
                            -unit], axis=2)                                                   # S(13)
        return dofs.edge_stencil_index(n), alpha[:, None] * unit, dfdphys, slots

    slots = problem.layout.vertex_map
    u_prev, u_next, k0, k1, mbar, beta, gamma = slots.evaluate(p).T
    rest_sum = l0[:-1] * (1 + u_prev) + l0[1:] * (1 + u_next)   # lbar_{i-1} + lbar_i, m
    kappa4, j_kappa4, m, grad_m = _vertex_kinematics(q, frames)
    dfdphys = np.zeros((n - 2, 11, 7))
    if term == "bend":
        variant = problem.curvature
        check_variant(variant)
        kappa, j_kappa = _material_curvature(variant, kappa4, j_kappa4, m, grad_m)
        k01 = np.stack([k0, k1], axis=1)
        rest_map = np.broadcast_to(np.eye(2), (n - 2, 2, 2))
        if variant == "4d":
            rest_map = np.concatenate([rest_map, _rotation(problem.twist_star)], axis=1)
        scale = 2 * BEND_WEIGHT[variant] * np.pi * r**4 / rest_sum   # S(10) prefactor per unit beta
        excess = kappa - np.einsum("kcs,ks->kc", rest_map, k01)       # kappa - kbar
        unit = scale[:, None] * np.einsum("kcy,kc->ky", j_kappa, excess)
        grad = beta[:, None] * unit
        rest_force = np.einsum("kcy,kcs->kys", j_kappa, rest_map)     # J^T d kbar / d(k0, k1)
        dfdphys[:, :, 2:4] = (beta * scale)[:, None, None] * rest_force  # S(15)
        dfdphys[:, :, 5] = -unit                                      # S(16)
    else:
        scale = np.pi * r**4 / rest_sum                               # S(11) prefactor per unit gamma
        unit = (scale * (m - mbar))[:, None] * grad_m
        grad = gamma[:, None] * unit
        dfdphys[:, :, 4] = (gamma * scale)[:, None] * grad_m          # S(18)
        dfdphys[:, :, 6] = -unit                                      # S(19)
    dfdphys[:, :, 0] = grad * (l0[:-1] / rest_sum)[:, None]           # S(14)/(17) times l0_{i-1}
    dfdphys[:, :, 1] = grad * (l0[1:] / rest_sum)[:, None]            # S(14)/(17) times l0_i
    return dofs.vertex_stencil_index(n), grad, dfdphys, slots


def _vertex_kinematics(q, frames):
    """kappa4 (K, 4), its Jacobian (K, 4, 11), twist m (K,) and grad m (K, 11) per vertex stencil."""
    x, theta = dofs.positions(q), dofs.thetas(q)
    e = np.diff(x, axis=0)
    length = np.linalg.norm(e, axis=1)
    t = e / length[:, None]
    a1 = frames.a1
    a2 = np.cross(t, a1)
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    d1, d2 = c * a1 + s * a2, -s * a1 + c * a2
    t0, t1, l_0, l_1 = t[:-1], t[1:], length[:-1, None], length[1:, None]
    chi = 1 + np.sum(t0 * t1, axis=1, keepdims=True)
    kb = 2 * np.cross(t0, t1) / chi

    def stencil(g0, g1, dth0, dth1):
        """Stencil gradient from d/de0 (K, 3), d/de1 (K, 3) and the two angle derivatives (K,)."""
        return np.concatenate([-g0, dth0[:, None], g0 - g1, dth1[:, None], g1], axis=1)

    def kb_dot_gradient(d):
        """d/de0 and d/de1 of kb.d for a transported director d (K, 3)."""
        kd = np.sum(kb * d, axis=1, keepdims=True) * (t0 + t1)
        return (2 * np.cross(t1, d) - kd) / (chi * l_0), (-2 * np.cross(t0, d) - kd) / (chi * l_1)

    directors = (d2[:-1], -d1[:-1], d2[1:], -d1[1:])
    kappa4 = np.stack([np.sum(kb * d, axis=1) for d in directors], axis=1)
    zero = np.zeros(len(kb))
    angle_derivatives = ((kappa4[:, 1], zero), (-kappa4[:, 0], zero),
                         (zero, kappa4[:, 3]), (zero, -kappa4[:, 2]))
    j_kappa4 = np.stack([stencil(*kb_dot_gradient(d), *dth)
                         for d, dth in zip(directors, angle_derivatives)], axis=1)
    m = theta[1:] - theta[:-1] + frames.reference_twist
    grad_m = stencil(kb / (2 * l_0), kb / (2 * l_1), -np.ones_like(m), np.ones_like(m))
    return kappa4, j_kappa4, m, grad_m


def _material_curvature(variant, kappa4, j_kappa4, m, grad_m):
    """The variant's material curvature (K, 2 or 4) and its Jacobian in the stencil DOFs."""
    if variant == "4d":
        return kappa4, j_kappa4
    if variant == "2d-average":
        return 0.5 * (kappa4[:, :2] + kappa4[:, 2:]), 0.5 * (j_kappa4[:, :2] + j_kappa4[:, 2:])
    rotation = _rotation(0.5 * m)                                 # 2d-slerp: R(m/2)(kappa_0, kappa_1)
    kappa = np.einsum("kab,kb->ka", rotation, kappa4[:, :2])
    turn = 0.5 * np.stack([kappa[:, 1], -kappa[:, 0]], axis=1)    # d kappa / d m
    jac = np.einsum("kab,kby->kay", rotation, j_kappa4[:, :2]) + turn[:, :, None] * grad_m[:, None, :]
    return kappa, jac


def _rotation(angle):
    """R(a) = [[cos a, sin a], [-sin a, cos a]] per entry of ``angle``, shape (K, 2, 2)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([np.stack([c, s], axis=-1), np.stack([-s, c], axis=-1)], axis=-2)
