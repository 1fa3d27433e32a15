"""Compilation and first-call loading never enter a solver's time (frontend.warm)."""
import subprocess
import sys

import numpy as np
import pytest

import sagfree

FIRST_SOLVES = """
import json, sys
import numpy as np
import sagfree
strands = sagfree.scenes.groom(6, 30, seed=2)
results = sagfree.optimize(strands, solver=sys.argv[1], jobs=1)
print(json.dumps([r.time for r in results]))
"""


def _times_in_a_fresh_process(solver: str, directory) -> np.ndarray:
    # run outside the checkout: there `import sagfree` would find the source folder, not the install
    run = subprocess.run([sys.executable, "-c", FIRST_SOLVES, solver], capture_output=True, text=True, timeout=600,
                         cwd=directory)
    assert run.returncode == 0, run.stderr[-2000:]
    return np.array(__import__("json").loads(run.stdout.strip().splitlines()[-1]))


def test_a_fresh_process_first_solve_is_not_an_outlier(tmp_path):
    """In a new process the first strand used to carry the loading of every compiled kernel (~1 s
    warm, minutes cold) against ~10 ms per solve."""
    for solver in ("asc", "ipopt"):
        times = _times_in_a_fresh_process(solver, tmp_path)
        assert times[0] < 10 * np.median(times[1:]), (solver, times)


def test_ipopt_instance_build_is_setup_not_solve_time():
    strand = sagfree.scenes.groom(1, 37, seed=5)[0]   # a size no other test builds
    first = sagfree.solve(sagfree.Problem(strand, stabilize=False), "ipopt")
    again = sagfree.solve(sagfree.Problem(strand, stabilize=False), "ipopt")
    assert first.setup_time > 0 and again.setup_time < first.setup_time
    assert first.time < 10 * again.time


def test_a_kernel_compiled_during_a_solve_is_setup_not_solve_time(monkeypatch):
    """A numba kernel compiled in the middle of a solve (a branch the warm-up did not run) moves
    from Result.time to Result.setup_time."""
    import time

    import numba
    import numpy as np

    import sagfree
    from sagfree.solvers import alm

    problem = sagfree.Problem(sagfree.scenes.horizontal(12))
    sagfree.solve(problem)  # warm

    @numba.njit  # not cached: compiles on the first call, inside the solve
    def fresh(x):
        return x.sum() * 0.0

    original = alm.kkt_optimality  # every converged asc solve confirms its point by it (on the
    monkeypatch.setattr(alm, "confirmed_start", lambda *args: None)  # Python path, from here)
    calls = []

    def compiling_check(*args, **kwargs):
        if not calls:
            fresh(np.ones(3))
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(alm, "kkt_optimality", compiling_check)
    start = time.perf_counter()
    result = sagfree.solve(problem)
    wall = time.perf_counter() - start
    assert calls and result.setup_time > 0.05            # numba took its time compiling `fresh`
    assert result.time < wall - result.setup_time + 1e-3  # ... and it is not in the solve's time
    assert sum(result.time_split.values()) == pytest.approx(result.time, rel=1e-6)
    assert result.time_split["linear_algebra"] >= 0


WARMED_RARE_BRANCHES = """
import sagfree
from sagfree.formulation.newton import newton_kernel
from sagfree.formulation.stencils import parameter_hessians
from sagfree.frontend.floor_steps import _checked_floors, _stabilization_rounds
from sagfree.frontend.warm import warm_up
from sagfree.linalg.cholesky import solve_rows
from sagfree.solvers.interior_point import interior_point
from sagfree.solvers.sag_operator import cgls as _cgls
from sagfree.solvers.least_sag_loop import least_sag_loop
from sagfree.solvers.reaction_start import least_over_reactions
from sagfree.linalg.square import square_solutions
warm_up("asc")
print(len(interior_point.signatures), parameter_hessians.cache_info().currsize, len(_checked_floors.signatures),
      len(_stabilization_rounds.signatures), len(solve_rows.signatures), len(newton_kernel.signatures),
      len(_cgls.signatures), len(least_over_reactions.signatures), len(square_solutions.signatures),
      len(least_sag_loop.signatures))
"""


