"""Strands from OpenUSD ``BasisCurves`` stages, and optimized parameters written back as primvars.

Needs the ``usd-core`` package (``pip install "sagfree[usd]"``); ``pxr`` is imported only when a
stage is read or written, so the rest of sagfree works without it.

Reading (``load_stage``): every defined, active ``UsdGeomBasisCurves`` prim of the stage, in stage
traversal order (depth first, as ``Usd.PrimRange``), each curve of a prim in its
``curveVertexCounts`` order, is one strand. Values are taken at the first time sample (the groomed
shape), else the default value.
- Space: points are multiplied by the prim's ``ComputeLocalToWorldTransform`` (row vectors,
  p' = p M), turned into sagfree's Z-up frame when the stage is Y-up ((x, y, z) -> (x, -z, y), a
  rotation about x; gravity is -z) and scaled to metres by the stage's ``metersPerUnit``. USD's
  fallbacks apply to a stage that does not author them: Y up, 0.01 m per unit (centimetres).
  ``units`` is a check, not an override: a stage states its unit, so ``units`` must be None or the
  stage's own (m, cm, mm), else ValueError.
- Curve types: ``linear`` curves as they are; ``cubic`` with basis ``catmullRom``: the control
  vertices are the strand's vertices (the curve passes through them; with wrap ``nonperiodic`` the
  first and last only shape the end tangents), so that every per-vertex primvar written back
  belongs to a control vertex of the same prim. Other cubic bases (bspline, bezier, hermite) are
  refused naming the prim: their control vertices are not on the curve, and a strand evaluated
  along it would not map onto the prim's vertices; convert them to linear or catmullRom first.
  ``periodic`` curves are refused naming the prim (a closed loop has no root).
- Radius: ``widths`` (or ``primvars:widths``, which takes precedence) are diameters in the prim's
  own space: constant, uniform, vertex or varying interpolation. A strand has one radius: half the
  mean of its curve's widths, times metersPerUnit and the transform's scale (|det| ** (1/3) of its
  3x3 part, the scale of a uniform scaling). Without widths: ``MATERIAL["radius"]``. A radius that is
  implausible for the strand (a rendering width) gets one warning naming the file (file_io).
- Material: per-curve primvars in SI units, ``constant`` or ``uniform``:
  ``sagfree:youngsModulus`` (Pa), ``sagfree:shearModulus`` (Pa), ``sagfree:density`` (kg/m^3);
  and ``sagfree:theta`` (``vertex``: the material angle of edge j at vertex j, rad; the last
  vertex's value is unused). Absent ones come from ``MATERIAL`` (theta 0); keyword arguments
  override the stage. Roots are clamped and tips free unless the caller attaches them otherwise: a
  stage stores no root, tip, pins or loads (``sagfree:attachments`` records them with the
  parameters, and ``sagfree simulate`` refuses strands held otherwise).
- Errors name the file, the prim path, the curve index within the prim and the vertex, e.g.
  ``groom.usda: /Groom/Left: curve 1: vertex 3 has a non-finite coordinate``; with ``keep_invalid``
  a curve's own error becomes an InvalidStrand in its slot (file_io). A stage without any
  BasisCurves prim, a prim whose arrays do not fit its curve counts, a file USD cannot open: always
  a ValueError naming the file (and the prim).

Writing (``save_stage``): with ``source`` (the stage the strands were read from), a copy of that
stage: its root layer is copied (every prim, attribute and composition arc kept; relative asset
paths that name a file beside the source rewritten relative to the output's folder) and the
primvars are authored on the same prims, over whatever the source composes. Without it, a new stage
(metersPerUnit from ``units``, default 1; upAxis Z) with one linear BasisCurves prim ``/Strands``
holding every strand. Either way the stage then reads back as the same strands: the strand inputs
above (widths as uniform 2r, the material and theta primvars) are authored where the stage does not
already give the strands' values (a source without material primvars, material keywords given to
``load``). USD stores points and widths as float: strands read from a stage round-trip exactly,
strands from elsewhere come back rounded to ~1e-7 of their size (a .npz keeps them exact). The
file is built as a temporary stage beside the output and moved over it (file_io.write_atomically):
a failed write leaves no file and the old one intact.

With ``results`` (one Result per strand), these primvars, all double precision (rest lengths differ
from the groomed edges by ~1e-8, below float's resolution), NaN where a strand has no parameters
(it failed before its Problem was built):

| primvar                    | interpolation | value                                                      |
| sagfree:restLength         | vertex  | edge j's rest length at vertex j (m); 0 at the last vertex       |
| sagfree:stretchModulus     | vertex  | edge j's alpha_j (Pa) at vertex j; 0 at the last vertex          |
| sagfree:stretchMultiplier  | vertex  | alpha_j / E at vertex j; 0 at the last vertex                    |
| sagfree:restCurvature      | vertex  | double2 (kbar_i0, kbar_i1) of interior vertex i; (0, 0) at ends  |
| sagfree:restTwist          | vertex  | mbar_i (rad) of interior vertex i; 0 at the ends                 |
| sagfree:bendModulus        | vertex  | beta_i (Pa); 0 at the ends                                       |
| sagfree:twistModulus       | vertex  | gamma_i (Pa); 0 at the ends                                      |
| sagfree:bendMultiplier     | vertex  | beta_i / E; 0 at the ends                                        |
| sagfree:twistMultiplier    | vertex  | gamma_i / G; 0 at the ends                                       |
| sagfree:status             | uniform | token: converged, infeasible, max_iterations or failed           |
| sagfree:message            | uniform | string: the solver's message                                     |
| sagfree:minEigenvalue      | uniform | smallest mass-normalized eigenvalue at the rest state (s^-2)     |
| sagfree:length             | uniform | the strand's length (m) the parameters were computed for         |
| sagfree:radius             | uniform | the strand's radius (m) the parameters were computed for         |
| sagfree:attachments        | uniform | string: Strand.attachments (root, tip, pins, loads)              |
| sagfree:parameterCount     | uniform | int: entries of the curve's normalized parameter vector          |
| sagfree:parameters         | constant| double[]: the prim's curves' normalized p, one after another     |
| sagfree:solver             | constant| string: the solver                                               |
| sagfree:problemOptions     | constant| string: the Problem options as JSON (scenes.npz)                 |
| sagfree:format             | constant| string: ``sagfree-usd-parameters-1``                             |

0 pads what does not exist (the tip has no edge; the ends have no curvature, twist or bending):
finite, so viewers and simulators accept the primvars, and never a value of a real rest length,
modulus or multiplier. A multiplier is the factor the optimizer put on the strand's Young's (stretch,
bend) or shear (twist) modulus, 1 where it stayed. ``load_stage_parameters`` reads the parameters
back as a ParameterFile (scenes.npz), so ``sagfree simulate OUT.usda`` needs no ``--params``; it
checks the stage's strands against the recorded vertex counts, length, radius and attachments.
"""
from __future__ import annotations

