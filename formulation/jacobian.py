"""dc/dp of one strand: a fixed sparsity pattern and the products the solvers take of it.

Rows are the free DOFs and columns the parameters, both in strand order, so J is banded. Its
pattern never changes for a Problem; only the values do. ``JacobianPattern`` sums the stencils'
parameter Jacobians into the values of that pattern (compressed sparse column order), and
``StrandJacobian`` holds one set of values with the products a Gauss-Newton iteration needs, compiled
with numba: J x, J^T y, the squared column norms and the row-ordered (CSR) view that J^T J is
accumulated from (linalg.band.gram). A scipy matrix costs ~50 us per construction and the
products ~20 us each in Python overhead, about a third of a 100-vertex strand's model evaluation
per Gauss-Newton step; ``tocsc`` gives one where a sparse factorization needs it.
"""
from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp

from sagfree.linalg.compressed import csc_column_norms, csc_matvec, csc_rmatvec
from sagfree.linalg.identity import IdentityMemo

from .parameters import SlotMap


#: pattern structures by (shape, free rows, stencil DOFs, slots): the strands of a groom share a few
_STRUCTURES: dict = {}


#: the same structures by the identity of the index arrays (the strands of one size share the
#: arrays themselves: dofs' stencil indices, the free rows of _free_dofs, a layout structure's slot
#: indices); read-only arrays only, whose values cannot change under the same identity
_STRUCTURES_BY_ARRAYS = IdentityMemo()


def _structure(free_row, n_rows, n_parameters, stencils):
    """(target, source, CSC indices and indptr, CSR indptr, indices and order, (coefficient, DOF)
    of each source) of the pattern: value entry target[k] sums the flattened stencil Jacobian entry
    source[k], whose slot's coefficient is entry coefficient[k] of the stencil kinds' raveled
    coefficients and whose row is DOF dof[k] (JacobianPattern's scale). Compiled (_kind_entries,
    _compressed): a strand on a body has a pattern of its own (its contacts' columns), and numpy's
    unique and scipy's conversion took a third of its Problem's construction."""
    free_row = np.ascontiguousarray(free_row, dtype=np.int64)
    parts, offset, coefficient_offset = [], 0, 0
    for dof_index, slots in stencils:
        dof_index = np.ascontiguousarray(dof_index, dtype=np.int64)
        slot_index = np.ascontiguousarray(slots.index, dtype=np.int64)
        parts.append(_kind_entries(free_row, dof_index, slot_index, offset, coefficient_offset))
        offset += dof_index.size * slot_index.shape[1]
        coefficient_offset += slot_index.size
    rows, cols, sources, coefficients, dofs = (np.concatenate([part[k] for part in parts]) for k in range(5))
    return (*_compressed(rows, cols, n_rows, n_parameters, sources), (coefficients, dofs))


@numba.njit(cache=True)
def _kind_entries(free_row, dof_index, slot_index, offset, coefficient_offset):  # pragma: no cover - compiled
    """(row, column, source, coefficient, DOF) of one stencil kind's entries that land in J: every
    stencil s, DOF slot i with a free row and parameter slot a with a column, in (s, i, a) order;
    source = offset + the flat index of (s, i, a), coefficient = coefficient_offset + s * slots + a."""
    count, width = dof_index.shape
    slots = slot_index.shape[1]
    size = 0
    for s in range(count):
        linked = 0
        for a in range(slots):
            linked += slot_index[s, a] >= 0
        for i in range(width):
            size += linked if free_row[dof_index[s, i]] >= 0 else 0
    rows, cols, sources = np.empty(size, np.int64), np.empty(size, np.int64), np.empty(size, np.int64)
    coefficients, dofs = np.empty(size, np.int64), np.empty(size, np.int64)
    k = 0
    for s in range(count):
        for i in range(width):
            row = free_row[dof_index[s, i]]
            if row < 0:
                continue
            for a in range(slots):
                if slot_index[s, a] < 0:
                    continue
                rows[k], cols[k] = row, slot_index[s, a]
                sources[k] = offset + (s * width + i) * slots + a
                coefficients[k], dofs[k] = coefficient_offset + s * slots + a, dof_index[s, i]
                k += 1
    return rows, cols, sources, coefficients, dofs