def test_the_warm_up_prepares_what_rare_branches_run(tmp_path):
    """No warm-up strand walks an active set or needs Newton-SQP, so the QPs' interior-point
    fallback and the constraints' curvature stencils were built inside timed solves, and the
    warm-up strand is stable, so the stabilization round's kernel (floor_steps) was compiled by
    every worker of a batch, and so was the compiled loop of rounds, and the warm-up strand is feasible,
    so the least sag's many-right-hand-side solve, its static solves' compiled Newton, its
    trust region's Gauss-Newton direction and its compiled loop were loaded by the first infeasible
    strand, and the
    warm-up strand is held by its root alone, so the search over a held strand's reactions and its
    band solves were loaded by the first strand with a pinned tip: in a fresh process the warm-up
    has all ten ready."""
    run = subprocess.run([sys.executable, "-c", WARMED_RARE_BRANCHES], capture_output=True, text=True,
                         timeout=600, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    counts = list(map(int, run.stdout.strip().splitlines()[-1].split()))
    assert len(counts) == 10 and min(counts) >= 1, counts


FIRST_CHECKS = """
import json
import numba.core.dispatcher as dispatcher
import sagfree
from sagfree.formulation import compiled
from sagfree.frontend import batch
strands = sagfree.scenes.groom(2, 30, seed=2)
parameters = [result.p for result in sagfree.optimize(strands, jobs=1)]
loads, during = [], []
for owner, name in ((dispatcher.Dispatcher, "compile"), (compiled, "compile_library")):
    def counting(*args, _original=getattr(owner, name), _name=name):
        loads.append(_name)
        return _original(*args)
    setattr(owner, name, counting)
timed = batch.sag_check
def check(*args, **kwargs):
    before = len(loads)
    result = timed(*args, **kwargs)
    during.append(loads[before:])
    return result
batch.sag_check = check
checks = sagfree.frontend.batch.simulate_strands(strands, parameters, jobs=1)
print(json.dumps({"during": during, "warm": len(loads), "held": [c.holds for c in checks]}))
"""


def test_the_first_forward_check_loads_nothing_in_its_time(tmp_path):
    """The first strand's SagCheck.time held the loading of the check's kernels (band
    factorizations, stencils; a third of a 100-vertex check): warm_check runs before, untimed."""
    run = subprocess.run([sys.executable, "-c", FIRST_CHECKS], capture_output=True, text=True, timeout=600,
                         cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    report = __import__("json").loads(run.stdout.strip().splitlines()[-1])
    assert report["during"] == [[], []] and report["warm"] >= 1 and report["held"] == [True, True]


NOTHING_AFTER_THE_WARM_UP = """
import json
import numba.core.dispatcher as dispatcher
import sagfree
from sagfree.formulation import compiled
from sagfree.frontend import warm
from sagfree.scenes.head import HEAD, head_groom
batches = [(sagfree.scenes.groom(400, 100, seed=0), {}),
           ([sagfree.Strand(s.points, tip="pinned") for s in sagfree.scenes.groom(30, 100, seed=1)], {}),
           (head_groom(40, 100, seed=0), {"bodies": [HEAD]})]
for _, options in batches:
    warm.warm_up("asc", problem_options=options)
loads = []
for owner, name in ((dispatcher.Dispatcher, "compile"), (compiled, "compile_library")):
    def counting(*args, _original=getattr(owner, name), _name=name):
        loads.append(_name)
        return _original(*args)
    setattr(owner, name, counting)
during, converged = [], []
for strands, options in batches:
    before = len(loads)
    results = sagfree.optimize(strands, jobs=1, **options)
    during.append(len(loads) - before)
    converged.append(sum(r.status == "converged" for r in results) == len(strands))
print(json.dumps({"during": during, "converged": converged}))
"""


def test_nothing_compiles_or_loads_after_the_warm_up(tmp_path):
    """After the warm-up a batch compiles or loads no kernel: on a groom (whose stabilization
    re-solves reach the infeasibility certificate), on strands with a pinned tip (whose
    stabilization takes its Python steps) and on a head. Each of those loaded kernels inside a
    timed solve before the warm-up ran their paths."""
    run = subprocess.run([sys.executable, "-c", NOTHING_AFTER_THE_WARM_UP], capture_output=True, text=True,
                         timeout=600, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    report = __import__("json").loads(run.stdout.strip().splitlines()[-1])
    assert report["during"] == [0, 0, 0] and report["converged"] == [True, True, True]