import json
import os
import shutil
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sagfree.formulation.strand import Strand

from .file_io import (UNITS, check_material, implausible_radius, make_strand, warn_implausible_radii,
                      write_atomically)
from .npz import PHYSICAL, ParameterFile, body_spec, save_summary
from .synthetic import MATERIAL

EXTENSIONS = (".usd", ".usda", ".usdc")
FORMAT = "sagfree-usd-parameters-1"
#: Strand field -> the primvar a stage gives it by (constant or uniform)
MATERIAL_PRIMVARS = {"youngs_modulus": "sagfree:youngsModulus", "shear_modulus": "sagfree:shearModulus",
                     "density": "sagfree:density"}
THETA = "sagfree:theta"
#: Physical block (scenes.npz.PHYSICAL: per edge or per interior vertex) -> its vertex primvar
PHYSICAL_PRIMVARS = {"rest_length": "sagfree:restLength", "stretch_modulus": "sagfree:stretchModulus",
                     "rest_curvature": "sagfree:restCurvature", "rest_twist": "sagfree:restTwist",
                     "bend_modulus": "sagfree:bendModulus", "twist_modulus": "sagfree:twistModulus"}
#: multiplier primvar -> (modulus block, material field it multiplies)
MULTIPLIERS = {"sagfree:stretchMultiplier": ("stretch_modulus", "youngs_modulus"),
               "sagfree:bendMultiplier": ("bend_modulus", "youngs_modulus"),
               "sagfree:twistMultiplier": ("twist_modulus", "shear_modulus")}


