"""Where a solve's time goes: seconds spent evaluating the model and in linear algebra, per process.

A solver comparison that reports only totals cannot tell a faster algorithm from a faster model
evaluation (issue: Ipopt once evaluated the model in CasADi's virtual machine while ours ran compiled
C). So the Problem's evaluation methods count as ``model`` and the solvers' QP / factorization calls
as ``linear_algebra``; ``frontend.stabilize`` reads the counters around a whole solve and stores
the split in ``Result.time_split`` (the rest of ``Result.time`` is ``other``: the solver's own
iteration logic, line searches, Python). Ipopt adds the evaluation times CasADi measures for it.

Nested timed calls count once, in the outermost category (a Jacobian evaluated inside a timed QP
is linear algebra). One strand is solved at a time per process, so plain module counters suffice.

Numba compiles a kernel the first time a branch runs it (cached on disk afterwards): a cold run's
first strand through the interior-point fallback paid 7 s for it. Numba announces each compilation
(its ``numba:compile`` event); the seconds go to ``compile``, out of the category they interrupted,
and the front end moves them from ``Result.time`` to ``Result.setup_time``.

Compiled loops time their own parts (solvers.gauss_newton) with ``clock_seconds``, the monotonic
clock of time.perf_counter read through the C library's clock_gettime, and ``add`` the sums.
"""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import time

import numba
import numba.core.event
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

MODEL, LINEAR_ALGEBRA, COMPILE = "model", "linear_algebra", "compile"
CATEGORIES = (MODEL, LINEAR_ALGEBRA)

_seconds = {MODEL: 0.0, LINEAR_ALGEBRA: 0.0, COMPILE: 0.0}
_depth = 0
_active: str | None = None  # the category being timed, if any
_paused = 0                 # inside ``uncounted``: not part of any solve's time


class _CompileListener(numba.core.event.Listener):
    """Adds the seconds of each outermost numba compilation to COMPILE (module docstring)."""

    def __init__(self):
        self.depth, self.start = 0, 0.0

    def on_start(self, event):
        if self.depth == 0:
            self.start = time.perf_counter()
        self.depth += 1

    def on_end(self, event):
        self.depth -= 1
        if self.depth == 0 and not _paused:
            seconds = time.perf_counter() - self.start
            _seconds[COMPILE] += seconds
            if _active is not None:
                _seconds[_active] -= seconds


numba.core.event.register("numba:compile", _CompileListener())


def timed(category: str):
    """Decorator: the wrapped function's wall time counts in ``category`` (outermost call only)."""
    if category not in CATEGORIES:
        raise ValueError(f"unknown timing category {category!r}; choose from {CATEGORIES}")

    def decorate(function):
        @functools.wraps(function)
        def wrapper(*args, **kwargs):
            global _depth, _active
            if _depth:
                return function(*args, **kwargs)
            _depth, _active = 1, category
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                _depth, _active = 0, None
                _seconds[category] += time.perf_counter() - start
        return wrapper
    return decorate


@contextlib.contextmanager
def uncounted():
    """Nothing inside counts in any category (measuring a solution after its time was taken)."""
    global _depth, _paused
    _depth += 1
    _paused += 1
    try:
        yield
    finally:
        _depth -= 1
        _paused -= 1


def add(category: str, seconds: float) -> None:
    """Count ``seconds`` measured elsewhere (e.g. by CasADi for Ipopt's evaluations) in ``category``."""
    _seconds[category] += float(seconds)


def snapshot() -> dict[str, float]:
    return dict(_seconds)


def compiled_since(mark: dict[str, float]) -> float:
    """Seconds numba spent compiling since ``mark`` (a ``snapshot``)."""
    return _seconds[COMPILE] - mark[COMPILE]


def split_since(mark: dict[str, float], total: float) -> dict[str, float]:
    """{model, linear_algebra, other} seconds of a solve that took ``total`` s since ``mark``
    (a ``snapshot``); other = total minus the two, never below 0."""
    spent = {name: _seconds[name] - mark[name] for name in CATEGORIES}
    return {**spent, "other": max(0.0, total - sum(spent.values()))}


def _monotonic_clock() -> tuple[int, int] | None:
    """(address of the C library's clock_gettime, time.CLOCK_MONOTONIC), or None without one."""
    try:
        function = ctypes.CDLL(ctypes.util.find_library("c") or None).clock_gettime
        return int(ctypes.cast(function, ctypes.c_void_p).value), time.CLOCK_MONOTONIC
    except (OSError, AttributeError, TypeError):  # no C library by that name, or no clock_gettime
        return None


#: what ``clock_seconds`` reads in compiled code: (clock_gettime's address, clock id), or None
CLOCK = _monotonic_clock()


def clock_offset() -> float:
    """time.perf_counter() minus ``clock_seconds``'s reading now: a perf_counter deadline plus the
    negated offset is a deadline on the compiled clock."""
    return time.perf_counter() - time.clock_gettime(CLOCK[1])


@intrinsic
def _clock_gettime(typing_context, address, clock_id, timespec):
    """clock_gettime(clock_id, timespec) through the function at the integer ``address``."""
    if not all(isinstance(t, types.Integer) for t in (address, clock_id, timespec)):
        return None

    def codegen(context, builder, signature, args):
        function_type = ir.FunctionType(ir.IntType(32), [ir.IntType(32), ir.IntType(8).as_pointer()])
        function = builder.inttoptr(args[0], function_type.as_pointer())
        clock = context.cast(builder, args[1], signature.args[1], types.int32)
        return builder.call(function, [clock, builder.inttoptr(args[2], ir.IntType(8).as_pointer())])

    return types.int32(address, clock_id, timespec), codegen


@numba.njit(cache=True)
def clock_seconds(address, clock_id, timespec):  # pragma: no cover - compiled
    """Seconds on the monotonic clock ``CLOCK`` (address, id), read from compiled code (timespec: an
    int64 array of 2, overwritten)."""
    _clock_gettime(address, clock_id, timespec.ctypes.data)
    return timespec[0] + 1e-9 * timespec[1]
