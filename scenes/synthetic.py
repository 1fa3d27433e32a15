"""Reference single-strand scenes (DESIGN section 8), SI units.

Every scene returns a ``Strand`` with the material of the `horizontal` reference unless overridden:
radius 50 um, density 1300 kg/m^3, E = 1e9 Pa, G = 4e8 Pa, clamped root at the origin. Curves are
sampled at equal arc length, so all edges have (nearly) the same length.
"""
from __future__ import annotations

import numpy as np

from sagfree.formulation.strand import Strand

MATERIAL = dict(radius=5e-5, density=1300.0, youngs_modulus=1e9, shear_modulus=4e8)


def _strand(points, **material) -> Strand:
    return Strand(points, **{**MATERIAL, **material})


def resample(dense: np.ndarray, n: int, length: float | None = None) -> np.ndarray:
    """n points at equal arc length along the dense polyline ``dense``, up to arc length ``length``
    (default: the whole polyline)."""
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))]
    total = arc[-1] if length is None else length
    if total > arc[-1] * (1 + 1e-12):
        raise ValueError(f"cannot cut {total} m from a curve of {arc[-1]} m")
    s = np.linspace(0.0, total, n)
    return np.column_stack([np.interp(s, arc, dense[:, k]) for k in range(3)])


def _orthonormal_pair(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing unit ``axis`` to a right-handed frame (u: the most vertical)."""
    up = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = up - np.dot(up, axis) * axis
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def horizontal(n: int = 30, length: float = 0.10, **material) -> Strand:
    """A straight strand along +x from the origin (supplement sections IV and V)."""
    x = np.linspace(0.0, length, n)
    return _strand(np.column_stack([x, np.zeros(n), np.zeros(n)]), **material)


def cable(n: int = 50, length: float = 1.0, **material) -> Strand:
    """A straight horizontal cable along +x clamped at both ends (r 2 mm, E 1 GPa, G 0.4 GPa,
    1300 kg/m^3: a polymer-sheathed cable); gravity would make it a catenary."""
    x = np.linspace(0.0, length, n)
    options = {"radius": 2e-3, "tip": "clamped", **material}
    return _strand(np.column_stack([x, np.zeros(n), np.zeros(n)]), **options)


def flipped(n: int = 30, length: float = 0.10, **material) -> Strand:
    """`horizontal` with the material frames of alternate edges flipped, th = pi (supplement Fig. 2)."""
    base = horizontal(n, length)
    theta = np.where(np.arange(n - 1) % 2 == 1, np.pi, 0.0)
    return _strand(base.points, theta=theta, **material)


def helix(n: int = 50, length: float = 0.10, coil_radius: float = 0.01, pitch: float = 0.02,
          axis=(1.0, 0.0, 0.0), **material) -> Strand:
    """A helix of the given coil radius and pitch (m per turn) about ``axis`` (default horizontal
    +x; (0, 0, -1) hangs it), starting at the origin, arc length ``length``."""
    a = np.asarray(axis, dtype=float)
    a /= np.linalg.norm(a)
    u, w = _orthonormal_pair(a)
    rise = pitch / (2 * np.pi)
    phi = np.linspace(0.0, length / np.hypot(coil_radius, rise), n)
    points = (coil_radius * (np.cos(phi)[:, None] - 1) * u + coil_radius * np.sin(phi)[:, None] * w
              + rise * phi[:, None] * a)
    return _strand(points, **material)


def curly(n: int = 50, length: float = 0.10, coil_radius: float = 0.005, pitch: float = 0.01,
          axis=(1.0, 0.0, 0.0), **material) -> Strand:
    """A tight helix (R 5 mm, pitch 10 mm): a curly strand."""
    return helix(n, length, coil_radius, pitch, axis, **material)


def wavy(n: int = 50, length: float = 0.10, amplitude: float = 0.005, wavelength: float = 0.02,
         direction=(1.0, 0.0, 0.0), **material) -> Strand:
    """A planar sine wave along ``direction`` (default +x, held horizontally), waving in the vertical
    plane, arc length ``length``."""
    d = np.asarray(direction, dtype=float)
    d /= np.linalg.norm(d)
    u, _ = _orthonormal_pair(d)
    t = np.linspace(0.0, length, 20 * n)  # the wave is longer than its span: enough to cut from
    dense = t[:, None] * d + amplitude * np.sin(2 * np.pi * t / wavelength)[:, None] * u
    return _strand(resample(dense, n, length), **material)
