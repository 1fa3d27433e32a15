"""Options checked once, before any strand is solved (``solve``, ``optimize``, the CLI, Dask alike).

A misspelled option must never silently change what runs, nor fail a thousand strands one by one:
an unknown name, or a common option with a value of the wrong kind, raises InvalidOption naming the
option, the solver and the options it accepts.
"""
from __future__ import annotations

import ast
import difflib
import inspect
import numbers

import numpy as np

from sagfree.contract.options import COMMON
from sagfree.formulation.parameters import check_user_bounds
from sagfree.formulation.problem import Problem

from .table import solver_entry


class InvalidOption(ValueError):
    """An option a solver (or the Problem) does not accept, or a value it cannot take."""


def _unknown(name: str, what: str, accepted) -> InvalidOption:
    close = difflib.get_close_matches(name, list(accepted), n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return InvalidOption(f"{what} has no option {name!r}{hint}; it accepts: {', '.join(accepted)}")


def check_options(solver: str, options: dict | None) -> dict:
    """``options`` if ``solver`` accepts every one of them, else InvalidOption (see module docstring)."""
    options = dict(options or {})
    accepted = solver_entry(solver).options
    for name, value in options.items():
        if name not in accepted:
            raise _unknown(name, f"solver {solver!r}", accepted)
        _check_common_value(solver, name, value)
    return options


def _check_common_value(solver: str, name: str, value) -> None:
    if name in ("tol", "kkt_tol", "max_seconds"):
        good = isinstance(value, numbers.Real) and not isinstance(value, bool) and value > 0
        kind = "a positive number"
    elif name == "max_iterations":
        good = isinstance(value, numbers.Integral) and not isinstance(value, bool) and value >= 0
        kind = "a non-negative integer"
    elif name == "p_start":
        good = value is None or np.ndim(value) == 1
        kind = "None or a 1-D array of parameters"
    else:
        return
    if not good:
        raise InvalidOption(f"solver {solver!r}: option {name!r} must be {kind} ({COMMON[name]}); "
                            f"got {value!r}")


def check_problem_options(problem_options: dict) -> dict:
    """``problem_options`` if Problem accepts every name, else InvalidOption listing what it accepts;
    also InvalidOption for ``bounds`` that no strand could take (parameters.check_user_bounds)."""
    accepted = list(inspect.signature(Problem).parameters)[1:]  # after the strand
    for name in problem_options:
        if name not in accepted:
            raise _unknown(name, "Problem", accepted)
    try:
        check_user_bounds(problem_options.get("bounds"))
    except ValueError as exc:
        raise InvalidOption(str(exc)) from None
    return dict(problem_options)


def parse_option(text: str, solver: str) -> tuple[str, object]:
    """(name, value) of a command-line ``NAME=VALUE``, the value typed like the option's default
    (a number, a string or True/False); InvalidOption for an unknown name or an unreadable value."""
    name, equals, raw = text.partition("=")
    name, raw = name.strip(), raw.strip()
    accepted = solver_entry(solver).options
    if not equals or not name:
        raise InvalidOption(f"an option is NAME=VALUE, got {text!r}")
    if name not in accepted:
        raise _unknown(name, f"solver {solver!r}", accepted)
    value = _typed(raw, accepted[name])
    if value is None and raw not in ("None", "none"):
        raise InvalidOption(f"option {name}: cannot read {raw!r} as a value like {accepted[name]!r}")
    _check_common_value(solver, name, value)
    return name, value


def _typed(raw: str, default):
    """raw read like ``default``: bool, int, float (also 'inf'), str; None if it cannot be."""
    if isinstance(default, bool):
        return {"true": True, "false": False}.get(raw.lower())
    if isinstance(default, str):
        return raw
    for kind in ((int, float) if isinstance(default, int) or default is None else (float,)):
        try:
            return kind(raw)
        except ValueError:
            pass
    if default is None:
        try:
            return ast.literal_eval(raw)
        except (ValueError, SyntaxError):
            return raw
    return None
