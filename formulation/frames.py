"""Discrete Elastic Rod frames in numpy (DESIGN section 3).

Conventions (used by every other module):

* edges ``e^j = x_{j+1} - x_j``, tangents ``t^j = e^j / |e^j|``, ``j = 0..n-2``;
* a reference frame per edge ``(a1^j, a2^j, t^j)`` with ``a2 = t x a1``;
* material frame ``d1 = cos(th) a1 + sin(th) a2``, ``d2 = -sin(th) a1 + cos(th) a2``;
* the parallel transport ``P(t_from -> t_to)`` is the rotation about ``b = t_from x t_to`` taking
  ``t_from`` to ``t_to``, in the branch-free form (Rodrigues with ``cos = c = t_from . t_to``)
  ``P v = c v + b x v + b (b . v) / (1 + c)``, singular only for opposite tangents;
* the reference twist at interior vertex ``i`` is the signed angle, about ``t^i``, from the space-parallel
  transported ``a1^{i-1}`` to ``a1^i``; it is updated incrementally (Bergou et al. 2010) so that it
  never wraps at +-pi.

The input shape's frames are space-parallel (Bishop) frames: reference twist 0 by construction.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

#: Fallback directors for the first edge when "up" is (nearly) parallel to it, tried in order.
FALLBACK_AXES = (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
#: Below this sine of the angle between "up" and the first edge, the fallback axis is used.
PARALLEL_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Frames:
    """Reference frames of one strand configuration.

    tangents: (n-1, 3) unit edge tangents; a1: (n-1, 3) reference directors (unit, perpendicular to
    the tangents); reference_twist: (n-2,) reference twist per interior vertex, rad.
    """

    tangents: np.ndarray
    a1: np.ndarray
    reference_twist: np.ndarray

    @property
    def a2(self) -> np.ndarray:
        return np.cross(self.tangents, self.a1)


def edges(points: np.ndarray) -> np.ndarray:
    """Edge vectors e^j = x_{j+1} - x_j, shape (n-1, 3), metres."""
    return np.diff(points, axis=0)


def unit(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` normalized to unit length."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def parallel_transport(t_from: np.ndarray, t_to: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate ``v`` by the minimal rotation taking unit ``t_from`` to unit ``t_to`` (row-wise).

    P v = c v + b x v + b (b.v) / (1 + c),  b = t_from x t_to,  c = t_from . t_to.
    """
    b = np.cross(t_from, t_to)
    c = np.sum(t_from * t_to, axis=-1, keepdims=True)
    return c * v + np.cross(b, v) + b * np.sum(b * v, axis=-1, keepdims=True) / (1.0 + c)


