"""Checkpoints of a long batch, so that ``sagfree optimize --resume`` continues an interrupted run.

While ``sagfree optimize ... -o OUT`` runs, every finished chunk of strands is written (atomically)
to ``OUT.partial/``, next to a manifest holding a fingerprint of the input strands, the solver, the
Problem options and the sagfree version. ``--resume`` reads the finished chunks back and solves only
the strands they lack; since every strand is solved by the same deterministic code from the same
start, the final file equals an uninterrupted run's. A resume whose fingerprint differs (other
strands, options or version) is refused rather than mixed. The directory is removed once OUT is
written.
"""
from __future__ import annotations

import hashlib
import json
import pickle
import shutil
from pathlib import Path

import numpy as np

from sagfree.scenes.file_io import write_atomically

from sagfree.contract.result import Result

MANIFEST = "manifest.json"


def fingerprint(strands, solver: str, options: dict) -> str:
    """sha256 over every strand's geometry, material and attachments, the solver, the options and the version."""
    from sagfree import __version__

    digest = hashlib.sha256(json.dumps([solver, options, __version__], sort_keys=True, default=repr).encode())
    for strand in strands:
        digest.update(np.ascontiguousarray(strand.points, dtype=float).tobytes())
        for name in ("theta", "radius", "youngs_modulus", "shear_modulus", "density", "root", "tip", "pins", "loads",
                     "message"):
            value = getattr(strand, name, None)
            digest.update(np.asarray(value).tobytes() if isinstance(value, np.ndarray) else repr(value).encode())
    return digest.hexdigest()


class Checkpoint:
    """The finished strands of a run writing ``output``: ``done`` maps strand index -> Result."""

    def __init__(self, output, strands, solver: str, options: dict, resume: bool):
        self.directory = Path(f"{output}.partial")
        self.done: dict[int, Result] = {}
        key = fingerprint(strands, solver, options)
        manifest = self.directory / MANIFEST
        if self.directory.exists():
            if resume:
                found = json.loads(manifest.read_text()).get("fingerprint") if manifest.exists() else None
                if found != key:
                    raise ValueError(f"{self.directory} is from a run with other strands, solver, options or "
                                     "sagfree version; remove it, or run without --resume")
                for chunk in sorted(self.directory.glob("chunk-*.pkl")):
                    indices, results = pickle.loads(chunk.read_bytes())
                    self.done.update(zip(indices, results))
            else:
                shutil.rmtree(self.directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        text = json.dumps({"fingerprint": key, "strands": len(strands), "solver": solver})
        write_atomically(manifest, lambda f: f.write(text.encode()))

    def save(self, indices: list[int], results: list[Result]) -> None:
        """Record finished strands (their indices in the whole input)."""
        data = pickle.dumps((list(indices), list(results)))
        write_atomically(self.directory / f"chunk-{indices[0]:09d}.pkl", lambda f: f.write(data))
        self.done.update(zip(indices, results))

    def remove(self) -> None:
        shutil.rmtree(self.directory, ignore_errors=True)
