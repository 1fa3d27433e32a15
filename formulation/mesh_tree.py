"""A bounding-volume tree over a triangle mesh: its distance and winding number in O(log F) per point.

bodies.Mesh measures, at each point, the exact distance to its nearest triangle and the generalized
winding number (Jacobson et al. 2013) whose value, 1 inside and 0 outside, signs it. Over every
triangle that is O(F) per point, which put scanned heads of tens of thousands of triangles out of
reach (benchmarks/bench_mesh.py measures both). Here the triangles are
sorted into a binary tree of axis-aligned boxes (split at the median centroid of the longest axis,
LEAF triangles per leaf), and

* the nearest triangle is found by descending the tree, nearer child first, skipping every box
  farther than the best distance so far: the same distance as over every triangle;
* the winding number is the sum of the triangles' solid angles over 4 pi, as before, except that a
  box whose triangles are all farther than FAR times its radius from the point contributes its
  dipole term, (sum_t A_t n_t) . (c - p) / (4 pi |c - p|^3) with c the box's area-weighted
  centroid (Barill et al. 2018, "Fast winding numbers for soups and clouds", first order). Its
  error falls like (radius / distance)^2 per box; the inside test compares the number with 1/2,
  so a closed mesh, or one with small cracks, is classified as before (tests/test_contact.py
  checks against the sum over every triangle).
"""
from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

#: Triangles per leaf.
LEAF = 4
#: A box counts by its dipole term where the point is farther than FAR times its radius from its centroid.
FAR = 2.0


class MeshTree(NamedTuple):
    """The tree of ``mesh_tree``: per node its box (lower, upper corners), its triangles' range in
    ``order`` (first, count; count 0 for an inner node), its children (-1 for a leaf), and for the
    winding number its area-weighted centroid, radius about it and sum of area-weighted normals."""
    lower: np.ndarray
    upper: np.ndarray
    first: np.ndarray
    count: np.ndarray
    children: np.ndarray
    order: np.ndarray
    centroid: np.ndarray
    radius: np.ndarray
    dipole: np.ndarray


def mesh_tree(vertices: np.ndarray, faces: np.ndarray) -> MeshTree:
    """The search tree of the triangles ``faces`` (F, 3) over ``vertices`` (V, 3) (module docstring)."""
    return MeshTree(*_build(np.ascontiguousarray(vertices, dtype=float), np.ascontiguousarray(faces, dtype=np.int64),
                            LEAF))


@numba.njit(cache=True)
def _build(vertices, faces, leaf):  # pragma: no cover - compiled
    """mesh_tree's arrays: nodes in depth-first order, built with an explicit stack."""
    count_faces = faces.shape[0]
    centers, areas, normals = np.empty((count_faces, 3)), np.empty(count_faces), np.empty((count_faces, 3))
    for f in range(count_faces):
        a, b, c = vertices[faces[f, 0]], vertices[faces[f, 1]], vertices[faces[f, 2]]
        centers[f] = (a + b + c) / 3.0
        normals[f] = 0.5 * np.cross(b - a, c - a)  # area-weighted
        areas[f] = np.sqrt(normals[f] @ normals[f])
    capacity = count_faces + 2  # a split range of more than LEAF (>= 3) leaves >= 2 per side: <= F - 1 nodes
    lower, upper = np.empty((capacity, 3)), np.empty((capacity, 3))
    first, count = np.zeros(capacity, np.int64), np.zeros(capacity, np.int64)
    children = np.full((capacity, 2), -1, np.int64)
    centroid, radius, dipole = np.zeros((capacity, 3)), np.zeros(capacity), np.zeros((capacity, 3))
    order = np.arange(count_faces)
    stack_node, stack_start, stack_stop = np.empty(capacity, np.int64), np.empty(capacity, np.int64), \
        np.empty(capacity, np.int64)
    stack_node[0], stack_start[0], stack_stop[0] = 0, 0, count_faces
    top, nodes = 1, 1
    while top:
        top -= 1
        node, start, stop = stack_node[top], stack_start[top], stack_stop[top]
        low, high = np.full(3, np.inf), np.full(3, -np.inf)
        center_low, center_high = np.full(3, np.inf), np.full(3, -np.inf)
        area, weighted = 0.0, np.zeros(3)
        for k in range(start, stop):
            f = order[k]
            for corner in range(3):
                low = np.minimum(low, vertices[faces[f, corner]])
                high = np.maximum(high, vertices[faces[f, corner]])
            center_low, center_high = np.minimum(center_low, centers[f]), np.maximum(center_high, centers[f])
            area += areas[f]
            weighted += areas[f] * centers[f]
            dipole[node] += normals[f]
        lower[node], upper[node] = low, high
        centroid[node] = weighted / area if area > 0 else 0.5 * (low + high)
        reach = 0.0
        for k in range(start, stop):
            for corner in range(3):
                offset = vertices[faces[order[k], corner]] - centroid[node]
                reach = max(reach, np.sqrt(offset @ offset))
        radius[node] = reach
        if stop - start <= leaf:
            first[node], count[node] = start, stop - start
            continue
        axis = np.argmax(center_high - center_low)
        keys = np.empty(stop - start)
        for k in range(start, stop):
            keys[k - start] = centers[order[k], axis]
        order[start:stop] = order[start:stop][np.argsort(keys, kind="mergesort")]
        middle = (start + stop) // 2
        children[node, 0], children[node, 1] = nodes, nodes + 1
        stack_node[top], stack_start[top], stack_stop[top] = nodes, start, middle
        stack_node[top + 1], stack_start[top + 1], stack_stop[top + 1] = nodes + 1, middle, stop
        top, nodes = top + 2, nodes + 2
    return (lower[:nodes].copy(), upper[:nodes].copy(), first[:nodes].copy(), count[:nodes].copy(),
            children[:nodes].copy(), order, centroid[:nodes].copy(), radius[:nodes].copy(), dipole[:nodes].copy())


