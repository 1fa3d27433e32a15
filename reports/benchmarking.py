"""Solver comparison the way optimization benchmarks do it: on common strands, with shifted geometric
means and Dolan-More performance profiles (Dolan & More, "Benchmarking optimization software with
performance profiles", Math. Program. 91, 2002).

- Common ground: a cross-solver number of one scene and mode uses only the strands every compared
  solver ran (a baseline limited to the first 6 strands limits the comparison to them).
- Shifted geometric mean of costs t_1..t_k: exp(mean(log(t_i + s))) - s, with the shift s keeping
  the tiny costs from dominating (SHIFTS: 1 ms for time, 1 for iterations).
- Performance profile of solver s over problems P: rho_s(tau) = |{p : r_ps <= tau}| / |P| with
  r_ps = t_ps / min_s' t_ps' (infinite where s did not converge); rho_s(1) is the share where s is
  the fastest, rho_s(tau -> inf) the share it solves at all.
- What an "iteration" is differs per solver: MAJOR_ITERATIONS names the count used, one linearization
  of c each (asc: Gauss-Newton steps; ipopt: its iterations; osqp: SQP steps; penalty-gn:
  Gauss-Newton steps).
"""
from __future__ import annotations

import numpy as np

from sagfree.contract.result import status_summary

from .study import Case, Study

#: shift of the shifted geometric mean, per cost
SHIFTS = {"time": 1e-3, "iterations": 1.0}
#: shift of the performance profiles' ratios (times are never 0, iteration counts can be)
PROFILE_SHIFTS = {"time": 0.0, "iterations": 1.0}
#: the iteration count of each solver that a comparison uses (module docstring)
MAJOR_ITERATIONS = {"asc": "gauss_newton", "ipopt": "ipopt", "osqp": "sqp", "penalty-gn": "gauss_newton"}
#: the report's iteration columns: column -> solver -> the Result.iterations counts summed into it
#: (a solver without an entry has no such level, "-")
ITERATION_COLUMNS = {
    "outer": {"asc": ("outer",)},
    "major": {solver: (key,) for solver, key in MAJOR_ITERATIONS.items()},
    "inner": {"asc": ("cg", "expansion", "proportioning"), "osqp": ("admm",)},
    "factorizations": {"asc": ("factorizations",)},
}
#: what each column counts, per solver (the report's glossary)
ITERATION_GLOSSARY = (
    "Iterations per strand (means): `outer`: augmented Lagrangian updates (asc); `major`: linearizations "
    "of c (asc and penalty-gn: Gauss-Newton steps; ipopt: its iterations; osqp: SQP steps); `inner`: "
    "steps of the QP solves (asc: MPRGP's conjugate-gradient, expansion and proportioning steps; osqp: "
    "ADMM iterations); `factorizations`: banded Cholesky factorizations (asc; Ipopt and OSQP factor "
    "inside their libraries and do not report it). `-`: the solver has no such level.")


def iteration_cells(case: Case) -> list:
    """The mean of each ITERATION_COLUMNS count over the case's strands ("-" where it has none)."""
    cells = []
    for per_solver in ITERATION_COLUMNS.values():
        keys = per_solver.get(case.solver)
        cells.append(float(np.mean([sum(r.iterations.get(k, 0) for k in keys) for r in case.results]))
                     if keys and case.results else "-")
    return cells


def shifted_geometric_mean(values, shift: float) -> float:
    """exp(mean(log(v + shift))) - shift over the finite values (NaN if none)."""
    values = np.asarray([v for v in values if np.isfinite(v)], dtype=float)
    if not values.size:
        return float("nan")
    return float(np.exp(np.mean(np.log(values + shift))) - shift)


def common_count(cases: list[Case]) -> int:
    """How many leading strands every case ran (studies solve a prefix of each scene)."""
    return min((len(c.results) for c in cases), default=0)


