"""``sagfree demo``: the main job on the embedded default groom.

At this stage of the project the demo builds the equilibrium problem of every strand of the default
groom, measures how far the naive parameters (p0) are from equilibrium, times the model evaluation
(residual + Jacobian), runs the derivative verification, and writes ``report.md``. Solvers, baselines
and simulation are added to it as they land (see the issues).
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from sagfree.formulation.problem import Problem
from sagfree.formulation.verification import FD_TOLERANCE, HAND_TOLERANCE, verify
from sagfree.scenes import default_groom

from .markdown import table, versions


@dataclass
class DemoSummary:
    report: Path
    strands: int
    vertices: int
    naive_residual: float        # max over strands of |c(p0)|_inf
    evaluation_seconds: float    # residual + Jacobian of every strand, once
    checks_passed: int
    checks_total: int


def run_demo(out_dir: str | os.PathLike = "sagfree-demo", progress: bool = True) -> DemoSummary:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    strands = default_groom()
    problems = [Problem(s) for s in tqdm(strands, desc="problems", disable=not progress)]

    start = time.perf_counter()
    residuals = [np.abs(pb.residual(pb.p0)).max() for pb in problems]
    for pb in problems:
        pb.jacobian(pb.p0)
    evaluation = time.perf_counter() - start
    forces = [np.abs(pb.forces(pb.p0)[pb.free]).max() for pb in problems]
    lengths = [s.length for s in strands]
    rows = verify()
    passed = sum(r.passed for r in rows)

    text = "\n\n".join([
        "# sagfree demo report",
        f"Default groom: {len(strands)} strands, {sum(s.n_vertices for s in strands)} vertices, "
        f"lengths {min(lengths) * 100:.1f} to {max(lengths) * 100:.1f} cm, "
        f"{sum(pb.n_parameters for pb in problems)} parameters in all.",
        "## Naive parameters (p0)",
        "With the rest shape equal to the groomed shape, the only force is gravity: the scaled "
        "residual |c(p0)|_inf is 1 (each free vertex carries its own weight).",
        table(["quantity", "min", "max"], [
            ["|c(p0)|_inf", float(min(residuals)), float(max(residuals))],
            ["max residual force (N)", float(min(forces)), float(max(forces))],
        ]),
        f"Residual + Jacobian of all {len(problems)} strands: {evaluation:.3f} s "
        f"({evaluation / len(problems) * 1e3:.2f} ms per strand).",
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
    return DemoSummary(report, len(strands), sum(s.n_vertices for s in strands),
                       float(max(residuals)), evaluation, passed, len(rows))