@numba.njit(cache=True)
def _compressed(rows, cols, n_rows, n_parameters, sources):  # pragma: no cover - compiled
    """(target, source, CSC indices, indptr, CSR indptr, indices, order) of the entries (rows,
    cols), duplicates summed: target[k] is entry k's place among the distinct (column, row) pairs in
    column order (np.unique's inverse), and the CSR arrays list the same places row by row, columns
    ascending (scipy's tocsr with sorted indices). O(entries): a counting sort by column, then each
    column's few rows by insertion (a band's columns hold a dozen entries or so)."""
    entries = rows.size
    start = np.zeros(n_parameters + 1, np.int64)
    for k in range(entries):
        start[cols[k] + 1] += 1
    for j in range(n_parameters):
        start[j + 1] += start[j]
    by_column, filled = np.empty(entries, np.int64), start[:-1].copy()
    for k in range(entries):
        by_column[filled[cols[k]]] = k
        filled[cols[k]] += 1
    target, indices = np.empty(entries, np.int64), np.empty(entries, np.int64)
    indptr = np.zeros(n_parameters + 1, np.int64)
    size = 0
    for j in range(n_parameters):
        first, end = start[j], start[j + 1]
        for a in range(first + 1, end):  # insertion sort of the column's entries by row
            k = by_column[a]
            b = a
            while b > first and rows[by_column[b - 1]] > rows[k]:
                by_column[b] = by_column[b - 1]
                b -= 1
            by_column[b] = k
        last = -1
        for a in range(first, end):
            k = by_column[a]
            if rows[k] != last:
                last = rows[k]
                indices[size] = last
                size += 1
            target[k] = size - 1
        indptr[j + 1] = size
    indices = indices[:size]
    csr_indptr = np.zeros(n_rows + 1, np.int64)
    for u in range(size):
        csr_indptr[indices[u] + 1] += 1
    for r in range(n_rows):
        csr_indptr[r + 1] += csr_indptr[r]
    csr_indices, csr_order = np.empty(size, np.int64), np.empty(size, np.int64)
    filled = csr_indptr[:-1].copy()
    for j in range(n_parameters):  # column order: each row's columns come ascending
        for u in range(indptr[j], indptr[j + 1]):
            place = filled[indices[u]]
            csr_indices[place], csr_order[place] = j, u
            filled[indices[u]] += 1
    return target, sources, indices, indptr, csr_indptr, csr_indices, csr_order


