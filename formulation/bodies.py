"""Rigid bodies strands rest on: signed distance, normal and surface curvature at points (m).

Every body gives, at points x (m, 3):

    phi(x)      signed distance to its surface (m), negative inside;
    n(x)        grad phi, the outward unit normal of the closest surface point;
    K(x)        d2 phi / dx2 (1/m), the curvature the stability and the simulation's contact
                Hessian need (zero on flat faces).

``Sphere(center, radius)`` and ``Capsule(a, b, radius)`` are exact; ``Mesh`` is a closed triangle
mesh (``Mesh.load`` reads the ``v``/``f`` records of an OBJ file), its distance the exact distance
to the nearest triangle, its sign from the generalized winding number (Jacobson et al. 2013: the
solid angle the mesh subtends, 4 pi inside, 0 outside), which tolerates small cracks in a scanned
head; both through a bounding-volume tree over the triangles (mesh_tree), O(log F) per point.
"""
from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from pathlib import Path

import numba
import numpy as np

from .mesh_tree import MeshTree, mesh_tree, nearest_triangle, winding_number


def _points(x) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    return x.reshape(1, 3) if x.ndim == 1 else x


def parse_body(spec) -> "Body":
    """A Body from itself or its spec: "sphere:cx,cy,cz,radius", "capsule:ax,ay,az,bx,by,bz,radius"
    (m), or the path of an OBJ mesh (in m; "mesh:path" too). What the command line and the
    parameters file's problem options carry."""
    if isinstance(spec, Body):
        return spec
    text = str(spec)
    kind, _, rest = text.partition(":")
    try:
        if kind == "sphere":
            *center, radius = (float(v) for v in rest.split(","))
            if len(center) == 3:
                return Sphere(center, radius)
        elif kind == "capsule":
            *ends, radius = (float(v) for v in rest.split(","))
            if len(ends) == 6:
                return Capsule(ends[:3], ends[3:], radius)
        elif kind == "mesh" or text.lower().endswith(".obj"):
            return Mesh.load(rest if kind == "mesh" else text)
    except ValueError as exc:
        if "could not convert" not in str(exc):
            raise ValueError(f"body {text!r}: {exc}") from None
    raise ValueError(f"body {text!r}: expected sphere:cx,cy,cz,radius or capsule:ax,ay,az,bx,by,bz,radius "
                     "(m) or an .obj mesh")


class Body(ABC):
    """Base: ``name`` for messages; subclasses give ``_evaluate(x) -> (phi, n, K)`` and ``spec``, the
    text ``parse_body`` rebuilds them from."""

    name = "body"

    @property
    @abstractmethod
    def spec(self) -> str:
        """The body as text (parse_body), e.g. "sphere:0,0,0,0.1"."""

    @abstractmethod
    def _evaluate(self, x) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(phi, n, K) at the points x (m, 3)."""

    def signed_distance(self, x) -> np.ndarray:
        return self._evaluate(_points(x))[0]

    def normal(self, x) -> np.ndarray:
        return self._evaluate(_points(x))[1]

    def curvature(self, x) -> np.ndarray:
        return self._evaluate(_points(x))[2]

    def evaluate(self, x) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(phi (m,), n (m, 3), K (m, 3, 3)) at the points x (m, 3)."""
        return self._evaluate(_points(x))


@numba.njit(cache=True)
def _round(offset: np.ndarray, radius: float):  # pragma: no cover - compiled
    """phi, n, K of the points at ``offset`` from their closest point on a core (point or segment)
    inflated by ``radius``; the curvature without the core's own direction (added by the caller).
    Compiled, numpy's norm and products bit for bit (contact detection and every simulation step
    evaluate it on a strand's few hundred points, where numpy's passes cost more than the sums)."""
    m = offset.shape[0]
    phi, n, K = np.empty(m), np.empty((m, 3)), np.empty((m, 3, 3))
    for i in range(m):
        x, y, z = offset[i, 0], offset[i, 1], offset[i, 2]
        distance = np.sqrt(x * x + y * y + z * z)
        safe = distance if distance > 0 else 1.0
        if distance == 0:
            n[i, 0], n[i, 1], n[i, 2] = 0.0, 0.0, 1.0  # the centre itself: any direction is as good
        else:
            n[i, 0], n[i, 1], n[i, 2] = x / safe, y / safe, z / safe
        for a in range(3):
            for b in range(3):
                K[i, a, b] = ((1.0 if a == b else 0.0) - n[i, a] * n[i, b]) / safe
        phi[i] = distance - radius
    return phi, n, K


