"""Compilation and first-call loading never enter a solver's time.

A process's first solve compiles (first run) or loads (later runs) the C stencils, the numba kernels
and the solver's libraries: 144 s cold, ~1 s warm, against ~10 ms for a 50-vertex strand, and a batch
that booked it to its first strand made Ipopt look twice as fast as ours. So before the first timed
solve of a solver in a process, ``warm_up`` solves a small strand with the same solver and model
options, untimed: the batch runner does it in every process it solves in (a forked worker inherits
its parent's), ``sagfree.solve`` before its first call. What stays per strand size (building Ipopt's
instance for a new size) is the solver's own ``Result.setup_time``, kept out of ``Result.time``.
"""
from __future__ import annotations

import time
from functools import partial

import numpy as np

from sagfree.formulation.problem import Problem
from sagfree.formulation.strand import Strand

from .stabilize import solve_stabilized
from .table import solver_entry

#: (solver, model options) already warm in this process
_WARM: set = set()
#: the options that change what is compiled or loaded (the others only change numbers)
_MODEL_OPTIONS = ("curvature", "energies", "stiffness", "couple_twist", "optimize", "stabilize", "friction")


def _key(solver: str, problem_options: dict | None) -> tuple:
    return (solver, repr([(name, (problem_options or {}).get(name)) for name in _MODEL_OPTIONS]))


def is_warm(solver: str, problem_options: dict | None) -> bool:
    return _key(solver, problem_options) in _WARM


def announced_warm_up(solver: str, solver_options: dict | None = None, problem_options: dict | None = None,
                      progress: bool = True, strands=()) -> float:
    """``warm_up`` and ``prepare`` for ``strands``, saying on the screen (with ``progress``) what the
    wait is when it is noticeable; returns the seconds both took."""
    start = time.perf_counter()
    announce = progress and not is_warm(solver, problem_options)
    if announce:
        print(f"{solver}: loading the compiled model (compiling it on the first run only) ...", flush=True)
    warm_up(solver, solver_options, problem_options)
    prepare(solver, strands, solver_options, problem_options, progress)
    seconds = time.perf_counter() - start
    if announce or seconds > 1.0:
        print(f"{solver}: model ready in {seconds:.1f} s (not counted in any solver's time)", flush=True)
    return seconds


def prepare(solver: str, strands, solver_options: dict | None = None, problem_options: dict | None = None,
            progress: bool = False) -> None:
    """The solver's per-structure preparation (Solver.prepare: Ipopt's compiled instance) for the
    first strand of each size in ``strands``, in this process. Never raises (as warm_up)."""
    entry = solver_entry(solver)
    if entry.prepare is None:
        return
    options = {k: v for k, v in (solver_options or {}).items() if k != "p_start"}
    for n, strand in {s.n_vertices: s for s in reversed(list(strands))}.items():
        try:
            problem = Problem(strand, **(problem_options or {}))
            entry.prepare(problem, announce=partial(print, f"{solver}: building its model for {n}-vertex strands "
                                                   "(compiling it on the first run only) ...", flush=True)
                          if progress else None, **options)
        except Exception:  # noqa: BLE001 - the batch reports real errors
            pass


def warm_up(solver: str, solver_options: dict | None = None, problem_options: dict | None = None) -> float:
    """Solve a small strand with ``solver`` once per process and model options, untimed (module
    docstring); returns the seconds it took (0 if already warm). Never raises: a strand the real
    batch cannot solve reports its own error."""
    key = _key(solver, problem_options)
    if key in _WARM:
        return 0.0
    start = time.perf_counter()
    _WARM.add(key)
    model = {k: v for k, v in (problem_options or {}).items() if k in _MODEL_OPTIONS}
    x = np.linspace(0.0, 0.02, 8)
    try:
        problem = Problem(Strand(np.column_stack([x, 0.002 * np.sin(200 * x), 0.0 * x])), **model)
        entry = solver_entry(solver)
        options = {k: v for k, v in (solver_options or {}).items() if k != "p_start"}
        solve_stabilized(entry.function, problem, {**options, **entry.warm_options})
    except Exception:  # noqa: BLE001 - warming is best effort; the batch reports real errors
        pass
    return time.perf_counter() - start
