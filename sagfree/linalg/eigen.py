"""The smallest eigenvalue of a symmetric band matrix in O(n): shift-and-invert Lanczos, compiled.

Problem.stability needs lambda_min of the free-DOF energy Hessian at q* for every result. The
banded eigensolver (LAPACK dsbevx through scipy) reduces the band to tridiagonal form in O(n^2 w);
ARPACK's Lanczos on a banded Cholesky solve is O(n) but pays Python overhead on every iteration.
Here the Cholesky (cholesky module), its solves and the Lanczos recurrence (with full
reorthogonalization) are numba-compiled, about four times faster than ARPACK on a 100-vertex strand,
and ``scaled_block_eigenpair`` takes the free block of a strand's Hessian band and its mass scaling
in the same call (no numpy passes over the band in between).

Method: find tau >= 0 such that H + tau I has a Cholesky factor (tau = 0 when H is positive
definite; otherwise tau grows 10-fold from 1e-14 of the largest entry, so tau is within 10x of
-lambda_min); Lanczos on (H + tau I)^-1 from a fixed start vector (results are reproducible) gives
its largest eigenvalue theta = 1 / (lambda_min + tau), stopped when the Ritz residual
|beta_k s_k| <= 1e-10 theta.
"""
from __future__ import annotations

import functools

import numba
import numpy as np

from .band import projected_band
from .cholesky import factor_active, plain_solve
from .timing import LINEAR_ALGEBRA, timed

TOLERANCE = 1e-10  # relative Ritz residual at which Lanczos stops
MAX_STEPS = 300
TINY = float(np.finfo(float).tiny)  # the first shift's floor (a zero band)


def smallest_eigenvalue(band: np.ndarray) -> float:
    """lambda_min of the symmetric matrix with LAPACK lower band storage band[k, j] = H[j + k, j]."""
    return smallest_eigenpair(band)[0]


@timed(LINEAR_ALGEBRA)
def smallest_eigenpair(band: np.ndarray) -> tuple[float, np.ndarray]:
    """(lambda_min, its unit eigenvector) of the symmetric matrix in lower band storage."""
    band = np.asarray(band, dtype=float)
    n = band.shape[1]
    if n == 0:
        raise ValueError("the matrix is empty")
    return _eigenpair(np.ascontiguousarray(band), start_vector(n))


@timed(LINEAR_ALGEBRA)
def scaled_block_eigenpair(band: np.ndarray, gather: tuple[np.ndarray, np.ndarray], size: int,
                           row_scale: np.ndarray, column_scale: np.ndarray) -> tuple[float, np.ndarray]:
    """``smallest_eigenpair`` of the principal block of ``band`` given by ``gather`` (band.principal_band:
    ``size`` rows) scaled to S B S: its band times row_scale times column_scale, entry by entry
    (R[k, j] = s[j + k], C[k, j] = s[j]). One compiled call (Problem.stability: the free DOFs'
    mass-normalized Hessian)."""
    target, source = gather
    return block_eigenpair(np.ascontiguousarray(band, dtype=float), target, source, size, row_scale, column_scale,
                           start_vector(size))


@numba.njit(cache=True)
def block_eigenpair(band, target, source, size, row_scale, column_scale, v0):  # pragma: no cover
    """``scaled_block_eigenpair`` from the start vector v0 (``start_vector(size)``), callable from
    compiled code."""
    rows = band.shape[0]
    flat, block = band.ravel(), np.zeros(rows * size)
    for k in range(target.size):
        block[target[k]] = flat[source[k]]
    return _eigenpair(block.reshape(rows, size) * row_scale * column_scale, v0)


@timed(LINEAR_ALGEBRA)
def projected_eigenpair(band: np.ndarray, support: np.ndarray, values: np.ndarray,
                        masses: np.ndarray) -> tuple[float, np.ndarray]:
    """(lambda, v) of the smallest eigenpair of B^T H B u = lambda B^T M B u, H the symmetric matrix
    of ``band`` (lower storage), M = diag(``masses``) and B the basis of ``projected_band`` (support,
    values: columns along H's rows), whose B^T M B must be diagonal (orthonormal tangents of
    isotropic vertex masses); v = B u with u^T B^T M B u = 1, on all of H's rows. One compiled call
    (Problem's stability on bodies)."""
    return _projected_eigenpair(np.ascontiguousarray(band, dtype=float), np.ascontiguousarray(support, dtype=np.int64),
                                np.ascontiguousarray(values, dtype=float), np.ascontiguousarray(masses, dtype=float),
                                start_vector(support.shape[0]))


