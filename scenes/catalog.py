"""``sagfree.load`` / ``sagfree.save``: strands from a file (picked by extension) or a built-in scene.

Formats: ``.npz`` (scenes.npz: SI units, material and angles per strand), ``.hair`` (cyHair, default
unit cm), ``.data`` (USC-HairSalon, default unit m), ``.obj`` (OBJ polylines, default unit m),
``.usd``/``.usda``/``.usdc`` (OpenUSD BasisCurves, scenes.usd: the stage's own metersPerUnit and up
axis; material from widths and ``sagfree:`` primvars). The hair formats carry at most a radius;
``units`` and material keywords (radius, youngs_modulus, shear_modulus, density) apply to them (to a
stage: material keywords only). Built-in scenes: ``default-groom`` (the demo's groom) and
the single-strand reference scenes (DESIGN section 8).
"""
from __future__ import annotations

from pathlib import Path

from sagfree.formulation.strand import Strand

from .cyhair import load_hair, save_hair
from .groom import default_groom
from .head import HEAD, head_groom
from .npz import MATERIAL_FIELDS, load_strands, save_parameters, save_strands
from .obj_polylines import load_obj, save_obj
from .synthetic import cable, curly, flipped, helix, horizontal, wavy
from .usc_data import load_data, save_data
from .usd import EXTENSIONS as USD_EXTENSIONS
from .usd import load_stage, save_stage

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
#: the material fields each format stores (MATERIAL_FIELDS); the others come from MATERIAL or the caller
STORED_MATERIAL = {".npz": MATERIAL_FIELDS, ".hair": ("radius",), ".data": (), ".obj": (),
                   **{ext: MATERIAL_FIELDS for ext in USD_EXTENSIONS}}  # widths and sagfree: primvars
#: what a reader looks for, said when a file holds no strands
EMPTY_HINTS = {".obj": " (no 'l' polyline elements)", ".hair": " (a strand count of 0 in its header)"}
#: extension -> (reader, writer); the hair formats take units and material keywords
FORMATS = {
    ".npz": (load_strands, save_strands),
    ".hair": (load_hair, save_hair),
    ".data": (load_data, save_data),
    ".obj": (load_obj, save_obj),
    **{ext: (load_stage, save_stage) for ext in USD_EXTENSIONS},
}


def stored_material(source) -> tuple[str, ...]:
    """The material fields that ``source`` (a strands file or a built-in scene) gives its strands."""
    return STORED_MATERIAL.get(Path(source).suffix.lower(), MATERIAL_FIELDS)


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
            strands = load_strands(path, keep_invalid)
        else:
            strands = FORMATS[suffix][0](path, **({"units": units} if units else {}), keep_invalid=keep_invalid,
                                         **material)
        if not strands:  # an empty file is almost surely the wrong file: an error, not 0 strands solved
            raise ValueError(f"{path}: the file holds no strands{EMPTY_HINTS.get(suffix, '')}")
        return strands
    if str(source) in BUILTIN:
        if units is not None or material:
            raise ValueError(f"{source}: a built-in scene has its own units and material; units and material "
                             "options apply to strand files")
        return BUILTIN[str(source)]()
    raise ValueError(f"{source}: not a strands file ({', '.join(FORMATS)}) nor a built-in scene "
                     f"({', '.join(BUILTIN)})")


def save(path, strands: list[Strand], results=None, units: str | None = None, solver: str | None = None,
         problem_options: dict | None = None, source=None) -> Path | None:
    """Write strands to a file whose format is picked by extension (``units`` for the hair formats).

    With ``results`` (one Result per strand, from ``sagfree.optimize``), their parameters also go to
    ``<path stem>.params.npz`` (and its JSON summary; scenes.npz), which ``sagfree simulate`` reads;
    ``solver`` (default: the Results' solver) and ``problem_options`` are recorded there. Returns the
    parameters file's path, or None. An OpenUSD stage (.usd, .usda, .usdc) holds the parameters
    itself, as ``sagfree:`` primvars on its curves (scenes.usd; the path is returned): with
    ``source``, the stage the strands were read from, a copy of it, else a new stage.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"{path}: cannot write strands as '{suffix}'; use one of {', '.join(FORMATS)}")
    if suffix == ".npz" and units not in (None, "m"):
        raise ValueError(f"{path}: a .npz strands file is always in metres")
    strands = list(strands)
    if results is not None:  # checked before anything is written: a refused save leaves no file
        results = list(results)
        if len(results) != len(strands):
            raise ValueError(f"{path}: {len(strands)} strands but {len(results)} results; nothing written")
    if suffix in USD_EXTENSIONS:
        save_stage(path, strands, results, solver, problem_options, source=source, units=units)
        return None if results is None else path
    if source is not None:
        raise ValueError(f"{path}: 'source' (a stage to copy) applies to an OpenUSD output only")
    FORMATS[suffix][1](path, strands, **({"units": units} if units and suffix != ".npz" else {}))
    if results is None:
        return None
    params = path.with_name(path.stem + ".params.npz")
    save_parameters(params, strands, results, solver or (results[0].solver if results else "unknown"),
                    dict(problem_options or {}))
    return params
