"""What the strand file readers and writers (cyhair, usc_data, obj_polylines, npz) share.

Invalid strands: a strand whose geometry or material Strand rejects is an error naming the file and
strand, or, with ``keep_invalid=True``, an InvalidStrand in its slot (a batch reports it as failed
and goes on). A file that cannot be parsed at all is always an error.

Length units: a file stores lengths in one of ``UNITS`` (metres per file unit); readers multiply by
it to get metres, writers divide by it. Material: a file gives at most a radius, the rest comes
from ``synthetic.MATERIAL`` unless the caller overrides it with keyword arguments.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

from sagfree.formulation.strand import InvalidStrand, Strand

from .synthetic import MATERIAL

#: Metres per file unit.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def metres_per_unit(units: str) -> float:
    if units not in UNITS:
        raise ValueError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
    return UNITS[units]


def check_material(material: dict) -> dict:
    """The caller's material overrides, checked against the MATERIAL fields."""
    unknown = sorted(set(material) - set(MATERIAL))
    if unknown:
        raise TypeError(f"unknown material keyword(s) {', '.join(unknown)}; use {', '.join(MATERIAL)}")
    return material


def make_strand(points, where: str, keep_invalid: bool = False, **material) -> Strand | InvalidStrand:
    """Strand(points, **material), its ValueError prefixed with ``where`` (file and strand); with
    ``keep_invalid``, an InvalidStrand carrying that message instead of the error."""
    try:
        return Strand(points, **material)
    except ValueError as exc:
        if keep_invalid:
            return InvalidStrand(points, f"{where}: {exc}")
        raise ValueError(f"{where}: {exc}") from None


def write_bytes(path, data: bytes) -> None:
    write_atomically(path, lambda f: f.write(data))


def write_atomically(path, write) -> None:
    """``write(binary file)`` into a temporary file next to ``path``, then rename it over ``path``:
    readers never see a half-written file, and an interrupted write leaves the old one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
