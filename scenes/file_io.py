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
import warnings
from pathlib import Path

import numpy as np

from sagfree.formulation.strand import InvalidStrand, Strand, radius_per_edge

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


#: A radius from a file above this share of the strand's length is implausible (a hair of 10 cm: 1 mm).
MAX_RADIUS_PER_LENGTH = 0.01


def implausible_radius(points, radius: float) -> str | None:
    """Why ``radius`` (m) is implausible for the polyline ``points`` (m), or None: above its shortest
    edge (DER models thin rods) or above MAX_RADIUS_PER_LENGTH of its length."""
    points = np.asarray(points, dtype=float)
    if len(points) < 2 or not np.all(np.isfinite(points)):
        return None  # the strand's own validation names what is wrong
    _, per_edge = radius_per_edge(points, radius)
    if per_edge > 1.0:
        return f"{per_edge:.3g} times its shortest edge"
    length = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
    if radius > MAX_RADIUS_PER_LENGTH * length:
        return f"{radius / length:.3g} of its length"
    return None


def warn_implausible_radii(path, field: str, found: list[tuple[int, float, float, str]]) -> None:
    """One UserWarning for a file whose ``field`` gives strands an implausible radius: ``found`` holds
    (strand, file value, radius in m, why) per such strand. cyHair thickness, for one, is often a
    rendering width rather than the physical diameter (1.0 in a cm file: a 5 mm radius)."""
    if not found:
        return
    shown = "; ".join(f"strand {k}: {field} {value:g} -> radius {radius:.3g} m, {why}"
                      for k, value, radius, why in found[:3])
    warnings.warn(f"{path}: the {field} gives {len(found)} strand(s) an implausible radius ({shown}"
                  f"{'; ...' if len(found) > 3 else ''}); it is often a rendering width, not the physical "
                  "diameter: give the radius instead (command line --radius M, Python radius=)",
                  UserWarning, stacklevel=4)


def write_bytes(path, data: bytes) -> None:
    write_atomically(path, lambda f: f.write(data))


def write_atomically(path, write) -> None:
    """``write(binary file)`` into a temporary file next to ``path``, then rename it over ``path``:
    readers never see a half-written file, and an interrupted write leaves the old one. The file gets
    the permissions ``open`` would give it (0666 less the umask; mkstemp's own are 0600)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.chmod(handle, 0o666 & ~_umask())
        with os.fdopen(handle, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    """The process's umask (reading it means setting it; set back at once)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
