"""Studies: scenes x solvers x parameter modes, solved through ``sagfree.optimize`` and forward-checked
by simulation (DESIGN section 9).

A study keeps every Result and every SagCheck; the report module turns it into tables and figures.
``limits`` caps how many strands of a scene a solver solves (the slow baselines on a groom), and
``check_limits`` how many of them are simulated, ``push_limits`` how many of those are also pushed
along their softest mode (the costly part of a check: 5 s of simulated time); a case always covers
the FIRST strands of its scene, so cases of the same scene compare on the same strands.
Solvers whose parameters include no stiffness (``naive``, ``penalty-gn``: Solver.uses_stiffness) give
the same answer in every stiffness mode: they run in the first mode only, not once per mode.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

from sagfree.contract.result import Result
from sagfree.formulation.simulation import SagCheck
from sagfree.formulation.strand import Strand
from sagfree.frontend.batch import optimize, simulate_strands
from sagfree.frontend.options import check_options
from sagfree.frontend.table import SOLVERS, solver_entry
from sagfree.frontend.warm import announced_warm_up, precompile

MODES = ("element", "strand")


@dataclass
class Case:
    """One solver in one parameter mode on (the first strands of) one scene.

    results: one Result per solved strand; checks: one SagCheck per simulated strand (the first
    ones); wall, check_wall: wall time (s) of the batch solve and of the simulations; warm: the
    one-time cost (s) of compiling or loading the model before the batch (frontend.warm), outside
    ``wall`` (0 when this process was already warm).
    """

    scene: str
    solver: str
    mode: str
    results: list[Result]
    checks: list[SagCheck]
    wall: float
    check_wall: float
    warm: float = 0.0

    @property
    def label(self) -> str:
        return f"{self.solver} ({self.mode})"

    @property
    def pushed(self) -> list[SagCheck]:
        """The checks that include a push (push_limits)."""
        return [check for check in self.checks if check.push == check.push]  # not NaN


@dataclass
class Study:
    """scenes: name -> strands; cases in the order scene, mode, solver; settings of the run."""

    scenes: dict[str, list[Strand]]
    cases: list[Case] = field(default_factory=list)
    settings: dict = field(default_factory=dict)

    def case(self, scene: str, solver: str, mode: str) -> Case | None:
        return next((c for c in self.cases if (c.scene, c.solver, c.mode) == (scene, solver, mode)), None)

    def rows(self) -> list[dict]:
        """The whole study as one table: a row per (case, strand) with its Result and SagCheck numbers."""
        rows = []
        for c in self.cases:
            for k, r in enumerate(c.results):
                check = c.checks[k] if k < len(c.checks) else None
                bend = r.stiffening.get("bend_stiffness", r.stiffening.get("strand_stiffness", {}))
                rows.append({
                    "scene": c.scene, "strand": k, "vertices": self.scenes[c.scene][k].n_vertices,
                    "mode": c.mode, "solver": c.solver, "status": r.status, "time_s": r.time,
                    **{f"time_{name}_s": seconds for name, seconds in r.time_split.items()},
                    "setup_time_s": r.setup_time,
                    **{f"iterations_{name}": count for name, count in r.iterations.items()},
                    "residual_inf": r.residual_inf, "max_force_N": r.max_force, "objective": r.objective,
                    "bend_max": bend.get("max", float("nan")), "bend_mean": bend.get("mean", float("nan")),
                    "bend_stiffened": bend.get("stiffened", float("nan")),
                    "min_eigenvalue_s-2": r.min_eigenvalue, "stable": r.stable, "support": r.support,
                    "sag": check.relative_sag if check else float("nan"),
                    "push": check.push if check else float("nan"), "holds": check.holds if check else False,
                    "static_sag": check.static_sag if check else float("nan"),
                    "message": r.message})
        return rows


def run_study(scenes: dict[str, list[Strand]], solvers=tuple(SOLVERS), modes=("element",),
              simulate: bool = True, steps: int = 200, dt: float = 1e-3, jobs: int | None = None,
              progress: bool = False, limits: dict[str, int] | None = None,
              check_limits: dict[str, int] | None = None, solver_options: dict | None = None,
              scheduler=None, scene_options: dict[str, dict] | None = None,
              push_limits: dict[str, int] | None = None, scene_solvers: dict[str, list] | None = None) -> Study:
    """Solve every scene with every solver in every mode (``stiffness`` of the Problem) and simulate.

    limits / check_limits / push_limits: solver -> largest number of strands solved / simulated /
    pushed per scene (default: all). solver_options: solver -> keyword arguments of the solver.
    scene_options: scene -> Problem options of its strands (e.g. the bodies they rest on).
    scene_solvers: scene -> the solvers run on it (default: all of ``solvers``). jobs, scheduler: as
    for ``sagfree.optimize``.
    """
    # unknown or unavailable solvers and misspelled options fail before any work
    for name in solvers:
        solver_entry(name)
    for name, options in (solver_options or {}).items():
        check_options(name, options)
    unknown = set(modes) - {"element", "strand", "fixed"}
    if unknown:
        raise ValueError(f"unknown parameter mode(s) {sorted(unknown)}; choose from element, strand, fixed")
    limits, check_limits, solver_options = limits or {}, check_limits or {}, solver_options or {}
    scene_options, push_limits, scene_solvers = scene_options or {}, push_limits or {}, scene_solvers or {}
    study = Study(dict(scenes), settings=dict(solvers=list(solvers), modes=list(modes), simulate=simulate,
                                              steps=steps, dt=dt, limits=dict(limits),
                                              check_limits=dict(check_limits), push_limits=dict(push_limits),
                                              solver_options=dict(solver_options),
                                              scene_options=dict(scene_options)))

    def start_compiling() -> None:  # what can compile while other solvers work (Ipopt's NLP), in the background
        for scene, strands in scenes.items():
            for mode in modes:
                for solver in scene_solvers.get(scene, solvers):
                    precompile(solver, strands[: limits.get(solver, len(strands))], solver_options.get(solver),
                               {"stiffness": mode, **scene_options.get(scene, {})})

    for scene, strands in scenes.items():
        for mode in modes:
            for solver in scene_solvers.get(scene, solvers):
                if mode != modes[0] and not SOLVERS[solver].uses_stiffness:
                    continue  # the same answer as in the first mode (module docstring)
                batch = strands[: limits.get(solver, len(strands))]
                options = {"stiffness": mode, **scene_options.get(scene, {})}
                warm = (announced_warm_up(solver, solver_options.get(solver), options, progress, batch)
                        if batch else 0.0)
                if not study.cases:  # after the first warm-up, which compiled the stencils on screen
                    start_compiling()
                start = time.perf_counter()
                results = optimize(batch, solver=solver, jobs=jobs, progress=progress, stiffness=mode,
                                   solver_options=solver_options.get(solver), scheduler=scheduler,
                                   **scene_options.get(scene, {}))
                wall = time.perf_counter() - start
                checks, check_wall = [], 0.0
                if simulate:
                    count = min(len(batch), check_limits.get(solver, len(batch)))
                    pushed = min(count, push_limits.get(solver, count))
                    start = time.perf_counter()
                    for part, push in ((slice(0, pushed), True), (slice(pushed, count), False)):
                        if part.stop > part.start:
                            checks += simulate_strands(batch[part], [r.p for r in results[part]], steps, dt,
                                                       jobs=jobs, progress=progress, scheduler=scheduler,
                                                       push=push, stiffness=mode, **scene_options.get(scene, {}))
                    check_wall = time.perf_counter() - start
                study.cases.append(Case(scene, solver, mode, results, checks, wall, check_wall, warm))
    return study