def signed_angle(u: np.ndarray, v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Signed angle from ``u`` to ``v`` about ``axis`` (row-wise), rad, in (-pi, pi]."""
    return np.arctan2(np.sum(np.cross(u, v) * axis, axis=-1), np.sum(u * v, axis=-1))


def rotate_about(v: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotate ``v`` (perpendicular to unit ``axis``) by ``angle`` about ``axis`` (row-wise)."""
    angle = np.asarray(angle)[..., None]
    return np.cos(angle) * v + np.sin(angle) * np.cross(axis, v)


def default_director(first_tangent: np.ndarray, gravity: np.ndarray) -> np.ndarray:
    """Default a1 of edge 0: "up" (minus gravity) projected perpendicular to the first edge.

    When gravity is zero, "up" is +z. When "up" is (nearly) parallel to the first edge, the first of
    FALLBACK_AXES that is not is projected instead (DESIGN section 3). Compiled (every Problem asks:
    ~30 us of numpy on 3-vectors), with numpy's norm sqrt(x . x) through the same BLAS dot.
    """
    return _default_director(np.ascontiguousarray(first_tangent, dtype=float),
                             np.ascontiguousarray(gravity, dtype=float))


@numba.njit(cache=True)
def _default_director(first_tangent, g):  # pragma: no cover - compiled
    g_norm = np.sqrt(np.dot(g, g))
    up = -g / g_norm if g_norm > 0 else np.array([0.0, 0.0, 1.0])
    for k in range(len(FALLBACK_AXES) + 1):
        candidate = up if k == 0 else FALLBACK_AXES[k - 1]
        projected = candidate - np.dot(candidate, first_tangent) * first_tangent
        norm = np.sqrt(np.dot(projected, projected))
        if norm > PARALLEL_TOLERANCE:
            return projected / norm
    raise AssertionError("unreachable: two orthogonal fallback axes cannot both be parallel")


@numba.njit(cache=True)
def first_tangent(points):  # pragma: no cover - compiled
    """t^0 = e^0 / |e^0| of the (n, 3) float ``points``, |e| = sqrt(e . e) as numpy's norm."""
    e = points[1] - points[0]
    return e / np.sqrt(np.dot(e, e))


def project_director(first_tangent: np.ndarray, director: np.ndarray) -> np.ndarray:
    """A user director made perpendicular to the first edge and unit; error if parallel to it."""
    d = np.asarray(director, dtype=float)
    projected = d - np.dot(d, first_tangent) * first_tangent
    norm = np.linalg.norm(projected)
    if not np.isfinite(norm) or norm <= PARALLEL_TOLERANCE * max(np.linalg.norm(d), 1e-300):
        raise ValueError(
            f"director {d.tolist()} is zero, non-finite or parallel to the first edge "
            f"(tangent {first_tangent.tolist()}); give a vector perpendicular to it"
        )
    return projected / norm


@numba.njit(cache=True)
def _transport(t_from, t_to, v):  # pragma: no cover - compiled
    """P(t_from -> t_to) v, the parallel transport of the module docstring (compiled)."""
    b = np.cross(t_from, t_to)
    c = t_from @ t_to
    return c * v + np.cross(b, v) + b * (b @ v) / (1.0 + c)


@numba.njit(cache=True)
def _transport_along(tangents: np.ndarray, a1_first: np.ndarray) -> np.ndarray:  # pragma: no cover
    """Sequential space-parallel transport of a1 along the edges (compiled loop in scalars: with
    3-vectors it allocated ~10 temporaries per edge, 45 of a 100-vertex Problem's ~430 us, and its
    dot products went to BLAS, whose rounding depends on the CPU)."""
    m = tangents.shape[0]
    a1 = np.empty((m, 3))
    a1[0] = a1_first
    for j in range(1, m):
        f0, f1, f2 = tangents[j - 1, 0], tangents[j - 1, 1], tangents[j - 1, 2]
        t0, t1, t2 = tangents[j, 0], tangents[j, 1], tangents[j, 2]
        v0, v1, v2 = a1[j - 1, 0], a1[j - 1, 1], a1[j - 1, 2]
        b0, b1, b2 = f1 * t2 - f2 * t1, f2 * t0 - f0 * t2, f0 * t1 - f1 * t0  # P v of _transport
        c = f0 * t0 + f1 * t1 + f2 * t2
        bv, d = b0 * v0 + b1 * v1 + b2 * v2, 1.0 + c
        w0 = c * v0 + (b1 * v2 - b2 * v1) + b0 * bv / d
        w1 = c * v1 + (b2 * v0 - b0 * v2) + b1 * bv / d
        w2 = c * v2 + (b0 * v1 - b1 * v0) + b2 * bv / d
        drift = w0 * t0 + w1 * t1 + w2 * t2  # remove round-off drift off the tangent
        w0, w1, w2 = w0 - drift * t0, w1 - drift * t1, w2 - drift * t2
        norm = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        a1[j, 0], a1[j, 1], a1[j, 2] = w0 / norm, w1 / norm, w2 / norm
    return a1


def bishop_frames(points: np.ndarray, a1_first: np.ndarray) -> Frames:
    """Space-parallel (Bishop) reference frames of a polyline; reference twist is zero."""
    tangents = unit(edges(points))
    a1 = _transport_along(np.ascontiguousarray(tangents), np.asarray(a1_first, dtype=float))
    return Frames(tangents, a1, np.zeros(len(points) - 2))


def reference_twist(tangents: np.ndarray, a1: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """Reference twist per interior vertex, updated incrementally from ``previous`` (rad).

    rt_i = rt_i_old + angle(R(rt_i_old) P(t^{i-1} -> t^i) a1^{i-1}, a1^i) about t^i.
    """
    transported = parallel_transport(tangents[:-1], tangents[1:], a1[:-1])
    rotated = rotate_about(transported, tangents[1:], previous)
    return previous + signed_angle(rotated, a1[1:], tangents[1:])


def transport_frames(frames: Frames, points: np.ndarray) -> Frames:
    """Time-parallel transport of ``frames`` to a moved configuration ``points`` (Bergou 2010).

    Each a1^j is transported from the old tangent to the new one; the reference twist is updated
    (``reference_twist``; the same formulas in one compiled loop, called at every time step).
    """
    tangents, a1, twist = _transported(np.ascontiguousarray(points, dtype=float), frames.tangents, frames.a1,
                                       frames.reference_twist)
    return Frames(tangents, a1, twist)


@numba.njit(cache=True)
def _transported(points, old_tangents, old_a1, old_twist):  # pragma: no cover - compiled
    """transport_frames' loop: new tangents, a1 transported and re-orthonormalized, reference twist."""
    m = points.shape[0] - 1
    tangents, a1, twist = np.empty((m, 3)), np.empty((m, 3)), np.empty(m - 1)
    for j in range(m):
        e = points[j + 1] - points[j]
        tangents[j] = e / np.sqrt(e @ e)
        a = _transport(old_tangents[j], tangents[j], old_a1[j])
        a -= (a @ tangents[j]) * tangents[j]
        a1[j] = a / np.sqrt(a @ a)
    for i in range(m - 1):
        t = tangents[i + 1]
        moved = _transport(tangents[i], t, a1[i])
        angle = old_twist[i]
        rotated = np.cos(angle) * moved + np.sin(angle) * np.cross(t, moved)
        twist[i] = angle + np.arctan2(np.cross(rotated, a1[i + 1]) @ t, rotated @ a1[i + 1])
    return tangents, a1, twist


def material_frames(frames: Frames, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Material directors (d1, d2) per edge: d1 = cos th a1 + sin th a2, d2 = -sin th a1 + cos th a2."""
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    a1, a2 = frames.a1, frames.a2
    return c * a1 + s * a2, -s * a1 + c * a2
