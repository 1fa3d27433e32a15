"""Strand geometry: the reference scenes and a synthetic groom (DESIGN section 8)."""
from .groom import DEFAULT_GROOM, default_groom, groom
from .synthetic import curly, flipped, helix, horizontal, resample, wavy

__all__ = ["horizontal", "flipped", "helix", "wavy", "curly", "groom", "default_groom", "DEFAULT_GROOM",
           "resample"]
