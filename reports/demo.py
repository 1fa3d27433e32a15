"""``sagfree demo``: the main job on the embedded default groom.

Solves every strand of the default groom with our solver (``asc``) on all cores and compares it with
the naive parameters (p0); runs the baselines (Ipopt, OSQP-SQP, the predecessor's penalty-gn) on the
first ``baseline_strands`` strands, where each is timed against ours on the same strands; runs the
derivative verification, forward-checks the parameters by simulation (``asc`` on the whole groom,
``naive`` on the baseline strands: implicit Euler from rest and the static equilibrium, sag relative to
the strand length), and writes ``report.md``. The PDF report joins it with the reports issue.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sagfree.formulation.verification import FD_TOLERANCE, HAND_TOLERANCE, verify
from sagfree.scenes import DEFAULT_GROOM, default_groom
from sagfree.solvers.batch import optimize, simulate_strands
from sagfree.solvers.registry import SOLVERS
from sagfree.solvers.result import STATUSES, Result, iteration_summary

from .markdown import table, versions

DEMO_SOLVERS = tuple(SOLVERS)
GROOM_SOLVERS = ("asc", "naive")  # run on the whole groom; the others on the first baseline_strands
COUNTS = ("outer", "gauss_newton", "cg", "expansion", "proportioning", "factorizations")


@dataclass
class DemoSummary:
    report: Path
    strands: int
    vertices: int
    wall_time: dict[str, float]            # solver -> seconds for the whole groom
    statuses: dict[str, dict[str, int]]    # solver -> status -> strands
    checks_passed: int
    checks_total: int
    still: dict[str, tuple[int, int]]      # solver -> (strands within STILL of L, strands checked)


def solver_rows(name: str, results: list[Result], wall: float) -> list:
    """One row of the solver table: what every report tabulates for a solver on a groom."""
    ok = [r for r in results if r.status == "converged"]
    bend = [r.stiffening.get("bend_stiffness", r.stiffening.get("strand_stiffness")) for r in ok]
    bend = [b for b in bend if b]
    count = lambda key: np.mean([r.iterations.get(key, 0) for r in results])  # noqa: E731
    return [
        name, f"{len(ok)}/{len(results)}", wall, 1e3 * np.mean([r.time for r in results]),
        *[float(count(k)) for k in COUNTS],
        float(max(r.residual_inf for r in results)), float(max(r.max_force for r in results)),
        float(np.mean([r.objective for r in results])),
        float(max((b["max"] for b in bend), default=1.0)),
        f"{100 * np.mean([b['stiffened'] for b in bend]) if bend else 0.0:.0f}%",
        f"{sum(r.stable for r in ok)}/{len(ok)}",
    ]


def comparison_rows(results: dict[str, list[Result]], count: int) -> list[list]:
    """Every solver on the first ``count`` strands: statuses, time per strand and its ratio to asc,
    iterations, residuals, and R(p*) relative to asc where both converged."""
    reference = results["asc"][:count]
    reference_time = np.mean([r.time for r in reference])
    rows = []
    for name, res in results.items():
        res = res[:count]
        both = [r.objective / a.objective - 1 for r, a in zip(res, reference)
                if r.status == a.status == "converged" and a.objective > 0]
        per_strand = float(np.mean([r.time for r in res]))
        rows.append([name, ", ".join(f"{s} {n}" for s in STATUSES if (n := sum(r.status == s for r in res))),
                     1e3 * per_strand, per_strand / reference_time, iteration_summary(res),
                     float(max(r.residual_inf for r in res)), float(max(r.max_force for r in res)),
                     float(np.max(np.abs(both))) if both else "-"])
    return rows


#: Largest sag, relative to strand length, that counts as standing still; simulated steps of 1 ms.
STILL = 1e-6
SIMULATION_STEPS = 200


def simulation_rows(name: str, checks, wall: float) -> list:
    """One row of the forward-check table (maxima over the strands that could be simulated)."""
    still = sum(not c.sags(STILL) for c in checks)
    return [name, f"{still}/{len(checks)}", float(np.nanmax([c.relative_sag for c in checks] + [0.0])),
            float(np.nanmax([c.static_sag for c in checks] + [0.0])),
            float(np.mean([c.newton for c in checks])), wall]


#: per-solver options of the demo: OSQP-SQP stalls for minutes on some strands (see baselines/osqp_sqp)
DEMO_OPTIONS = {"osqp": {"max_seconds": 20.0}}


def run_demo(out_dir: str | os.PathLike = "sagfree-demo", progress: bool = True,
             jobs: int | None = None, solvers=DEMO_SOLVERS, baseline_strands: int = 6) -> DemoSummary:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    strands = default_groom()
    solvers = ["asc"] + [name for name in solvers if name != "asc"]
    results, walls = {}, {}
    for name in solvers:
        start = time.perf_counter()
        batch = strands if name in GROOM_SOLVERS else strands[:baseline_strands]
        results[name] = optimize(batch, solver=name, jobs=jobs, progress=progress,
                                 solver_options=DEMO_OPTIONS.get(name))
        walls[name] = time.perf_counter() - start
    compared = min(baseline_strands, len(strands))
    checks, check_walls = {}, {}
    for name, count in (("asc", len(strands)), ("naive", compared)):
        if name in results:
            start = time.perf_counter()
            checks[name] = simulate_strands(strands[:count], [r.p for r in results[name][:count]],
                                            steps=SIMULATION_STEPS, jobs=jobs, progress=progress)
            check_walls[name] = time.perf_counter() - start
    rows = verify()
    passed = sum(r.passed for r in rows)
    lengths = [s.length for s in strands]
    statuses = {name: {s: sum(r.status == s for r in res) for s in STATUSES} for name, res in results.items()}
    asc = results["asc"]
    not_converged = [(k, r) for k, r in enumerate(asc) if r.status != "converged"]

    text = "\n\n".join([
        "# sagfree demo report",
        f"Default groom (`sagfree.scenes.groom(**{DEFAULT_GROOM})`): {len(strands)} strands, "
        f"{sum(s.n_vertices for s in strands)} vertices, lengths {min(lengths) * 100:.1f} to "
        f"{max(lengths) * 100:.1f} cm, radii {min(s.radius for s in strands) * 1e6:.0f} to "
        f"{max(s.radius for s in strands) * 1e6:.0f} um; clamped roots, gravity -z, 4d curvatures, "
        "per-element stiffness, default boxes.",
        "## Solvers",
        "`asc`: our augmented Lagrangian + MPRGP + active-set Cholesky. `naive`: the specified "
        "parameters p0 (rest shape = groomed shape), whose residual is gravity. Iteration counts are "
        "means per strand; |c|_inf and the residual force are maxima over the groom; stiffening is "
        "the bend multiplier (max over the groom, and the mean share of stiffened vertices).",
        table(["solver", "converged", "wall s", "ms/strand", *COUNTS, "max abs c", "max force N",
               "mean R", "max stiffening", "stiffened", "stable"],
              [solver_rows(name, res, walls[name]) for name, res in results.items()
               if name in GROOM_SOLVERS]),
        "Statuses: " + "; ".join(f"{name}: " + ", ".join(f"{k} {v}" for k, v in st.items() if v)
                                 for name, st in statuses.items()) + ".",
        *([("Strands `asc` did not converge on: " + "; ".join(
            f"strand {k}: {r.status}: {r.message}" for k, r in not_converged[:10]))] if not_converged else []),
        "## Forward check",
        f"Each strand simulated with its parameters: {SIMULATION_STEPS} implicit-Euler steps of 1 ms from "
        "rest at the groomed shape, and the static equilibrium from it (Newton, tolerance below the "
        f"round-off floor, so it always steps). `still`: strands that moved at most {STILL:g} of their "
        "length in both. `asc` on the whole groom, `naive` on the first "
        f"{compared} strands.",
        table(["solver", "still", "max sag / L", "max static sag / L", "Newton steps per time step", "wall s"],
              [simulation_rows(name, c, check_walls[name]) for name, c in checks.items()]),
        f"## All solvers on the first {compared} strands",
        "`ipopt`: the same NLP through CasADi's Ipopt (exact Hessian, MUMPS). `osqp`: SQP with OSQP "
        "subproblems. `penalty-gn`: the predecessor (rest shape only, penalized forces and boxes, "
        "Gauss-Newton). Times are per strand (one process each); `vs asc` divides by ours on the same "
        "strands; `R gap` is the largest |R(p*) / R_asc - 1| over strands where both converged.",
        table(["solver", "statuses", "ms/strand", "vs asc", "iterations (mean)", "max abs c", "max force N",
               "R gap"], comparison_rows(results, compared)),
        "## Derivative verification",
        f"CasADi AD against the hand-derived formulas S(7)-(19) (tolerance {HAND_TOLERANCE:g}) and "
        f"central finite differences (tolerance {FD_TOLERANCE:g}): {passed} of {len(rows)} passed.",
        table(["term", "quantity", "variant", "AD vs hand", "AD vs FD", "pass"],
              [[r.term, r.quantity + (" (zero)" if r.structural_zero else ""), r.variant,
                r.hand_error, r.fd_error, "yes" if r.passed else "NO"] for r in rows]),
        "## Versions",
        table(["component", "version"], [[k, v] for k, v in versions().items()]),
    ]) + "\n"
    report = out / "report.md"
    report.write_text(text)
    still = {name: (sum(not c.sags(STILL) for c in cs), len(cs)) for name, cs in checks.items()}
    return DemoSummary(report, len(strands), sum(s.n_vertices for s in strands), walls, statuses,
                       passed, len(rows), still)
