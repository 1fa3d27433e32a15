"""Reports: a tiny study's markdown carries the Results' numbers; the PDF is a real multi-page PDF with
the tables and figures; `sagfree optimize` on a .hair file gives parameters `sagfree simulate` confirms."""
import csv

import numpy as np
import pypdf
import pytest

import sagfree
from sagfree.cli import main
from sagfree.reports.document import cell
from sagfree.reports.figures import FIGURES
from sagfree.reports.report import write_report
from sagfree.reports.study import run_study


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    scenes = {"horizontal": [sagfree.scenes.horizontal(n=15)], "groom": sagfree.scenes.groom(2, 12, seed=4)}
    study = run_study(scenes, solvers=("asc", "penalty-gn", "naive"), modes=("element", "strand"), steps=20,
                      jobs=1)
    out = tmp_path_factory.mktemp("report")
    return study, write_report(study, out, "tiny study")


def table_rows(markdown: str, first_header: str) -> list[list[str]]:
    """Rows of the markdown table whose header starts with ``first_header``."""
    lines = markdown.splitlines()
    start = next(k for k, line in enumerate(lines) if line.startswith(f"| {first_header} |"))
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip("|").split(" | ")])
    return rows


def test_markdown_tables_carry_the_numbers_of_the_results(tiny):
    study, files = tiny
    text = files.markdown.read_text()
    per_strand = table_rows(text, "scene | strand")
    expected = [(c, k, r) for c in study.cases for k, r in enumerate(c.results)]
    # 3 strands: asc in both modes, penalty-gn and naive (no stiffness) in the first mode only
    assert len(per_strand) == len(expected) == 12
    assert not any(c.mode == "strand" and c.solver in ("naive", "penalty-gn") for c in study.cases)
    for row, (case, k, result) in zip(per_strand, expected):
        assert row[:5] == [case.scene, str(k), case.mode, case.solver, result.status]
        assert row[6:9] == [cell(result.residual_inf), cell(result.max_force), cell(result.objective)]
        assert row[11] == cell(case.checks[k].static_sag) and row[12] == cell(case.checks[k].holds)
        assert row[13] == cell(result.min_eigenvalue)
    convergence = table_rows(text, "scene | mode | solver | strands | statuses | ms/strand")
    for row, case in zip(convergence, study.cases):
        assert row[:4] == [case.scene, case.mode, case.solver, str(len(case.results))]
        assert row[11] == cell(max(r.residual_inf for r in case.results))
        major = "gauss_newton"  # asc and penalty-gn: the major iterations are Gauss-Newton steps
        assert row[8] == ("-" if case.solver == "naive" else
                          cell(float(np.mean([r.iterations[major] for r in case.results]))))
    with open(files.markdown.parent / "results.csv") as f:
        table = list(csv.DictReader(f))
    assert [(row["solver"], row["status"], float(row["objective"])) for row in table] == \
        [(c.solver, r.status, r.objective) for c, _, r in expected]
    checks = table_rows(text, "scene | mode | solver | still")
    asc = [row for row in checks if row[2] == "asc"]
    assert len(asc) == 4 and all(row[3] in ("1/1", "2/2") for row in asc)  # optimized strands stand still
    assert all(row[4] in ("1/1", "2/2") for row in asc)  # ... and hold after a push
    assert all(row[3].startswith("0/") and row[4].startswith("0/") for row in checks if row[2] == "naive")


def test_constant_columns_are_dropped_and_named():
    from sagfree.reports.report import without_constant_columns

    header, rows, note = without_constant_columns(["scene", "mode", "solver", "ms"],
                                                  [["groom", "element", "asc", 1.0], ["groom", "strand", "ipopt", 2.0]])
    assert header == ["mode", "solver", "ms"] and rows[1] == ["strand", "ipopt", 2.0] and note == "scene `groom`"


def test_pdf_is_a_multi_page_document_with_the_tables_and_figures(tiny):
    study, files = tiny
    assert files.pdf.read_bytes().startswith(b"%PDF")
    reader = pypdf.PdfReader(files.pdf)
    assert len(reader.pages) >= 3
    text = "\n".join(page.extract_text() for page in reader.pages)
    for heading in ("Convergence", "Parameters", "Forward check", "Solver comparison", "Per strand", "Versions"):
        assert heading in text
    asc = study.case("horizontal", "asc", "element").results[0]
    assert cell(asc.objective) in text and "ipopt (CasADi plugin)" in text
    # every figure but time against size, which needs a size sweep (write_report's ``sizes``)
    assert set(files.figures) == set(FIGURES) - {"time"}
    assert sum(len(page.images) for page in reader.pages) == len(FIGURES) - 1
    for path in files.figures.values():
        assert path.stat().st_size > 10_000  # a drawn PNG, not an empty canvas


def test_optimize_a_hair_file_then_simulate_confirms_no_sag(tmp_path, capsys):
    strands = [*sagfree.scenes.groom(2, 16, seed=9), sagfree.scenes.curly(n=16)]
    sagfree.save(tmp_path / "groom.hair", strands, units="cm")
    loaded = sagfree.load(tmp_path / "groom.hair")  # cyHair defaults to cm
    np.testing.assert_allclose(loaded[0].points, strands[0].points, atol=1e-7 * np.abs(strands[0].points).max())
    params = tmp_path / "params.npz"
    assert main(["optimize", str(tmp_path / "groom.hair"), "-o", str(params), "--jobs", "1", "--quiet"]) == 0
    assert main(["simulate", str(tmp_path / "groom.hair"), "--params", str(params), "--steps", "40", "--jobs", "1",
                 "--quiet"]) == 0
    assert "3/3 strands stay within 1e-06" in capsys.readouterr().out
    # the same file read in the wrong unit is caught, not simulated
    assert main(["simulate", str(tmp_path / "groom.hair"), "--units", "mm", "--params", str(params), "--quiet"]) == 2
    assert "same file and --units" in capsys.readouterr().err


def test_report_command_writes_markdown_and_pdf(tmp_path, capsys):
    assert main(["report", "--out", str(tmp_path), "--scenes", "horizontal", "--solvers", "asc,naive",
                 "--modes", "strand", "--steps", "10", "--jobs", "1", "--quiet"]) == 0
    assert (tmp_path / "report.md").exists() and (tmp_path / "report.pdf").exists()
    assert "wrote" in capsys.readouterr().out
