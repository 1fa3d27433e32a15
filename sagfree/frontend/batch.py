"""Many strands on all cores: ``sagfree.optimize`` and the forward check ``simulate_strands``
(DESIGN sections 5, 7 and 10).

Strands are independent, so the batch is split into contiguous chunks that worker processes solve
one strand at a time. Each strand's Problem is built inside the worker (a Problem holds compiled
libraries that do not cross process boundaries; a Strand is a few numpy arrays). Results come back
in input order and do not depend on the number of jobs: every strand is solved by the same
deterministic code from the same start.

A strand that fails (bad geometry, a solver error, a non-finite value) gets a Result with status
``failed`` and the error in its message; the other strands are unaffected.
"""
from __future__ import annotations

import contextlib
import gc
import multiprocessing
import os
import signal
import time
import traceback
import warnings
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from functools import partial

import numpy as np

from sagfree.contract.result import Result, failed_result
from sagfree.formulation.compiled import builds_paused
from sagfree.formulation.problem import Problem
from sagfree.formulation.simulation import SagCheck, sag_check
from sagfree.formulation.strand import Strand

from .options import check_options, check_problem_options
from .stabilize import solve_stabilized
from .table import solver_entry
from .warm import announced_warm_up, warm_check, warm_up

#: Seconds a strand may take before a batch on worker processes declares its chunk hung.
STRAND_TIMEOUT = 600.0


def solve_strand(strand: Strand, solver: str = "asc", solver_options: dict | None = None,
                 **problem_options) -> Result:
    """Build the Problem of one strand and solve it; never raises for a bad strand or a solver error
    (the options are checked once by ``optimize``, before the batch)."""
    start = time.perf_counter()
    try:
        problem = Problem(strand, **problem_options)
    except Exception as exc:  # noqa: BLE001 - reported in the Result, the batch goes on
        return failed_result(solver, f"invalid strand or options: {exc}", time=time.perf_counter() - start)
    try:
        return solve_stabilized(solver_entry(solver).function, problem, solver_options or {})
    except Exception as exc:  # noqa: BLE001
        detail = traceback.format_exception_only(type(exc), exc)[-1].strip()
        return failed_result(solver, f"{solver} raised {detail}", problem.n_parameters,
                             time.perf_counter() - start)


#: Seconds to wait for a process pool's manager thread after its workers were killed.
MANAGER_JOIN = 10.0
#: Largest chunk of strands sent to a worker at once (a 100-vertex strand takes ~10 ms).
MAX_CHUNK = 64