def is_stage(path) -> bool:
    """Whether ``path`` names an OpenUSD stage (by extension)."""
    return Path(str(path)).suffix.lower() in EXTENSIONS


def require_pxr() -> None:
    """Raise the ImportError of ``_pxr`` now (before a long run that ends in writing a stage)."""
    _pxr()


def _pxr():
    """The pxr modules, or an ImportError that says how to get them."""
    try:
        from pxr import Sdf, Usd, UsdGeom, UsdUtils, Vt
    except ImportError as exc:
        raise ImportError(f"OpenUSD stages need the usd-core package: pip install \"sagfree[usd]\" ({exc})") from None
    return Sdf, Usd, UsdGeom, UsdUtils, Vt


@dataclass
class _Curve:
    """One curve of a prim as sagfree reads it."""

    where: str                 # "{file}: {prim}: curve {k}"
    points: np.ndarray         # (n, 3) m, world space, Z up
    radius: float | None       # m, from widths (None: the prim has none)
    width: float | None        # the mean width in the prim's space (for the warning)
    material: dict = field(default_factory=dict)  # from the material primvars the prim authors
    theta: np.ndarray | None = None


@dataclass
class _Prim:
    """A BasisCurves prim and its curves."""

    prim: object               # Usd.Prim
    counts: np.ndarray         # curveVertexCounts
    scale: float               # |det| ** (1/3) of the local-to-world transform
    widths: str | None         # the attribute the radius came from ("widths", "primvars:widths") or None
    curves: list[_Curve]


def _open(path: Path):
    """The stage at ``path`` (reloaded if this process holds an older copy of its layer)."""
    Sdf, Usd, *_ = _pxr()
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    cached = Sdf.Layer.Find(str(path))
    try:
        if cached:
            cached.Reload()
        stage = Usd.Stage.Open(str(path))
    except Exception as exc:  # noqa: BLE001 - pxr.Tf.ErrorException and kin: a file USD cannot read
        raise ValueError(f"{path}: not a readable USD stage ({str(exc).strip()})") from None
    if stage is None:
        raise ValueError(f"{path}: not a readable USD stage")
    return stage


def _metres_per_unit(stage, path, units: str | None) -> float:
    _, _, UsdGeom, *_ = _pxr()
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    if not (np.isfinite(mpu) and mpu > 0):
        raise ValueError(f"{path}: metersPerUnit {mpu} is not a positive number")
    if units is not None:
        if units not in UNITS:
            raise ValueError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
        if not np.isclose(UNITS[units], mpu, rtol=1e-9):
            raise ValueError(f"{path}: the stage is in metersPerUnit {mpu:g}; units={units!r} ({UNITS[units]:g} m) "
                             "does not apply: a stage states its own unit (author metersPerUnit on it)")
    return mpu


def _values(primvar, time, where: str, name: str) -> np.ndarray:
    """A primvar's (or attribute's) values as floats, indexed primvars flattened."""
    value = primvar.ComputeFlattened(time) if hasattr(primvar, "ComputeFlattened") else primvar.Get(time)
    try:
        return np.atleast_1d(np.asarray(value, dtype=float))
    except (TypeError, ValueError):
        raise ValueError(f"{where}: {name} holds {value!r}, not numbers") from None


def _split(values, interpolation: str, counts, varying, where: str, name: str) -> list[np.ndarray]:
    """One array per curve of a primvar's ``values`` by its interpolation (constant: the same values
    for every curve; uniform: one per curve; vertex: one per vertex; varying/faceVarying: one per
    segment end)."""
    sizes = {"constant": None, "uniform": np.ones(len(counts), dtype=int), "vertex": counts,
             "varying": varying, "faceVarying": varying}
    if interpolation not in sizes:
        raise ValueError(f"{where}: {name} has interpolation {interpolation!r}; use one of {', '.join(sizes)}")
    if interpolation == "constant":
        if values.shape[0] != 1:
            raise ValueError(f"{where}: {name} is constant but has {values.shape[0]} values, expected 1")
        return [values] * len(counts)
    per = np.asarray(sizes[interpolation], dtype=int)
    if values.shape[0] != per.sum():
        raise ValueError(f"{where}: {name} has {values.shape[0]} value(s); {interpolation} interpolation on "
                         f"these {len(counts)} curve(s) needs {per.sum()}")
    ends = np.cumsum(per)
    return [values[end - size: end] for end, size in zip(ends, per)]


