"""Strands as cyHair ``.hair`` files (Cem Yuksel's binary hair format, http://www.cemyuksel.com/cyCodeBase).

Byte layout, little-endian. A 128-byte header:

    offset size
         0    4  signature b"HAIR"
         4    4  uint32  number of strands S
         8    4  uint32  total number of points P
        12    4  uint32  flags: bit 0 segments array, bit 1 points array (required), bit 2 thickness
                         array, bit 3 transparency array, bit 4 color array (other bits are ignored)
        16    4  uint32  default number of segments per strand (used without a segments array)
        20    4  float32 default thickness
        24    4  float32 default transparency
        28   12  float32[3] default color
        40   88  char[88] file information, zero padded

then the flagged arrays, in this order: segments (uint16 per strand: vertices - 1), points (float32
x, y, z per point), thickness (float32 per point), transparency (float32 per point), color
(float32 r, g, b per point). Strand k owns the next segments[k] + 1 points.

Units: ``units`` is the length unit of the file ("m", "cm" or "mm"). The default is "cm", what the
cyHair sample files use; points (and thickness) are converted to metres.

Decisions:
- Radius: thickness is a diameter in file units. A strand's radius is half the mean thickness over
  its points when there is a thickness array, else half the default thickness when that is
  positive, else ``MATERIAL["radius"]``. Files often store a rendering width there (a default of 1.0
  in a cm file makes a 10 cm hair 1 cm thick): a radius above a strand's shortest edge or 1% of its
  length gets one warning naming the file, the value and the ``radius`` override. Keyword arguments
  (radius, youngs_modulus, shear_modulus, density) override the file and MATERIAL. Transparency and
  color are read past and dropped.
- The reader is strict: the file must hold exactly the arrays the header announces (truncated files
  and trailing bytes are errors), and the strands' points must add up to P. A strand with fewer than
  3 vertices, or any other defect Strand rejects, is an error naming the file and the strand index
  ("{path}: strand {k}: ...").
- The writer stores the segments, points and thickness (2 * radius per point) arrays as float32, so
  points and radii come back to float32 precision (relative 1e-7); the info string is b"sagfree".
  Twist angles, root condition and the other material parameters are not stored.
"""
from __future__ import annotations

import numpy as np

from sagfree.formulation.strand import Strand

from .file_io import (check_material, implausible_radius, make_strand, metres_per_unit, warn_implausible_radii,
                      write_bytes)
from .synthetic import MATERIAL

HEADER = np.dtype([("signature", "S4"), ("strands", "<u4"), ("points", "<u4"), ("flags", "<u4"),
                   ("segments", "<u4"), ("thickness", "<f4"), ("transparency", "<f4"),
                   ("color", "<f4", (3,)), ("info", "S88")])
#: The per-point arrays after the segments array: (name, flag bit, float32 values per point).
POINT_ARRAYS = (("points", 1, 3), ("thickness", 2, 1), ("transparency", 3, 1), ("color", 4, 3))
SEGMENTS, POINTS, THICKNESS = 1, 2, 4


