"""Studies declared in a TOML file: ``sagfree study STUDY.toml`` (the same report as ``run_study`` +
``write_report``, whose arguments the file's keys are one to one; ``[sizes]``, ``experiments`` and
``derivatives`` are the functions of ``reports.sections``, ``intro`` a paragraph before the tables).

    title = "2d-average against 4d"          # the report's title (default: the file name)
    out = "curvature-study"                   # output directory (default: the file name's stem)
    solvers = ["asc", "ipopt", "naive"]       # default: every solver of the table
    modes = ["element"]                       # stiffness modes (default ["element"])
    curvatures = ["4d", "2d-average"]         # each scene once per variant (default ["4d"])
    simulate = true                           # forward checks (default true)
    steps = 200                               # implicit-Euler steps of the check (default 200)
    dt = 1e-3                                 # their time step, s (default 1e-3)
    limits = { ipopt = 6 }                    # a solver solves only the first N strands of a scene
    check_limits = { ipopt = 6 }              # ... and simulates only the first N
    push_limits = { asc = 20 }                # ... and pushes only the first N of those (5 s each)
    intro = "What this study shows."          # a paragraph at the top of the report
    experiments = true                        # the supplement's experiments IV.A, IV.B, V (default false)
    derivatives = true                        # the derivative verification (default false)

    [sizes]                                   # time against strand size (default: none)
    strands = 4                               # groom(strands, n, seed=0) for each n of vertices
    vertices = [25, 50, 100, 200]
    solvers = ["asc", "penalty-gn"]

    [[scenes]]
    name = "curly"                            # the label in the report (default: source)
    source = "curly"                          # a built-in scene or a strands file
    units = "cm"                              # a hair file's length unit (default: the format's)
    strands = 10                              # only the first N strands (default: all)
    bodies = ["sphere:0,0,0,0.1"]             # Problem options of this scene's strands (bodies,
    contact_distance = 1e-4                   # contact_distance, friction, gravity; default: none,
                                              # and a built-in scene's own bodies)
    solvers = ["asc", "naive"]                # the solvers run on this scene (default: all the study's)

    [options.osqp]                            # a solver's options (checked against the solver's)
    max_seconds = 20.0

Each scene with several ``curvatures`` becomes one scene per variant, labelled "name (variant)".
A malformed file is an error that names the key and its line, raised before any strand is solved.
"""
from __future__ import annotations

import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

from sagfree.formulation.curvature import VARIANTS
from sagfree.frontend.options import check_options
from sagfree.frontend.table import SOLVERS, solver_entry
from sagfree.scenes import load
from sagfree.scenes.catalog import BUILTIN, SCENE_BODIES

if TYPE_CHECKING:  # imported where a study runs: matplotlib is slow, and a bad file must fail in < 1 s
    from .report import ReportFiles
    from .study import Study

TOP_KEYS = {"title": str, "out": str, "solvers": list, "modes": list, "curvatures": list, "simulate": bool,
            "steps": int, "dt": float, "limits": dict, "check_limits": dict, "push_limits": dict, "scenes": list,
            "options": dict, "intro": str, "experiments": bool, "derivatives": bool, "sizes": dict}
SCENE_KEYS = {"name": str, "source": str, "units": str, "strands": int, "bodies": list,
              "contact_distance": float, "friction": float, "gravity": list, "solvers": list}
SIZES_KEYS = {"strands": int, "vertices": list, "solvers": list}
SCENE_PROBLEM_OPTIONS = ("bodies", "contact_distance", "friction", "gravity")


class StudyFileError(ValueError):
    """A malformed study file: the message names the file, the line and the key."""


@dataclass
class StudySpec:
    """A study file read and checked: run_study's arguments plus the report's title and directory."""

    title: str
    out: str
    scenes: dict = field(default_factory=dict)             # label -> strands
    scene_options: dict = field(default_factory=dict)      # label -> Problem options
    solvers: list = field(default_factory=list)
    modes: list = field(default_factory=list)
    simulate: bool = True
    steps: int = 200
    dt: float = 1e-3
    limits: dict = field(default_factory=dict)
    check_limits: dict = field(default_factory=dict)
    push_limits: dict = field(default_factory=dict)
    solver_options: dict = field(default_factory=dict)
    scene_solvers: dict = field(default_factory=dict)      # label -> solvers run on it
    intro: str = ""
    experiments: bool = False
    derivatives: bool = False
    sizes: dict | None = None                              # {strands, vertices, solvers}