def _read(stage, path: Path, mpu: float) -> list[_Prim]:
    """Every BasisCurves prim of ``stage`` in traversal order, with its curves in metres, Z up."""
    _, Usd, UsdGeom, *_ = _pxr()
    time = Usd.TimeCode.EarliestTime()
    y_up = UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    prims = []
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()):
        if not prim.IsA(UsdGeom.BasisCurves):
            continue
        where = f"{path}: {prim.GetPath()}"
        if prim.IsInstanceProxy():
            raise ValueError(f"{where}: the curves are inside an instance, which sagfree cannot write onto; make "
                             "the instance uninstanceable (instanceable = false)")
        curves = UsdGeom.BasisCurves(prim)
        kind, basis, wrap = (str(a.Get(time)) for a in (curves.GetTypeAttr(), curves.GetBasisAttr(),
                                                       curves.GetWrapAttr()))
        if wrap == "periodic":
            raise ValueError(f"{where}: periodic curves (wrap = periodic) are closed loops, not strands with a root")
        if kind == "cubic" and basis != "catmullRom":
            raise ValueError(f"{where}: cubic {basis} curves are not read: their control vertices are not on the "
                             "curve, so a strand along it would not map onto the prim's vertices; convert them to "
                             "linear (or catmullRom) curves")
        if kind not in ("linear", "cubic"):
            raise ValueError(f"{where}: unknown curve type {kind!r}")
        counts = np.asarray(curves.GetCurveVertexCountsAttr().Get(time) or [], dtype=np.int64)
        raw = curves.GetPointsAttr().Get(time)
        points = np.asarray(raw if raw is not None else np.zeros((0, 3)), dtype=float).reshape(-1, 3)
        if np.any(counts < 0) or counts.sum() != len(points):
            raise ValueError(f"{where}: curveVertexCounts add up to {counts.sum()} vertices, the prim has "
                             f"{len(points)} points")
        matrix = np.array(curves.ComputeLocalToWorldTransform(time), dtype=float)
        scale = float(abs(np.linalg.det(matrix[:3, :3])) ** (1.0 / 3.0))
        with np.errstate(invalid="ignore", over="ignore"):  # a NaN point: the strand's validation names it
            world = points @ matrix[:3, :3] + matrix[3, :3]
            if y_up:
                world = np.column_stack([world[:, 0], -world[:, 2], world[:, 1]])
            world = world * mpu
        # varying data: one value per segment end, n on a linear curve, n - 2 on a catmullRom one (vstep 1;
        # pinned too, as UsdGeomBasisCurves.ComputeVaryingDataSize counts it)
        varying = np.maximum(counts - (2 if kind == "cubic" else 0), 1)
        primvars = UsdGeom.PrimvarsAPI(prim)

        def per_curve(source, name, interpolation):
            return _split(_values(source, time, where, name), interpolation, counts, varying, where, name)

        widths = per_curve_width = None
        widths_primvar = primvars.GetPrimvar("widths")
        if widths_primvar and widths_primvar.HasValue():  # primvars:widths takes precedence over widths
            widths = "primvars:widths"
            per_curve_width = per_curve(widths_primvar, widths, widths_primvar.GetInterpolation())
        elif curves.GetWidthsAttr().HasValue():
            widths = "widths"
            per_curve_width = per_curve(curves.GetWidthsAttr(), widths, curves.GetWidthsInterpolation())
        material = {}
        for name, primvar_name in MATERIAL_PRIMVARS.items():
            primvar = primvars.GetPrimvar(primvar_name)
            if primvar and primvar.HasValue():
                interpolation = primvar.GetInterpolation()
                if interpolation not in ("constant", "uniform"):
                    raise ValueError(f"{where}: {primvar_name} must be constant or uniform (one value per curve), "
                                     f"not {interpolation}")
                material[name] = per_curve(primvar, primvar_name, interpolation)
        theta = None
        primvar = primvars.GetPrimvar(THETA)
        if primvar and primvar.HasValue():
            if primvar.GetInterpolation() != "vertex":
                raise ValueError(f"{where}: {THETA} must have vertex interpolation (edge j's angle at vertex j)")
            theta = per_curve(primvar, THETA, "vertex")
        starts = np.r_[0, np.cumsum(counts)]
        prims.append(_Prim(prim, counts, scale, widths, [
            _Curve(f"{where}: curve {c}", world[starts[c]: starts[c + 1]],
                   None if widths is None else 0.5 * float(np.mean(per_curve_width[c])) * mpu * scale,
                   None if widths is None else float(np.mean(per_curve_width[c])),
                   {name: float(values[c][0]) for name, values in material.items()},
                   None if theta is None else theta[c][:-1])
            for c in range(len(counts))]))
    if not prims:
        raise ValueError(f"{path}: the stage has no BasisCurves prim: no strands to read")
    return prims