def comparable_cases(study: Study, scene: str, mode: str) -> list[Case]:
    """The cases of one scene and mode whose solver optimizes (naive has no cost to compare)."""
    return [c for c in study.cases if c.scene == scene and c.mode == mode and c.solver in MAJOR_ITERATIONS]


def costs(case: Case, count: int, kind: str) -> np.ndarray:
    """Per strand (the first ``count``): time (s) or major iterations; inf where not converged."""
    values = []
    for result in case.results[:count]:
        if result.status != "converged":
            values.append(np.inf)
        elif kind == "time":
            values.append(result.time)
        else:
            values.append(float(result.iterations.get(MAJOR_ITERATIONS[case.solver], 0)))
    return np.array(values, dtype=float)


def performance_profile(table: dict[str, np.ndarray], shift: float = 0.0, taus: np.ndarray | None = None):
    """(taus, {solver: rho(tau)}) for costs per solver over the same problems (inf: unsolved), the
    ratios taken of cost + ``shift`` (PROFILE_SHIFTS: iterations can be 0, asc's linear start is
    sometimes feasible and optimal). A problem no solver solved counts as unsolved for all."""
    names = list(table)
    matrix = np.array([table[name] for name in names], dtype=float) + shift   # (solvers, problems)
    best = np.min(matrix, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratios = np.where(np.isfinite(matrix) & np.isfinite(best), matrix / best, np.inf)
    if taus is None:
        finite = ratios[np.isfinite(ratios)]
        top = max(2.0, float(finite.max()) * 1.1) if finite.size else 2.0
        taus = np.geomspace(1.0, top, 200)
    problems = max(matrix.shape[1], 1)
    return taus, {name: np.array([(ratios[k] <= tau).sum() / problems for tau in taus])
                  for k, name in enumerate(names)}


def comparison_rows(study: Study) -> list[list]:
    """Per scene and mode, per optimizing solver, on the strands every one of them ran: strands,
    statuses, shifted geometric mean time (ms) and major iterations, each as min / median / max too,
    the time ratio to asc's shifted geometric mean, and the largest |R / R_asc - 1| where both
    converged."""
    rows = []
    for scene in study.scenes:
        for mode in dict.fromkeys(c.mode for c in study.cases):
            cases = comparable_cases(study, scene, mode)
            count = common_count(cases)
            reference = next((c for c in cases if c.solver == "asc"), None)
            if count == 0 or len(cases) < 2:
                continue
            asc_time = (shifted_geometric_mean([r.time for r in reference.results[:count]], SHIFTS["time"])
                        if reference else float("nan"))
            for case in cases:
                results = case.results[:count]
                times = np.array([r.time for r in results])
                iterations = np.array([r.iterations.get(MAJOR_ITERATIONS[case.solver], 0) for r in results], float)
                mean_time = shifted_geometric_mean(times, SHIFTS["time"])
                gaps = ([abs(r.objective / a.objective - 1) for r, a in zip(results, reference.results[:count])
                         if r.status == a.status == "converged" and a.objective > 0] if reference else [])
                rows.append([scene, mode, case.solver, count, status_summary(results),
                             1e3 * mean_time, _spread(1e3 * times), time_split_cell(results),
                             shifted_geometric_mean(iterations, SHIFTS["iterations"]), _spread(iterations),
                             mean_time / asc_time, max(gaps) if gaps and case.solver != "asc" else "-"])
    return rows


def time_split_cell(results) -> str:
    """'model / linear algebra / other' as percentages of the strands' summed time (Result.time_split;
    '-' where a solver did not record it)."""
    splits = [r.time_split for r in results if r.time_split]
    total = sum(sum(s.values()) for s in splits)
    if not splits or total <= 0:
        return "-"
    shares = [100 * sum(s.get(k, 0.0) for s in splits) / total for k in ("model", "linear_algebra", "other")]
    return " / ".join(f"{share:.0f}" for share in shares)


def _spread(values) -> str:
    values = np.asarray(values, dtype=float)
    return f"{values.min():.3g} / {np.median(values):.3g} / {values.max():.3g}" if values.size else "-"
