"""Strands as Wavefront OBJ polylines (``.obj``).

Syntax, one statement a line, ``#`` starts a comment:

    v x y z        a vertex (further numbers, such as w or vertex colors, are ignored)
    l i j k ...    a line element, one per strand, root first; indices are 1-based, negative
                   indices count back from the last vertex defined so far (-1 = the latest), and
                   "i/t" index pairs keep the vertex index i

Every other statement (vt, vn, f, o, g, s, usemtl, ...) is ignored, and vertices used by no line
element are dropped. Line continuation with a trailing backslash is not supported.

Units: ``units`` is the length unit of the file ("m", "cm" or "mm"; default "m"); points are
converted to metres. OBJ stores no radius or material: strands get ``MATERIAL`` with the caller's
keyword overrides (radius, youngs_modulus, shear_modulus, density).

Decisions:
- Exporters that write a polyline as 2-vertex segments (``l 1 2``, ``l 2 3``, ...) are supported:
  consecutive 2-vertex line elements whose first vertex index is the last vertex index of the
  previous ones are joined into one strand. Longer line elements are never joined.
- Errors name the file and the line ("{path}:{line}: ..."): a malformed vertex, a bad or
  out-of-range index, and anything Strand rejects (then also the strand index; for a joined strand
  the line of its first segment), including a line element of fewer than 3 vertices.
- The writer writes each strand's vertices then its ``l`` element, coordinates as repr of the
  float64 values, so an OBJ in metres round-trips exactly.
"""
from __future__ import annotations

import numpy as np

from sagfree.formulation.strand import Strand

from .file_io import check_material, make_strand, metres_per_unit, write_bytes
from .synthetic import MATERIAL


def load_obj(path, units: str = "m", keep_invalid: bool = False, **material) -> list[Strand]:
    """Strands (m) from the line elements of an OBJ file in ``units``; material keywords override;
    keep_invalid: see file_io."""
    scale = metres_per_unit(units)
    material = {**MATERIAL, **check_material(material)}
    vertices, elements = [], []  # elements: [line number, 0-based vertex indices, joinable]
    with open(path, encoding="utf-8", errors="replace") as f:
        for no, line in enumerate(f, 1):
            tokens = line.split("#", 1)[0].split()
            if tokens[:1] == ["v"]:
                try:
                    x, y, z = (float(t) for t in tokens[1:4])
                except ValueError:
                    raise ValueError(f"{path}:{no}: bad vertex {line.strip()!r}, "
                                     "expected 'v x y z'") from None
                vertices.append((x, y, z))
            elif tokens[:1] == ["l"]:
                indices = [_index(t, len(vertices), f"{path}:{no}") for t in tokens[1:]]
                previous = elements[-1] if elements else None
                if len(indices) == 2 and previous and previous[2] and previous[1][-1] == indices[0]:
                    previous[1].append(indices[1])
                else:
                    elements.append([no, indices, len(indices) == 2])
    points = np.array(vertices, dtype=float).reshape(-1, 3) * scale
    strands = []
    for k, (no, indices, _) in enumerate(elements):
        out = [i for i in indices if i >= len(vertices)]
        if out:
            raise ValueError(f"{path}:{no}: vertex index {out[0] + 1} out of range: the file has "
                             f"{len(vertices)} vertices")
        strands.append(make_strand(points[indices], f"{path}:{no}: strand {k}", keep_invalid, **material))
    return strands


def _index(token: str, defined: int, where: str) -> int:
    """The 0-based vertex index of an ``l`` token (``i`` or ``i/t``); ``defined`` vertices so far."""
    try:
        i = int(token.split("/", 1)[0])
    except ValueError:
        raise ValueError(f"{where}: bad vertex index {token!r}") from None
    if i == 0:
        raise ValueError(f"{where}: vertex index 0: OBJ indices start at 1")
    if i < 0 and defined + i < 0:
        raise ValueError(f"{where}: vertex index {i} out of range: only {defined} vertices precede it")
    return defined + i if i < 0 else i - 1


def save_obj(path, strands, units: str = "m") -> None:
    """Write strands to an OBJ file in ``units``: per strand its ``v`` lines and one ``l`` element."""
    scale = metres_per_unit(units)
    lines, start = [f"# sagfree: {len(strands)} strands as polylines, lengths in {units}"], 1
    for s in strands:
        lines += ["v " + " ".join(repr(float(c)) for c in p) for p in s.points / scale]
        lines.append("l " + " ".join(str(i) for i in range(start, start + s.n_vertices)))
        start += s.n_vertices
    write_bytes(path, ("\n".join(lines) + "\n").encode())