def load_stage(path, units: str | None = None, keep_invalid: bool = False, **material) -> list[Strand]:
    """Strands (m, Z up) of every BasisCurves prim of an OpenUSD stage (module docstring); ``units``
    must be None or the stage's own; material keywords override the stage's primvars and widths;
    keep_invalid: see file_io."""
    path = Path(path)
    check_material(material)
    stage = _open(path)
    prims = _read(stage, path, _metres_per_unit(stage, path, units))
    strands, implausible = [], []
    for curve in (c for p in prims for c in p.curves):
        options = {**MATERIAL, **curve.material, **material}
        if curve.radius is not None and "radius" not in material:
            options["radius"] = curve.radius
            why = implausible_radius(curve.points, curve.radius)
            if why:
                implausible.append((len(strands), curve.width, curve.radius, why))
        if curve.theta is not None:
            options["theta"] = curve.theta
        strands.append(make_strand(curve.points, curve.where, keep_invalid, **options))
    warn_implausible_radii(path, "widths", implausible)
    return strands


# ---- writing ----------------------------------------------------------------------------------

def save_stage(path, strands, results=None, solver: str | None = None, problem_options: dict | None = None,
               source=None, units: str | None = None) -> None:
    """Write ``strands`` (and, with ``results``, their parameters as primvars; module docstring) to the
    stage ``path``: a copy of the stage ``source`` they were read from, else a new stage in ``units``
    (default m). With results, also a JSON summary ``<path>.json`` (scenes.npz.save_summary)."""
    Sdf, Usd, UsdGeom, UsdUtils, Vt = _pxr()
    path, strands = Path(path), list(strands)
    if not is_stage(path):
        raise ValueError(f"{path}: an OpenUSD stage must end in {', '.join(EXTENSIONS)}")
    if results is not None:
        results = list(results)
        if len(results) != len(strands):
            raise ValueError(f"{path}: {len(strands)} strands but {len(results)} results; nothing written")
    path.parent.mkdir(parents=True, exist_ok=True)
    work = path.parent / f".{path.stem}.{uuid.uuid4().hex}.tmp{path.suffix}"
    try:
        if source is not None:
            source = Path(source)
            stage = _open(source)
            mpu = _metres_per_unit(stage, source, units)
            layer = Sdf.Layer.CreateNew(str(work))
            layer.TransferContent(stage.GetRootLayer())
            UsdUtils.ModifyAssetPaths(layer, _anchor(source.resolve().parent, path.resolve().parent))
            del stage
        else:
            if (units or "m") not in UNITS:
                raise ValueError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
            mpu = UNITS[units or "m"]
            layer = Sdf.Layer.CreateNew(str(work))
        stage = Usd.Stage.Open(layer)
        if source is None:
            _new_curves(stage, strands, mpu)
        prims = _read(stage, source or path, mpu)
        _match(prims, strands, path, source)
        offset = 0
        for prim in prims:
            mine = slice(offset, offset + len(prim.curves))
            offset = mine.stop
            if not prim.curves:
                continue
            _author_inputs(prim, strands[mine], mpu, path)
            if results is not None:
                _author_results(prim, strands[mine], results[mine], solver or results[mine][0].solver,
                                json.dumps(dict(problem_options or {}), sort_keys=True, default=body_spec))
        layer.Save()
        del stage, layer

        def copy(f):
            with open(work, "rb") as built:
                shutil.copyfileobj(built, f)
        write_atomically(path, copy)
    finally:
        work.unlink(missing_ok=True)
    if results is not None:
        save_summary(path.with_suffix(".json"), strands, results,
                     solver or (results[0].solver if results else "unknown"), dict(problem_options or {}))


