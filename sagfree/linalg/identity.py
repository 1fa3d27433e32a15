"""Values remembered by the identity of the arrays they were computed from.

The strands of a groom share their index arrays (a Jacobian pattern's, the stencils' DOF indices),
so what depends only on those arrays' values (a saddle system's band order, a Jacobian's sparsity
structure) can be found by the arrays' ids instead of hashing their bytes (~15-20 us per lookup at
100 vertices). Each entry keeps weak references to its arrays: a hit needs the very same objects
alive, never an array that took a dead one's id. The caller must not change an array's values
under the same identity (read-only arrays, or arrays it owns).
"""
from __future__ import annotations

import weakref


class IdentityMemo:
    """value by (the identities of a tuple of arrays, a hashable ``extra``), the last ``limit``."""

    def __init__(self, limit: int = 16):
        self.limit, self._entries = limit, {}

    def get(self, arrays: tuple, extra=None):
        """The value remembered for these very arrays and ``extra``, or None."""
        known = self._entries.get((extra, *map(id, arrays)))
        if known is None or any(reference() is not array for reference, array in zip(known[0], arrays)):
            return None
        return known[1]

    def put(self, arrays: tuple, extra, value):
        """Remember ``value`` for these arrays and ``extra`` (the oldest entry goes beyond the limit);
        returns ``value``."""
        if len(self._entries) >= self.limit:
            self._entries.pop(next(iter(self._entries)))
        self._entries[(extra, *map(id, arrays))] = (tuple(map(weakref.ref, arrays)), value)
        return value
