"""numpy's pairwise summation in compiled code, bit for bit.

np.sum of a float array is not a running sum: numpy adds blocks of up to 128 entries with eight
running sums and halves longer ranges, so a compiled loop that sums the same entries in order
gives other last bits. Compiled kernels that replace a numpy computation and must give its numbers
exactly (asc's merit, solvers.gauss_newton; the stabilization's floor step, frontend.floor_steps;
the strand multiplier's stiffening gradient, formulation.at_rest) sum with ``pairwise_sum``.
"""
from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def _block_sum(a, start, n):  # pragma: no cover - compiled
    """numpy's pairwise sum of a block of at most 128 entries: eight running sums, then the rest."""
    if n < 8:
        total = 0.0
        for i in range(start, start + n):
            total += a[i]
        return total
    r0, r1, r2, r3 = a[start], a[start + 1], a[start + 2], a[start + 3]
    r4, r5, r6, r7 = a[start + 4], a[start + 5], a[start + 6], a[start + 7]
    i = 8
    while i < n - n % 8:
        r0 += a[start + i]
        r1 += a[start + i + 1]
        r2 += a[start + i + 2]
        r3 += a[start + i + 3]
        r4 += a[start + i + 4]
        r5 += a[start + i + 5]
        r6 += a[start + i + 6]
        r7 += a[start + i + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        total += a[start + i]
        i += 1
    return total


@numba.njit(cache=True)
def pairwise_sum(a):  # pragma: no cover - compiled
    """np.sum of a contiguous float array, bit for bit: numpy halves a range of more than 128 entries
    (at a multiple of 8) and adds the halves' sums. Its recursion is unrolled onto a stack here (a
    cached numba function that calls a recursive one crashed when loaded from the cache)."""
    starts, sizes, stages = np.empty(64, dtype=np.int64), np.empty(64, dtype=np.int64), np.empty(64, dtype=np.int64)
    lefts = np.empty(64)
    starts[0], sizes[0], stages[0] = 0, a.size, 0
    top, total = 0, 0.0
    while top >= 0:
        start, size = starts[top], sizes[top]
        half = size // 2 - (size // 2) % 8
        if size <= 128 or stages[top] == 2:
            value = _block_sum(a, start, size) if size <= 128 else lefts[top] + total
            top -= 1
            if top >= 0 and stages[top] == 1:  # a left half: keep it, go on with the right one
                lefts[top], stages[top] = value, 2
                top += 1
                parent_half = sizes[top - 1] // 2 - (sizes[top - 1] // 2) % 8
                starts[top], sizes[top], stages[top] = starts[top - 1] + parent_half, sizes[top - 1] - parent_half, 0
            else:  # a right half (its parent adds it next) or the whole range
                total = value
        else:  # first visit: the left half
            stages[top] = 1
            top += 1
            starts[top], sizes[top], stages[top] = start, half, 0
    return total