def _anchor(source_dir: Path, output_dir: Path):
    """ModifyAssetPaths callback: a relative asset path naming a file beside the source, relative to
    the output's folder instead."""
    def anchored(asset: str) -> str:
        if not asset or output_dir == source_dir or os.path.isabs(asset) or ":" in asset:
            return asset
        target = source_dir / asset
        return Path(os.path.relpath(target, output_dir)).as_posix() if target.exists() else asset
    return anchored


def _new_curves(stage, strands, mpu: float) -> None:
    """A new stage's prim ``/Strands``: every strand as a linear curve, metres / mpu, Z up."""
    _, _, UsdGeom, _, Vt = _pxr()
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    curves = UsdGeom.BasisCurves.Define(stage, "/Strands")
    stage.SetDefaultPrim(curves.GetPrim())
    curves.CreateTypeAttr(UsdGeom.Tokens.linear)
    curves.CreateWrapAttr(UsdGeom.Tokens.nonperiodic)
    points = [np.asarray(s.points, dtype=float).reshape(-1, 3) if np.size(s.points) % 3 == 0 else np.zeros((0, 3))
              for s in strands]
    curves.CreateCurveVertexCountsAttr(Vt.IntArray([len(p) for p in points]))
    curves.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(
        np.concatenate(points or [np.zeros((0, 3))]) / mpu, dtype=np.float32)))


def _match(prims, strands, path: Path, source) -> None:
    """Raise ValueError unless ``strands`` are the curves of ``prims``, one by one."""
    curves = [c for p in prims for c in p.curves]
    counts = [int(n) for p in prims for n in p.counts]
    origin = f"the curves of {source}" if source is not None else "the curves written"
    if len(curves) != len(strands):
        raise ValueError(f"{path}: {len(strands)} strands, but {origin} are {len(curves)}; nothing written")
    for k, (curve, n, strand) in enumerate(zip(curves, counts, strands)):
        if strand.n_vertices != n:
            raise ValueError(f"{path}: strand {k} has {strand.n_vertices} vertices, {curve.where} has {n}; "
                             "nothing written")


def _author_inputs(prim: _Prim, strands, mpu: float, path: Path) -> None:
    """Author widths, the material primvars and theta where the stage does not already give the
    strands' values, so that the written stage reads back as ``strands``."""
    Sdf, _, UsdGeom, _, Vt = _pxr()
    primvars, curves = UsdGeom.PrimvarsAPI(prim.prim), UsdGeom.BasisCurves(prim.prim)
    valid = [isinstance(s, Strand) for s in strands]

    def differs(values, recorded) -> bool:
        return any(ok and (r is None or not np.isclose(v, r, rtol=1e-12, atol=0))
                   for ok, v, r in zip(valid, values, recorded))

    radii = [s.radius if ok else (c.radius or MATERIAL["radius"]) for s, ok, c in zip(strands, valid, prim.curves)]
    if prim.widths is None or differs(radii, [c.radius for c in prim.curves]):
        target = primvars.GetPrimvar("widths") if prim.widths == "primvars:widths" else None
        attribute = target.GetAttr() if target else curves.CreateWidthsAttr()
        attribute.Set(Vt.FloatArray([2.0 * r / (mpu * prim.scale) for r in radii]))
        if target:
            target.SetInterpolation(UsdGeom.Tokens.uniform)
        else:
            curves.SetWidthsInterpolation(UsdGeom.Tokens.uniform)
    for name, primvar_name in MATERIAL_PRIMVARS.items():
        values = [getattr(s, name) if ok else c.material.get(name, MATERIAL[name])
                  for s, ok, c in zip(strands, valid, prim.curves)]
        if not differs(values, [c.material.get(name) for c in prim.curves]):
            continue
        existing = primvars.GetPrimvar(primvar_name)
        if existing and existing.HasValue() and not existing.GetTypeName().isArray:
            if len(set(values)) > 1:
                raise ValueError(f"{path}: {prim.prim.GetPath()}: {primvar_name} is a single value on the source, "
                                 "the strands have different ones; nothing written")
            existing.Set(values[0])
            continue
        primvar = existing if existing and existing.HasValue() else primvars.CreatePrimvar(
            primvar_name, Sdf.ValueTypeNames.DoubleArray, UsdGeom.Tokens.uniform)
        primvar.SetInterpolation(UsdGeom.Tokens.uniform)
        primvar.Set(Vt.DoubleArray(values))
    recorded = [c.theta for c in prim.curves]
    angles = [s.theta if ok else (t if t is not None else np.zeros(max(s.n_vertices - 1, 0)))
              for s, ok, t in zip(strands, valid, recorded)]
    stale = any(ok and (t is None and np.any(a) or t is not None and not np.array_equal(a, t))
                for ok, a, t in zip(valid, angles, recorded))
    if stale:
        primvar = primvars.GetPrimvar(THETA)
        if not (primvar and primvar.HasValue()):
            primvar = primvars.CreatePrimvar(THETA, Sdf.ValueTypeNames.DoubleArray, UsdGeom.Tokens.vertex)
        primvar.Set(Vt.DoubleArray(np.concatenate([_padded(a, n, 0) for a, n in zip(angles, prim.counts)]
                                                  or [np.zeros(0)]).tolist()))


