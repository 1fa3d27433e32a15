"""The LLVM IR numba keeps in memory for every loaded kernel, kept as bitcode instead.

A kernel numba loads from its cache keeps, next to its machine code, the LLVM IR of itself and of
every kernel it calls (``CPUCodeLibrary._shared_module``), parsed into memory, because a later compile
of a kernel that calls this one links that IR in. Parsed IR takes ~10x its bitcode: a kernel that
calls the model (the Gauss-Newton loop, the confirmed start, the stabilization's rounds) held several
times its machine code in it, in every process, for compiles that after a warm-up rarely come.

``release_linking_ir`` replaces each loaded kernel's parsed IR by its bitcode bytes and hands the
kernel a ``_get_module_for_linking`` that parses them again, for the compile that links it. Its
machine code stays loaded and runs as before; a compile that links it gets the same IR. The two
attributes are numba's private ones; with a numba that lacks them nothing is released.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
import sys

from llvmlite import binding as llvm
from numba.core.compiler_lock import global_compiler_lock
from numba.core.dispatcher import Dispatcher

#: numba's CPUCodeLibrary attribute holding a loaded kernel's IR for linking, and its method returning it
_LINKING_IR, _LINKING_METHOD = "_shared_module", "_get_module_for_linking"


def release_linking_ir(package: str = "sagfree") -> int:
    """Keep the linking IR of every loaded overload of ``package``'s kernels as bitcode (module
    docstring), and hand the freed heap back to the system; returns how many overloads released theirs.
    Under numba's compiler lock: no compile in another thread links a library while it changes."""
    with global_compiler_lock:
        released = sum(_released(result.library) for kernel in package_kernels(package)
                       for result in list(kernel.overloads.values()) if hasattr(result, "library"))
    if released:
        _trim_heap()
    return released


def _released(library) -> bool:
    """Whether ``library``'s parsed linking IR was there and is now kept as bitcode."""
    module = getattr(library, _LINKING_IR, None)
    if module is None or not hasattr(library, _LINKING_METHOD):
        return False
    setattr(library, _LINKING_METHOD, functools.partial(_parsed, module.as_bitcode()))
    setattr(library, _LINKING_IR, None)
    return True


def _parsed(bitcode: bytes):
    """A released kernel's linking IR, parsed again (linking clones it: the caller keeps no reference)."""
    return llvm.parse_bitcode(bitcode)


def package_kernels(package: str) -> list[Dispatcher]:
    """The numba dispatchers bound to module-level names of ``package``'s imported modules."""
    found: dict[int, Dispatcher] = {}
    for name, module in list(sys.modules.items()):
        if module is None or (name != package and not name.startswith(package + ".")):
            continue
        for value in list(vars(module).values()):
            if isinstance(value, Dispatcher):
                found[id(value)] = value
    return list(found.values())


def _trim_heap() -> None:
    """glibc's malloc_trim: LLVM frees the IR into the C heap, which keeps the pages resident until
    trimmed. Elsewhere (no malloc_trim) the pages are reused by later allocations instead."""
    name = ctypes.util.find_library("c")
    trim = getattr(ctypes.CDLL(name), "malloc_trim", None) if name else None
    if trim is not None:
        trim(0)
