"""Strand geometry: the reference scenes, a synthetic groom and strand files (DESIGN section 8)."""
from .catalog import BUILTIN, FORMATS, load, save
from .groom import DEFAULT_GROOM, default_groom, groom
from .synthetic import cable, curly, flipped, helix, horizontal, resample, wavy

__all__ = ["horizontal", "cable", "flipped", "helix", "wavy", "curly", "groom", "default_groom", "DEFAULT_GROOM",
           "resample", "load", "save", "BUILTIN", "FORMATS"]
