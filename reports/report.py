"""A study's report: ``report.md`` and ``report.pdf`` with the same tables and figures (DESIGN 9).

Tables (one row per case = scene x mode x solver, aggregated over its strands):
1. convergence: statuses, time, iterations of each kind, factorizations, |c|_inf, residual force, R;
2. parameters: stiffening per block (max and mean ratio to the specified value, share of elements
   above 1.01) and the largest rest-shape change per block (as a share of its box half-width);
3. forward check: sag in simulation and in the static solve (over L), strands that stay within
   1e-6 L, strands that hold after a push along their softest mode, Newton steps per time step, the
   smallest mass-normalized eigenvalue (s^-2), stable rest states;
4. the solver comparison on common strands (benchmarking): shifted geometric means, time ratio to
   ``asc``, R gap, and the performance profiles;
5. per strand (small studies only): the numbers of each Result and SagCheck.
Then the figures (figures module) and the versions of everything that produced the numbers. Every
(case, strand) row also goes to ``results.csv`` (Study.rows), whatever the study's size.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.image import imread

from sagfree.baselines import ipopt
from sagfree.contract.result import status_summary
from sagfree.formulation.simulation import PUSH, PUSH_DT, PUSH_DURATION

from . import benchmarking
from .document import Document, Figure, Heading, Paragraph, Table, to_markdown, write_pdf
from .environment import versions
from .figures import FIGURES, draw_all
from .study import Study

#: A strand counts as still when it moves at most this share of its length (simulation and static).
STILL = 1e-6
#: A PNG this many pixels wide fills the PDF's text width; narrower ones are scaled alike.
FULL_WIDTH_PIXELS = 1400
#: Studies with at most this many (case, strand) rows get the per-strand table.
PER_STRAND_ROWS = 60


@dataclass
class ReportFiles:
    markdown: Path
    pdf: Path | None
    figures: dict[str, Path]


def _nanmax(values) -> float:
    values = [v for v in values if np.isfinite(v)]
    return float(max(values)) if values else float("nan")


CONVERGENCE_HEADER = ["scene", "mode", "solver", "strands", "statuses", "ms/strand", "wall (s)",
                      *benchmarking.ITERATION_COLUMNS, "max abs c", "max force (N)", "mean R"]


def convergence_rows(study: Study) -> list[list]:
    rows = []
    for c in study.cases:
        res = c.results
        rows.append([c.scene, c.mode, c.solver, len(res), status_summary(res),
                     1e3 * float(np.mean([r.time for r in res])), c.wall, *benchmarking.iteration_cells(c),
                     _nanmax(r.residual_inf for r in res), _nanmax(r.max_force for r in res),
                     float(np.nanmean([r.objective for r in res]))])
    return rows


def without_constant_columns(header: list[str], rows: list[list], names=("scene", "mode")):
    """(header, rows, note): the columns among ``names`` whose value is the same on every row
    dropped, and the note saying their value ("scene `x`, mode element")."""
    drop = [k for k, name in enumerate(header) if name in names and len(rows) > 1
            and len({str(row[k]) for row in rows}) == 1]
    note = ", ".join(f"{header[k]} `{rows[0][k]}`" for k in drop)
    keep = [k for k in range(len(header)) if k not in drop]
    return [header[k] for k in keep], [[row[k] for k in keep] for row in rows], note


def _table(header: list[str], rows: list[list]) -> tuple[Table, str]:
    header, rows, note = without_constant_columns(header, rows)
    return Table(header, rows), (f" All rows: {note}." if note else "")


def parameter_rows(study: Study) -> list[list]:
    rows = []
    for c in study.cases:
        ok = [r for r in c.results if r.status == "converged"] or c.results
        cells = []
        for block in ("bend_stiffness", "stretch_stiffness", "twist_stiffness"):
            stats = [r.stiffening[block] for r in ok if block in r.stiffening]
            if not stats and block == "bend_stiffness":  # strand mode: one multiplier for everything
                stats = [r.stiffening["strand_stiffness"] for r in ok if "strand_stiffness" in r.stiffening]
            cells.append(f"{_nanmax(s['max'] for s in stats):.3g} / {np.mean([s['mean'] for s in stats]):.3g} / "
                         f"{100 * np.mean([s['stiffened'] for s in stats]):.0f}%" if stats else "-")
        for block in ("rest_length", "rest_curvature", "rest_twist"):
            stats = [r.rest_change[block] for r in ok if block in r.rest_change]
            cells.append(f"{_nanmax(s['max'] for s in stats):.2e} ({100 * _nanmax(s['box'] for s in stats):.0f}%)"
                         if stats else "-")
        rows.append([c.scene, c.mode, c.solver, len(ok), *cells])
    return rows


def check_rows(study: Study) -> list[list]:
    rows = []
    for c in study.cases:
        checks, res = c.checks, c.results
        still = sum(not ch.sags(STILL) for ch in checks)
        pushed = c.pushed
        rows.append([c.scene, c.mode, c.solver, f"{still}/{len(checks)}" if checks else "-",
                     f"{sum(ch.holds for ch in pushed)}/{len(pushed)}" if pushed else "-",
                     _nanmax(ch.push for ch in pushed),
                     _nanmax(ch.relative_sag for ch in checks), _nanmax(ch.static_sag for ch in checks),
                     float(np.mean([ch.newton for ch in checks])) if checks else float("nan"),
                     float(np.nanmin([r.min_eigenvalue for r in res])) if res else float("nan"),
                     f"{sum(r.stable for r in res)}/{len(res)}"])
    return rows


STRAND_COLUMNS = ("scene", "strand", "mode", "solver", "status", "time_s", "residual_inf", "max_force_N",
                  "objective", "bend_max", "sag", "static_sag", "holds", "min_eigenvalue_s-2")


def strand_rows(study: Study) -> list[list]:
    """The per-strand table: STRAND_COLUMNS of Study.rows (time in ms)."""
    return [[1e3 * row[k] if k == "time_s" else row[k] for k in STRAND_COLUMNS] for row in study.rows()]


def _note_and_table(header, rows) -> list:
    """[the note on dropped constant columns (if any), the table]."""
    table, note = _table(header, rows)
    return ([Paragraph(note.strip())] if note else []) + [table]


def _warm_note(study: Study) -> str:
    """'; first run: compiling / loading the model X s (asc), ...' for the one-time costs above 0.1 s."""
    costs = [f"{c.warm:.1f} s ({c.solver})" for c in study.cases if c.warm > 0.1]
    return "; one-time cost of compiling or loading the model, not in any time: " + ", ".join(costs) if costs else ""


def _setup(study: Study) -> str:
    scenes = "; ".join(f"`{name}`: {len(s)} strands of {min(x.n_vertices for x in s)}"
                       + (f"-{max(x.n_vertices for x in s)}" if len({x.n_vertices for x in s}) > 1 else "")
                       + " vertices" for name, s in study.scenes.items())
    st = study.settings
    limits = ", ".join(f"{k} on the first {v}" for k, v in st.get("limits", {}).items())
    checks = ", ".join(f"{k} on the first {v}" for k, v in st.get("check_limits", {}).items())
    return (f"Scenes: {scenes}. Solvers: {', '.join(st['solvers'])}"
            + (f" ({limits} strands of each scene)" if limits else "") + f"; parameter modes: "
            f"{', '.join(st['modes'])}. Forward check: {st['steps']} implicit-Euler steps of {st['dt']:g} s "
            "from rest at the groomed shape, then the static equilibrium from it, Newton tolerance below "
            "the round-off floor" + (f" ({checks} strands)" if checks else "") + ". Times are per strand "
            "in one process, without compiling or loading the model (each process warms up first); wall "
            "times are for the whole batch on all cores" + _warm_note(study) + ". Sag: the largest vertex displacement from the "
            "groomed shape, over the strand length L (in the simulation from rest, or at the static "
            "equilibrium the groomed shape relaxes into).")


def _evaluation_note(study: Study) -> str:
    """How each solver evaluated the model in this study (Ipopt: compiled unless its options or
    $SAGFREE_IPOPT_MODEL said otherwise)."""
    model = study.settings.get("solver_options", {}).get("ipopt", {}).get("model") or ipopt.default_model()
    if "ipopt" in study.settings.get("solvers", ()) and model != "compiled":
        return ("ours, osqp and the predecessor evaluate the compiled stencils; Ipopt here evaluates its NLP in "
                "CasADi's virtual machine (model = casadi), which makes it several times slower")
    return ("every solver evaluates compiled C: ours, osqp and the predecessor the stencils, Ipopt its NLP "
            "generated by CasADi and compiled")


def _figure(path: Path, name: str, directory: Path | None, width: float) -> Figure:
    """The figure ``name`` of FIGURES at ``path`` (relative to the report's directory) with its caption."""
    return Figure(str(path.relative_to(directory)) if directory else str(path), FIGURES[name][1], width)


def build_document(study: Study, title: str, intro: list | None = None, figures: dict[str, Path] | None = None,
                   directory: Path | None = None, extra: list | None = None,
                   appendix: list | None = None) -> Document:
    """The report of ``study``; ``intro`` and ``extra`` blocks go before and after the study tables,
    ``appendix`` blocks after the versions."""
    doc = Document(title)
    doc.add(*(intro or []), Heading("Setup"), Paragraph(_setup(study)))
    compared = benchmarking.comparison_rows(study)
    if compared:
        doc.add(Heading("Solver comparison"), Paragraph(
            "Per scene and mode, on the strands every optimizing solver ran (the baselines may run fewer "
            "than `asc`): shifted geometric means of the time per strand (shift 1 ms; compilation and "
            "Ipopt's per-size setup excluded) and of the major iterations (shift 1; asc and penalty-gn: "
            "Gauss-Newton steps, ipopt: its iterations, osqp: SQP steps), each with min / median / max; "
            "`time / asc`: ratio of the shifted geometric means; `R gap`: the largest |R / R_asc - 1| "
            "where both converged. Where the time goes, as shares of the summed time: evaluating the model "
            f"({_evaluation_note(study)}), linear algebra (asc: QP solves and factorizations; osqp: "
            "OSQP's setup and solves; penalty-gn: its Cholesky; Ipopt's MUMPS is not timed apart from the "
            "rest of Ipopt by CasADi and counts as other) and the rest."),
            *_note_and_table(["scene", "mode", "solver", "strands", "statuses", "time (ms)",
                              "time min/med/max (ms)", "model / lin. alg. / other (%)", "major iterations",
                              "iterations min/med/max",
                              "time / asc", "R gap"], compared))
        if figures and "profiles" in figures:
            doc.add(_figure(figures["profiles"], "profiles", directory, 1.0))
    table, note = _table(CONVERGENCE_HEADER, convergence_rows(study))
    doc.add(Heading("Convergence"), Paragraph(
        "Means per strand; |c|_inf (unit-free: each row's force over its DOF's weight) and the residual "
        "force (N) are maxima over the strands; R is the regularizer (unit-free). `converged` means "
        "|c|_inf <= 1e-8 and a KKT distance <= 1e-5 for every solver. " + benchmarking.ITERATION_GLOSSARY
        + note), table)
    doc.add(Heading("Parameters"), Paragraph(
        "Stiffening per block over converged strands: max / mean ratio to the specified stiffness / share "
        "of elements above 1.01 (strand mode: the one multiplier, shown as bend; twist: `-` where it follows "
        "bend, the default). Rest-shape change: the "
        "largest absolute change of the block's normalized parameter (in brackets: as a share of its box "
        "half-width)."),
        *_note_and_table(["scene", "mode", "solver", "strands", "bend", "stretch", "twist", "rest length",
                          "rest curvature", "rest twist"], parameter_rows(study)))
    if any(c.checks for c in study.cases):
        doc.add(Heading("Forward check"), Paragraph(
            f"`still`: strands that moved at most {STILL:g} of their length both in simulation from rest and "
            f"in the static solve. `hold`: strands pushed by {PUSH:g} L along their softest mode that are back "
            f"within their push after {PUSH_DURATION:g} s of implicit Euler (steps of {PUSH_DT * 1e3:g} ms); "
            "`push / L`: the largest deviation left at the end. Sags are maxima over the strands, relative to "
            "the strand length. `min eigenvalue`: the smallest mass-normalized eigenvalue of the free-DOF "
            "Hessian at the groomed shape (omega^2 of the slowest mode, s^-2), positive for a stable rest "
            "state; `stable`: strands where it is."),
            *_note_and_table(["scene", "mode", "solver", "still", "hold", "push / L", "max sag / L",
                              "max static sag / L", "Newton per step", "min eigenvalue (s^-2)", "stable"],
                             check_rows(study)))
    rows = strand_rows(study)
    if len(rows) <= PER_STRAND_ROWS:
        doc.add(Heading("Per strand"), Table(["scene", "strand", "mode", "solver", "status", "ms", "abs c",
                                              "max force (N)", "R", "bend max", "sag / L", "static sag / L",
                                              "min eigenvalue (s^-2)"], rows))
    if figures:
        doc.add(Heading("Figures"))
        for name, path in figures.items():
            if name == "profiles":
                continue  # shown with the comparison
            doc.add(_figure(path, name, directory, min(1.0, imread(path).shape[1] / FULL_WIDTH_PIXELS)))
    doc.add(*(extra or []))
    doc.add(Heading("Versions"), Table(["component", "version"], [[k, v] for k, v in versions().items()]))
    doc.add(*(appendix or []))
    return doc


def write_report(study: Study, out_dir, title: str = "sagfree report", intro: list | None = None,
                 extra: list | None = None, pdf: bool = True, sizes: Study | None = None,
                 appendix: list | None = None) -> ReportFiles:
    """Draw the figures and write report.md (and report.pdf) into ``out_dir``; ``sizes``: a study of
    strands at several sizes for the time figure (none: no time figure)."""
    directory = Path(out_dir)
    directory.mkdir(parents=True, exist_ok=True)
    figures = draw_all(study, directory / "figures", sizes)
    document = build_document(study, title, intro, figures, directory, extra, appendix)
    markdown = directory / "report.md"
    markdown.write_text(to_markdown(document))
    write_csv(study, directory / "results.csv")
    return ReportFiles(markdown, write_pdf(document, directory) if pdf else None, figures)


def write_csv(study: Study, path: Path) -> None:
    """``Study.rows`` as CSV (columns: the union over rows; absent counts are empty)."""
    rows = study.rows()
    columns = list(dict.fromkeys(key for row in rows for key in row))
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, columns)
        writer.writeheader()
        writer.writerows(rows)

