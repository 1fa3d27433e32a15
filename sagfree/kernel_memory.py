"""The LLVM IR numba keeps for every loaded kernel, released where no later compile can need it.

A kernel numba loads from its cache keeps, next to its machine code, the LLVM IR of itself and of
every kernel it calls (``CPUCodeLibrary._shared_module``), parsed into memory, because a later compile
of a kernel that calls this one links that IR in. Parsed IR takes ~10x its bitcode: each entry kernel
that calls the model (the Gauss-Newton loop, the confirmed start, the stabilization's round) holds
12-17 MB of it per process, where its machine code takes 2-5 MB.

An *entry kernel* is one no other kernel of the package calls: Python calls it, nothing links it.
``release_linking_ir`` drops the IR of the loaded entry kernels; their machine code stays loaded
and runs as before. Callers are found by reading every kernel's code: the names it loads resolved
in its globals (directly, or as an attribute of a module it names) and its closure. A kernel the scan
missed as a callee would fail loudly (numba: "library unfit for linking") when a caller compiles,
never run wrong code. Kernels that others call keep their IR: a kernel compiled later (a solver's or
a body's, in place) may link them. The attribute is numba's private one; with a numba that lacks it
nothing is released.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import sys
import types

from numba.core.dispatcher import Dispatcher

#: the CPUCodeLibrary attribute holding a loaded kernel's IR for linking (numba's private name)
_LINKING_IR = "_shared_module"


def release_linking_ir(package: str = "sagfree") -> int:
    """Drop the parsed LLVM IR of every loaded overload of ``package``'s entry kernels (module
    docstring), and hand the freed heap back to the system; returns how many overloads released theirs."""
    kernels = package_kernels(package)
    called = called_kernels(kernels)
    released = 0
    for kernel in kernels:
        if id(kernel) in called:
            continue
        for result in list(kernel.overloads.values()):
            library = getattr(result, "library", None)
            if getattr(library, _LINKING_IR, None) is not None:
                setattr(library, _LINKING_IR, None)
                released += 1
    if released:
        _trim_heap()
    return released


def _trim_heap() -> None:
    """glibc's malloc_trim: LLVM frees the IR into the C heap, which keeps the pages resident until
    trimmed. Elsewhere (no malloc_trim) the pages are reused by later allocations instead."""
    name = ctypes.util.find_library("c")
    trim = getattr(ctypes.CDLL(name), "malloc_trim", None) if name else None
    if trim is not None:
        trim(0)


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


def called_kernels(kernels: list[Dispatcher]) -> set[int]:
    """ids of the dispatchers some kernel of ``kernels`` calls (module docstring's rule)."""
    called: set[int] = set()
    for kernel in kernels:
        function = kernel.py_func
        scope = function.__globals__
        for code in _code_objects(function.__code__):
            for name in code.co_names:
                value = scope.get(name)
                if isinstance(value, Dispatcher):
                    called.add(id(value))
                elif isinstance(value, types.ModuleType):
                    called.update(id(attribute) for attribute in
                                  (getattr(value, other, None) for other in code.co_names)
                                  if isinstance(attribute, Dispatcher))
        for cell in function.__closure__ or ():
            try:
                if isinstance(cell.cell_contents, Dispatcher):
                    called.add(id(cell.cell_contents))
            except ValueError:  # an empty cell
                continue
    return called


def _code_objects(code: types.CodeType):
    yield code
    for constant in code.co_consts:
        if isinstance(constant, types.CodeType):
            yield from _code_objects(constant)
