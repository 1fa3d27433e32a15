"""Studies declared in TOML files (sagfree study): errors name the key and line before any work; a
study from a file gives the report run_study + write_report give."""
import time

import pytest

from sagfree.cli import main
from sagfree.reports.study_file import StudyFileError, load_study_file, run_study_file

SMALL = """
title = "small"
solvers = ["asc", "naive"]
modes = ["element"]
curvatures = ["4d", "2d-average"]
steps = 10

[[scenes]]
source = "horizontal"

[[scenes]]
name = "groom"
source = "default-groom"
strands = 2
"""


def test_a_misspelled_key_fails_fast_naming_key_and_line(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(SMALL.replace("steps = 10", "stpes = 10"))
    start = time.perf_counter()
    with pytest.raises(StudyFileError, match=r"bad.toml:6: stpes: unknown key in the study"):
        load_study_file(path)
    assert time.perf_counter() - start < 1.0
    path.write_text(SMALL.replace('strands = 2', 'strands = 2\nunits = "cm"\nradius = 1'))
    with pytest.raises(StudyFileError, match=r":16: radius: unknown key in a \[\[scenes\]\] table"):
        load_study_file(path)
    path.write_text(SMALL + "\n[options.asc]\ntol = 1e-9\nmax_outter = 3\n")
    with pytest.raises(StudyFileError, match="max_outter"):
        load_study_file(path)
    path.write_text(SMALL.replace('"asc", "naive"', '"asc", "ipoptt"'))
    with pytest.raises(StudyFileError, match=r":3: solvers: unknown solver 'ipoptt'"):
        load_study_file(path)


def test_curvature_variants_expand_the_scenes(tmp_path):
    path = tmp_path / "small.toml"
    path.write_text(SMALL)
    spec = load_study_file(path)
    assert list(spec.scenes) == ["horizontal (4d)", "horizontal (2d-average)", "groom (4d)", "groom (2d-average)"]
    assert spec.scene_options["groom (2d-average)"] == {"curvature": "2d-average"}
    assert len(spec.scenes["groom (4d)"]) == 2


def test_a_study_runs_from_a_file(tmp_path, capsys):
    path = tmp_path / "small.toml"
    path.write_text(SMALL.replace("steps = 10", "simulate = false"))
    run = run_study_file(path, str(tmp_path / "out"), jobs=1, progress=False, pdf=False)
    study, files = run.study, run.files
    assert {c.scene for c in study.cases} == {"horizontal (4d)", "horizontal (2d-average)", "groom (4d)",
                                               "groom (2d-average)"}
    assert all(r.status == "converged" for c in study.cases if c.solver == "asc" for r in c.results)
    assert "Solver comparison" not in files.markdown.read_text()   # only asc optimizes here
    assert main(["study", str(path), "--out", str(tmp_path / "cli"), "--jobs", "1", "--quiet", "--no-pdf"]) == 0
    assert main(["study", str(tmp_path / "missing.toml"), "--quiet"]) == 2


def test_scene_solvers_pushes_and_sizes_are_declared_and_checked(tmp_path):
    path = tmp_path / "sections.toml"
    text = SMALL.replace('modes = ["element"]', 'modes = ["element", "strand"]') + \
        'solvers = ["asc"]\n' + "\n[sizes]\nstrands = 1\nvertices = [10, 20]\nsolvers = [\"asc\"]\n"
    text = text.replace("steps = 10", "steps = 10\npush_limits = { asc = 1, naive = 0 }")
    path.write_text(text)
    spec = load_study_file(path)
    assert spec.scene_solvers["groom (4d)"] == ["asc"] and spec.scene_solvers["horizontal (4d)"] == ["asc", "naive"]
    assert spec.sizes == {"strands": 1, "vertices": [10, 20], "solvers": ["asc"]}
    run = run_study_file(path, str(tmp_path / "out"), jobs=1, progress=False, pdf=False, spec=spec)
    cases = {(c.scene, c.mode, c.solver): c for c in run.study.cases}
    # naive ignores the stiffness mode: it runs once, in the first mode; the groom runs asc only
    assert ("horizontal (4d)", "element", "naive") in cases and ("horizontal (4d)", "strand", "naive") not in cases
    assert not any(scene.startswith("groom") and solver == "naive" for scene, _, solver in cases)
    asc = cases[("groom (4d)", "element", "asc")]
    assert len(asc.checks) == 2 and len(asc.pushed) == 1   # only the first strand is pushed
    assert "Time against strand size" in run.files.markdown.read_text()
    path.write_text(text.replace('vertices = [10, 20]', 'vertices = [10, 2]'))
    with pytest.raises(StudyFileError, match="vertices"):
        load_study_file(path)
    path.write_text(text.replace('solvers = ["asc"]\n\n[sizes]', 'solvers = ["ipopt"]\n\n[sizes]'))
    with pytest.raises(StudyFileError, match="not a solver of the study"):
        load_study_file(path)


def test_the_demo_is_the_shipped_demo_study():
    from importlib import resources

    from sagfree.reports.demo import demo_study_path

    with resources.as_file(demo_study_path()) as path:
        spec = load_study_file(path)
    assert spec.experiments and spec.derivatives and spec.sizes
    assert len(spec.scenes["default groom"]) == 100 and "asc" in spec.solvers
    assert spec.scene_options["long hair on a head"]["bodies"]         # the scene's own head
    assert spec.scene_options["long hair, no head"].get("bodies") == []