@numba.njit(cache=True, inline="always")
def _box_distance2(p, low, high):  # pragma: no cover - compiled
    """Squared distance from p to the box [low, high] (0 inside)."""
    total = 0.0
    for c in range(3):
        gap = max(low[c] - p[c], 0.0, p[c] - high[c])
        total += gap * gap
    return total


@numba.njit(cache=True)
def solid_angle(p, a, b, c):  # pragma: no cover - compiled
    """The signed solid angle of triangle abc seen from p (Van Oosterom & Strackee), in sr."""
    ra, rb, rc = a - p, b - p, c - p
    la, lb, lc = np.sqrt(ra @ ra), np.sqrt(rb @ rb), np.sqrt(rc @ rc)
    numerator = ra @ np.cross(rb, rc)
    denominator = la * lb * lc + (ra @ rb) * lc + (rb @ rc) * la + (rc @ ra) * lb
    return 2.0 * np.arctan2(numerator, denominator)


@numba.njit(cache=True)
def winding_number(p, vertices, faces, lower, upper, first, count, children, order, centroid, radius,
                   dipole):  # pragma: no cover - compiled
    """The generalized winding number of the mesh at p (module docstring): ~1 inside, ~0 outside."""
    total = 0.0
    stack = np.empty(128, np.int64)
    stack[0], top = 0, 1
    while top:
        top -= 1
        node = stack[top]
        offset = centroid[node] - p
        distance = np.sqrt(offset @ offset)
        if distance > FAR * radius[node]:
            total += (dipole[node] @ offset) / distance**3
            continue
        if count[node]:
            for k in range(first[node], first[node] + count[node]):
                f = order[k]
                total += solid_angle(p, vertices[faces[f, 0]], vertices[faces[f, 1]], vertices[faces[f, 2]])
            continue
        stack[top], stack[top + 1] = children[node, 0], children[node, 1]
        top += 2
    return total / (4.0 * np.pi)


@numba.njit(cache=True)
def closest_on_triangle(p, a, b, c):  # pragma: no cover - compiled
    """Closest point of triangle abc to p, and its feature: 0 face, 1 edge, 2 vertex (Ericson,
    Real-Time Collision Detection, 5.1.5), with the edge's direction (unit) for an edge
    (``_closest_components`` on the three corners)."""
    corners = np.empty((3, 3))
    corners[0], corners[1], corners[2] = a, b, c
    first, second, third = np.int64(0), np.int64(1), np.int64(2)
    _, qx, qy, qz, feature, edge = _closest_components(p, corners, first, second, third)
    return np.array([qx, qy, qz]), feature, _edge_direction(corners, first, second, third, edge)


@numba.njit(cache=True, inline="always")
def _edge_direction(vertices, i, j, k, edge):  # pragma: no cover - compiled
    """The unit direction of the triangle's edge 0 (i to j), 1 (i to k) or 2 (j to k); zero for -1."""
    if edge < 0:
        return np.zeros(3)
    start, stop = (i, j) if edge == 0 else ((i, k) if edge == 1 else (j, k))
    segment = vertices[stop] - vertices[start]
    return segment / np.sqrt(segment @ segment)


