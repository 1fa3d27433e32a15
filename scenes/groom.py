"""A synthetic groom: strands rooted on a sphere (a head), mixed straight / wavy / curly (DESIGN 8).

Each strand leaves the scalp along the outward normal and is combed down: its centerline turns in the
plane of the normal and gravity at a constant rate until it points down. Wavy strands add a sine
offset across that plane, curly strands a helical offset around the centerline. Everything is drawn
from ``numpy.random.default_rng(seed)``, so a seed gives the same groom on every machine.
"""
from __future__ import annotations

import numpy as np

from sagfree.formulation.strand import Strand

from .synthetic import MATERIAL, resample

STYLES = ("straight", "wavy", "curly")


def groom(num_strands: int = 200, vertices: int = 100, seed: int = 0, head_radius: float = 0.1,
          length=(0.08, 0.16), radius=(4e-5, 6e-5), styles=(0.4, 0.3, 0.3),
          max_polar_angle_deg: float = 100.0, combing_radius: float = 0.12) -> list[Strand]:
    """``num_strands`` strands of ``vertices`` vertices each.

    length, radius: uniform ranges (m). styles: probabilities of straight, wavy, curly.
    Roots are uniform by area on the cap of polar angle <= max_polar_angle_deg (0 = top of the head).
    combing_radius: radius of curvature (m) of the centerline while it turns down.
    """
    if num_strands < 0 or vertices < 3:
        raise ValueError("groom needs num_strands >= 0 and vertices >= 3")
    rng = np.random.default_rng(seed)
    cos_max = np.cos(np.radians(max_polar_angle_deg))
    strands = []
    for _ in range(num_strands):
        z = rng.uniform(cos_max, 1.0)
        azimuth = rng.uniform(0.0, 2 * np.pi)
        s = np.sqrt(1.0 - z * z)
        normal = np.array([s * np.cos(azimuth), s * np.sin(azimuth), z])
        style = STYLES[rng.choice(len(STYLES), p=styles)]
        points = _strand_points(head_radius * normal, normal, style, vertices,
                                rng.uniform(*length), combing_radius, rng)
        strands.append(Strand(points, **{**MATERIAL, "radius": rng.uniform(*radius)}))
    return strands


def _strand_points(root, normal, style, n, length, combing_radius, rng) -> np.ndarray:
    down = np.array([0.0, 0.0, -1.0])
    side = down - np.dot(down, normal) * normal
    if np.linalg.norm(side) < 1e-9:  # root at the bottom pole: any side direction
        side = np.array([1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    binormal = np.cross(normal, side)
    total_turn = np.arccos(np.clip(np.dot(normal, down), -1.0, 1.0))
    span = 3.0 * length  # wavy and curly curves are longer than their centerline: cut from more
    s = np.linspace(0.0, span, 40 * n)
    turn = np.minimum(s / combing_radius, total_turn)
    direction = np.cos(turn)[:, None] * normal + np.sin(turn)[:, None] * side
    ds = np.diff(s, prepend=0.0)[:, None]
    centerline = root + np.cumsum(direction * ds, axis=0) - direction[0] * ds[0]
    # offsets in the plane perpendicular to the centerline direction
    across = np.cross(direction, binormal)
    if style == "wavy":
        amplitude, wavelength = rng.uniform(0.003, 0.006), rng.uniform(0.015, 0.03)
        offset = amplitude * np.sin(2 * np.pi * s / wavelength)[:, None] * binormal
    elif style == "curly":
        coil, pitch = rng.uniform(0.003, 0.006), rng.uniform(0.008, 0.015)
        phase = 2 * np.pi * s / pitch
        offset = coil * ((1 - np.cos(phase))[:, None] * across + np.sin(phase)[:, None] * binormal)
    else:
        offset = np.zeros_like(centerline)
    return resample(centerline + offset, n, length)


#: The embedded default groom of ``sagfree demo``: seeded, so the same on every machine.
DEFAULT_GROOM = dict(num_strands=100, vertices=50, seed=0)


def default_groom() -> list[Strand]:
    """The demo's groom: ``groom(**DEFAULT_GROOM)``."""
    return groom(**DEFAULT_GROOM)