@numba.njit(cache=True)
def _capsule_distance(x, a, b, radius):  # pragma: no cover - compiled
    """phi, n, K of the capsule of ``radius`` about the segment ab at the points x (n, 3): ``_round``
    from each point's nearest point on the segment, less the curvature along the axis where that
    point is inside the segment (along the cylinder the distance does not change). Also the
    compiled contact penalty's (newton._body_distance)."""
    axis = b - a
    length2 = np.dot(axis, axis)
    s, offset = np.empty(x.shape[0]), np.empty(x.shape)
    for i in range(x.shape[0]):
        along = 0.0
        for c in range(3):
            along += (x[i, c] - a[c]) * axis[c]
        s[i] = min(max(along / length2, 0.0), 1.0)
        for c in range(3):
            offset[i, c] = x[i, c] - (a[c] + s[i] * axis[c])
    phi, n, K = _round(offset, radius)
    t = axis / np.sqrt(length2)
    for i in range(x.shape[0]):
        if 0.0 < s[i] < 1.0:
            distance = np.sqrt(offset[i, 0] ** 2 + offset[i, 1] ** 2 + offset[i, 2] ** 2)
            distance = distance if distance > 0 else 1.0
            for c in range(3):
                for e in range(3):
                    K[i, c, e] -= t[c] * t[e] / distance
    return phi, n, K


class Sphere(Body):
    """A sphere of ``radius`` (m) about ``center`` (m)."""

    def __init__(self, center, radius: float, name: str = "sphere"):
        self.center = _vector("center", center)
        self.radius = _positive("radius", radius)
        self.name = name

    def _evaluate(self, x):
        return _round(x - self.center, self.radius)

    @property
    def spec(self) -> str:
        return "sphere:" + ",".join(f"{v:.17g}" for v in (*self.center, self.radius))

    def __repr__(self) -> str:
        return f"Sphere(center={self.center.tolist()}, radius={self.radius:g})"


class Capsule(Body):
    """The points within ``radius`` (m) of the segment from ``a`` to ``b`` (m): a limb, a neck."""

    def __init__(self, a, b, radius: float, name: str = "capsule"):
        self.a, self.b = _vector("a", a), _vector("b", b)
        self.radius = _positive("radius", radius)
        axis = self.b - self.a
        if not np.linalg.norm(axis) > 0:
            raise ValueError("a capsule needs distinct end points a and b")
        self.name = name

    def _evaluate(self, x):
        return _capsule_distance(np.ascontiguousarray(x, dtype=float), self.a, self.b, self.radius)

    @property
    def spec(self) -> str:
        return "capsule:" + ",".join(f"{v:.17g}" for v in (*self.a, *self.b, self.radius))

    def __repr__(self) -> str:
        return f"Capsule(a={self.a.tolist()}, b={self.b.tolist()}, radius={self.radius:g})"


