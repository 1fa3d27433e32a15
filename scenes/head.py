"""Long hair lying on a head: a sphere, strands combed down its back along meridians, then hanging.

The head is ``HEAD`` (a sphere of radius 10 cm at the origin). Each strand's root sits on the upper
back of the head; from there it follows the meridian through the root downwards, its centreline one
strand radius above the scalp (so every vertex there rests on the head, contact module), until the
meridian turns vertical at the equator, and then hangs straight down to its length. Material as the
default groom (radius 50 um, E 1 GPa, G 0.4 GPa, 1300 kg/m^3). The scalp part is held by the head and
by the tension of the hanging part; without the head it is long hair sticking out of a crown.
"""
from __future__ import annotations

import numpy as np

from sagfree.formulation.bodies import Sphere
from sagfree.formulation.strand import Strand

from .synthetic import MATERIAL, resample

HEAD_RADIUS = 0.1
HEAD = Sphere((0.0, 0.0, 0.0), HEAD_RADIUS, name="head")


def head_groom(strands: int = 50, vertices: int = 100, lengths=(0.5, 0.9), seed: int = 0) -> list[Strand]:
    """``strands`` strands of ``vertices`` vertices and lengths drawn uniformly in ``lengths`` (m),
    roots at polar angles 15-60 degrees from the crown and azimuths over the back half of the head
    (module docstring); rest on ``HEAD``."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(strands):
        polar = np.radians(rng.uniform(15.0, 60.0))
        azimuth = np.radians(rng.uniform(100.0, 260.0))
        length = rng.uniform(*lengths)
        out.append(Strand(resample(_combed(polar, azimuth, length), vertices, length), **MATERIAL))
    return out


def _combed(polar: float, azimuth: float, length: float, samples: int = 4000) -> np.ndarray:
    """A dense polyline: the meridian from ``polar`` to the equator at HEAD_RADIUS + r, then down."""
    radius = HEAD_RADIUS + MATERIAL["radius"]
    horizontal = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    angles = np.linspace(polar, np.pi / 2, samples)
    scalp = radius * (np.sin(angles)[:, None] * horizontal + np.cos(angles)[:, None] * np.array([0, 0, 1.0]))
    arc = radius * (np.pi / 2 - polar)
    drop = max(length - arc, 0.0) * 1.01
    hanging = scalp[-1] + np.linspace(0.0, drop, samples)[1:, None] * np.array([0, 0, -1.0])
    return np.vstack([scalp, hanging])