def _padded(values, n: int, first: int, columns: int | None = None) -> np.ndarray:
    """A curve of n vertices' per-vertex array: ``values`` (one row per element) at vertices first,
    first + 1, ..., 0 elsewhere; all NaN when values is None (no parameters)."""
    out = np.full((n, columns) if columns else n, np.nan if values is None else 0.0)
    if values is not None:
        count = min(len(values), max(n - first, 0))
        out[first: first + count] = np.asarray(values, dtype=float)[:count]
    return out


def _author_results(prim: _Prim, strands, results, solver: str, options: str) -> None:
    """The primvars of the module docstring's table on one prim."""
    Sdf, _, UsdGeom, _, Vt = _pxr()
    primvars = UsdGeom.PrimvarsAPI(prim.prim)
    T = Sdf.ValueTypeNames

    def author(name, type_name, interpolation, value):
        primvar = primvars.CreatePrimvar(name, type_name, interpolation)
        primvar.SetInterpolation(interpolation)
        primvar.Set(value)

    counts = [int(n) for n in prim.counts]
    for block, name in PHYSICAL_PRIMVARS.items():
        first = 0 if PHYSICAL[block] == "edge" else 1
        columns = 2 if block == "rest_curvature" else None
        parts = [_padded(r.physical.get(block), n, first, columns) for r, n in zip(results, counts)]
        values = np.concatenate(parts) if parts else np.zeros((0, columns) if columns else 0)
        if columns:
            author(name, T.Double2Array, UsdGeom.Tokens.vertex, Vt.Vec2dArray.FromNumpy(np.ascontiguousarray(values)))
        else:
            author(name, T.DoubleArray, UsdGeom.Tokens.vertex, Vt.DoubleArray.FromNumpy(values))
    for name, (block, modulus) in MULTIPLIERS.items():
        first = 0 if PHYSICAL[block] == "edge" else 1
        parts = [_padded(np.asarray(r.physical[block]) / getattr(s, modulus)
                         if block in r.physical and isinstance(s, Strand) else None, n, first)
                 for s, r, n in zip(strands, results, counts)]
        author(name, T.DoubleArray, UsdGeom.Tokens.vertex, Vt.DoubleArray.FromNumpy(np.concatenate(parts)))
    uniform = UsdGeom.Tokens.uniform
    author("sagfree:status", T.TokenArray, uniform, Vt.TokenArray([r.status for r in results]))
    author("sagfree:message", T.StringArray, uniform, Vt.StringArray([r.message for r in results]))
    author("sagfree:minEigenvalue", T.DoubleArray, uniform, Vt.DoubleArray([float(r.min_eigenvalue) for r in results]))
    author("sagfree:length", T.DoubleArray, uniform, Vt.DoubleArray([float(s.length) for s in strands]))
    author("sagfree:radius", T.DoubleArray, uniform,
           Vt.DoubleArray([float(getattr(s, "radius", np.nan)) for s in strands]))
    author("sagfree:attachments", T.StringArray, uniform,
           Vt.StringArray([getattr(s, "attachments", "") for s in strands]))
    author("sagfree:parameterCount", T.IntArray, uniform, Vt.IntArray([int(np.size(r.p)) for r in results]))
    constant = UsdGeom.Tokens.constant
    p = np.concatenate([np.asarray(r.p, dtype=float).reshape(-1) for r in results])
    author("sagfree:parameters", T.DoubleArray, constant, Vt.DoubleArray.FromNumpy(p))
    author("sagfree:solver", T.String, constant, solver)
    author("sagfree:problemOptions", T.String, constant, options)
    author("sagfree:format", T.String, constant, FORMAT)


