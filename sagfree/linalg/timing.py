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
"""
from __future__ import annotations

import contextlib
import functools
import time

import numba.core.event

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