@numba.njit(cache=True)
def _projected_eigenpair(band, support, values, masses, v0):  # pragma: no cover - compiled
    """``projected_eigenpair`` from the start vector v0 (``start_vector(m)``)."""
    m = support.shape[0]
    scale = np.empty(m)
    for a in range(m):  # the diagonal of B^T M B, as M^-1/2 on the columns
        mass = 0.0
        for t in range(3):
            if support[a, t] >= 0:
                mass += values[a, t] * masses[support[a, t]] * values[a, t]
        scale[a] = 1.0 / np.sqrt(mass)
    reduced = projected_band(band, support, values)
    for k in range(reduced.shape[0]):
        for a in range(m - k):
            reduced[k, a] = scale[a + k] * reduced[k, a] * scale[a]
    value, mode = _eigenpair(reduced, v0)
    v = np.zeros(band.shape[1])
    for a in range(m):
        for t in range(3):
            if support[a, t] >= 0:
                v[support[a, t]] += values[a, t] * (mode[a] * scale[a])
    return value, v


@numba.njit(cache=True)
def _eigenpair(band, v0):  # pragma: no cover - compiled
    """``smallest_eigenpair`` of a non-empty C-contiguous band from the start vector v0; NaN (value
    and vector) for a band with a non-finite entry, which no shift would make definite."""
    w1, n = band.shape
    largest = 0.0
    for k in range(w1):
        for j in range(n):
            if not np.isfinite(band[k, j]):
                return np.nan, np.full(n, np.nan)
            largest = max(largest, abs(band[k, j]))
    start = 1e-14 * largest + TINY
    shift = 0.0
    shifted = band.copy()
    factor = np.empty((n, w1))
    no_border, no_corner, free = np.zeros((0, n)), np.zeros((0, 0)), np.ones(n, dtype=np.bool_)
    while True:  # ends: a large shift makes it diagonally dominant
        for j in range(n):
            shifted[0, j] = band[0, j] + shift
        if factor_active(shifted, no_border, no_corner, free, factor, no_border, no_corner, np.int64(0), np.int64(0)):
            break
        shift = max(10.0 * shift, start)
    theta, vector = _largest_inverse_eigenpair(factor, v0, min(MAX_STEPS, n), TOLERANCE)
    return 1.0 / theta - shift, vector / np.sqrt(np.dot(vector, vector))


@functools.lru_cache(maxsize=16)
def start_vector(n: int) -> np.ndarray:
    """The fixed Lanczos start of size n (read-only; results are reproducible)."""
    v0 = np.random.default_rng(0).standard_normal(n)
    v0.flags.writeable = False
    return v0


@numba.njit(cache=True, inline="always")
def _largest_inverse_eigenpair(factor, v0, steps, tolerance):  # pragma: no cover - compiled
    """Largest eigenvalue of (L L^T)^-1 and its Ritz vector, by Lanczos with full reorthogonalization."""
    n = v0.size
    basis = np.empty((min(steps, 16) + 1, n))  # grown when Lanczos takes more steps
    alpha, beta = np.zeros(steps), np.zeros(steps)
    basis[0] = v0 / np.sqrt(np.dot(v0, v0))
    w = np.empty(n)
    theta = 0.0
    ritz = np.zeros(steps)
    last = 0
    for k in range(steps):
        plain_solve(factor, basis[k], w)
        alpha[k] = np.dot(w, basis[k])
        for _ in range(2):  # classical Gram-Schmidt against the basis, twice
            w -= np.dot(np.dot(basis[:k + 1], w), basis[:k + 1])
        beta[k] = np.sqrt(np.dot(w, w))
        tridiagonal = np.diag(alpha[:k + 1])
        for i in range(k):
            tridiagonal[i, i + 1] = tridiagonal[i + 1, i] = beta[i]
        values, vectors = np.linalg.eigh(tridiagonal)
        theta = values[k]
        ritz[:k + 1] = vectors[:, k]
        last = k
        if abs(beta[k] * vectors[k, k]) <= tolerance * abs(theta) or beta[k] == 0.0:
            break
        if k + 1 == basis.shape[0]:
            grown = np.empty((min(steps, 2 * k) + 1, n))
            grown[:k + 1] = basis
            basis = grown
        basis[k + 1] = w / beta[k]
    return theta, ritz[:last + 1] @ basis[:last + 1]