class JacobianPattern:
    """Constant sparsity of dc/dp, with the scatter that sums stencil contributions into it.

    Entry k of the values is sum over its contributions s of scale_s * (stencil Jacobian)_s, where
    scale = -coefficient / D (the slot's parameter scaling over the row's force scale, see
    parameters.SlotMap and dofs.row_scales). The index structure depends only on the strand's size,
    root and parameter layout, so the strands of a groom share it (_STRUCTURES): building it took
    1.3 ms of the 2 ms a 100-vertex Problem cost.
    """

    def __init__(self, free_row: np.ndarray, row_scale: np.ndarray, n_rows: int, n_parameters: int,
                 stencils: list[tuple[np.ndarray, SlotMap]]):
        """free_row: row of each DOF in c (-1: prescribed). stencils: (DOF index (S, width), SlotMap)
        per stencil kind, in the order their Jacobians are passed to ``values``."""
        self.shape = (n_rows, n_parameters)
        arrays = (free_row, *(a for ix, slots in stencils for a in (ix, slots.index)))
        structure = _STRUCTURES_BY_ARRAYS.get(arrays, self.shape)
        if structure is None:
            key = (self.shape, *(a.tobytes() for a in arrays))
            structure = _STRUCTURES.get(key)
            if structure is None:
                structure = _structure(free_row, n_rows, n_parameters, stencils)
                if len(_STRUCTURES) >= 16:
                    _STRUCTURES.pop(next(iter(_STRUCTURES)))
                _STRUCTURES[key] = structure
            if not any(array.flags.writeable for array in arrays):
                _STRUCTURES_BY_ARRAYS.put(arrays, self.shape, structure)
        (self._target, self._source, self.indices, self.indptr, self.csr_indptr, self.csr_indices,
         self.csr_order, (coefficient, dof)) = structure
        # scale_k = coefficient / -D of source k's slot and row, gathered only where J has entries
        coefficients = np.concatenate([slots.coefficient.ravel() for _, slots in stencils])
        self._scale = _scales(coefficients, coefficient, dof, row_scale)

    def values(self, *stencil_jacobians: np.ndarray) -> np.ndarray:
        """CSC values of dc/dp from the stencil kinds' parameter Jacobians (in constructor order)."""
        target, source, scale, size = self.scatter_plan
        return scatter_values(target, source, scale, np.concatenate([j.ravel() for j in stencil_jacobians]), size)

    @property
    def scatter_plan(self) -> tuple:
        """(target, source, scale, size) of ``scatter_values`` on the stencils' raveled Jacobians
        (also called from at_rest's compiled evaluation)."""
        return self._target, self._source, self._scale, self.indices.size


class StrandJacobian:
    """dc/dp (free DOFs x parameters) as values on a JacobianPattern; ``J @ x``, ``J.T @ y``."""

    def __init__(self, pattern: JacobianPattern, data: np.ndarray):
        self.pattern, self.data, self.shape = pattern, data, pattern.shape

    def __matmul__(self, x: np.ndarray) -> np.ndarray:
        return csc_matvec(self.pattern.indptr, self.pattern.indices, self.data,
                          np.ascontiguousarray(x, dtype=float), self.shape[0])

    @property
    def T(self) -> "_Transposed":
        return _Transposed(self)

    def column_norms(self) -> np.ndarray:
        """||J_{:,j}||^2 per parameter."""
        return csc_column_norms(self.pattern.indptr, self.data)

    def csc(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(indptr, indices, data) in column order (the storage itself, no copy)."""
        return self.pattern.indptr, self.pattern.indices, self.data

    def csr(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(indptr, indices, data) of the same matrix in row order."""
        return self.pattern.csr_indptr, self.pattern.csr_indices, self.data[self.pattern.csr_order]

    def tocsc(self) -> sp.csc_matrix:
        return sp.csc_matrix((self.data.copy(), self.pattern.indices, self.pattern.indptr), shape=self.shape)


class _Transposed:
    """J^T of a StrandJacobian, for ``J.T @ y``."""

    def __init__(self, jacobian: StrandJacobian):
        self._jacobian = jacobian

    def __matmul__(self, y: np.ndarray) -> np.ndarray:
        J = self._jacobian
        return csc_rmatvec(J.pattern.indptr, J.pattern.indices, J.data, np.ascontiguousarray(y, dtype=float))


@numba.njit(cache=True)
def _scales(coefficients, coefficient, dof, row_scale):  # pragma: no cover - compiled
    """coefficients[coefficient] / -row_scale[dof] in one pass, the same bits (numpy takes four
    passes and three temporaries for it, once per Problem)."""
    scale = np.empty(coefficient.size)
    for k in range(coefficient.size):
        scale[k] = coefficients[coefficient[k]] / -row_scale[dof[k]]
    return scale


@numba.njit(cache=True)
def scatter_values(target, source, scale, entries, size):  # pragma: no cover - compiled
    """The pattern's values: value target[k] adds scale[k] * entries[source[k]] (JacobianPattern.scatter_plan)."""
    out = np.zeros(size)
    for k in range(target.size):
        out[target[k]] += scale[k] * entries[source[k]]
    return out
