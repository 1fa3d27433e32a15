"""One Result type for every solver (DESIGN sections 5, 6, 10), in the manner of scipy's OptimizeResult.

Every solver (``asc``, the baselines, ``naive``) ends in ``make_result``, which measures the outcome on
the Problem itself, so a report never needs to know which solver produced a row: |c|_inf recomputed
from ``problem.residual``, the largest residual force on a free vertex (N), R(p*), the stiffening and
rest-shape change summaries, and the stability of the rest state.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numba
import numpy as np

from sagfree.formulation import dofs
from sagfree.formulation.parameters import REST_BLOCKS, STIFFNESS_BLOCKS, STRAND_BLOCK
from sagfree.formulation.problem import Problem
from sagfree.formulation.simulation import Equilibrium
from sagfree.linalg import timing
from sagfree.linalg.pairwise import pairwise_sum

#: converged: |c|_inf <= tol and KKT distance <= kkt_tol; infeasible: no point of the box balances
#: the load; max_iterations: stopped at a limit (max_iterations, max_seconds or a solver's own);
#: failed: anything else (the message says what).
STATUSES = ("converged", "infeasible", "max_iterations", "failed")
#: A multiplier above this counts as stiffened (DESIGN section 8).
STIFFENED = 1.01


@dataclass
class Result:
    """Outcome of one solver on one strand.

    p: normalized parameters (Problem layout); status: converged | infeasible | max_iterations | failed;
    iterations: counts by name (per solver; ours: outer, gauss_newton, cg, expansion, proportioning,
    active_set = primal-dual active-set steps before MPRGP, interior = interior-point iterations of its
    fallback, factorizations, factored_rows = band rows the (partial) refactorizations recomputed,
    line_search, tightened); residual_inf: |c(p)|_inf (unit-free); max_force: largest residual force on a
    free vertex (N); objective: R(p); stiffening: per stiffness block {max, mean, stiffened} (ratio to the
    specified stiffness, share of elements above 1.01); rest_change: per rest block {max, mean} absolute
    change from p0 and {box} the largest change over the box half-width; time (s); min_eigenvalue: the
    mass-normalized smallest eigenvalue of the free-DOF Hessian at q* (Problem.stability: omega^2 of
    the slowest mode, s^-2), for an ``infeasible`` strand at the static equilibrium where it rests,
    and stable = min_eigenvalue > 0; history: |c|_inf after each primal step;
    physical: the parameters in physical units (Problem.physical: rest lengths m, rest curvatures, rest
    twists rad, moduli Pa); floors: the lower bounds of the problem p solves when the stabilization
    raised stiffness floors (frontend.stabilize; ``problem.with_lower_bounds(floors)`` is that
    problem), else None; static_sag: for an ``infeasible`` strand, the static sag of p over L (the
    largest vertex displacement of the equilibrium q* relaxes into, formulation.simulation.equilibrium;
    NaN otherwise); contact_forces: (n, 3) the bodies' push on each vertex at q* (N; zero away from
    them; without bodies one read-only array of zeros shared by the Results of a strand size);
    support: the share of the strand's weight (and loads) they carry, the supports' total along
    -f_ext over |f_ext| summed (0 without bodies); setup_time: one-time cost
    (s) the solver paid before solving and that ``time`` excludes (Ipopt: building its instance
    for a new strand size, compiling its model the first time), 0 otherwise; time_split: ``time``
    split into seconds of model evaluation, linear algebra and the rest ({model, linear_algebra,
    other}, linalg.timing; filled by the front end around a whole solve, empty when a solver function
    is called directly).
    """

    solver: str
    p: np.ndarray
    status: str
    message: str
    iterations: dict[str, int]
    residual_inf: float
    max_force: float
    objective: float
    stiffening: dict[str, dict[str, float]]
    rest_change: dict[str, dict[str, float]]
    time: float
    min_eigenvalue: float
    stable: bool
    history: list[float] = field(default_factory=list)
    physical: dict[str, np.ndarray] = field(default_factory=dict)
    floors: np.ndarray | None = None
    static_sag: float = float("nan")
    contact_forces: np.ndarray | None = None
    support: float = 0.0
    setup_time: float = 0.0
    time_split: dict[str, float] = field(default_factory=dict)

    @property
    def success(self) -> bool:
        return self.status == "converged"

    def __getstate__(self) -> dict:
        """Pickled without the zeros of contact_forces away from bodies (its shape instead): a
        strand's Result crosses a pipe from each worker process, and those zeros were a fifth of it."""
        state = dict(self.__dict__)
        forces = state["contact_forces"]
        if isinstance(forces, np.ndarray) and forces.dtype == float and not forces.any():
            state["contact_forces"] = ("zeros", forces.shape)
        return state

    def __setstate__(self, state: dict) -> None:
        forces = state["contact_forces"]
        if isinstance(forces, tuple):
            shape = tuple(forces[1])
            zeros = no_contact_forces(shape[0]) if shape[1:] == (3,) else np.zeros(shape)
            state = {**state, "contact_forces": zeros}
        self.__dict__.update(state)

    def __repr__(self) -> str:
        counts = ", ".join(f"{k}={v}" for k, v in self.iterations.items())
        stiff = ", ".join(f"{k} max {v['max']:.3g}" for k, v in self.stiffening.items())
        return (f"Result(solver={self.solver!r}, status={self.status!r}, |c|_inf={self.residual_inf:.3g}, "
                f"max_force={self.max_force:.3g} N, R={self.objective:.6g}, {counts}, "
                f"time={self.time:.3g} s, min_eigenvalue={self.min_eigenvalue:.3g} s^-2, stable={self.stable}"
                f"{', ' + stiff if stiff else ''})\n"
                f"  message: {self.message}")


