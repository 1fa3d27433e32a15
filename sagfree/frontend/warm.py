"""Compilation and first-call loading never enter a solver's time.

A process's first solve compiles (first run) or loads (later runs) the C stencils, the numba kernels
and the solver's libraries: 144 s cold, ~1 s warm, against ~10 ms for a 50-vertex strand, and a batch
that booked it to its first strand made Ipopt look twice as fast as ours. So before the first timed
solve of a solver in a process, ``warm_up`` solves a small strand with the same solver and model
options, untimed: the batch runner does it in every process it solves in (a forked worker inherits
its parent's), ``sagfree.solve`` before its first call. What stays per strand size (building Ipopt's
instance for a new size) is the solver's own ``Result.setup_time``, kept out of ``Result.time``.
Strands resting on bodies run further compiled code (contact detection and forces, stability on the
bodies' tangent planes): with bodies, the warm-up strand rests on the first of them. A solver's
``warm_paths`` solve the strand again along paths its own solve skips (asc's compiled outer loop: the
warm-up strand, held by its root alone, starts at its optimum, and the first strand that needed a
Gauss-Newton step loaded the loop, ~90 ms, in its Result.time). What only rarer branches reach is
prepared on its own: the QPs' interior-point fallback, the constraints' curvature of Newton-SQP,
the infeasibility certificate, the stabilization's rounds (the warm-up strand is stable), the
many-right-hand-side band solve of the least sag (the warm-up strand is feasible), the search over
the reactions of a strand held at more points than its root (the warm-up strand is held by its root
alone). On a machine whose caches do not hold this code's kernels yet, the first warm-up runs once
in a child interpreter first (priming), so that the process that solves, and the workers it forks,
load the kernels instead of carrying a compile.
The forward check has its own (``warm_check``), which the batch's ``simulate_strands`` runs before
its first timed SagCheck. Each warm-up ends by releasing the parsed LLVM IR numba keeps for the
kernels it loaded (``sagfree.kernel_memory``): a third of what the warm-up adds to each process.
"""
from __future__ import annotations

import time
from functools import partial

import numpy as np

from sagfree.formulation.bodies import parse_body
from sagfree.formulation.problem import Problem
from sagfree.formulation.simulation import equilibrium, sag_check
from sagfree.formulation.strand import Strand
from sagfree.kernel_memory import release_linking_ir
from sagfree.linalg import cholesky
from sagfree.solvers import interior_point, reaction_start, sag_operator
from sagfree.solvers.alm import zero_counts
from sagfree.solvers.least_residual import least_residual
from sagfree.solvers.least_sag import compile_model, least_sag
from sagfree.solvers.statics_start import unbalanceable

from .priming import primed_in_child
from .stabilize import solve_stabilized, warm_floor_steps
from .table import solver_entry

#: (solver, model options) already warm in this process, and ("check", model options) for warm_check
_WARM: set = set()
#: the options that change what is compiled or loaded (the others only change numbers)
_MODEL_OPTIONS = ("curvature", "energies", "stiffness", "couple_twist", "optimize", "stabilize", "friction")


def _key(solver: str, problem_options: dict | None) -> tuple:
    options = problem_options or {}
    return (solver, repr([(name, options.get(name)) for name in _MODEL_OPTIONS]), bool(options.get("bodies")))


def _warm_strand(problem_options: dict) -> Problem:
    """A small strand (8 vertices, 2 cm) with the model options; with bodies, its middle vertex rests
    one radius above the first body's top (the surface point nearest to a point far above it)."""
    model = {k: v for k, v in problem_options.items() if k in _MODEL_OPTIONS}
    x = np.linspace(0.0, 0.02, 8)
    points = np.column_stack([x, 0.002 * np.sin(200 * x), 0.0 * x])
    if not problem_options.get("bodies"):
        return Problem(Strand(points), **model)
    body = parse_body(problem_options["bodies"][0])
    above = np.array([[0.0, 0.0, 100.0]])
    distance, normal, _ = body.evaluate(above)
    n = normal[0]
    top = above[0] - distance[0] * n
    along = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    along /= np.linalg.norm(along)
    strand = Strand(top + Strand(points).radius * n + np.outer(x - 0.01, along))
    return Problem(strand, bodies=[body], **{k: v for k, v in problem_options.items()
                                             if k in _MODEL_OPTIONS or k == "contact_distance"})


