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

from sagfree.formulation.bodies import Mesh, Sphere
from sagfree.formulation.strand import Strand

from .synthetic import MATERIAL, resample

HEAD_RADIUS = 0.1
HEAD = Sphere((0.0, 0.0, 0.0), HEAD_RADIUS, name="head")


def icosphere(radius: float = HEAD_RADIUS, subdivisions: int = 2, name: str = "icosphere") -> Mesh:
    """A triangle mesh of the sphere of ``radius`` (m) about the origin: the icosahedron with each
    face split in four ``subdivisions`` times, the new vertices pushed onto the sphere (20 x 4^s
    outward faces; with 2, 320 faces at most 1.8% of the radius inside the sphere), e.g. ``HEAD`` as a
    mesh."""
    t = (1 + 5 ** 0.5) / 2
    v = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
         [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
         [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    vertices = [np.array(p, float) / np.linalg.norm(p) for p in v]
    for _ in range(subdivisions):
        cache, faces = {}, []

        def middle(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = vertices[a] + vertices[b]
                vertices.append(m / np.linalg.norm(m))
                cache[key] = len(vertices) - 1
            return cache[key]
        for a, b, c in f:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            faces += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        f = faces
    return Mesh(radius * np.array(vertices), np.array(f), name=name)


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
