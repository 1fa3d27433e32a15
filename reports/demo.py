"""``sagfree demo``: the main job on the embedded default groom (DESIGN sections 9 and 10).

1. A study of the default groom: our solver (``asc``) and ``naive`` on every strand, on all cores;
   the baselines (Ipopt, OSQP-SQP, the predecessor's penalty-gn) on the first ``baseline_strands``;
   every strand's parameters forward-checked by simulation (``asc`` on the whole groom, the others
   on the baseline strands).
2. Time against strand size: the same kind of groom strands at 25 to 200 vertices, ``asc`` and the
   predecessor.
3. The supplement's experiments IV.A, IV.B and V (reports.experiments).
4. Held strands and long hair on a head, with and without it (reports.held).
5. The derivative verification (AD against the hand-derived formulas and finite differences).
All of it goes into ``report.md`` and ``report.pdf`` with their figures.
"""
from __future__ import annotations

import csv
import os
import time
from dataclasses import dataclass
from pathlib import Path

from sagfree.formulation.verification import FD_TOLERANCE, HAND_TOLERANCE, verify
from sagfree.scenes import DEFAULT_GROOM, default_groom, groom
from sagfree.frontend.table import SOLVERS
from sagfree.contract.result import status_counts, status_summary

from . import experiments, held
from .document import Heading, Paragraph, Table
from .report import STILL, write_report
from .study import run_study

DEMO_SOLVERS = tuple(SOLVERS)
GROOM_SOLVERS = ("asc", "naive")  # solved on the whole groom; the others on the first baseline strands
#: per-solver options of the demo: OSQP-SQP stalls for minutes on some strands (see baselines/osqp_sqp)
DEMO_OPTIONS = {"osqp": {"max_seconds": 20.0}}
#: the size sweep: strands per size, sizes, solvers
SWEEP = (4, (25, 50, 100, 200), ("asc", "penalty-gn"))
SCENE = "default groom"


@dataclass
class DemoSummary:
    report: Path
    pdf: Path
    strands: int
    vertices: int
    wall_time: dict[str, float]            # solver -> seconds for its batch
    statuses: dict[str, dict[str, int]]    # solver -> status -> strands
    still: dict[str, tuple[int, int]]      # solver -> (strands within STILL of L, strands simulated)
    holds: dict[str, tuple[int, int]]      # solver -> (strands that hold after a push, strands simulated)
    checks_passed: int
    checks_total: int
    seconds: float


def run_demo(out_dir: str | os.PathLike = "sagfree-demo", progress: bool = True, jobs: int | None = None,
             solvers=DEMO_SOLVERS, baseline_strands: int = 6) -> DemoSummary:
    start = time.perf_counter()
    strands = default_groom()
    solvers = ["asc"] + [name for name in solvers if name != "asc"]
    limits = {name: baseline_strands for name in solvers if name not in GROOM_SOLVERS}
    study = run_study({SCENE: strands}, solvers, ("element",), jobs=jobs, progress=progress, limits=limits,
                      check_limits={name: baseline_strands for name in solvers if name != "asc"},
                      solver_options=DEMO_OPTIONS)
    count, sizes, sweep_solvers = SWEEP
    sweep_solvers = [s for s in sweep_solvers if s in solvers]
    # in this process, after one warm-up solve per solver: a process's first solve loads the compiled
    # kernels, which would count in Result.time (compile time never enters a solver's time)
    run_study({"warm-up": groom(1, 10, seed=1)}, sweep_solvers, ("element",), simulate=False, jobs=1)
    sweep = run_study({f"groom, {n} vertices": groom(count, n, seed=0) for n in sizes}, sweep_solvers,
                      ("element",), simulate=False, jobs=1)
    rows = verify()
    passed = sum(r.passed for r in rows)
    lengths = [s.length for s in strands]
    intro = [Paragraph(
        f"Default groom (`sagfree.scenes.groom(**{DEFAULT_GROOM})`): {len(strands)} strands, "
        f"{sum(s.n_vertices for s in strands)} vertices, lengths {min(lengths) * 100:.1f} to "
        f"{max(lengths) * 100:.1f} cm, radii {min(s.radius for s in strands) * 1e6:.0f} to "
        f"{max(s.radius for s in strands) * 1e6:.0f} um; clamped roots, gravity -z, 4d curvatures, "
        "per-element stiffness, default boxes. `asc` is our augmented Lagrangian + MPRGP + active-set "
        "Cholesky; `naive` the specified parameters (rest shape = groomed shape); `ipopt` the same NLP "
        "through CasADi's Ipopt; `osqp` SQP with OSQP subproblems; `penalty-gn` the predecessor (rest shape "
        "only, penalized forces and boxes).")]
    extra = [
        Heading("Time against strand size"),
        Paragraph(f"{count} groom strands per size (`groom({count}, n, seed=0)`), solved one after another "
                  "in one process after a warm-up solve (a process's first solve also loads the compiled "
                  "kernels); drawn in the time figure above."),
        Table(["vertices", "solver", "statuses", "ms/strand", "ms per 100 vertices"],
              [[n, c.solver, status_summary(c.results),
                1e3 * _mean_time(c.results), 1e5 * _mean_time(c.results) / n]
               for c in sweep.cases for n in [sweep.scenes[c.scene][0].n_vertices]]),
        *experiments.document_blocks(),
        *held.document_blocks(jobs=jobs),
        Heading("Derivative verification"),
        Paragraph(f"CasADi AD against the hand-derived formulas S(7)-(19) (tolerance {HAND_TOLERANCE:g}) and "
                  f"central finite differences (tolerance {FD_TOLERANCE:g}), every energy term, parameter block "
                  f"and curvature variant: {passed} of {len(rows)} passed (`sagfree check`; table in the appendix "
                  "and in `derivatives.csv`)."),
    ]
    derivative_header = ["term", "quantity", "variant", "AD vs hand", "AD vs FD", "pass"]
    derivative_rows = [[r.term, r.quantity + (" (zero)" if r.structural_zero else ""), r.variant, r.hand_error,
                        r.fd_error, r.passed] for r in rows]
    appendix = [Heading("Appendix: derivative verification"),
                Paragraph("Relative errors, largest over the random verification strands; `(zero)`: a block the "
                          "term does not depend on, checked to vanish in both forms."),
                Table(derivative_header, derivative_rows)]
    files = write_report(study, out_dir, "sagfree demo report", intro, extra, sizes=sweep, appendix=appendix)
    with open(Path(out_dir) / "derivatives.csv", "w", newline="") as f:
        csv.writer(f).writerows([derivative_header, *derivative_rows])
    return DemoSummary(
        files.markdown, files.pdf, len(strands), sum(s.n_vertices for s in strands),
        {c.solver: c.wall for c in study.cases}, {c.solver: status_counts(c.results) for c in study.cases},
        {c.solver: (sum(not ch.sags(STILL) for ch in c.checks), len(c.checks)) for c in study.cases},
        {c.solver: (sum(ch.holds for ch in c.checks), len(c.checks)) for c in study.cases},
        passed, len(rows), time.perf_counter() - start)


def _mean_time(results) -> float:
    return sum(r.time for r in results) / max(len(results), 1)
