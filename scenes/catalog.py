"""``sagfree.load`` / ``sagfree.save``: strands from a file (picked by extension) or a built-in scene.

Formats: ``.npz`` (scenes.npz: SI units, material and angles per strand), ``.hair`` (cyHair, default
unit cm), ``.data`` (USC-HairSalon, default unit m), ``.obj`` (OBJ polylines, default unit m). The
hair formats carry at most a radius; ``units`` and material keywords (radius, youngs_modulus,
shear_modulus, density) apply to them. Built-in scenes: ``default-groom`` (the demo's groom) and
the single-strand reference scenes (DESIGN section 8).
"""
from __future__ import annotations

from pathlib import Path

from sagfree.formulation.strand import Strand

from .cyhair import load_hair, save_hair
from .groom import default_groom
from .head import HEAD, head_groom
from .npz import load_strands, save_parameters, save_strands
from .obj_polylines import load_obj, save_obj
from .synthetic import cable, curly, flipped, helix, horizontal, wavy
from .usc_data import load_data, save_data

BUILTIN = {
    "default-groom": default_groom,
    "horizontal": lambda: [horizontal()],
    "flipped": lambda: [flipped()],
    "helix": lambda: [helix()],
    "wavy": lambda: [wavy()],
    "curly": lambda: [curly()],
    "cable": lambda: [cable()],
    "horizontal-tip-pinned": lambda: [horizontal(tip="pinned")],
    "long-hair-on-head": head_groom,
}
#: the bodies a built-in scene's strands rest on (specs, formulation.bodies.parse_body)
SCENE_BODIES = {"long-hair-on-head": (HEAD.spec,)}
#: extension -> (reader, writer); the hair formats take units and material keywords
FORMATS = {
    ".npz": (load_strands, save_strands),
    ".hair": (load_hair, save_hair),
    ".data": (load_data, save_data),
    ".obj": (load_obj, save_obj),
}


def load(source, units: str | None = None, keep_invalid: bool = False, **material) -> list[Strand]:
    """Strands from a file or a built-in scene name; ``units`` (m, cm, mm; None: the format's
    default) and material keywords for the hair formats; ``keep_invalid``: a strand that fails
    validation becomes an InvalidStrand in its slot instead of an error (file_io)."""
    path = Path(source)
    suffix = path.suffix.lower()
    if suffix in FORMATS:
        if suffix == ".npz":
            if units not in (None, "m") or material:
                raise ValueError(f"{path}: a .npz strands file is in SI units with its own material; "
                                 "units and material options do not apply")
            return load_strands(path, keep_invalid)
        return FORMATS[suffix][0](path, **({"units": units} if units else {}), keep_invalid=keep_invalid,
                                  **material)
    if str(source) in BUILTIN:
        return BUILTIN[str(source)]()
    raise ValueError(f"{source}: not a strands file ({', '.join(FORMATS)}) nor a built-in scene "
                     f"({', '.join(BUILTIN)})")


def save(path, strands: list[Strand], results=None, units: str | None = None, solver: str | None = None,
         problem_options: dict | None = None) -> Path | None:
    """Write strands to a file whose format is picked by extension (``units`` for the hair formats).

    With ``results`` (one Result per strand, from ``sagfree.optimize``), their parameters also go to
    ``<path stem>.params.npz`` (and its JSON summary; scenes.npz), which ``sagfree simulate`` reads;
    ``solver`` (default: the Results' solver) and ``problem_options`` are recorded there. Returns the
    parameters file's path, or None.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"{path}: cannot write strands as '{suffix}'; use one of {', '.join(FORMATS)}")
    if suffix == ".npz" and units not in (None, "m"):
        raise ValueError(f"{path}: a .npz strands file is always in metres")
    FORMATS[suffix][1](path, strands, **({"units": units} if units and suffix != ".npz" else {}))
    if results is None:
        return None
    results = list(results)
    if len(results) != len(strands):
        raise ValueError(f"{len(strands)} strands but {len(results)} results")
    params = path.with_name(path.stem + ".params.npz")
    save_parameters(params, strands, results, solver or (results[0].solver if results else "unknown"),
                    dict(problem_options or {}))
    return params
