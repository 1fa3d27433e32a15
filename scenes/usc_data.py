"""Strands as USC-HairSalon ``.data`` files (Hu et al. 2015, "Single-View Hair Modeling Using A
Hairstyle Database").

Byte layout, little-endian, no header beyond the count:

    int32 number of strands S
    S times: int32 number of vertices n_k, then n_k float32 (x, y, z) triples, root first

Units: ``units`` is the length unit of the file ("m", "cm" or "mm"); the default is "m", the scale of
the HairSalon models. Points are converted to metres. The format stores no radius or material:
strands get ``MATERIAL`` with the caller's keyword overrides (radius, youngs_modulus, shear_modulus,
density).

Decisions:
- Short strands: the HairSalon models contain strands with fewer than 3 vertices (mostly 1: scalp
  points without hair). Dropping them silently would shift every later strand index, so by default
  such a strand is an error naming it. With ``skip_short=True`` strands with fewer than 3 vertices are
  dropped: indices into the returned list then refer to the remaining strands, while error messages
  keep counting strands as stored in the file.
- The reader is strict: a truncated file, a negative count or bytes after the last strand are errors
  naming the file and the strand ("{path}: strand {k}: ..."), as is anything Strand rejects.
- The writer stores float32, so points come back to float32 precision (relative 1e-7).
"""
from __future__ import annotations

import numpy as np

from sagfree.formulation.strand import InvalidStrand, Strand

from .file_io import check_material, make_strand, metres_per_unit, write_bytes
from .synthetic import MATERIAL


def load_data(path, units: str = "m", *, skip_short: bool = False, keep_invalid: bool = False,
              **material) -> list[Strand]:
    """Strands (m) from a .data file whose lengths are in ``units``; material keywords override;
    keep_invalid: see file_io (short strands too, unless skip_short drops them)."""
    scale = metres_per_unit(units)
    material = {**MATERIAL, **check_material(material)}
    with open(path, "rb") as f:
        data = f.read()
    if len(data) < 4:
        raise ValueError(f"{path}: truncated file: {len(data)} bytes, no strand count")
    n_strands = int(np.frombuffer(data, "<i4", count=1)[0])
    if n_strands < 0:
        raise ValueError(f"{path}: negative strand count {n_strands}")
    pos, strands = 4, []
    for k in range(n_strands):
        where = f"{path}: strand {k}"
        if pos + 4 > len(data):
            raise ValueError(f"{where}: truncated file: it ends at byte {len(data)}, before the vertex "
                             f"count of strand {k} of the {n_strands} announced")
        n = int(np.frombuffer(data, "<i4", count=1, offset=pos)[0])
        pos += 4
        if n < 0:
            raise ValueError(f"{where}: negative vertex count {n}")
        if pos + 12 * n > len(data):
            raise ValueError(f"{where}: truncated file: {n} vertices need {12 * n} bytes, "
                             f"{len(data) - pos} are left")
        # in metres, as float64; a corrupted file's signaling NaN would make the cast warn without
        # naming the file: Strand rejects it with the strand and vertex instead
        with np.errstate(invalid="ignore"):
            points = np.frombuffer(data, "<f4", count=3 * n, offset=pos).reshape(n, 3).astype(float) * scale
        pos += 12 * n
        if n < 3:
            if skip_short:
                continue
            message = (f"{where}: a strand needs at least 3 vertices, got {n} (a scalp point without hair? "
                       "load with skip_short=True to drop such strands)")
            if not keep_invalid:
                raise ValueError(message)
            strands.append(InvalidStrand(points, message))
            continue
        strands.append(make_strand(points, where, keep_invalid, **material))
    if pos != len(data):
        raise ValueError(f"{path}: {len(data) - pos} bytes of trailing data after strand "
                         f"{n_strands - 1}, the last of the {n_strands} announced")
    return strands


def save_data(path, strands, units: str = "m") -> None:
    """Write strands to a .data file in ``units`` (float32)."""
    scale = metres_per_unit(units)
    parts = [np.array([len(strands)], "<i4").tobytes()]
    for s in strands:
        parts += [np.array([s.n_vertices], "<i4").tobytes(), (s.points / scale).astype("<f4").tobytes()]
    write_bytes(path, b"".join(parts))
