"""Products with a matrix J in compressed columns (indptr, indices, data), compiled: J x, J^T y and
the squared column norms (a strand's dc/dp, formulation.jacobian, and the compiled loops that take
its products without Python in between)."""
from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def csc_matvec(indptr, indices, data, x, rows):  # pragma: no cover - compiled
    """J x for J (rows x n) in compressed columns (indptr, indices, data)."""
    out = np.zeros(rows)
    for j in range(indptr.size - 1):
        xj = x[j]
        for k in range(indptr[j], indptr[j + 1]):
            out[indices[k]] += data[k] * xj
    return out


@numba.njit(cache=True)
def csc_rmatvec(indptr, indices, data, y):  # pragma: no cover - compiled
    """J^T y for J in compressed columns (indptr, indices, data)."""
    out = np.zeros(indptr.size - 1)
    for j in range(indptr.size - 1):
        s = 0.0
        for k in range(indptr[j], indptr[j + 1]):
            s += data[k] * y[indices[k]]
        out[j] = s
    return out


@numba.njit(cache=True)
def csc_column_norms(indptr, data):  # pragma: no cover - compiled
    """||J_{:,j}||^2 per column of J in compressed columns."""
    out = np.zeros(indptr.size - 1)
    for j in range(indptr.size - 1):
        s = 0.0
        for k in range(indptr[j], indptr[j + 1]):
            s += data[k] * data[k]
        out[j] = s
    return out
