"""Optional sections of a study's report beyond its scenes x solvers tables (study files' ``[sizes]``
and ``derivatives`` keys; ``experiments`` is reports.experiments.document_blocks):

- ``size_sweep``: the same kind of groom strands at several sizes, solved one after another in one
  process (time against strand size, drawn in the report's time figure);
- ``derivative_blocks``: the derivative verification as one line in the body, the table in an
  appendix and in ``derivatives.csv``.
"""
from __future__ import annotations

import csv
from pathlib import Path

from sagfree.contract.result import status_summary
from sagfree.formulation.verification import FD_TOLERANCE, HAND_TOLERANCE, verify
from sagfree.scenes import groom

from .document import Heading, Paragraph, Table
from .study import Study, run_study


def size_sweep(strands: int, sizes, solvers, progress: bool = False) -> tuple[Study, list]:
    """(the sweep's Study, its report blocks): ``groom(strands, n, seed=0)`` for each n in ``sizes``."""
    # in this process, after one warm-up solve per solver (run_study warms up): a process's first
    # solve loads the compiled kernels, which never count in Result.time
    sweep = run_study({f"groom, {n} vertices": groom(strands, n, seed=0) for n in sizes}, solvers, ("element",),
                      simulate=False, jobs=1, progress=progress)
    blocks = [
        Heading("Time against strand size"),
        Paragraph(f"{strands} groom strands per size (`groom({strands}, n, seed=0)`), solved one after another "
                  "in one process after a warm-up solve; drawn in the time figure above."),
        Table(["vertices", "solver", "statuses", "ms/strand", "ms per 100 vertices"],
              [[n, c.solver, status_summary(c.results), 1e3 * _mean_time(c.results),
                1e5 * _mean_time(c.results) / n]
               for c in sweep.cases for n in [sweep.scenes[c.scene][0].n_vertices]]),
    ]
    return sweep, blocks


def _mean_time(results) -> float:
    return sum(r.time for r in results) / max(len(results), 1)


DERIVATIVE_HEADER = ["term", "quantity", "variant", "AD vs hand", "AD vs FD", "pass"]


def derivative_blocks(directory: Path) -> tuple[list, list, int, int]:
    """(body blocks, appendix blocks, checks passed, checks run); writes ``derivatives.csv``."""
    rows = verify()
    passed = sum(r.passed for r in rows)
    table = [[r.term, r.quantity + (" (zero)" if r.structural_zero else ""), r.variant, r.hand_error,
              r.fd_error, r.passed] for r in rows]
    directory.mkdir(parents=True, exist_ok=True)
    with open(directory / "derivatives.csv", "w", newline="") as f:
        csv.writer(f).writerows([DERIVATIVE_HEADER, *table])
    body = [Heading("Derivative verification"), Paragraph(
        f"CasADi AD against the hand-derived formulas S(7)-(19) (tolerance {HAND_TOLERANCE:g}) and central "
        f"finite differences (tolerance {FD_TOLERANCE:g}), every energy term, parameter block and curvature "
        f"variant: {passed} of {len(rows)} passed (`sagfree check`; table in the appendix and in "
        "`derivatives.csv`).")]
    appendix = [Heading("Appendix: derivative verification"),
                Paragraph("Relative errors, largest over the random verification strands; `(zero)`: a block the "
                          "term does not depend on, checked to vanish in both forms."),
                Table(DERIVATIVE_HEADER, table)]
    return body, appendix, passed, len(rows)
