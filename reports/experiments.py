"""The supplement's experiments as reproducible functions (S sections IV.A, IV.B and V).

All three use the `horizontal` strand (30 vertices, L = 0.10 m, clamped root) and run the forward
simulator (formulation.simulation) for ``steps`` implicit-Euler steps of ``dt`` from rest at q*, plus
the static equilibrium from q*. The supplement's bending coefficient c_be is read as Young's modulus
in Pa (DESIGN section 8).

* IV.A ``frame_averaging``: 4d against 2d-average, with and without flipped frames, E = 1e10 Pa.
  With flipped frames the averaged frames vanish, so 2d-average has no bending energy at all and the
  strand falls like a chain; 4d behaves as unflipped (S Fig. 2).
* IV.B ``slerp``: 4d against 2d-slerp on flipped frames at E = 1e8 and 1e9 Pa (S Fig. 3). The
  original 2d-slerp used approximate gradients and went unstable; ours are exact (CasADi AD), so this
  records how both models behave under the same Newton solver.
* V ``stiffness_modes``: naive parameters, one stiffness per strand, one per element, E = 1e9 Pa
  (S Fig. 4): the stiffening each needs, where it goes, the sag, and how the strand answers a
  vertical root motion (a stiffer tail deflects less).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sagfree.formulation import dofs
from sagfree.formulation.problem import Problem
from sagfree.formulation.simulation import CHECK_TOLERANCE, Simulation, equilibrium, simulate
from sagfree.scenes import flipped, horizontal
from sagfree.frontend.batch import map_strands
from sagfree.frontend.solve import solve
from sagfree.contract.result import Result

SCENES = {"horizontal": horizontal, "flipped": flipped}
#: Share of the strand, from the tip, that must keep its specified stiffness (DESIGN section 8).
TAIL = 0.4
#: Vertical root motion of section V: a smooth rise of ROOT_RISE m over ROOT_RISE_TIME s.
ROOT_RISE = 0.01
ROOT_RISE_TIME = 0.05


@dataclass
class ModelRun:
    """One bending model on one scene with the naive parameters p0.

    bending_energy: energy (J) of the bend term alone when the strand is bent into an arc of radius L
    (0 means no bending resistance); sag, final: max and end-of-run displacement from q* over L;
    static_sag: the static equilibrium's displacement over L; newton: mean Newton steps per time step;
    rejected: Newton directions whose line search failed (mu raised), over the run; converged: every
    Newton solve converged.
    """

    scene: str
    curvature: str
    youngs_modulus: float
    bending_energy: float
    sag: float
    final: float
    static_sag: float
    static_converged: bool
    newton: float
    rejected: int
    converged: bool
    simulation: Simulation


def _arc(problem: Problem) -> np.ndarray:
    """q of the straight input strand bent (downwards, in the x-z plane) into an arc of radius L,
    edge lengths and material angles kept."""
    strand = problem.strand
    s = np.r_[0.0, np.cumsum(strand.edge_lengths)]
    radius = strand.length
    points = np.column_stack([radius * np.sin(s / radius), np.zeros_like(s), radius * (np.cos(s / radius) - 1)])
    return dofs.interleave(points, strand.theta)


def model_run(scene: str, curvature: str, youngs_modulus: float, steps: int = 300, dt: float = 1e-3,
              n: int = 30) -> ModelRun:
    """Simulate the naive parameters of ``scene`` under one curvature model."""
    strand = SCENES[scene](n, youngs_modulus=youngs_modulus)
    problem = Problem(strand, curvature=curvature)
    bend_only = problem.with_options(energies=("bend",))
    run = simulate(problem, problem.p0, steps=steps, dt=dt)
    static = equilibrium(problem, problem.p0)
    length = strand.length
    return ModelRun(scene, curvature, youngs_modulus, bend_only.energy(bend_only.p0, _arc(problem)),
                    run.relative_sag, float(run.displacement[-1] / length), static.relative_sag,
                    static.converged, float(run.newton_iterations.mean()) if run.newton else 0.0,
                    sum(s.rejected for s in run.newton), run.converged, run)


def frame_averaging(steps: int = 300, dt: float = 1e-3, youngs_modulus: float = 1e10) -> list[ModelRun]:
    """S section IV.A / Fig. 2: 4d and 2d-average, without and with flipped frames."""
    return [model_run(scene, curvature, youngs_modulus, steps, dt)
            for curvature in ("2d-average", "4d") for scene in ("horizontal", "flipped")]


def slerp(steps: int = 300, dt: float = 1e-3, moduli=(1e8, 1e9)) -> list[ModelRun]:
    """S section IV.B / Fig. 3: 2d-slerp and 4d on flipped frames at two bending moduli."""
    return [model_run("flipped", curvature, e, steps, dt) for curvature in ("2d-slerp", "4d") for e in moduli]


@dataclass
class StiffnessModeRun:
    """One parameter mode of section V on `horizontal`.

    result: the solver's Result (naive: p0); bend_max: largest bend multiplier (S); stiffened: share
    of interior vertices with a multiplier above 1.01; tail_max: largest multiplier over the last
    TAIL of the vertices; sag, static_sag: displacement from q* over L (simulation, static; Newton
    tolerance below the round-off floor, so that it steps even where q* is an equilibrium);
    root_response: largest tip deflection from the rigidly moved input shape, over L, while the root
    rises by ROOT_RISE (smaller: the strand acts stiffer).
    """

    mode: str
    result: Result
    bend_max: float
    stiffened: float
    tail_max: float
    sag: float
    static_sag: float
    root_response: float


def _root_rise(t: float) -> np.ndarray:
    """Smooth vertical root rise: ROOT_RISE (1 - cos(pi t / T)) / 2 for t < T, then held."""
    share = 0.5 * (1.0 - np.cos(np.pi * min(t, ROOT_RISE_TIME) / ROOT_RISE_TIME))
    return np.array([0.0, 0.0, ROOT_RISE * share])


def stiffness_modes(steps: int = 300, dt: float = 1e-3, youngs_modulus: float = 1e9,
                    n: int = 30) -> list[StiffnessModeRun]:
    """S section V / Fig. 4: naive, one bend stiffness per strand, one per element (ours)."""
    strand = horizontal(n, youngs_modulus=youngs_modulus)
    runs = []
    for mode, stiffness, solver in (("naive", "element", "naive"), ("strand", "strand", "asc"),
                                    ("element", "element", "asc")):
        problem = Problem(strand, stiffness=stiffness)
        result = solve(problem, solver)
        bend = problem.physical(result.p)["bend_modulus"] / youngs_modulus
        tail = bend[int(np.floor((1 - TAIL) * bend.size)):]
        run = simulate(problem, result.p, steps=steps, dt=dt, tol=CHECK_TOLERANCE)
        moved = simulate(problem, result.p, steps=steps, dt=dt, root_motion=_root_rise)
        rigid = strand.points[-1] + np.array([_root_rise(t) for t in moved.times])
        response = np.max(np.linalg.norm(moved.trajectory[:, -1] - rigid, axis=1)) / strand.length
        runs.append(StiffnessModeRun(mode, result, float(bend.max()), float(np.mean(bend > 1.01)),
                                     float(tail.max()), run.relative_sag,
                                     equilibrium(problem, result.p, tol=CHECK_TOLERANCE).relative_sag,
                                     float(response)))
    return runs


def _run(name: str, steps: int, dt: float):
    return {"frames": frame_averaging, "slerp": slerp, "modes": stiffness_modes}[name](steps, dt)


def _crashed(message: str):
    raise RuntimeError(f"an experiment's worker process failed: {message}")


def run_all(steps: int = 300, dt: float = 1e-3, jobs: int | None = None):
    """(frame_averaging, slerp, stiffness_modes) runs, the three on worker processes."""
    return tuple(map_strands(_run, [("frames",), ("slerp",), ("modes",)], (steps, dt), jobs, on_crash=_crashed))


def document_blocks(steps: int = 300, dt: float = 1e-3, directory=None) -> list:
    """The three experiments run and tabulated, as report blocks (document module); with a report
    ``directory``, also their figure (figures/experiments.png)."""
    from pathlib import Path

    from .document import Figure, Heading, Paragraph, Table
    from .figures import experiments_figure

    header = ["scene", "curvature", "E (Pa)", "bend energy of an arc (J)", "sag / L", "final / L",
              "static sag / L", "Newton per step", "converged"]

    def model_rows(runs):
        return [[r.scene, r.curvature, r.youngs_modulus, r.bending_energy, r.sag, r.final,
                 r.static_sag if r.static_converged else "no convergence", r.newton, r.converged] for r in runs]

    frames, slerps, modes = run_all(steps, dt)
    figure = []
    if directory is not None:
        (Path(directory) / "figures").mkdir(parents=True, exist_ok=True)
        experiments_figure(frames, slerps, modes, Path(directory) / "figures" / "experiments.png")
        figure = [Figure("figures/experiments.png", (
            "The supplement's experiments on `horizontal` (30 vertices, 10 cm). Left and middle: the largest "
            "vertex displacement over the strand length against time (s), from rest at the groomed shape with "
            "the naive parameters (2d-average with flipped frames has no bending energy and falls "
            "like a chain, S Fig. 2). Right: the bend modulus over Young's modulus at each interior vertex "
            "for the naive parameters, one stiffness per strand and one per element (S Fig. 4); the legend "
            "gives the largest multiplier and the tip's deflection over L while the root rises by 1 cm."),
            1.0)]
    return [
        Heading("The supplement's experiments"),
        Paragraph(f"`horizontal` strand (30 vertices, 10 cm, clamped), naive parameters unless stated, {steps} "
                  f"implicit-Euler steps of {dt:g} s from rest, and the static equilibrium from the groomed "
                  "shape. Bend energy of an arc: the bending energy alone when the strand is bent into an arc "
                  "of radius L (zero: no bending resistance)."),
        Heading("IV.A: 4d against 2d-average, with and without flipped frames (Fig. 2)", 3),
        Table(header, model_rows(frames)),
        Heading("IV.B: 4d against 2d-slerp on flipped frames (Fig. 3)", 3),
        Table(header, model_rows(slerps)),
        Heading("V: naive, one stiffness per strand, per-element stiffness (Fig. 4)", 3),
        Paragraph(f"Tail: the last {TAIL:.0%} of the vertices. Root response: the largest tip deflection from "
                  f"the rigidly moved shape while the root rises by {ROOT_RISE * 100:g} cm in "
                  f"{ROOT_RISE_TIME * 1e3:g} ms (smaller: stiffer)."),
        Table(["parameters", "status", "max bend multiplier", "stiffened", "tail max", "sag / L",
               "static sag / L", "root response / L"],
              [[r.mode, r.result.status, r.bend_max, f"{r.stiffened:.0%}", r.tail_max, r.sag, r.static_sag,
                r.root_response] for r in modes]),
        *figure,
    ]
