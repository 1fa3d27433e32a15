"""A report as a list of blocks, rendered to markdown and to Typst (for the PDF).

Reports build one ``Document`` (headings, paragraphs, tables, figures) and write it twice, so the
markdown and the PDF carry the same numbers. Table cells are kept as Python values; both renderers
format floats the same way (``cell``).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class Heading:
    text: str
    level: int = 2


@dataclass
class Paragraph:
    text: str  # markdown-light: `code` spans only


@dataclass
class Table:
    header: list[str]
    rows: list[list]
    caption: str = ""


@dataclass
class Figure:
    path: str  # relative to the report's directory
    caption: str
    width: float = 1.0  # share of the text width in the PDF


@dataclass
class Document:
    title: str
    blocks: list = field(default_factory=list)

    def add(self, *blocks) -> "Document":
        self.blocks.extend(blocks)
        return self


def cell(value) -> str:
    """A table cell as text: floats in compact scientific form, everything else as str."""
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, float):
        if value != value:
            return "-"
        return f"{value:.3g}" if 1e-3 <= abs(value) < 1e4 or value == 0 else f"{value:.2e}"
    return str(value)


def to_markdown(document: Document) -> str:
    out = [f"# {document.title}"]
    for block in document.blocks:
        if isinstance(block, Heading):
            out.append("#" * block.level + " " + block.text)
        elif isinstance(block, Paragraph):
            out.append(block.text)
        elif isinstance(block, Table):
            lines = ["| " + " | ".join(h.replace("|", "\\|") for h in block.header) + " |",
                     "|" + "---|" * len(block.header)]
            lines += ["| " + " | ".join(cell(v).replace("|", "\\|") for v in row) + " |" for row in block.rows]
            out.append(("*" + block.caption + "*\n\n" if block.caption else "") + "\n".join(lines))
        elif isinstance(block, Figure):
            out.append(f"![{block.caption}]({block.path})\n\n*{block.caption}*")
    return "\n\n".join(out) + "\n"


_TYPST_SPECIAL = re.compile(r"([\\#$*_@<>\[\]~\"'/=+-])")


def _typst_text(text: str) -> str:
    """Plain text with `code` spans for Typst: code spans become raw, the rest is escaped."""
    parts = re.split(r"(`[^`]*`)", text)
    return "".join(f"#raw({_typst_string(p[1:-1])})" if p.startswith("`") and p.endswith("`") and len(p) > 1
                   else _TYPST_SPECIAL.sub(r"\\\1", p) for p in parts)


def _typst_string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def to_typst(document: Document) -> str:
    out = ['#set page(paper: "a4", margin: (x: 1.5cm, y: 1.8cm), numbering: "1")',
           '#set text(size: 9pt)', '#set table(inset: 3pt, stroke: 0.4pt + gray)',
           '#show table: set text(size: 7pt)', '#show heading.where(level: 2): it => block(above: 1.4em, it)',
           f"#align(center, text(size: 16pt, weight: \"bold\")[{_typst_text(document.title)}])"]
    for block in document.blocks:
        if isinstance(block, Heading):
            out.append("=" * (block.level - 1) + " " + _typst_text(block.text))
        elif isinstance(block, Paragraph):
            out.append(_typst_text(block.text))
        elif isinstance(block, Table):
            cells = ", ".join(f"[*{_typst_text(h)}*]" for h in block.header)
            body = ", ".join(f"[{_typst_text(cell(v))}]" for row in block.rows for v in row)
            table = f"table(columns: {len(block.header)}, align: left, {cells}{', ' + body if body else ''})"
            caption = f", caption: [{_typst_text(block.caption)}]" if block.caption else ""
            out.append(f"#figure(kind: table, {table}{caption})")
        elif isinstance(block, Figure):
            out.append(f"#figure(image({_typst_string(block.path)}, width: {100 * block.width:.0f}%), "
                       f"caption: [{_typst_text(block.caption)}])")
    return "\n\n".join(out) + "\n"


def write_pdf(document: Document, directory: Path, name: str = "report") -> Path:
    """Render to Typst next to the figures and compile ``name.pdf`` with the typst package."""
    import typst

    source = directory / f"{name}.typ"
    source.write_text(to_typst(document))
    pdf = directory / f"{name}.pdf"
    typst.compile(str(source), output=str(pdf), root=str(directory))
    return pdf
