"""The interleaved DOF vector q = (x_0, th_0, x_1, th_1, ..., th_{n-2}, x_{n-1}), length 4n-1.

Every vertex stencil is 11 consecutive entries, so every Hessian is banded (half bandwidth 10).
Also: which DOFs the attachments prescribe, external forces on lumped masses, and the row scales D
(DESIGN 3, 4).
"""
from __future__ import annotations

import functools

import numba
import numpy as np

STANDARD_GRAVITY = 9.81  # m/s^2, the weight scale when the given gravity is zero


def dof_count(n_vertices: int) -> int:
    return 4 * n_vertices - 1


def interleave(points: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """q from vertex positions (n, 3) and edge angles (n-1,)."""
    n = len(points)
    q = np.empty(dof_count(n))
    q[position_index(n)] = points
    q[theta_index(n)] = theta
    return q


@functools.lru_cache(maxsize=64)
def position_index(n_vertices: int) -> np.ndarray:
    """(n, 3) indices of the vertex positions in q (shared per n, read-only: index with it only)."""
    index = 4 * np.arange(n_vertices)[:, None] + np.arange(3)
    index.flags.writeable = False
    return index


def theta_index(n_vertices: int) -> np.ndarray:
    """(n-1,) indices of the edge angles in q."""
    return 4 * np.arange(n_vertices - 1) + 3


def positions(q: np.ndarray) -> np.ndarray:
    return q[position_index((len(q) + 1) // 4)]


def thetas(q: np.ndarray) -> np.ndarray:
    return q[theta_index((len(q) + 1) // 4)]


@functools.lru_cache(maxsize=64)
def vertex_stencil_index(n_vertices: int) -> np.ndarray:
    """(n-2, 11) indices of (x_{i-1}, th_{i-1}, x_i, th_i, x_{i+1}) for i = 1..n-2 (shared per n,
    read-only)."""
    index = 4 * np.arange(n_vertices - 2)[:, None] + np.arange(11)
    index.flags.writeable = False
    return index


@functools.lru_cache(maxsize=64)
def edge_stencil_index(n_vertices: int) -> np.ndarray:
    """(n-1, 6) indices of (x_j, x_{j+1}) for j = 0..n-2 (shared per n, read-only)."""
    index = 4 * np.arange(n_vertices - 1)[:, None] + np.array([0, 1, 2, 4, 5, 6])
    index.flags.writeable = False
    return index


def free_mask(n_vertices: int, root: str, tip: str | None = None, pins=()) -> np.ndarray:
    """True for free DOFs. A clamped root prescribes x_0, th_0, x_1 (the first 7 entries of q), a
    pinned one x_0; a clamped tip x_{n-2}, th_{n-2}, x_{n-1} (the last 7), a pinned one x_{n-1};
    each pin i its position x_i."""
    free = np.ones(dof_count(n_vertices), dtype=bool)
    free[: 7 if root == "clamped" else 3] = False
    if tip is not None:
        free[-(7 if tip == "clamped" else 3):] = False
    free[position_index(n_vertices)[np.asarray(pins, dtype=int)].ravel()] = False
    return free


def external_forces(masses: np.ndarray, gravity: np.ndarray, loads: np.ndarray | None = None) -> np.ndarray:
    """Generalized external force: m_i g plus the load on each vertex position, 0 on angles (N)."""
    return _external_forces(np.ascontiguousarray(masses, dtype=float), np.ascontiguousarray(gravity, dtype=float),
                            _loads(loads, len(masses)))


def row_scales(masses: np.ndarray, edge_lengths: np.ndarray, density: float, radius: float,
               gravity: np.ndarray, loads: np.ndarray | None = None) -> np.ndarray:
    """Characteristic force D per DOF: vertex weight m_i |g| plus the norm of its load (N) on
    positions, and edge weight times edge length rho pi r^2 l0_j^2 |g| (N m) on angles; |g| = 9.81
    m/s^2 when gravity is zero. (A load enters the scale where it acts: a hanging weight thousands of
    times the vertex's own would otherwise make the tolerance on c unreachably tight there.)"""
    g = float(np.linalg.norm(gravity)) or STANDARD_GRAVITY
    load_norms = np.zeros(0) if loads is None else np.linalg.norm(loads, axis=1)
    return _row_scales(np.ascontiguousarray(masses, dtype=float), np.ascontiguousarray(edge_lengths, dtype=float),
                       float(density), float(radius), g, load_norms)


def _loads(loads, n_vertices: int) -> np.ndarray:
    """The (n, 3) loads as floats, or (0, 3) for none (the compiled kernels' "no loads")."""
    return np.zeros((0, 3)) if loads is None else np.ascontiguousarray(loads, dtype=float).reshape(n_vertices, 3)


# The kernels below take the numpy forms' operations in the same order (scalar factors first), so
# their numbers are the same bit for bit; compiled because every Problem calls them (~30 us of
# numpy calls on 100 vertices).

@numba.njit(cache=True)
def _external_forces(masses, gravity, loads):  # pragma: no cover - compiled
    f = np.zeros(4 * masses.size - 1)
    for i in range(masses.size):
        for k in range(3):
            f[4 * i + k] = masses[i] * gravity[k] + loads[i, k] if loads.shape[0] else masses[i] * gravity[k]
    return f


@numba.njit(cache=True)
def _row_scales(masses, edge_lengths, density, radius, g, load_norms):  # pragma: no cover - compiled
    d = np.empty(4 * masses.size - 1)
    for i in range(masses.size):
        weight = masses[i] * g + load_norms[i] if load_norms.size else masses[i] * g
        d[4 * i], d[4 * i + 1], d[4 * i + 2] = weight, weight, weight
    factor = density * np.pi * radius**2
    for j in range(edge_lengths.size):
        d[4 * j + 3] = factor * edge_lengths[j] ** 2 * g
    return d