def is_warm(solver: str, problem_options: dict | None) -> bool:
    return _key(solver, problem_options) in _WARM


def announced_warm_up(solver: str, solver_options: dict | None = None, problem_options: dict | None = None,
                      progress: bool = True, strands=()) -> float:
    """``warm_up`` and ``prepare`` for ``strands``, saying on the screen (with ``progress``) what the
    wait is when it is noticeable; returns the seconds both took."""
    start = time.perf_counter()
    line_open = [False]  # a "... " line waiting for its "ready" (one line per solver when all is quick)

    def say(text: str) -> None:
        if progress:
            print(("\n" if line_open[0] else "") + text, end=" ", flush=True)
            line_open[0] = True

    if not is_warm(solver, problem_options):
        say(f"{solver}: loading the compiled model (compiling it on the first run only) ...")
    warm_up(solver, solver_options, problem_options)
    prepare(solver, strands, solver_options, problem_options, say)
    seconds = time.perf_counter() - start
    if line_open[0]:
        print(f"ready in {seconds:.1f} s (not counted in any solver's time)", flush=True)
    return seconds


def prepare(solver: str, strands, solver_options: dict | None = None, problem_options: dict | None = None,
            say=None) -> None:
    """The solver's per-structure preparation (Solver.prepare: Ipopt's compiled instance) for the
    first strand of each size in ``strands``, in this process; ``say(text)`` before a noticeable
    wait. Never raises (as warm_up)."""
    entry = solver_entry(solver)
    if entry.prepare is not None:
        for n, problem in _one_per_size(strands, problem_options):
            announce = partial(say, f"{solver}: building its model for {n}-vertex strands (compiling it on the "
                                    "first run only) ...") if say else None
            _quietly(entry.prepare, problem, announce=announce, **_structure_options(solver_options))


def precompile(solver: str, strands, solver_options: dict | None = None,
               problem_options: dict | None = None) -> None:
    """Start the solver's per-structure compilation (Solver.precompile) for the first strand of
    each size in ``strands`` in the background; ``prepare`` later waits for it. Never raises."""
    entry = solver_entry(solver)
    if entry.precompile is not None:
        for _, problem in _one_per_size(strands, problem_options):
            _quietly(entry.precompile, problem, **_structure_options(solver_options))


def _one_per_size(strands, problem_options: dict | None):
    """(n, Problem) of the first strand of each vertex count n (a strand the batch will reject is skipped)."""
    for n, strand in {s.n_vertices: s for s in reversed(list(strands))}.items():
        try:
            problem = Problem(strand, **(problem_options or {}))
        except Exception:  # noqa: BLE001 - the batch reports real errors
            continue
        yield n, problem


def _structure_options(solver_options: dict | None) -> dict:
    """The solver options that matter before a solve (a start point does not)."""
    return {k: v for k, v in (solver_options or {}).items() if k != "p_start"}


def _quietly(function, *args, **kwargs) -> None:
    """Preparation is best effort: the batch reports real errors."""
    try:
        function(*args, **kwargs)
    except Exception:  # noqa: BLE001
        pass


def warm_up(solver: str, solver_options: dict | None = None, problem_options: dict | None = None, *,
            paths: bool = True) -> float:
    """Solve a small strand with ``solver`` once per process and model options, untimed (module
    docstring); returns the seconds it took (0 if already warm). ``paths=False`` leaves out the
    solver's warm paths (priming's first child: its sibling runs them at the same time,
    ``warm_paths``). Never raises: a strand the real batch cannot solve reports its own error."""
    key = _key(solver, problem_options)
    if key in _WARM:
        return 0.0
    start = time.perf_counter()
    primed_in_child(solver, solver_options, problem_options)  # a machine's first compile: in a child (priming)
    _WARM.add(key)
    _quietly(interior_point.compile_kernels)
    _quietly(cholesky.compile_kernels)
    _quietly(sag_operator.compile_kernels)
    _quietly(reaction_start.compile_kernels)
    entry = solver_entry(solver)
    _quietly(_solve_warm_strand, entry, solver_options, problem_options or {}, paths)
    release_linking_ir()  # the loaded kernels' IR, which only compiles of their callers read
    return time.perf_counter() - start


