"""Releasing the loaded entry kernels' LLVM IR (sagfree.kernel_memory) changes no result, releases only
kernels no other kernel calls, and finds calls through globals, module attributes and closures."""
import json
import subprocess
import sys
import types

import numba

from sagfree import kernel_memory


@numba.njit
def _leaf(x):
    return x + 1.0


_module = types.ModuleType("kernels")
_module.leaf = numba.njit(lambda x: 2.0 * x)


@numba.njit
def _through_global(x):
    return _leaf(x)


@numba.njit
def _through_module(x):
    return _module.leaf(x)


def _closure_kernel():
    inner = numba.njit(lambda x: x - 1.0)

    @numba.njit
    def outer(x):
        return inner(x)
    return outer, inner


def test_called_kernels_sees_globals_module_attributes_and_closures():
    outer, inner = _closure_kernel()
    kernels = [_leaf, _module.leaf, _through_global, _through_module, outer, inner]
    called = kernel_memory.called_kernels(kernels)
    assert called == {id(_leaf), id(_module.leaf), id(inner)}


_RELEASE_SCRIPT = r"""
import json
import sagfree.frontend.warm as warm
import sagfree
from sagfree import kernel_memory
from sagfree.scenes.groom import groom
from sagfree.solvers import confirmed_start, gauss_newton

warm.release_linking_ir = lambda: 0          # keep the IR through the warm-up: the reference solve
warm.warm_up("asc")
problems = [sagfree.Problem(strand) for strand in groom(3, 30, seed=2)]
before = [sagfree.solve(problem).p for problem in problems]
held = [k.__name__ for k in (confirmed_start._confirmed, gauss_newton._inner)
        if any(r.library._shared_module is not None for r in k.overloads.values())]
released = kernel_memory.release_linking_ir()
after = [sagfree.solve(problem).p for problem in problems]
left = [k.__name__ for k in (confirmed_start._confirmed, gauss_newton._inner)
        if any(r.library._shared_module is not None for r in k.overloads.values())]
print(json.dumps({"released": released, "held": held, "left": left,
                  "same": all(a.tobytes() == b.tobytes() for a, b in zip(before, after))}))
"""


def test_released_kernels_give_the_same_bits():
    """After the release the entry kernels run from their machine code alone, with the same results."""
    out = subprocess.run([sys.executable, "-c", _RELEASE_SCRIPT], capture_output=True, text=True, check=True)
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert report["held"] == ["_confirmed", "_inner"]
    assert report["released"] >= 2 and report["left"] == []
    assert report["same"]


_SCAN_SCRIPT = r"""
import json, importlib, pkgutil
import sagfree
from sagfree import kernel_memory
from sagfree.frontend.warm import warm_up

warm_up("asc")
kernels = kernel_memory.package_kernels("sagfree")
entries = {id(k): k for k in kernels if k.overloads}
entries = {i: k for i, k in entries.items() if i not in kernel_memory.called_kernels(kernels)}
for info in pkgutil.walk_packages(sagfree.__path__, "sagfree."):
    importlib.import_module(info.name)
everything = kernel_memory.package_kernels("sagfree")
called = kernel_memory.called_kernels(everything)
print(json.dumps({"entries": len(entries), "modules": len(everything),
                  "called": sorted(k.__name__ for i, k in entries.items() if i in called)}))
"""


def test_no_kernel_of_the_package_calls_an_entry_kernel_the_warm_up_releases():
    """The scan at the warm-up sees the modules imported by then; no kernel in any other module of the
    package (baselines, scenes, reports, ...) may call what it released, or that kernel's compile fails."""
    out = subprocess.run([sys.executable, "-c", _SCAN_SCRIPT], capture_output=True, text=True, check=True)
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert report["entries"] >= 10
    assert report["called"] == []