# ---- reading the parameters back --------------------------------------------------------------

def load_stage_parameters(path) -> ParameterFile | None:
    """The parameters a stage written by ``save_stage`` carries, as a ParameterFile (scenes.npz), or
    None if its curves carry none. Errors name the file, the prim and the primvar."""
    _, Usd, UsdGeom, *_ = _pxr()
    path = Path(path)
    stage = _open(path)
    time = Usd.TimeCode.EarliestTime()
    prims = [prim for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies())
             if prim.IsA(UsdGeom.BasisCurves)]
    carrying = [bool(UsdGeom.PrimvarsAPI(p).GetPrimvar("sagfree:parameters")) for p in prims]
    if not any(carrying):
        return None
    p, status, message, lengths, radii, attachments, counts = [], [], [], [], [], [], []
    physical = {block: [] for block in PHYSICAL}
    solver = options = None
    for prim, carries in zip(prims, carrying):
        where = f"{path}: {prim.GetPath()}"
        curve_counts = np.asarray(UsdGeom.BasisCurves(prim).GetCurveVertexCountsAttr().Get(time) or [], dtype=int)
        if not curve_counts.size:
            continue
        if not carries:
            raise ValueError(f"{where}: carries no sagfree:parameters while other prims do (a stage partly "
                             "written, or curves added after optimizing?)")
        primvars = UsdGeom.PrimvarsAPI(prim)

        def get(name, size=None, strings=False):
            primvar = primvars.GetPrimvar(name)
            value = primvar.Get(time) if primvar else None
            if value is None:
                raise ValueError(f"{where}: sagfree parameters without {name}")
            if strings:
                value = [str(v) for v in value] if size is not None else str(value)
            else:
                value = np.asarray(value, dtype=float)
            if size is not None and len(value) != size:
                raise ValueError(f"{where}: {name} has {len(value)} values, expected {size}")
            return value

        if get("sagfree:format", strings=True) != FORMAT:
            raise ValueError(f"{where}: sagfree:format is not {FORMAT!r}: written by another version")
        prim_solver, prim_options = get("sagfree:solver", strings=True), get("sagfree:problemOptions", strings=True)
        if solver is not None and (prim_solver, prim_options) != (solver, options):
            raise ValueError(f"{where}: its solver or problem options differ from the stage's other prims")
        solver, options = prim_solver, prim_options
        curves = len(curve_counts)
        sizes = get("sagfree:parameterCount", curves).astype(int)
        vector = get("sagfree:parameters", int(sizes.sum()))
        ends = np.cumsum(sizes)
        p += [vector[end - size: end] for end, size in zip(ends, sizes)]
        status += get("sagfree:status", curves, strings=True)
        message += get("sagfree:message", curves, strings=True)
        attachments += get("sagfree:attachments", curves, strings=True)
        lengths += list(get("sagfree:length", curves))
        radii += list(get("sagfree:radius", curves))
        counts += list(curve_counts)
        starts = np.r_[0, np.cumsum(curve_counts)]
        for block, name in PHYSICAL_PRIMVARS.items():
            values = get(name, int(curve_counts.sum()))
            first = 0 if PHYSICAL[block] == "edge" else 1
            physical[block] += [values[s + first: s + n - 1] for s, n in zip(starts, curve_counts)]
    try:
        problem_options = json.loads(options)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: sagfree:problemOptions is not valid JSON ({exc})") from None
    return ParameterFile(p, status, message, solver, problem_options, np.asarray(counts, dtype=np.int64),
                         np.asarray(lengths, dtype=float), physical, {"radius": np.asarray(radii, dtype=float)},
                         attachments)
