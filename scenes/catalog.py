"""``sagfree.load`` / ``sagfree.save``: strands from a file or a built-in scene name.

A source is a path to a strands file (``.npz``, scenes.npz; the hair formats join with the
command-line issue) or the name of a built-in scene: ``default-groom`` (the demo's groom) or one of
the single-strand reference scenes (DESIGN section 8).
"""
from __future__ import annotations

from pathlib import Path

from sagfree.formulation.strand import Strand

from .groom import default_groom
from .npz import load_strands, save_strands
from .synthetic import curly, flipped, helix, horizontal, wavy

BUILTIN = {
    "default-groom": default_groom,
    "horizontal": lambda: [horizontal()],
    "flipped": lambda: [flipped()],
    "helix": lambda: [helix()],
    "wavy": lambda: [wavy()],
    "curly": lambda: [curly()],
}
READERS = {".npz": load_strands}
WRITERS = {".npz": save_strands}


def load(source) -> list[Strand]:
    """Strands from a file (picked by extension) or a built-in scene name."""
    path = Path(source)
    if path.suffix.lower() in READERS:
        return READERS[path.suffix.lower()](path)
    if str(source) in BUILTIN:
        return BUILTIN[str(source)]()
    raise ValueError(f"{source}: not a strands file ({', '.join(READERS)}) nor a built-in scene "
                     f"({', '.join(BUILTIN)})")


def save(path, strands: list[Strand]) -> None:
    """Write strands to a file whose format is picked by extension."""
    suffix = Path(path).suffix.lower()
    if suffix not in WRITERS:
        raise ValueError(f"{path}: cannot write strands as '{suffix}'; use one of {', '.join(WRITERS)}")
    WRITERS[suffix](path, strands)
