"""Studies declared in a TOML file: ``sagfree study STUDY.toml`` (the same report as ``run_study`` +
``write_report``, whose arguments the file's keys are one to one).

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

    [[scenes]]
    name = "curly"                            # the label in the report (default: source)
    source = "curly"                          # a built-in scene or a strands file
    units = "cm"                              # a hair file's length unit (default: the format's)
    strands = 10                              # only the first N strands (default: all)
    bodies = ["sphere:0,0,0,0.1"]             # Problem options of this scene's strands (bodies,
    contact_distance = 1e-4                   # contact_distance, friction, gravity; default: none,
                                              # and a built-in scene's own bodies)

    [options.osqp]                            # a solver's options (checked against the solver's)
    max_seconds = 20.0

Each scene with several ``curvatures`` becomes one scene per variant, labelled "name (variant)".
A malformed file is an error that names the key and its line, raised before any strand is solved.
"""
from __future__ import annotations

import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

from sagfree.formulation.curvature import VARIANTS
from sagfree.frontend.options import check_options
from sagfree.frontend.table import SOLVERS, solver_entry
from sagfree.scenes import load
from sagfree.scenes.catalog import BUILTIN, SCENE_BODIES

TOP_KEYS = {"title": str, "out": str, "solvers": list, "modes": list, "curvatures": list, "simulate": bool,
            "steps": int, "dt": float, "limits": dict, "check_limits": dict, "scenes": list, "options": dict}
SCENE_KEYS = {"name": str, "source": str, "units": str, "strands": int, "bodies": list,
              "contact_distance": float, "friction": float, "gravity": list}
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
    solver_options: dict = field(default_factory=dict)


def load_study_file(path) -> StudySpec:
    """Read and check a study file (module docstring); StudyFileError names what is wrong and where."""
    path = Path(path)
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
    for key in ("limits", "check_limits"):
        for name, count in data.get(key, {}).items():
            if name not in solvers or not isinstance(count, int) or count < 1:
                fail(key, f"{name} = {count!r}: expected a solver of the study and a positive strand count")
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
    spec = StudySpec(data.get("title", path.stem), data.get("out", path.stem), solvers=solvers, modes=modes,
                     simulate=data.get("simulate", True), steps=data.get("steps", 200), dt=data.get("dt", 1e-3),
                     limits=data.get("limits", {}), check_limits=data.get("check_limits", {}),
                     solver_options=solver_options)
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
        for variant in curvatures:
            name = label if len(curvatures) == 1 else f"{label} ({variant})"
            if name in spec.scenes:
                fail("name", f"two scenes are called {name!r}")
            spec.scenes[name] = strands
            spec.scene_options[name] = {**options, "curvature": variant}
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


def run_study_file(path, out: str | None = None, jobs: int | None = None, progress: bool = True,
                   pdf: bool = True):
    """Run the study of ``path`` and write its report (to ``out``, default the file's ``out``);
    returns (Study, ReportFiles)."""
    from .report import write_report
    from .study import run_study

    spec = load_study_file(path)
    study = run_study(spec.scenes, spec.solvers, spec.modes, simulate=spec.simulate, steps=spec.steps,
                      dt=spec.dt, jobs=jobs, progress=progress, limits=spec.limits,
                      check_limits=spec.check_limits, solver_options=spec.solver_options,
                      scene_options=spec.scene_options)
    return study, write_report(study, out or spec.out, spec.title, pdf=pdf)