def load_study_file(path) -> StudySpec:
    """Read and check a study file (module docstring); StudyFileError names what is wrong and where.
    A path that does not exist but names a shipped study (``studies/demo.toml``, ``curvature.toml``)
    reads the shipped one, so the examples work outside the source tree too."""
    path = Path(path)
    if not path.exists():
        from sagfree import studies

        shipped = Path(studies.__file__).parent / path.name
        path = shipped if shipped.exists() and path.suffix == ".toml" else path
    try:
        text = path.read_text()
    except OSError as exc:
        raise StudyFileError(f"{path}: cannot read the study file ({exc.strerror})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise StudyFileError(f"{path}: not valid TOML: {exc}") from None

    def fail(key: str, message: str):
        raise StudyFileError(f"{path}:{_line(text, key)}: {key}: {message}")

    _check_keys(data, TOP_KEYS, fail, "the study")
    solvers = data.get("solvers", list(SOLVERS))
    for name in solvers:
        try:
            solver_entry(name)
        except ValueError as exc:
            fail("solvers", str(exc))
    modes = data.get("modes", ["element"])
    for mode in modes:
        if mode not in ("element", "strand", "fixed"):
            fail("modes", f"unknown stiffness mode {mode!r}; choose from element, strand, fixed")
    curvatures = data.get("curvatures", ["4d"])
    for variant in curvatures:
        if variant not in VARIANTS:
            fail("curvatures", f"unknown curvature variant {variant!r}; choose from {', '.join(VARIANTS)}")
    for key in ("limits", "check_limits", "push_limits"):
        for name, count in data.get(key, {}).items():
            least = 1 if key == "limits" else 0
            if name not in solvers or not isinstance(count, int) or isinstance(count, bool) or count < least:
                fail(key, f"{name} = {count!r}: expected a solver of the study and a strand count >= {least}")
    solver_options = {}
    for name, options in data.get("options", {}).items():
        if name not in solvers or not isinstance(options, dict):
            fail("options", f"[options.{name}] must name a solver of the study ({', '.join(solvers)})")
        try:
            solver_options[name] = check_options(name, options)
        except ValueError as exc:
            fail(next(iter(options), "options"), str(exc))
    if not data.get("scenes"):
        fail("scenes", "a study needs at least one [[scenes]] table with a source")
    sizes = data.get("sizes")
    if sizes is not None:
        _check_keys(sizes, SIZES_KEYS, fail, "[sizes]")
        sizes = {"strands": 4, "vertices": [25, 50, 100, 200], "solvers": ["asc"], **sizes}
        for name in sizes["solvers"]:
            if name not in solvers:
                fail("sizes", f"[sizes] solver {name!r} is not a solver of the study ({', '.join(solvers)})")
        if not all(isinstance(n, int) and n >= 3 for n in sizes["vertices"]) or sizes["strands"] < 1:
            fail("vertices", "[sizes] needs strands >= 1 and vertices: a list of integers >= 3")
    spec = StudySpec(data.get("title", path.stem), data.get("out", path.stem), solvers=solvers, modes=modes,
                     simulate=data.get("simulate", True), steps=data.get("steps", 200), dt=data.get("dt", 1e-3),
                     limits=data.get("limits", {}), check_limits=data.get("check_limits", {}),
                     push_limits=data.get("push_limits", {}), solver_options=solver_options,
                     intro=data.get("intro", ""), experiments=data.get("experiments", False),
                     derivatives=data.get("derivatives", False), sizes=sizes)
    for scene in data["scenes"]:
        if not isinstance(scene, dict):
            fail("scenes", "each [[scenes]] entry must be a table")
        _check_keys(scene, SCENE_KEYS, fail, "a [[scenes]] table")
        if "source" not in scene:
            fail("scenes", "a [[scenes]] table needs a source (a built-in scene or a strands file)")
        source = scene["source"]
        where = source if source in BUILTIN else str(path.parent / source)  # files: relative to the study
        try:
            strands = load(where, scene.get("units"), keep_invalid=True)
        except (ValueError, FileNotFoundError) as exc:
            fail("source", str(exc))
        strands = strands[: scene["strands"]] if "strands" in scene else strands
        options = {k: scene[k] for k in SCENE_PROBLEM_OPTIONS if k in scene}
        if "bodies" not in options and source in SCENE_BODIES:
            options["bodies"] = list(SCENE_BODIES[source])
        label = scene.get("name", source)
        scene_solvers = scene.get("solvers", solvers)
        for name in scene_solvers:
            if name not in solvers:
                fail("solvers", f"scene {label!r}: solver {name!r} is not a solver of the study ({', '.join(solvers)})")
        for variant in curvatures:
            name = label if len(curvatures) == 1 else f"{label} ({variant})"
            if name in spec.scenes:
                fail("name", f"two scenes are called {name!r}")
            spec.scenes[name] = strands
            spec.scene_options[name] = {**options, "curvature": variant}
            spec.scene_solvers[name] = list(scene_solvers)
    return spec


def _check_keys(table: dict, allowed: dict, fail, where: str) -> None:
    for key, value in table.items():
        if key not in allowed:
            fail(key, f"unknown key in {where}; expected one of {', '.join(allowed)}")
        kind = allowed[key]
        if not (isinstance(value, kind) or (kind is float and isinstance(value, int) and not isinstance(value, bool))):
            fail(key, f"expected a {kind.__name__}, got {value!r}")


def _line(text: str, key: str) -> int:
    """The line of the first assignment to ``key`` (or table header naming it); 1 if not found."""
    pattern = re.compile(rf"^\s*(\[+\s*[\w.-]*{re.escape(key)}[\w.-]*\s*\]+|{re.escape(key)}\s*=)", re.MULTILINE)
    match = pattern.search(text)
    return text.count("\n", 0, match.start()) + 1 if match else 1


@dataclass
class StudyRun:
    """What running a study file produced: the Study, its report files, the derivative checks
    (passed, run; (0, 0) without ``derivatives``) and the wall time (s)."""

    study: Study
    files: ReportFiles
    checks_passed: int = 0
    checks_total: int = 0
    seconds: float = 0.0


def run_study_file(path, out: str | None = None, jobs: int | None = None, progress: bool = True,
                   pdf: bool = True, spec: StudySpec | None = None) -> StudyRun:
    """Run the study of ``path`` (or the already loaded ``spec``) with its sections and write its
    report to ``out`` (default: the file's ``out``)."""
    from . import experiments, sections
    from .document import Paragraph
    from .report import write_report
    from .study import run_study

    start = time.perf_counter()
    spec = spec or load_study_file(path)
    directory = Path(out or spec.out)
    study = run_study(spec.scenes, spec.solvers, spec.modes, simulate=spec.simulate, steps=spec.steps,
                      dt=spec.dt, jobs=jobs, progress=progress, limits=spec.limits,
                      check_limits=spec.check_limits, solver_options=spec.solver_options,
                      scene_options=spec.scene_options, push_limits=spec.push_limits,
                      scene_solvers=spec.scene_solvers)
    extra, appendix, sweep, passed, total = [], [], None, 0, 0
    if spec.sizes:
        sweep, blocks = sections.size_sweep(spec.sizes["strands"], spec.sizes["vertices"], spec.sizes["solvers"])
        extra += blocks
    if spec.experiments:
        extra += experiments.document_blocks(directory=directory)
    if spec.derivatives:
        body, appendix, passed, total = sections.derivative_blocks(directory)
        extra += body
    intro = [Paragraph(spec.intro)] if spec.intro else []
    files = write_report(study, directory, spec.title, intro, extra, pdf=pdf, sizes=sweep, appendix=appendix)
    return StudyRun(study, files, passed, total, time.perf_counter() - start)