def warm_paths(solver: str, solver_options: dict | None = None, problem_options: dict | None = None) -> None:
    """The warm-up strand solved along the solver's warm paths alone (SolverEntry.warm_paths), the
    part of ``warm_up`` that priming's second child runs while the first runs the rest: for asc
    the compiled outer loop, the largest group of kernels that nothing else calls; and every
    solver's best effort, the least sag's compiled loop (solvers.least_sag_loop; its model kernel,
    which the first child compiles first, loaded). Raises what the solve raises (the child's exit
    status is all that reads it)."""
    entry = solver_entry(solver)
    problem = _solved_along(entry, solver_options, problem_options or {}, entry.warm_paths)
    least_sag(problem, problem.p0, max_evaluations=2)


def warm_check(problem_options: dict | None = None) -> float:
    """The forward check (formulation.simulation.sag_check: time steps, static solve, push) run once
    per process and model options on the warm-up strand at p0, untimed, so that the first checked
    strand's SagCheck.time holds no kernel loading (the band factorizations and stencils: a third
    of a 100-vertex strand's check); returns the seconds it took (0 if already warm). Never
    raises: a strand the real check cannot run reports its own error."""
    key = _key("check", problem_options)
    if key in _WARM:
        return 0.0
    start = time.perf_counter()
    _WARM.add(key)
    _quietly(_check_warm_strand, problem_options or {})
    release_linking_ir()
    return time.perf_counter() - start


def _check_warm_strand(problem_options: dict) -> None:
    problem = _warm_strand(problem_options)
    sag_check(problem, problem.p0, steps=2)


def _solved_along(entry, solver_options: dict | None, problem_options: dict, paths) -> Problem:
    """The warm-up strand, solved with the entry's solver once per path (options over the warm-up's)."""
    problem = _warm_strand(problem_options)
    options = {**_structure_options(solver_options), **entry.warm_options}
    for path in paths:
        solve_stabilized(entry.function, problem, {**options, **path})
    return problem


def _solve_warm_strand(entry, solver_options: dict | None, problem_options: dict, paths: bool = True) -> None:
    """The warm-up strand solved (along the solver's warm paths too, with ``paths``), then its
    constraints' curvature evaluated once (asc's Newton-SQP, for held tips and long strands, builds
    those stencils on first use, inside the first such strand's Result.time otherwise), the
    infeasibility certificate checked (solvers.statics_start: only strands that fail their start
    reach it), a stabilization round taken from its optimum (the warm-up strand is stable, and
    the round's kernels, floor_steps, otherwise compile or load in the first stabilized strand of
    each worker of a batch), one Newton step of its static solve, one step of the least residual
    and, with ``paths``, two evaluations of the least sag (formulation.newton,
    solvers.least_residual, solvers.least_sag_loop: the best effort of an infeasible strand runs
    them, and would load them inside the first one's time). Without ``paths`` (priming's first
    child) the least sag's loop is left to the sibling child (``warm_paths``), and its model kernel
    is compiled here first, with the static solve it calls, so that the sibling loads both
    (frontend.priming balances the two children so)."""
    if not paths:  # first: the sibling child, compiling the least sag's loop, then finds its model kernel cached
        compile_model(_warm_strand(problem_options))
    problem = _solved_along(entry, solver_options, problem_options, ({}, *(entry.warm_paths if paths else ())))
    problem.constraint_hessian(problem.p0, np.zeros(problem.free_index.size))
    equilibrium(problem, problem.p0, max_steps=1)
    least_residual(problem, [problem.p0], zero_counts(), max_steps=1)
    if paths:
        least_sag(problem, problem.p0, max_evaluations=2)
    change = problem.remembered("least rest change")
    if change is not None:  # the infeasibility certificate's kernels (a feasible strand's solve skips it)
        unbalanceable(problem, change)
    if problem.stabilize:
        warm_floor_steps(problem)