def load_hair(path, units: str = "cm", keep_invalid: bool = False, **material) -> list[Strand]:
    """Strands (m) from a cyHair file whose lengths are in ``units``; material keywords override;
    keep_invalid: see file_io."""
    scale = metres_per_unit(units)
    check_material(material)
    with open(path, "rb") as f:
        data = f.read()
    if len(data) < HEADER.itemsize:
        raise ValueError(f"{path}: truncated file: {len(data)} bytes, shorter than the "
                         f"{HEADER.itemsize}-byte cyHair header")
    h = np.frombuffer(data, HEADER, count=1)[0]
    if h["signature"] != b"HAIR":
        raise ValueError(f"{path}: not a cyHair file: signature {data[:4]!r}, expected b'HAIR'")
    n_strands, n_points, flags = int(h["strands"]), int(h["points"]), int(h["flags"])
    if not flags & POINTS:
        raise ValueError(f"{path}: the header flags {flags:#x} announce no points array (bit 1)")
    pos = HEADER.itemsize

    def take(name, dtype, rows, width, strand_of):
        nonlocal pos
        row_bytes = width * np.dtype(dtype).itemsize
        if pos + rows * row_bytes > len(data):
            raise ValueError(f"{path}: strand {strand_of((len(data) - pos) // row_bytes)}: truncated "
                             f"file ({len(data)} bytes): the {name} array needs {rows * row_bytes} "
                             f"bytes from byte {pos}")
        out = np.frombuffer(data, dtype, count=rows * width, offset=pos).reshape(rows, width)
        pos += rows * row_bytes
        return out

    if flags & SEGMENTS:
        counts = take("segments", "<u2", n_strands, 1, lambda row: row)[:, 0].astype(np.int64) + 1
        source = "the segments array"
    else:
        if n_strands > (len(data) - pos) // 12:  # checked before allocating per-strand counts
            raise ValueError(f"{path}: corrupted header: {n_strands} strands of at least one 12-byte point "
                             f"cannot fit in a file of {len(data)} bytes")
        counts = np.full(n_strands, int(h["segments"]) + 1, dtype=np.int64)
        source = f"the default of {int(h['segments'])} segments per strand"
    if counts.sum() != n_points:
        raise ValueError(f"{path}: point count mismatch: {source} gives {counts.sum()} points for "
                         f"{n_strands} strands, the header says {n_points}")
    offsets = np.r_[0, np.cumsum(counts)]
    arrays = {name: take(name, "<f4", n_points, width,
                         lambda row: int(np.searchsorted(offsets, row, side="right")) - 1)
              for name, bit, width in POINT_ARRAYS if flags >> bit & 1}
    if pos != len(data):
        raise ValueError(f"{path}: {len(data) - pos} bytes of trailing data after the arrays the "
                         f"header announces (after strand {n_strands - 1})")

    thickness, default = arrays.get("thickness"), float(h["thickness"])
    strands, implausible = [], []
    for k in range(n_strands):
        rows = slice(offsets[k], offsets[k + 1])
        if thickness is not None:
            with np.errstate(invalid="ignore", over="ignore"):  # a corrupt file's NaN: implausible_radius names it
                value = float(thickness[rows].astype(float).mean())
        else:
            value = default if default > 0 else 2 * MATERIAL["radius"] / scale
        radius = 0.5 * scale * value
        with np.errstate(invalid="ignore", over="ignore"):  # a corrupt file's NaN / huge values: the
            points = arrays["points"][rows].astype(float) * scale  # strand's validation names them
        why = None if "radius" in material else implausible_radius(points, radius)
        if why:
            implausible.append((k, value, radius, why))
        strands.append(make_strand(points, f"{path}: strand {k}", keep_invalid,
                                   **{**MATERIAL, "radius": radius, **material}))
    warn_implausible_radii(path, "thickness" if thickness is not None else "default thickness", implausible)
    return strands


def save_hair(path, strands, units: str = "cm") -> None:
    """Write strands to a cyHair file in ``units``: segments, points and thickness arrays."""
    scale = metres_per_unit(units)
    counts = np.array([s.n_vertices for s in strands], dtype=np.int64)
    too_long = np.flatnonzero(counts - 1 > np.iinfo("<u2").max)
    if too_long.size:
        k = too_long[0]
        raise ValueError(f"{path}: strand {k}: {counts[k]} vertices, cyHair stores at most 65536")
    diameters = np.array([2 * s.radius / scale for s in strands])
    header = np.zeros(1, HEADER)
    header[0] = (b"HAIR", len(strands), counts.sum(), SEGMENTS | POINTS | THICKNESS,
                 counts[0] - 1 if len(strands) else 0, diameters[0] if len(strands) else 0.0, 0.0,
                 (0.0, 0.0, 0.0), b"sagfree")
    points = np.concatenate([s.points for s in strands] or [np.zeros((0, 3))]) / scale
    write_bytes(path, b"".join([header.tobytes(), (counts - 1).astype("<u2").tobytes(),
                                points.astype("<f4").tobytes(),
                                np.repeat(diameters, counts).astype("<f4").tobytes()]))
