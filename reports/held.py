"""Strands held by more than their root: long hair lying on a head, a cable clamped at both ends and a
strand pinned at its tip (the held and contact scenes of the scenes package), as report blocks.

``head_comparison`` solves the same long-hair strands with the head (their scalp part rests on it)
and without it (long hair sticking out of a crown), with ``asc``: statuses, stiffening, R, the share
of the weight the head carries, stability and the static sag. ``held_rows`` solves the two held
single strands with ``asc`` and Ipopt.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sagfree.contract.result import status_summary
from sagfree.formulation.problem import Problem
from sagfree.formulation.simulation import equilibrium
from sagfree.frontend.batch import optimize, simulate_strands
from sagfree.frontend.solve import solve
from sagfree.scenes import load
from sagfree.scenes.head import HEAD, head_groom


@dataclass
class HeadCase:
    """One row of the head comparison (means over the strands)."""

    label: str
    statuses: str
    bend_max: float
    bend_mean: float
    objective: float
    support: float
    stable: int
    holds: int
    static_sag: float
    strands: int


def head_comparison(strands: int = 8, vertices: int = 100, jobs: int | None = None) -> list[HeadCase]:
    groom = head_groom(strands, vertices)
    cases = []
    for label, options in (("on the head", {"bodies": [HEAD]}), ("without the head", {})):
        results = optimize(groom, jobs=jobs, progress=False, **options)
        checks = simulate_strands(groom, [r.p for r in results], jobs=jobs, **options)
        sags = [check.static_sag for check in checks]
        bends = [r.stiffening.get("bend_stiffness", {}) for r in results]
        cases.append(HeadCase(label, status_summary(results), max(b.get("max", np.nan) for b in bends),
                              float(np.mean([b.get("mean", np.nan) for b in bends])),
                              float(np.mean([r.objective for r in results])),
                              float(np.mean([r.support for r in results])), sum(r.stable for r in results),
                              sum(check.holds for check in checks), float(np.nanmax(sags)), len(results)))
    return cases


def held_rows() -> list[list]:
    """[scene, asc status, asc R, Ipopt R, relative gap, stable, static sag / L] per held scene."""
    rows = []
    for scene in ("cable", "horizontal-tip-pinned"):
        (strand,) = load(scene)
        problem = Problem(strand)
        ours = solve(problem)
        ipopt = solve(problem.with_options(stabilize=False), "ipopt")
        bare = solve(problem.with_options(stabilize=False))
        rows.append([scene, strand.attachments, ours.status, ours.objective, bare.objective, ipopt.objective,
                     abs(bare.objective - ipopt.objective) / ipopt.objective, ours.stable,
                     equilibrium(problem, ours.p).relative_sag])
    return rows


def document_blocks(jobs: int | None = None) -> list:
    from .document import Heading, Paragraph, Table

    cases = head_comparison(jobs=jobs)
    return [
        Heading("Held strands and strands on a head"),
        Paragraph("`long-hair-on-head` (the first 8 strands, 100 vertices, 50-90 cm): combed down the back "
                  "of a 10 cm sphere, then hanging. Solved by `asc` with the head (each scalp vertex within "
                  "two radii of it gets a non-negative support along its normal) and without it. Support: "
                  "the share of the weight the head carries (the root carries the rest). Each strand's "
                  "parameters are then simulated (with the head in the first row: frictionless penalty "
                  "contact): the static solve (its largest displacement over L, over the strands) and a "
                  "push of 1e-3 L along the softest mode, held if back within the push after 5 s. Without "
                  "the head, infeasible strands are simulated where their best effort rests."),
        Table(["case", "statuses", "max bend multiplier", "mean bend multiplier", "mean R", "mean support",
               "stable", "hold after a push", "max static sag / L"],
              [[c.label, c.statuses, c.bend_max, c.bend_mean, c.objective, c.support, f"{c.stable}/{c.strands}",
                f"{c.holds}/{c.strands}", c.static_sag] for c in cases]),
        Paragraph("Held single strands: `cable` (1 m, r 2 mm, E 1 GPa, clamped at both ends) and "
                  "`horizontal-tip-pinned`. R of `asc` with the stabilization, and of the bare problem by "
                  "`asc` and Ipopt; the static solve from `asc`'s parameters."),
        Table(["scene", "attachments", "asc status", "asc R", "bare asc R", "bare Ipopt R", "gap", "stable",
               "static sag / L"], held_rows()),
    ]
