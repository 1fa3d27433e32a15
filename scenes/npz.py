"""Strands and optimized parameters as ``.npz`` files (DESIGN sections 8 and 10).

Strands file: ``points`` (total vertices, 3) in m, all strands one after another; ``offsets``
(strands + 1), strand k being points[offsets[k]:offsets[k+1]]; per strand ``radius``,
``youngs_modulus``, ``shear_modulus``, ``density`` (SI) and ``root`` ("clamped" | "pinned");
``theta`` (total edges) material angles, strand k owning n_k - 1 of them in order. Strands may have
different vertex counts.

Parameters file (written by ``sagfree optimize``): ``p`` (all strands' normalized parameters one
after another), ``p_offsets`` (strands + 1), ``status`` and ``message`` per strand, ``solver``, and
``problem_options``: the Problem options as JSON, so that a reader rebuilds the same Problem. A strand
that failed keeps its slot (NaN parameters, its status and message). The command-line issue adds
named arrays per block and a JSON summary next to these.

Reading checks every array and names the file, the array and the strand that is wrong.
"""
from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sagfree.formulation.strand import Strand

MATERIAL_FIELDS = ("radius", "youngs_modulus", "shear_modulus", "density")
STRANDS_VERSION = 1
PARAMETERS_VERSION = 1


def _write_atomically(path: Path, arrays: dict) -> None:
    """np.savez into a temporary file next to ``path``, then rename over it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".npz")
    try:
        with os.fdopen(handle, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


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
        **{f: np.array([getattr(s, f) for s in strands], dtype=float) for f in MATERIAL_FIELDS},
    }
    _write_atomically(Path(path), arrays)


def load_strands(path) -> list[Strand]:
    """Strands of a strands ``.npz`` file; errors name the strand and what is wrong with it."""
    path = Path(path)
    arrays = _open(path, "strands", ("points", "offsets"))
    points = np.asarray(arrays["points"], dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{path}: 'points' must have shape (vertices, 3), got {points.shape}")
    offsets = _offsets(path, arrays, "offsets", len(points))
    count = offsets.size - 1
    per_strand = {}
    for name in (*MATERIAL_FIELDS, "root"):
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
    strands = []
    for k in range(count):
        options = {name: (str(v[k]) if name == "root" else float(v[k])) for name, v in per_strand.items()}
        if theta is not None:
            options["theta"] = theta[theta_offsets[k]: theta_offsets[k + 1]]
        try:
            strands.append(Strand(points[offsets[k]: offsets[k + 1]], **options))
        except ValueError as exc:
            raise ValueError(f"{path}: strand {k}: {exc}") from None
    return strands


@dataclass
class ParameterFile:
    """Contents of a parameters ``.npz`` file: one p per strand (NaN-filled when the strand failed)."""

    p: list[np.ndarray]
    status: list[str]
    message: list[str]
    solver: str
    problem_options: dict


def save_parameters(path, results, solver: str, problem_options: dict) -> None:
    """Write the Results of ``sagfree.optimize`` (one per strand, in order) to a parameters file."""
    results = list(results)
    sizes = [r.p.size for r in results]
    arrays = {
        "format": np.array(f"sagfree-parameters-{PARAMETERS_VERSION}"),
        "p": np.concatenate([r.p for r in results]) if results else np.zeros(0),
        "p_offsets": np.r_[0, np.cumsum(sizes)].astype(np.int64),
        "status": np.array([r.status for r in results], dtype=str),
        "message": np.array([r.message for r in results], dtype=str),
        "solver": np.array(solver),
        "problem_options": np.array(json.dumps(problem_options, sort_keys=True)),
    }
    _write_atomically(Path(path), arrays)


def load_parameters(path) -> ParameterFile:
    """Read a parameters file written by ``save_parameters``."""
    path = Path(path)
    arrays = _open(path, "parameters", ("p", "p_offsets", "status", "problem_options"))
    p = np.asarray(arrays["p"], dtype=float)
    offsets = _offsets(path, arrays, "p_offsets", p.size)
    count = offsets.size - 1
    status = [str(s) for s in np.atleast_1d(arrays["status"])]
    message = [str(s) for s in np.atleast_1d(arrays.get("message", np.full(count, "")))]
    if len(status) != count or len(message) != count:
        raise ValueError(f"{path}: 'status' and 'message' must have one entry per strand ({count})")
    try:
        options = json.loads(str(arrays["problem_options"]))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: 'problem_options' is not valid JSON ({exc})") from None
    return ParameterFile([p[offsets[k]: offsets[k + 1]] for k in range(count)], status, message,
                         str(arrays.get("solver", "unknown")), options)
