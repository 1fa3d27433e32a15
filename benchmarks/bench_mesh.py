"""Mesh bodies: the search tree's distance and sign against a pass over every triangle.

    python benchmarks/bench_mesh.py [--strands 10]

For heads of 320 to 20,480 triangles (``scenes.head.icosphere``) and the vertices of ``head_groom``
strands (100 vertices each), one core: the tree's build, one evaluation of Mesh.evaluate (distance,
normal, curvature at a strand's vertices) through the tree (formulation.mesh_tree) against the same
sums over every triangle (the baseline: compiled here, the code before the tree), their ratio and
the largest difference of the signed distances, and the Problem of a strand on the head (its
contacts: one evaluation at q*).
"""
from __future__ import annotations

import argparse
import time

import numba
import numpy as np

import sagfree
from sagfree.formulation.mesh_tree import closest_on_triangle, solid_angle
from sagfree.scenes.head import head_groom, icosphere


@numba.njit(cache=True)
def every_triangle(points, vertices, faces):  # pragma: no cover - compiled
    """Signed distance at ``points`` by a pass over every triangle (the nearest one's distance, the
    winding number's sign)."""
    out = np.empty(points.shape[0])
    for k in range(points.shape[0]):
        p, best, angle = points[k], np.inf, 0.0
        for f in range(faces.shape[0]):
            a, b, c = vertices[faces[f, 0]], vertices[faces[f, 1]], vertices[faces[f, 2]]
            q = closest_on_triangle(p, a, b, c)[0]
            best = min(best, np.sqrt((p - q) @ (p - q)))
            angle += solid_angle(p, a, b, c)
        out[k] = -best if angle > 2.0 * np.pi else best
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--strands", type=int, default=10, help="head_groom strands (default 10)")
    args = parser.parse_args()
    strands = head_groom(args.strands, 100, seed=0)
    points = [np.ascontiguousarray(s.points) for s in strands]
    print(f"signed distance at a strand's 100 vertices, {args.strands} strands, one core (ms)")
    print(f"   {'triangles':>9} {'tree build':>10} {'tree':>8} {'every':>8} {'ratio':>7} {'max |dphi|':>10} "
          f"{'Problem':>8}")
    for subdivisions in (2, 3, 4, 5):
        mesh = icosphere(subdivisions=subdivisions)
        start = time.perf_counter()
        mesh.tree  # noqa: B018 - built on first use
        build = time.perf_counter() - start
        mesh.evaluate(points[0]), every_triangle(points[0], mesh.vertices, mesh.faces)  # compiled before timing
        times, difference = np.zeros(2), 0.0
        for x in points:
            start = time.perf_counter()
            phi = mesh.evaluate(x)[0]
            times[0] += time.perf_counter() - start
            start = time.perf_counter()
            reference = every_triangle(x, mesh.vertices, mesh.faces)
            times[1] += time.perf_counter() - start
            difference = max(difference, float(np.abs(phi - reference).max()))
        sagfree.Problem(strands[0], bodies=[mesh])
        start = time.perf_counter()
        for strand in strands:
            sagfree.Problem(strand, bodies=[mesh])
        problem = (time.perf_counter() - start) / len(strands)
        times *= 1e3 / len(points)
        print(f"   {len(mesh.faces):9d} {1e3 * build:10.1f} {times[0]:8.3f} {times[1]:8.3f} {times[1] / times[0]:7.1f} "
              f"{difference:10.1e} {1e3 * problem:8.2f}")


if __name__ == "__main__":
    main()