@functools.lru_cache(maxsize=None)
def no_contact_forces(n_vertices: int) -> np.ndarray:
    """Result.contact_forces of a strand of ``n_vertices`` without bodies: (n, 3) zeros, read-only,
    one array per size, kept for every size seen (a groom read from a file has many sizes; each
    array is smaller than one Result)."""
    zeros = np.zeros((n_vertices, 3))
    zeros.flags.writeable = False
    return zeros


def measurements(problem: Problem, p: np.ndarray) -> tuple[float, float, float, dict, dict]:
    """(|c|_inf, the largest residual force on a free vertex position (N), R(p), the stiffening
    summary, the rest-change summary) of p, in one compiled pass over p and f(q*, p) (``_measured``,
    each number as its numpy form gives it). Stiffening, per stiffness block: the largest and mean
    multiplier over its specified value, and the share of its elements above STIFFENED. Rest change,
    per rest block: the largest and mean absolute change from p0, and the largest change over the
    box's half-width (the wider side)."""
    layout = problem.layout
    stiffness_names, stiffness_index, stiffness_offsets = layout.concatenated_blocks((*STIFFNESS_BLOCKS, STRAND_BLOCK))
    rest_names, rest_index, rest_offsets = layout.concatenated_blocks(REST_BLOCKS)
    residual_inf, max_force, objective, stiffening, rest = _measured(
        p, problem.forces(p), problem.free_index, problem.row_scale, dofs.position_index(problem.n_vertices),
        problem.free, layout.weights, layout.p0, layout.lower, layout.upper, stiffness_index, stiffness_offsets,
        rest_index, rest_offsets, STIFFENED)
    return (residual_inf, max_force, objective,
            {name: {"max": row[0], "mean": row[1], "stiffened": row[2]}
             for name, row in zip(stiffness_names, stiffening.tolist())},
            {name: {"max": row[0], "mean": row[1], "box": row[3]} for name, row in zip(rest_names, rest.tolist())})


@numba.njit(cache=True)
def _measured(p, f, free_index, row_scale, positions, free, w, p0, lower, upper, stiffness_index, stiffness_offsets,
              rest_index, rest_offsets, stiffened):  # pragma: no cover - compiled
    """``measurements``' numbers: np.abs(c).max(initial=0.0) with c = f[free] / D (NaN kept), the
    largest vertex force, 0.5 np.sum(w d d) (numpy's pairwise sum), and _block_statistics of
    the multipliers over p0 and of |p - p0| with its share of the box's half-width."""
    residual_inf = 0.0
    for r in range(free_index.size):
        value = abs(f[free_index[r]] / row_scale[free_index[r]])
        if not value <= residual_inf:  # larger, or NaN: kept from then on
            residual_inf = value if residual_inf == residual_inf else residual_inf
    terms = np.empty(p.size)
    for j in range(p.size):
        d = p[j] - p0[j]
        terms[j] = w[j] * d * d
    ratio = np.empty(stiffness_index.size)
    for k in range(stiffness_index.size):
        ratio[k] = p[stiffness_index[k]] / p0[stiffness_index[k]]
    change, share = np.empty(rest_index.size), np.empty(rest_index.size)
    for k in range(rest_index.size):
        j = rest_index[k]
        change[k] = abs(p[j] - p0[j])
        half_box = max(upper[j] - p0[j], p0[j] - lower[j])
        share[k] = change[k] / (half_box if half_box > 0 else 1.0)
    return (residual_inf, _largest_vertex_force(f, positions, free), 0.5 * pairwise_sum(terms),
            _block_statistics(ratio, ratio, stiffness_offsets, stiffened),
            _block_statistics(change, share, rest_offsets, np.inf))


@numba.njit(cache=True)
def _largest_vertex_force(f, positions, free):  # pragma: no cover - compiled
    """max over the vertices whose three positions are free of |f| on them, 0 if none, NaN if a
    norm is NaN: np.linalg.norm(axis=1).max(initial=0.0) in one pass (the same sums)."""
    largest = 0.0
    for i in range(positions.shape[0]):
        a, b, c = positions[i, 0], positions[i, 1], positions[i, 2]
        if free[a] and free[b] and free[c]:
            norm = np.sqrt(f[a] * f[a] + f[b] * f[b] + f[c] * f[c])
            if not norm <= largest:  # larger, or NaN: kept from then on
                largest = norm if largest == largest else largest
    return largest