class Mesh(Body):
    """A closed triangle mesh: ``vertices`` (V, 3) in m, ``faces`` (F, 3) vertex indices; ``path``:
    the OBJ file in m it was read from, if any (its ``spec``)."""

    def __init__(self, vertices, faces, name: str = "mesh", path: str | None = None):
        self.vertices = np.ascontiguousarray(vertices, dtype=float)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3 or not np.all(np.isfinite(self.vertices)):
            raise ValueError(f"{name}: vertices must be a finite (V, 3) array")
        if (self.faces.ndim != 2 or self.faces.shape[1] != 3 or len(self.faces) == 0
                or self.faces.min() < 0 or self.faces.max() >= len(self.vertices)):
            raise ValueError(f"{name}: faces must be a non-empty (F, 3) array of vertex indices "
                             f"in 0..{len(self.vertices) - 1}")
        self.name, self.path = name, path

    @staticmethod
    def load(path, units: str = "m") -> "Mesh":
        """A mesh from the ``v`` and ``f`` records of an OBJ file (polygons fanned into triangles;
        ``units``: m, cm or mm)."""
        path = Path(path)
        scale = {"m": 1.0, "cm": 0.01, "mm": 0.001}[units]
        vertices, faces = [], []
        for number, line in enumerate(path.read_text().splitlines(), 1):
            parts = line.split()
            if not parts:
                continue
            try:
                if parts[0] == "v":
                    vertices.append([float(v) for v in parts[1:4]])
                elif parts[0] == "f":
                    corners = [int(token.split("/")[0]) for token in parts[1:]]
                    corners = [c - 1 if c > 0 else len(vertices) + c for c in corners]
                    faces.extend([corners[0], corners[k], corners[k + 1]] for k in range(1, len(corners) - 1))
            except (ValueError, IndexError):
                raise ValueError(f"{path}, line {number}: cannot read {line.strip()!r}") from None
        if not faces:
            raise ValueError(f"{path}: no faces ('f' records): not a triangle mesh")
        return Mesh(np.array(vertices) * scale, np.array(faces), name=path.name,
                    path=str(path.resolve()) if units == "m" else None)

    @functools.cached_property
    def tree(self) -> MeshTree:
        """The search tree of its triangles (mesh_tree), built on first use."""
        return mesh_tree(self.vertices, self.faces)

    def _evaluate(self, x):
        return _mesh_distance(np.ascontiguousarray(x, dtype=float), self.vertices, self.faces, *self.tree)

    @property
    def spec(self) -> str:
        """"mesh:<path>" of the OBJ file it came from; a mesh built in memory has no spec (save it
        as OBJ in metres to record it in a parameters file)."""
        if self.path is None:
            raise ValueError(f"{self.name}: a mesh built in memory cannot be recorded; load it from an OBJ file in m")
        return "mesh:" + self.path

    def __repr__(self) -> str:
        return f"Mesh({self.name}, {len(self.vertices)} vertices, {len(self.faces)} triangles)"


@numba.njit(cache=True)
def _mesh_distance(points, vertices, faces, lower, upper, first, count, children, order, centroid, radius,
                   dipole):  # pragma: no cover - compiled
    """(phi, n, K) of a Mesh at ``points`` from its search tree (mesh_tree.MeshTree's arrays after
    vertices and faces): the nearest triangle's distance, signed by the winding number, the normal
    along the offset (the face's normal on the surface itself), and the curvature of an edge or a
    vertex feature (zero on a face)."""
    m = points.shape[0]
    phi, normal, curvature = np.empty(m), np.zeros((m, 3)), np.zeros((m, 3, 3))
    for k in range(m):
        p = points[k]
        best, closest, feature, edge, face = nearest_triangle(p, vertices, faces, lower, upper, first, count,
                                                              children, order)
        inside = winding_number(p, vertices, faces, lower, upper, first, count, children, order, centroid, radius,
                                dipole) > 0.5
        offset = p - closest
        if best > 0:
            n = offset / best
        else:
            a, b, c = vertices[faces[face, 0]], vertices[faces[face, 1]], vertices[faces[face, 2]]
            face_normal = np.cross(b - a, c - a)
            n = face_normal / np.sqrt(face_normal @ face_normal)
        if inside:
            n = -n
        phi[k] = -best if inside else best
        normal[k] = n
        if feature > 0 and best > 0:
            projector = np.eye(3) - np.outer(n, n)
            if feature == 1:
                projector -= np.outer(edge, edge)
            curvature[k] = projector / phi[k]
    return phi, normal, curvature


def _vector(name: str, value) -> np.ndarray:
    v = np.array(value, dtype=float).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be a finite 3-vector (m), got {value!r}")
    return v


def _positive(name: str, value) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be positive and finite (m), got {value!r}")
    return v