@numba.njit(cache=True, inline="always")
def _closest_components(p, vertices, i, j, k):  # pragma: no cover - compiled
    """Ericson's closest point (``closest_on_triangle``) of the triangle of vertices i, j, k to p, on
    scalars: (squared distance, closest point x, y, z, feature, edge: 0 ab, 1 ac, 2 bc, -1 none).
    The search runs it on every triangle it meets, so it allocates nothing (vector temporaries were
    most of the search's time)."""
    ax, ay, az = vertices[i, 0], vertices[i, 1], vertices[i, 2]
    abx, aby, abz = vertices[j, 0] - ax, vertices[j, 1] - ay, vertices[j, 2] - az
    acx, acy, acz = vertices[k, 0] - ax, vertices[k, 1] - ay, vertices[k, 2] - az
    apx, apy, apz = p[0] - ax, p[1] - ay, p[2] - az
    d1, d2 = abx * apx + aby * apy + abz * apz, acx * apx + acy * apy + acz * apz
    qx, qy, qz, feature, edge = ax, ay, az, 2, -1
    bpx, bpy, bpz = p[0] - vertices[j, 0], p[1] - vertices[j, 1], p[2] - vertices[j, 2]
    d3, d4 = abx * bpx + aby * bpy + abz * bpz, acx * bpx + acy * bpy + acz * bpz
    cpx, cpy, cpz = p[0] - vertices[k, 0], p[1] - vertices[k, 1], p[2] - vertices[k, 2]
    d5, d6 = abx * cpx + aby * cpy + abz * cpz, acx * cpx + acy * cpy + acz * cpz
    vc, vb, va = d1 * d4 - d3 * d2, d5 * d2 - d1 * d6, d3 * d6 - d5 * d4
    if d1 <= 0 and d2 <= 0:
        pass  # vertex a
    elif d3 >= 0 and d4 <= d3:
        qx, qy, qz = vertices[j, 0], vertices[j, 1], vertices[j, 2]
    elif vc <= 0 and d1 >= 0 and d3 <= 0:
        t = d1 / (d1 - d3)
        qx, qy, qz, feature, edge = ax + t * abx, ay + t * aby, az + t * abz, 1, 0
    elif d6 >= 0 and d5 <= d6:
        qx, qy, qz = vertices[k, 0], vertices[k, 1], vertices[k, 2]
    elif vb <= 0 and d2 >= 0 and d6 <= 0:
        t = d2 / (d2 - d6)
        qx, qy, qz, feature, edge = ax + t * acx, ay + t * acy, az + t * acz, 1, 1
    elif va <= 0 and (d4 - d3) >= 0 and (d5 - d6) >= 0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        bx, by, bz = vertices[j, 0], vertices[j, 1], vertices[j, 2]
        qx, qy, qz = bx + t * (vertices[k, 0] - bx), by + t * (vertices[k, 1] - by), bz + t * (vertices[k, 2] - bz)
        feature, edge = 1, 2
    else:
        denominator = 1.0 / (va + vb + vc)
        v, w = vb * denominator, vc * denominator
        qx, qy, qz, feature = ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w, 0
    ox, oy, oz = p[0] - qx, p[1] - qy, p[2] - qz
    return ox * ox + oy * oy + oz * oz, qx, qy, qz, feature, edge


@numba.njit(cache=True)
def nearest_triangle(p, vertices, faces, lower, upper, first, count, children, order):  # pragma: no cover
    """(distance, closest point, feature, edge direction, face) of the triangle nearest to p: the
    tree descended nearer box first, boxes farther than the best distance skipped; feature and
    direction as ``closest_on_triangle`` gives them; ties go to the first triangle met."""
    best, closest, feature, edge, face = np.inf, np.zeros(3), 0, -1, -1
    stack = np.empty(128, np.int64)
    stack[0], top = 0, 1
    while top:
        top -= 1
        node = stack[top]
        if _box_distance2(p, lower[node], upper[node]) >= best * best:
            continue
        if count[node]:
            for k in range(first[node], first[node] + count[node]):
                f = order[k]
                d2, qx, qy, qz, kind, which = _closest_components(p, vertices, faces[f, 0], faces[f, 1], faces[f, 2])
                d = np.sqrt(d2)
                if d < best:
                    best, feature, edge, face = d, kind, which, f
                    closest[0], closest[1], closest[2] = qx, qy, qz
            continue
        near, far = children[node, 0], children[node, 1]
        if _box_distance2(p, lower[far], upper[far]) < _box_distance2(p, lower[near], upper[near]):
            near, far = far, near
        stack[top], stack[top + 1] = far, near  # the nearer box popped first
        top += 2
    direction = np.zeros(3) if face < 0 else _edge_direction(vertices, faces[face, 0], faces[face, 1],
                                                             faces[face, 2], edge)
    return best, closest, feature, direction, face