@numba.njit(cache=True)
def _block_statistics(values, other, offsets, threshold):  # pragma: no cover - compiled
    """Per block b (entries offsets[b]:offsets[b + 1]): max and mean of values (0 if empty), the
    share of values above threshold, max of other (a NaN entry makes its max NaN, as numpy's):
    one pass where numpy took ~10 calls per block (the summaries of every Result)."""
    out = np.zeros((offsets.size - 1, 4))
    for b in range(offsets.size - 1):
        count = offsets[b + 1] - offsets[b]
        largest, total, above, other_largest = -np.inf, 0.0, 0, -np.inf
        for k in range(offsets[b], offsets[b + 1]):
            if not values[k] <= largest:  # larger, or NaN: kept from then on
                largest = values[k] if largest == largest else largest
            if not other[k] <= other_largest:
                other_largest = other[k] if other_largest == other_largest else other_largest
            total += values[k]
            above += values[k] > threshold
        if count:
            out[b, 0], out[b, 1], out[b, 2], out[b, 3] = largest, total / count, above / count, other_largest
    return out


def make_result(problem: Problem, p: np.ndarray, solver: str, status: str, message: str,
                iterations: dict[str, int], time: float, history: list[float] | None = None,
                floors: np.ndarray | None = None, rest: Equilibrium | None = None,
                setup_time: float = 0.0) -> Result:
    """Measure ``p`` on ``problem`` and package it; appends the stability verdict to the message.
    rest: where the strand rests if not at q* (an infeasible strand's static equilibrium): its
    stability is measured there, and its sag over L goes to ``static_sag``."""
    if status not in STATUSES:
        raise ValueError(f"status must be one of {STATUSES}, got {status!r}")
    with timing.uncounted():  # after the solve: not part of its time, nor of its split
        p = np.asarray(p, dtype=float).copy()
        eigenvalue = problem.stability(p) if rest is None else problem.stability(p, q=rest.q, frames=rest.frames)
        stable = bool(eigenvalue > 0)
        if status == "converged" and not stable:
            message += (f"; the rest state is UNSTABLE (smallest eigenvalue {eigenvalue:.3g} s^-2): a push "
                        "grows and the strand leaves q*")
        if problem.contacts.count:
            contacts = problem.contact_forces(p)
            support = _support(problem, contacts)
        else:
            contacts, support = no_contact_forces(problem.n_vertices), 0.0
        residual_inf, max_force, objective, stiffening, rest_change = measurements(problem, p)
        return Result(solver, p, status, message, dict(iterations), residual_inf, max_force, objective,
                      stiffening, rest_change, time, eigenvalue, stable, list(history or []), problem.physical(p), floors,
                      float("nan") if rest is None else rest.relative_sag, contacts, support, float(setup_time))


def _support(problem: Problem, contacts: np.ndarray) -> float:
    """Result.support: the share of the load the supports ``contacts`` (n, 3) carry."""
    load = problem.external_forces[dofs.position_index(problem.n_vertices)].sum(axis=0)
    return float(-contacts.sum(axis=0) @ load / (load @ load)) if load @ load > 0 else 0.0


def summed_iterations(counts: dict, more: dict) -> dict:
    """Two solves' ``iterations`` added kind by kind (a solve that ran another after it: asc's second
    start, the stabilization's re-solves)."""
    return {name: counts.get(name, 0) + more.get(name, 0) for name in {**counts, **more}}


def status_counts(results: list[Result]) -> dict[str, int]:
    """Strands per status, in STATUSES order, statuses with no strand left out."""
    return {s: n for s in STATUSES if (n := sum(r.status == s for r in results))}


def status_summary(results: list[Result]) -> str:
    """e.g. 'converged 98, max_iterations 2' (command lines and reports)."""
    return ", ".join(f"{s} {n}" for s, n in status_counts(results).items())


def iteration_summary(results: list[Result]) -> str:
    """Mean count of each kind of iteration over ``results``, e.g. 'sqp=9 admm=25850' (reports)."""
    keys = list(dict.fromkeys(k for result in results for k in result.iterations))
    return " ".join(f"{k}={np.mean([r.iterations.get(k, 0) for r in results]):.0f}" for k in keys) or "-"


def failed_result(solver: str, message: str, n_parameters: int = 0, time: float = 0.0) -> Result:
    """A Result for a strand whose problem could not even be built or evaluated."""
    nan = float("nan")
    return Result(solver, np.full(n_parameters, nan), "failed", message, {}, nan, nan, nan, {}, {}, time,
                  nan, False, [])