def chunk_starts(count: int, jobs: int) -> list[int]:
    """Boundaries of contiguous chunks of ``count`` items for ``jobs`` workers: guided scheduling,
    each chunk a quarter of the remaining items' share per worker (between 1 and MAX_CHUNK), so the
    first chunks amortize the transfer and the last ones are single strands that leave no worker
    idle while another finishes a long chunk (with equal chunks of 64, one core idled for up to a
    chunk's time at the end of a groom)."""
    starts, first = [0], 0
    while first < count:
        first += max(1, min(MAX_CHUNK, (count - first) // (4 * jobs)))
        starts.append(min(first, count))
    return starts


def _run_chunk(function, chunk, arguments) -> list:
    return [function(*item, *arguments) for item in chunk]


def map_strands(function, items: list[tuple], arguments: tuple = (), jobs: int | None = None,
                progress: bool = False, desc: str = "", on_crash=None, scheduler=None, on_chunk=None,
                strand_timeout: float = STRAND_TIMEOUT) -> list:
    """[function(*item, *arguments) for item in items] on ``jobs`` worker processes, in order.

    ``function`` must never raise for a bad strand (it returns a failed record instead);
    ``on_crash(message)`` makes the record of each item of a chunk whose worker died or hung.
    jobs: None = all cores, 1 = in this process. scheduler: None (local processes), "local" (a Dask
    LocalCluster of ``jobs`` workers), a Dask scheduler address or Client (cluster module). The items
    are cut into contiguous chunks, so results do not depend on the number of jobs nor on where they
    ran; ``on_chunk(first, results)`` is called in this process as each chunk finishes (checkpoints).
    strand_timeout: on worker processes, if no chunk finishes within strand_timeout x chunk size
    seconds, the running chunks are declared hung: their strands get on_crash records and the
    workers are killed (in this process, jobs = 1, there is no watchdog).
    """
    if jobs is not None and not (isinstance(jobs, (int, np.integer)) and jobs >= 1):
        raise ValueError(f"jobs must be None (all cores) or a number of processes >= 1, got {jobs!r}")
    jobs = (os.cpu_count() or 1) if jobs is None else int(jobs)
    starts = chunk_starts(len(items), jobs)
    chunks = [items[a:b] for a, b in zip(starts[:-1], starts[1:])]
    size = max((len(c) for c in chunks), default=1)
    bar = None
    if progress:
        from tqdm import tqdm
        where = "dask" if scheduler is not None else f"x{jobs}"
        bar = tqdm(total=len(items), desc=f"{desc} ({where})", unit="strand")

    def finished(k: int, results: list) -> None:
        if on_chunk is not None:
            on_chunk(starts[k], results)
        if bar is not None:
            bar.update(len(results))

    try:
        with _collector_spared():  # results pile up here: no full collection of this heap
            if scheduler is not None:
                from .cluster import run_chunks
                results = run_chunks(_run_chunk, function, chunks, arguments, scheduler, jobs, finished, on_crash,
                                     strand_timeout * size)
            elif jobs == 1 or len(chunks) <= 1:
                results = []
                for k, chunk in enumerate(chunks):
                    results.append(_run_chunk(function, chunk, arguments))
                    finished(k, results[-1])
            else:
                results = _run_on_processes(function, chunks, arguments, jobs, finished, on_crash,
                                            strand_timeout * size)
    finally:
        if bar is not None:
            bar.close()
    return [r for chunk_results in results for r in chunk_results]


@contextlib.contextmanager
def _collector_spared():
    """The objects this process holds now kept out of Python's cyclic garbage collector while the
    block runs (gc.freeze, undone after): a batch's Results pile up in this process, and the full
    collections they trigger scanned the whole heap of compiled modules, a core's time taken from
    the workers. Left alone where the caller froze objects itself."""
    if gc.get_freeze_count():
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def _run_on_processes(function, chunks, arguments, jobs, finished, on_crash, timeout) -> list[list]:
    context = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods()
                                          else "spawn")
    results: list[list] = [None] * len(chunks)  # type: ignore[list-item]
    pool = ProcessPoolExecutor(max_workers=min(jobs, len(chunks)), mp_context=context,
                               initializer=_start_worker)
    killed = True  # until every chunk came back: then the idle workers are joined, not abandoned
    try:
        pending = {pool.submit(_run_chunk, function, c, arguments): k for k, c in enumerate(chunks)}
        while pending:
            done, _ = wait(pending, timeout=timeout, return_when=FIRST_COMPLETED)
            if not done:  # nothing finished in time: the running chunks hang
                for future, k in pending.items():
                    results[k] = [on_crash(f"timed out: no chunk finished within {timeout:.0f} s")
                                  for _ in chunks[k]]
                    finished(k, results[k])
                _kill_workers(pool)
                break
            for future in done:
                k = pending.pop(future)
                try:
                    results[k] = future.result()
                except Exception as exc:  # noqa: BLE001 - a worker died: fail its strands only
                    results[k] = [on_crash(f"worker process failed: {exc}") for _ in chunks[k]]
                finished(k, results[k])
        else:
            killed = False
    except BaseException:  # Ctrl-C (or an error here): the workers must not go on without us
        _kill_workers(pool)
        raise
    finally:
        # idle workers are joined; killed ones are not waited for, but the pool's manager thread is
        # (it ends once it sees them dead): left running, it raced interpreter exit on its wakeup
        # pipe ("Exception ignored ... OSError: [Errno 9] Bad file descriptor" after a Ctrl-C)
        manager = getattr(pool, "_executor_manager_thread", None)
        pool.shutdown(wait=not killed, cancel_futures=True)
        if killed and manager is not None:
            manager.join(timeout=MANAGER_JOIN)
    return results


def _kill_workers(pool: ProcessPoolExecutor) -> None:
    """Kill the pool's worker processes and close this process's writing end of their result pipe.

    A worker killed while sending a chunk's results (a pickle larger than the pipe's 64 KiB buffer is
    sent in pieces) leaves a partial message on the pipe: the pool's manager thread then waits in
    recv() for bytes that never come, and interpreter exit, which joins that thread, hangs (a Ctrl-C
    that printed the resume command and never returned). With every writing end closed the read
    ends in EOF, and the manager thread marks the pool broken and ends. CPython's own clean-up
    (terminate_broken, gh-94777) unblocks only the call queue's writer."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.kill()
    writer = getattr(getattr(pool, "_result_queue", None), "_writer", None)
    if writer is not None:
        writer.close()


#: A worker's threshold of new container objects before Python's cyclic garbage collector runs
#: (default 700): the solves allocate many short-lived objects and make no reference cycles to speak
#: of, and at 700 the collector ran ~3000 times over a 1900-strand groom, 5% of the workers' time.
WORKER_GC_THRESHOLD = 50_000


def _start_worker() -> None:
    """A worker process leaves Ctrl-C to the parent, which stops it and keeps the finished chunks
    (one KeyboardInterrupt traceback per worker told the user nothing); the heap it inherited by
    fork is frozen out of the garbage collector (gc.freeze: never scanned, so the collector's writes
    do not copy the parent's pages), and the collector runs after WORKER_GC_THRESHOLD new objects."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    gc.freeze()
    gc.set_threshold(WORKER_GC_THRESHOLD, *gc.get_threshold()[1:])


def optimize(strands, solver: str = "asc", jobs: int | None = None, solver_options: dict | None = None,
             progress: bool = False, scheduler=None, on_chunk=None, strand_timeout: float = STRAND_TIMEOUT,
             **problem_options) -> list[Result]:
    """Solve every strand; returns one Result per strand, in order.

    jobs: worker processes (None = all cores, 1 = in this process; with "local", the LocalCluster's
    workers). scheduler: None, "local" or a Dask scheduler address / Client (cluster module).
    solver_options: the solver's options (e.g. ``tol``; contract.options), checked once before any
    strand is solved, like ``problem_options``: a misspelled name raises InvalidOption. on_chunk(first,
    results): called as each chunk of strands finishes (checkpoints; map_strands). strand_timeout:
    seconds a strand may take on worker processes before its chunk counts as hung. problem_options:
    keyword arguments of Problem (gravity, curvature, optimize, stiffness, couple_twist, bounds,
    weights).
    """
    strands = list(strands)
    # usage errors (unknown solver, missing plugin, misspelled option) are raised once, before any work
    solver_options = check_options(solver, solver_options)
    check_problem_options(problem_options)
    warn_thick_strands(strands)
    if strands:  # in this process, so that forked workers start warm; the screen says what the wait is
        announced_warm_up(solver, solver_options, problem_options, progress, strands)
    with builds_paused():  # a background compiler (formulation.compiled) never shares the cores with timing
        return map_strands(_solve, [(s,) for s in strands], (solver, solver_options, problem_options),
                           jobs, progress, solver, partial(failed_result, solver), scheduler, on_chunk,
                           strand_timeout)


def warn_thick_strands(strands) -> None:
    """One UserWarning naming the first strands whose radius exceeds one of their edge lengths.

    DER treats a strand as a thin rod; a radius of one to MAX_RADIUS_PER_EDGE edge lengths is still
    solved (a 2000-vertex hair is such a strand, 1.4 edge lengths) but the model is coarse there, and
    a groom of such strands is often a unit mix-up. Above that the Strand itself is refused."""
    thick = []
    for k, strand in enumerate(strands):
        if not isinstance(strand, Strand):
            continue  # solve_strand reports it
        edge, ratio = strand.thickness
        if ratio > 1.0:
            thick.append(f"strand {k} at edge {edge} ({ratio:.2g}x)")
    if thick:
        warnings.warn(f"{len(thick)} of {len(strands)} strands have a radius above an edge length "
                      f"({', '.join(thick[:3])}{', ...' if len(thick) > 3 else ''}): DER models thin rods, "
                      "so the model is coarse there; check the units of the radius, or resample the strands "
                      "with fewer vertices", UserWarning, stacklevel=3)


def _solve(strand, solver, solver_options, problem_options) -> Result:
    warm_up(solver, solver_options, problem_options)  # once per process, untimed (warm module)
    return solve_strand(strand, solver, solver_options, **problem_options)


def _check(strand, p, problem_options, steps, dt, damping, push) -> SagCheck:
    """sag_check of one strand; a strand without parameters or that fails gets a record saying why."""
    nan = float("nan")
    if p is None or not np.all(np.isfinite(p)):
        return SagCheck(nan, nan, nan, False, 0.0, 0.0, "no parameters (its optimization failed)")
    warm_check(problem_options)  # once per process, untimed (warm module); never raises
    start = time.perf_counter()
    try:
        return sag_check(Problem(strand, **problem_options), p, steps, dt, damping, push=push)
    except Exception as exc:  # noqa: BLE001 - reported per strand, the batch goes on
        detail = traceback.format_exception_only(type(exc), exc)[-1].strip()
        return SagCheck(nan, nan, nan, False, 0.0, time.perf_counter() - start, detail)


def simulate_strands(strands, parameters, steps: int = 200, dt: float = 1e-3, damping: float = 0.0,
                     jobs: int | None = None, progress: bool = False, scheduler=None, push: bool = True,
                     **problem_options) -> list[SagCheck]:
    """Forward-check every strand's parameters (formulation.simulation.sag_check) on all cores.

    parameters: one p per strand (None or NaN: not checked); push: also push each strand along its
    softest mode (push_check); jobs, scheduler and problem_options as for ``optimize``.
    """
    check_problem_options(problem_options)
    strands, parameters = list(strands), list(parameters)
    if len(strands) != len(parameters):
        raise ValueError(f"{len(strands)} strands but {len(parameters)} parameter vectors")
    nan = float("nan")
    warm_check(problem_options)  # here, so that forked workers inherit it
    return map_strands(_check, list(zip(strands, parameters)), (problem_options, steps, dt, damping, push),
                       jobs, progress, "simulate", partial(_unchecked, nan), scheduler)


def _unchecked(nan: float, message: str) -> SagCheck:
    return SagCheck(nan, nan, nan, False, 0.0, 0.0, message)
