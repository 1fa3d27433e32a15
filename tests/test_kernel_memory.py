"""Releasing the loaded kernels' LLVM IR (sagfree.kernel_memory) changes no result, and a kernel
compiled afterwards still links the released ones."""
import json
import subprocess
import sys

_SCRIPT = r"""
import json
import numba
import numpy as np
import sagfree
import sagfree.frontend.warm as warm
from sagfree import kernel_memory
from sagfree.formulation.strand import _shortest_edge
from sagfree.scenes.groom import groom
from sagfree.solvers import confirmed_start, interior_point, outer_loop

def holding(kernels):
    return [k.__name__ for k in kernels if any(r.library._shared_module is not None for r in k.overloads.values())]

kernels = (confirmed_start.confirmed_kernel, outer_loop._outer, interior_point.interior_point, _shortest_edge)
warm.release_linking_ir = lambda: 0          # keep the IR through the warm-up: the reference solves
warm.warm_up("asc")
problems = [sagfree.Problem(strand) for strand in groom(3, 30, seed=2)]
before = [sagfree.solve(problem).p for problem in problems]
held = holding(kernels)
released = kernel_memory.release_linking_ir()
after = [sagfree.solve(problem).p for problem in problems]
left = holding(kernels)

@numba.njit
def caller(points):  # compiled now: links the released _shortest_edge (and its IR parsed back)
    edge, length = _shortest_edge(points)
    return edge + 2.0 * length

points = np.random.default_rng(0).random((12, 3))
edge, length = _shortest_edge(points)
print(json.dumps({"released": released, "held": held, "left": left, "linked": caller(points) == edge + 2.0 * length,
                  "same": all(a.tobytes() == b.tobytes() for a, b in zip(before, after))}))
"""


def test_released_kernels_give_the_same_bits_and_still_link(tmp_path):
    """After the release the kernels run from their machine code alone, with the same results, and
    a kernel compiled later that calls one of them links it (its IR parsed back from bitcode)."""
    # outside the checkout: there `import sagfree` would find the source folder, not the install
    run = subprocess.run([sys.executable, "-c", _SCRIPT], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads(run.stdout.strip().splitlines()[-1])
    assert report["held"] == ["confirmed_kernel", "_outer", "interior_point", "_shortest_edge"]
    assert report["released"] >= 10 and report["left"] == []
    assert report["same"] and report["linked"]
