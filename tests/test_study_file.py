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
    study, files = run_study_file(path, str(tmp_path / "out"), jobs=1, progress=False, pdf=False)
    assert {c.scene for c in study.cases} == {"horizontal (4d)", "horizontal (2d-average)", "groom (4d)",
                                               "groom (2d-average)"}
    assert all(r.status == "converged" for c in study.cases if c.solver == "asc" for r in c.results)
    assert "Solver comparison" not in files.markdown.read_text()   # only asc optimizes here
    assert main(["study", str(path), "--out", str(tmp_path / "cli"), "--jobs", "1", "--quiet", "--no-pdf"]) == 0
    assert main(["study", str(tmp_path / "missing.toml"), "--quiet"]) == 2
