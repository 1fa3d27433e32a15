"""Many strands on all cores: ``sagfree.optimize`` (DESIGN sections 5 and 10).

Strands are independent, so the batch is split into contiguous chunks that worker processes solve
one strand at a time. Each strand's Problem is built inside the worker (a Problem holds compiled
libraries that do not cross process boundaries; a Strand is a few numpy arrays). Results come back
in input order and do not depend on the number of jobs: every strand is solved by the same
deterministic code from the same start.

A strand that fails (bad geometry, a solver error, a non-finite value) gets a Result with status
``failed`` and the error in its message; the other strands are unaffected.
"""
from __future__ import annotations

import multiprocessing
import os
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed

from sagfree.formulation.problem import Problem
from sagfree.formulation.strand import Strand

from .registry import solver_function
from .result import Result, failed_result


def solve_strand(strand: Strand, solver: str = "asc", solver_options: dict | None = None,
                 **problem_options) -> Result:
    """Build the Problem of one strand and solve it; never raises for a bad strand or a solver error."""
    start = time.perf_counter()
    try:
        problem = Problem(strand, **problem_options)
    except Exception as exc:  # noqa: BLE001 - reported in the Result, the batch goes on
        return failed_result(solver, f"invalid strand or options: {exc}", time=time.perf_counter() - start)
    try:
        return solver_function(solver)(problem, **(solver_options or {}))
    except Exception as exc:  # noqa: BLE001
        detail = traceback.format_exception_only(type(exc), exc)[-1].strip()
        return failed_result(solver, f"{solver} raised {detail}", problem.n_parameters,
                             time.perf_counter() - start)


def _solve_chunk(strands, solver, solver_options, problem_options) -> list[Result]:
    return [solve_strand(s, solver, solver_options, **problem_options) for s in strands]


def optimize(strands, solver: str = "asc", jobs: int | None = None, solver_options: dict | None = None,
             progress: bool = False, **problem_options) -> list[Result]:
    """Solve every strand; returns one Result per strand, in order.

    jobs: worker processes (None = all cores, 1 = in this process). solver_options: keyword
    arguments of the solver function (e.g. ``tol``). problem_options: keyword arguments of Problem
    (gravity, curvature, optimize, stiffness, couple_twist, bounds, weights).
    """
    strands = list(strands)
    solver_function(solver)  # an unknown solver is a usage error, raised before any work
    jobs = (os.cpu_count() or 1) if jobs is None else max(1, int(jobs))
    if jobs == 1 or len(strands) <= 1:
        iterator = strands
        if progress:
            from tqdm import tqdm
            iterator = tqdm(strands, desc=f"{solver}", unit="strand")
        return [solve_strand(s, solver, solver_options, **problem_options) for s in iterator]
    # small chunks keep all workers busy to the end; several per worker amortize the transfer
    chunk = max(1, min(64, len(strands) // (4 * jobs)))
    chunks = [strands[i: i + chunk] for i in range(0, len(strands), chunk)]
    context = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods()
                                          else "spawn")
    results: list[list[Result]] = [None] * len(chunks)  # type: ignore[list-item]
    with ProcessPoolExecutor(max_workers=min(jobs, len(chunks)), mp_context=context) as pool:
        futures = {pool.submit(_solve_chunk, c, solver, solver_options, problem_options): k
                   for k, c in enumerate(chunks)}
        bar = None
        if progress:
            from tqdm import tqdm
            bar = tqdm(total=len(strands), desc=f"{solver} x{jobs}", unit="strand")
        for future in as_completed(futures):
            k = futures[future]
            try:
                results[k] = future.result()
            except Exception as exc:  # noqa: BLE001 - a worker died: fail its strands only
                results[k] = [failed_result(solver, f"worker process failed: {exc}") for _ in chunks[k]]
            if bar is not None:
                bar.update(len(chunks[k]))
        if bar is not None:
            bar.close()
    return [r for chunk_results in results for r in chunk_results]
