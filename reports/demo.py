"""``sagfree demo``: the main job on the embedded default groom (DESIGN sections 9 and 10).

It runs the shipped study file ``studies/demo.toml`` (package ``sagfree.studies``), exactly what
``sagfree study studies/demo.toml`` runs: our solver (``asc``) and ``naive`` on the whole default
groom on all cores, the baselines (Ipopt, OSQP-SQP, the predecessor) on its first strands, forward
checks by simulation (pushes on a subset), held strands and long hair on a head, time against strand
size, the supplement's experiments and the derivative verification, written as ``report.md`` and
``report.pdf`` with their figures. ``solvers`` and ``baseline_strands`` narrow the file's study.
"""
from __future__ import annotations

import os
from importlib import resources

from sagfree.frontend.table import SOLVERS

from .study_file import StudyRun, load_study_file, run_study_file

DEMO_SOLVERS = tuple(SOLVERS)


def demo_study_path():
    """The shipped demo study file."""
    return resources.files("sagfree.studies") / "demo.toml"


def run_demo(out_dir: str | os.PathLike = "sagfree-demo", progress: bool = True, jobs: int | None = None,
             solvers=DEMO_SOLVERS, baseline_strands: int | None = None) -> StudyRun:
    """Run ``studies/demo.toml`` into ``out_dir``; ``solvers``: only these of the file's (asc always);
    ``baseline_strands``: the baselines' strand limit instead of the file's."""
    with resources.as_file(demo_study_path()) as path:
        spec = load_study_file(path)
    keep = ["asc"] + [s for s in spec.solvers if s in solvers and s != "asc"]
    spec.solvers = keep
    spec.scene_solvers = {scene: [s for s in names if s in keep] for scene, names in spec.scene_solvers.items()}
    if baseline_strands is not None:
        for limits in (spec.limits, spec.check_limits):
            for name in limits:
                limits[name] = baseline_strands
    return run_study_file(None, out_dir, jobs=jobs, progress=progress, spec=spec)
