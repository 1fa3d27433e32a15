"""Strands and optimized parameters as ``.npz`` files (DESIGN sections 8 and 10).

Strands file: ``points`` (total vertices, 3) in m, all strands one after another; ``offsets``
(strands + 1), strand k being points[offsets[k]:offsets[k+1]]; per strand ``radius``,
``youngs_modulus``, ``shear_modulus``, ``density`` (SI), ``root`` ("clamped" | "pinned") and ``tip``
("" for a free tip, "pinned" | "clamped"); ``theta`` (total edges) material angles, strand k owning
n_k - 1 of them in order; ``pins`` (vertex indices within their strand, all strands one after
another, strand k owning pins[pin_offsets[k]:pin_offsets[k+1]]) and, when any strand has loads,
``loads`` (total vertices, 3) in N (zero rows for strands without). Strands may have different vertex
counts. ``tip``, ``pins`` and ``loads`` are optional on reading.

Parameters file (written by ``sagfree optimize``):
- per block, in physical units, all strands one after another: ``rest_length`` (m) and
  ``stretch_modulus`` (Pa) per edge, strand k owning rows edge_offsets[k]:edge_offsets[k+1];
  ``rest_curvature`` ((rows, 2), dimensionless), ``rest_twist`` (rad), ``bend_modulus`` and
  ``twist_modulus`` (Pa) per interior vertex, rows vertex_offsets[k]:vertex_offsets[k+1];
  NaN rows for a strand that failed;
- per strand: ``p`` (the normalized parameters of the Problem layout, one after another, with
  ``p_offsets``), ``status``, ``message``, ``vertex_counts``, ``lengths`` (m) and the material
  (``radius``, ``youngs_modulus``, ``shear_modulus``, ``density``): a reader checks that it is given
  the same strands, since OBJ and .data files store no material;
- ``solver`` and ``problem_options`` (the Problem options as JSON, so that a reader rebuilds the same
  Problem);
- ``attachments``: each strand's ``Strand.attachments`` (root, tip, pins, loads), which a reader
  checks too (a strand held differently is a different problem);
- ``points`` (total vertices, 3), m: the geometry the parameters were computed for; a reader
  compares the strands it is given vertex by vertex (ParameterFile.check_matches: equal, within
  GEOMETRY_TOLERANCE with a note, or refused).
Next to it, ``<name>.json`` summarizes each strand's status, message, |c|_inf, residual force,
R(p*), iterations, stiffening, stability and time.

Reading checks every array and names the file, the array and the strand that is wrong.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sagfree.formulation.strand import Strand

from .file_io import make_strand, write_atomically

MATERIAL_FIELDS = ("radius", "youngs_modulus", "shear_modulus", "density")
#: Largest vertex offset (over the strand's length) between the geometry given to ``simulate`` and the
#: one the parameters were computed for that is still the same strand (with a note), beyond the
#: rounding of any file format (float32: ~1e-7 L); the still-threshold of ``simulate --max-sag``.
GEOMETRY_TOLERANCE = 1e-6
STRANDS_VERSION = 1
PARAMETERS_VERSION = 1


def _open(path: Path, kind: str, required: tuple[str, ...]) -> dict:
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file") from None
    except Exception as exc:  # noqa: BLE001 - zip / npy errors of every kind: a damaged file
        raise ValueError(f"{path}: not a readable .npz {kind} file ({exc})") from None
    missing = [k for k in required if k not in arrays]
    if missing:
        raise ValueError(f"{path}: not a sagfree {kind} file, missing array(s) {', '.join(missing)}")
    return arrays


def _offsets(path: Path, arrays: dict, name: str, total: int) -> np.ndarray:
    offsets = np.asarray(arrays[name])
    if (offsets.ndim != 1 or offsets.size < 1 or not np.issubdtype(offsets.dtype, np.integer)
            or offsets[0] != 0 or offsets[-1] != total or np.any(np.diff(offsets) < 0)):
        raise ValueError(f"{path}: '{name}' must be non-decreasing integers from 0 to {total}")
    return offsets.astype(np.int64)


def save_strands(path, strands: list[Strand]) -> None:
    """Write ``strands`` to a strands ``.npz`` file (module docstring)."""
    strands = list(strands)
    counts = [s.n_vertices for s in strands]
    arrays = {
        "format": np.array(f"sagfree-strands-{STRANDS_VERSION}"),
        "points": np.concatenate([s.points for s in strands]) if strands else np.zeros((0, 3)),
        "offsets": np.r_[0, np.cumsum(counts)].astype(np.int64),
        "theta": np.concatenate([s.theta for s in strands]) if strands else np.zeros(0),
        "root": np.array([s.root for s in strands], dtype=str),
        "tip": np.array([s.tip or "" for s in strands], dtype=str),
        "pins": np.concatenate([s.pins for s in strands]).astype(np.int64) if strands else np.zeros(0, np.int64),
        "pin_offsets": np.r_[0, np.cumsum([s.pins.size for s in strands])].astype(np.int64),
        **{f: np.array([getattr(s, f) for s in strands], dtype=float) for f in MATERIAL_FIELDS},
    }
    if any(s.loads is not None for s in strands):
        arrays["loads"] = np.concatenate([np.zeros((s.n_vertices, 3)) if s.loads is None else s.loads
                                          for s in strands])
    write_atomically(path, lambda f: np.savez(f, **arrays))


def load_strands(path, keep_invalid: bool = False) -> list[Strand]:
    """Strands of a strands ``.npz`` file; errors name the strand and what is wrong with it (with
    ``keep_invalid``, a strand's error becomes an InvalidStrand in its slot; file_io)."""
    path = Path(path)
    arrays = _open(path, "strands", ("points", "offsets"))
    points = np.asarray(arrays["points"], dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{path}: 'points' must have shape (vertices, 3), got {points.shape}")
    offsets = _offsets(path, arrays, "offsets", len(points))
    count = offsets.size - 1
    per_strand = {}
    for name in (*MATERIAL_FIELDS, "root", "tip"):
        if name in arrays:
            if np.shape(arrays[name]) != (count,):
                raise ValueError(f"{path}: '{name}' must have one entry per strand ({count}), "
                                 f"got shape {np.shape(arrays[name])}")
            per_strand[name] = arrays[name]
    counts = np.diff(offsets)
    theta = arrays.get("theta")
    if theta is not None and np.shape(theta) != (int(np.maximum(counts - 1, 0).sum()),):
        raise ValueError(f"{path}: 'theta' must have one angle per edge ({int(np.maximum(counts - 1, 0).sum())}),"
                         f" got shape {np.shape(theta)}")
    theta_offsets = np.r_[0, np.cumsum(np.maximum(counts - 1, 0))]
    pins = arrays.get("pins")
    if pins is not None:
        if pins.ndim != 1 or not np.issubdtype(pins.dtype, np.integer) or "pin_offsets" not in arrays:
            raise ValueError(f"{path}: 'pins' must be a 1-D integer array with 'pin_offsets'")
        pin_offsets = _offsets(path, arrays, "pin_offsets", len(pins))
        if pin_offsets.size != count + 1:
            raise ValueError(f"{path}: 'pin_offsets' must have {count + 1} entries, got {pin_offsets.size}")
    loads = arrays.get("loads")
    if loads is not None and np.shape(loads) != (len(points), 3):
        raise ValueError(f"{path}: 'loads' must have shape ({len(points)}, 3) (N per vertex), got {np.shape(loads)}")
    strands = []
    for k in range(count):
        options = {name: (str(v[k]) if name in ("root", "tip") else float(v[k])) for name, v in per_strand.items()}
        if "tip" in options:
            options["tip"] = options["tip"] or None
        if theta is not None:
            options["theta"] = theta[theta_offsets[k]: theta_offsets[k + 1]]
        if pins is not None:
            options["pins"] = pins[pin_offsets[k]: pin_offsets[k + 1]]
        if loads is not None and np.any(loads[offsets[k]: offsets[k + 1]]):
            options["loads"] = loads[offsets[k]: offsets[k + 1]]
        strands.append(make_strand(points[offsets[k]: offsets[k + 1]], f"{path}: strand {k}", keep_invalid,
                                   **options))
    return strands


#: Physical parameter arrays of a parameters file: name -> what each strand has one row per.
PHYSICAL = {"rest_length": "edge", "stretch_modulus": "edge", "rest_curvature": "vertex",
            "rest_twist": "vertex", "bend_modulus": "vertex", "twist_modulus": "vertex"}


@dataclass
class ParameterFile:
    """Contents of a parameters ``.npz`` file.

    p: one normalized parameter vector per strand (empty when the strand failed before its Problem
    was built); status, message per strand; solver; problem_options; vertex_counts, lengths (m) and
    material (radius, moduli, density per strand) of the strands they were computed for; physical:
    name -> one array per strand (PHYSICAL; NaN where the strand has no parameters).
    """

    p: list[np.ndarray]
    status: list[str]
    message: list[str]
    solver: str
    problem_options: dict
    vertex_counts: np.ndarray
    lengths: np.ndarray
    physical: dict[str, list[np.ndarray]]
    material: dict[str, np.ndarray]
    attachments: list[str] | None = None  # Strand.attachments per strand ("" for an invalid one)
    points: list[np.ndarray] | None = None  # the geometry per strand (m; files before it: None)

    def with_material(self, strands, fields) -> list:
        """``strands`` with the material ``fields`` (of MATERIAL_FIELDS) the parameters were computed
        for: what ``sagfree simulate`` does for a geometry file that stores no material (OBJ, .data)
        or only a radius (.hair), so that the parameters are checked on the strands they were
        computed for instead of on default material."""
        if not fields or len(strands) != len(self.p):
            return list(strands)  # check_matches names the mismatch
        out = []
        for k, strand in enumerate(strands):
            values = {f: float(self.material[f][k]) for f in fields if f in self.material}
            usable = isinstance(strand, Strand) and all(np.isfinite(v) and v > 0 for v in values.values())
            out.append(strand.replaced(**values) if usable and values else strand)
        return out

    def check_matches(self, strands, source: str = "the strands") -> list[str]:
        """Raise ValueError unless ``strands`` are those the parameters were computed for; return a
        note per strand whose geometry differs within GEOMETRY_TOLERANCE (the file's rounding: a
        float32 .hair of a float64 groom, 5e-8 L)."""
        if len(strands) != len(self.p):
            raise ValueError(f"the parameters are for {len(self.p)} strands, {source} has {len(strands)}")
        notes = []
        for k, strand in enumerate(strands):
            if strand.n_vertices != self.vertex_counts[k] or not np.isclose(
                    strand.length, self.lengths[k], rtol=1e-6, equal_nan=True):
                raise ValueError(
                    f"strand {k} of {source} has {strand.n_vertices} vertices and length {strand.length:.6g} m, "
                    f"the parameters were computed for {self.vertex_counts[k]} vertices and "
                    f"{self.lengths[k]:.6g} m (same file and --units as for optimize?)")
            for name, values in self.material.items():
                if not np.isclose(getattr(strand, name, np.nan), values[k], rtol=1e-6, equal_nan=True):
                    raise ValueError(
                        f"strand {k} of {source} has {name} {getattr(strand, name, np.nan):.6g}, the parameters "
                        f"were computed for {values[k]:.6g} (a file format that stores no {name}? use .npz)")
            held = getattr(strand, "attachments", "")
            if self.attachments is not None and self.attachments[k] and held != self.attachments[k]:
                raise ValueError(f"strand {k} of {source} is held with {held}; the parameters were computed "
                                 f"with {self.attachments[k]} (pass the same --root/--tip/--pin as to optimize)")
            note = self._geometry_note(k, strand, source)
            if note:
                notes.append(note)
        return notes

    def _geometry_note(self, k: int, strand, source: str) -> str | None:
        """None if strand k's vertices equal those the parameters were computed for (to 1e-12 L), a
        note if they differ by at most GEOMETRY_TOLERANCE L, else a ValueError naming the vertex."""
        if self.points is None or not isinstance(strand, Strand) or not np.all(np.isfinite(self.points[k])):
            return None
        offset = np.linalg.norm(strand.points - self.points[k], axis=1)
        vertex, length = int(np.argmax(offset)), strand.length
        if offset[vertex] <= 1e-12 * length:
            return None
        where = (f"strand {k} of {source}: vertex {vertex} is {offset[vertex]:.3g} m ({offset[vertex] / length:.2g} L) "
                 "from where it was when the parameters were computed")
        if offset[vertex] > GEOMETRY_TOLERANCE * length:
            raise ValueError(f"{where}, more than {GEOMETRY_TOLERANCE:g} L: another geometry (same file and --units "
                             "as for optimize?)")
        return (f"{where}; within {GEOMETRY_TOLERANCE:g} L (a file's rounding, e.g. float32), so the check goes on, "
                "but part of the sag it reports comes from this offset, amplified along the strand (a root edge "
                "turned by it turns the whole strand)")


def save_parameters(path, strands, results, solver: str, problem_options: dict) -> None:
    """Write the Results of ``sagfree.optimize`` (one per strand, in order) to a parameters file, and
    a JSON summary (same name, ``.json``) with each strand's status, residuals, stiffening, time."""
    strands, results = list(strands), list(results)
    counts = np.array([s.n_vertices for s in strands], dtype=np.int64)
    rows = {"edge": np.maximum(counts - 1, 0), "vertex": np.maximum(counts - 2, 0)}
    arrays = {
        "format": np.array(f"sagfree-parameters-{PARAMETERS_VERSION}"),
        "p": np.concatenate([r.p for r in results]) if results else np.zeros(0),
        "p_offsets": np.r_[0, np.cumsum([r.p.size for r in results])].astype(np.int64),
        "status": np.array([r.status for r in results], dtype=str),
        "message": np.array([r.message for r in results], dtype=str),
        "solver": np.array(solver),
        "problem_options": np.array(json.dumps(problem_options, sort_keys=True, default=body_spec)),
        "attachments": np.array([getattr(s, "attachments", "") for s in strands], dtype=str),
        "vertex_counts": counts,
        "lengths": np.array([s.length for s in strands]),
        "points": np.concatenate([_geometry(s) for s in strands]) if strands else np.zeros((0, 3)),
        **{f: np.array([getattr(s, f, np.nan) for s in strands], dtype=float) for f in MATERIAL_FIELDS},
        "edge_offsets": np.r_[0, np.cumsum(rows["edge"])].astype(np.int64),
        "vertex_offsets": np.r_[0, np.cumsum(rows["vertex"])].astype(np.int64),
    }
    for name, kind in PHYSICAL.items():
        width = (2,) if name == "rest_curvature" else ()
        parts = [r.physical[name] if name in r.physical else np.full((rows[kind][k], *width), np.nan)
                 for k, r in enumerate(results)]
        arrays[name] = np.concatenate(parts) if parts else np.zeros((0, *width))
    write_atomically(path, lambda f: np.savez(f, **arrays))
    save_summary(Path(path).with_suffix(".json"), strands, results, solver, problem_options)


def save_summary(path, strands, results, solver: str, problem_options: dict) -> None:
    """The JSON summary of a run (each strand's status, message, residuals, stiffening, stability,
    time), beside a parameters file or an OpenUSD stage (scenes.usd); NaN as null (strict JSON)."""
    summary = {"solver": solver, "problem_options": json.loads(json.dumps(problem_options, default=body_spec)),
               "strands": [
        {"strand": k, "vertices": int(s.n_vertices), "status": r.status, "message": r.message,
         "residual_inf": r.residual_inf, "max_force_N": r.max_force, "objective": r.objective,
         "time_s": r.time, "iterations": r.iterations, "stiffening": r.stiffening,
         "min_eigenvalue_s-2": r.min_eigenvalue, "stable": r.stable}
        for k, (s, r) in enumerate(zip(strands, results))]}
    text = json.dumps(_finite_or_none(summary), indent=1, allow_nan=False)
    write_atomically(path, lambda f: f.write(text.encode()))


def load_parameters(path) -> ParameterFile:
    """Read a parameters file written by ``save_parameters``."""
    path = Path(path)
    arrays = _open(path, "parameters", ("p", "p_offsets", "status", "problem_options", "vertex_counts",
                                        "lengths", "edge_offsets", "vertex_offsets", *PHYSICAL))
    p = np.asarray(arrays["p"], dtype=float)
    offsets = _offsets(path, arrays, "p_offsets", p.size)
    count = offsets.size - 1
    status = [str(s) for s in np.atleast_1d(arrays["status"])]
    message = [str(s) for s in np.atleast_1d(arrays.get("message", np.full(count, "")))]
    counts, lengths = np.asarray(arrays["vertex_counts"]), np.asarray(arrays["lengths"], dtype=float)
    if not len(status) == len(message) == counts.size == lengths.size == count:
        raise ValueError(f"{path}: 'status', 'message', 'vertex_counts' and 'lengths' must have one entry per "
                         f"strand ({count})")
    try:
        options = json.loads(str(arrays["problem_options"]))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: 'problem_options' is not valid JSON ({exc})") from None
    physical = {}
    for name, kind in PHYSICAL.items():
        values = np.asarray(arrays[name], dtype=float)
        rows = _offsets(path, arrays, f"{kind}_offsets", len(values))
        physical[name] = [values[rows[k]: rows[k + 1]] for k in range(count)]
    material = {f: np.asarray(arrays[f], dtype=float) for f in MATERIAL_FIELDS if f in arrays}
    if any(values.shape != (count,) for values in material.values()):
        raise ValueError(f"{path}: material arrays must have one entry per strand ({count})")
    attachments = arrays.get("attachments")
    if attachments is not None and np.shape(attachments) != (count,):
        raise ValueError(f"{path}: 'attachments' must have one entry per strand ({count})")
    points = arrays.get("points")
    if points is not None:
        if np.shape(points) != (int(counts.sum()), 3):
            raise ValueError(f"{path}: 'points' must have shape ({int(counts.sum())}, 3), one row per vertex")
        vertex_rows = np.r_[0, np.cumsum(counts)]
        points = [np.asarray(points[vertex_rows[k]: vertex_rows[k + 1]], dtype=float) for k in range(count)]
    return ParameterFile([p[offsets[k]: offsets[k + 1]] for k in range(count)], status, message,
                         str(arrays.get("solver", "unknown")), options, counts, lengths, physical, material,
                         None if attachments is None else [str(a) for a in attachments], points)


def _geometry(strand) -> np.ndarray:
    """A strand's (n, 3) vertices for the parameters file; NaN rows for an invalid strand's odd shape."""
    points = np.asarray(strand.points, dtype=float)
    return points if points.shape == (strand.n_vertices, 3) else np.full((strand.n_vertices, 3), np.nan)


def body_spec(value) -> str:
    """JSON for a Body in the problem options: its spec (formulation.bodies.parse_body reads it)."""
    if hasattr(value, "spec"):
        return value.spec
    raise TypeError(f"cannot record {value!r} in a parameters file")


def _finite_or_none(value):
    """The summary with NaN and infinities as null (strict JSON)."""
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite_or_none(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value
