"""The equilibrium problem of one strand (DESIGN sections 3, 4 and 10).

    minimize R(p)  subject to  c(p) = D^-1 S f(q*, p) = 0,  lower <= p <= upper,

f = -grad_q E(q*, p) + f_gravity, S selects the free DOFs, D scales each row by a characteristic
force (dofs.row_scales), so |c|_inf is relative and unit-free. c is evaluated by the compiled stencil
functions; dc/dp is assembled from their exact parameter Jacobians into a sparse matrix whose rows
(free DOFs) and columns (parameters) are both in strand order, hence banded.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from sagfree.linalg.eigen import smallest_eigenvalue

from . import dofs
from .curvature import check_variant
from .energies import TERMS
from .frames import Frames, bishop_frames, default_director, project_director
from .jacobian import JacobianPattern, StrandJacobian
from .parameters import BLOCKS, ParameterLayout
from .stencils import edge_stencil, vertex_fixed_shape, vertex_stencil
from .strand import InvalidStrand, Strand

#: Half bandwidth of every DOF Hessian: a vertex stencil spans 11 consecutive DOFs (dofs module).
HALF_BANDWIDTH = 10


class Problem:
    """Sag-free parameter problem of one strand.

    gravity: m/s^2 vector. curvature: "4d" | "2d-average" | "2d-slerp".
    optimize: parameter blocks to optimize (parameters module). stiffness: "element" | "strand" |
    "fixed". couple_twist: gamma follows the bend multiplier. bounds, weights: parameters module.
    energies: elastic terms included (all by default; a subset serves verification and experiments).

    Public members beyond the API of DESIGN section 10, for the model's own modules (symbolic,
    simulation, verification) and for tests: ``edge_functions`` / ``vertex_functions`` (the compiled
    stencil functions of stencils.edge_stencil / vertex_stencil: geometry, energy, gradient, Hessian,
    parameter Jacobian), ``vertex_fixed_functions`` (the same through the vertex kinematics at q*,
    stencils.vertex_fixed_shape), ``edge_dofs`` / ``vertex_dofs`` (each stencil's DOF indices into q,
    dofs module), ``kinematics_at_rest`` (k and (dk/dy)^T at q*), ``stencil_inputs`` and
    ``check_parameters``.
    """

    def __init__(self, strand: Strand, gravity=(0.0, 0.0, -9.81), curvature="4d", optimize=BLOCKS,
                 stiffness="element", couple_twist=True, bounds=None, weights=None, energies=TERMS):
        if not isinstance(strand, Strand):
            raise ValueError(strand.message if isinstance(strand, InvalidStrand) else
                             f"expected a sagfree.Strand, got {type(strand).__name__}")
        check_variant(curvature)
        self.gravity = np.array(gravity, dtype=float).reshape(-1)
        if self.gravity.shape != (3,) or not np.all(np.isfinite(self.gravity)):
            raise ValueError(f"gravity must be a finite 3-vector, got {gravity!r}")
        unknown = set(energies) - set(TERMS)
        if unknown:
            raise ValueError(f"unknown energy terms {sorted(unknown)}; choose from {TERMS}")
        self.strand, self.curvature, self.energies = strand, curvature, tuple(energies)
        self.options = dict(gravity=gravity, curvature=curvature, optimize=optimize, stiffness=stiffness,
                            couple_twist=couple_twist, bounds=bounds, weights=weights, energies=energies)
        n = self.n_vertices = strand.n_vertices
        points = strand.points
        first = (points[1] - points[0]) / np.linalg.norm(points[1] - points[0])
        a1 = (default_director(first, self.gravity) if strand.director is None
              else project_director(first, strand.director))
        self.frames: Frames = bishop_frames(points, a1)
        self.q_star = dofs.interleave(points, strand.theta)
        self.edge_functions = edge_stencil("stretch" in energies)
        vertex_terms = tuple(t for t in ("bend", "twist") if t in energies)
        self.vertex_functions = vertex_stencil(curvature, vertex_terms)
        self.vertex_fixed_functions = vertex_fixed_shape(curvature, vertex_terms)
        self.edge_dofs = dofs.edge_stencil_index(n)
        self.vertex_dofs = dofs.vertex_stencil_index(n)

        # input geometry through the same compiled expressions as the energies, so that the strains,
        # curvature and twist differences vanish exactly at p0
        (l0,) = self.edge_functions.geometry(self.q_star[self.edge_dofs])
        kappa, twist = self.vertex_functions.geometry(self.q_star[self.vertex_dofs], self._reference(self.frames))
        self.edge_lengths, self.twist_star = l0, twist
        r = strand.radius
        self._edge_geometry = np.column_stack([l0, np.full(n - 1, r)])
        self._vertex_geometry = np.column_stack([l0[:-1], l0[1:], np.full(n - 2, r), twist, kappa])
        self.layout = ParameterLayout(n, l0, kappa[:, :2], twist, strand.youngs_modulus,
                                      strand.shear_modulus, optimize, stiffness, couple_twist, bounds,
                                      weights)

        with np.errstate(all="ignore"):
            masses = 0.5 * strand.density * np.pi * np.float64(r) ** 2 * (np.r_[l0, 0.0] + np.r_[0.0, l0])
            self.row_scale = dofs.row_scales(masses, l0, strand.density, np.float64(r), self.gravity)
            moduli = np.array([strand.youngs_modulus, strand.shear_modulus])
            _check_scales(masses, self.row_scale, moduli * np.pi * np.float64(r) ** 4,
                          moduli * np.pi * np.float64(r) ** 2)
        self.masses = masses
        self.gravity_forces = dofs.gravity_forces(masses, self.gravity)
        self.free = dofs.free_mask(n, strand.root)
        self.first_free = int(np.argmax(self.free))  # the prescribed DOFs are a prefix of q
        free_row = np.full(self.q_star.size, -1)
        free_row[self.free] = np.arange(self.free.sum())
        self._jacobian_pattern = JacobianPattern(
            free_row, self.row_scale, int(self.free.sum()), self.layout.size,
            [(self.edge_dofs, self.layout.edge_map), (self.vertex_dofs, self.layout.vertex_map)])
        # the stencils' inputs at q* that do not depend on p (residual and Jacobian evaluate only there)
        self._at_rest = (np.ascontiguousarray(self.q_star[self.edge_dofs]),
                         np.ascontiguousarray(self.q_star[self.vertex_dofs]),
                         np.ascontiguousarray(self._reference(self.frames)))
        # the vertex kinematics k and dk/dy at q* (stencils.FixedShapeFunctions), dk/dy transposed
        kinematics, kinematics_jacobian = self.vertex_fixed_functions.kinematics(*self._at_rest[1:])
        self.kinematics_at_rest = (kinematics, np.ascontiguousarray(kinematics_jacobian.transpose(0, 2, 1)))
        self._free_index = np.flatnonzero(self.free)
        self._free_row_scale = self.row_scale[self._free_index]
        self._band_scatter = None  # built on the first hessian_band call

    def with_options(self, **changes) -> "Problem":
        """The same strand's Problem with some constructor options changed."""
        return Problem(self.strand, **{**self.options, **changes})

    # ---- parameters ----
    @property
    def p0(self) -> np.ndarray:
        return self.layout.p0.copy()

    @property
    def lower(self) -> np.ndarray:
        return self.layout.lower.copy()

    @property
    def upper(self) -> np.ndarray:
        return self.layout.upper.copy()

    @property
    def blocks(self) -> dict[str, np.ndarray]:
        return dict(self.layout.blocks)

    @property
    def n_parameters(self) -> int:
        return self.layout.size

    def objective(self, p) -> float:
        """Regularizer R(p) = 1/2 sum_j w_j (p_j - p0_j)^2 (dimensionless)."""
        return self.layout.regularizer(self.check_parameters(p))

    def objective_gradient(self, p) -> np.ndarray:
        return self.layout.regularizer_gradient(self.check_parameters(p))

    def physical(self, p) -> dict[str, np.ndarray]:
        """Physical parameters: rest lengths (m), rest curvatures (n-2, 2), rest twists (rad), moduli
        alpha (per edge), beta and gamma (per interior vertex) in Pa."""
        p = self.check_parameters(p)
        edge, vertex = self.layout.edge_map.evaluate(p), self.layout.vertex_map.evaluate(p)
        return {
            "rest_length": self.edge_lengths * (1.0 + edge[:, 0]),
            "rest_curvature": vertex[:, 2:4],
            "rest_twist": vertex[:, 4],
            "stretch_modulus": edge[:, 1],
            "bend_modulus": vertex[:, 5],
            "twist_modulus": vertex[:, 6],
        }

    # ---- model evaluation ----
    def check_parameters(self, p) -> np.ndarray:
        """p as a 1-D float array; ValueError if it does not have n_parameters entries."""
        p = np.asarray(p, dtype=float).reshape(-1)
        if p.shape != (self.n_parameters,):
            raise ValueError(f"p must have {self.n_parameters} entries, got {p.size}")
        return p

    def _state(self, q):
        q = self.q_star if q is None else np.asarray(q, dtype=float).reshape(-1)
        if q.shape != self.q_star.shape:
            raise ValueError(f"q must have {self.q_star.size} entries (4n-1), got {q.size}")
        return q

    @staticmethod
    def _reference(frames: Frames) -> np.ndarray:
        """(n-2, 13) stencil reference data: t^{i-1}, a1^{i-1}, t^i, a1^i, reference twist."""
        t, a1 = frames.tangents, frames.a1
        return np.column_stack([t[:-1], a1[:-1], t[1:], a1[1:], frames.reference_twist])

    def stencil_inputs(self, p, q, frames):
        """The arguments of the edge and vertex stencil functions for parameters p at state q (None:
        q*) with reference frames ``frames`` (None: those of q*): (edge_q, edge geometry, edge physical
        parameters), (vertex_q, reference data, vertex geometry, vertex physical parameters)."""
        p = self.check_parameters(p)
        if q is None and frames is None:
            edge_q, vertex_q, reference = self._at_rest
        else:
            q = self._state(q)
            edge_q, vertex_q = q[self.edge_dofs], q[self.vertex_dofs]
            reference = self._reference(self.frames if frames is None else frames)
        edge = (edge_q, self._edge_geometry, self.layout.edge_map.evaluate(p))
        vertex = (vertex_q, reference, self._vertex_geometry, self.layout.vertex_map.evaluate(p))
        return edge, vertex

    def energy(self, p, q=None, frames: Frames | None = None) -> float:
        """Elastic energy E(q, p), J; reference frames time-transported from those of q* (or
        ``frames``) inside the expression."""
        edge, vertex = self.stencil_inputs(p, q, frames)
        return float(self.edge_functions.energy(*edge)[0].sum() + self.vertex_functions.energy(*vertex)[0].sum())

    def elastic_gradient(self, p, q=None, frames: Frames | None = None) -> np.ndarray:
        """grad_q E(q, p) (4n-1): N on positions, N m on angles. At q* (q and frames None) the vertex
        stencils' part is (dk/dy)^T dE/dk with the kinematics k at q* (stencils.FixedShapeFunctions)."""
        edge, vertex = self.stencil_inputs(p, q, frames)
        size = self.q_star.size
        if q is None and frames is None:
            kinematics, transposed = self.kinematics_at_rest
            (by_kinematics,) = self.vertex_fixed_functions.gradient(kinematics, *vertex[2:])
            vertex_gradient = (transposed @ by_kinematics[:, :, None])[:, :, 0]
        else:
            (vertex_gradient,) = self.vertex_functions.gradient(*vertex)
        return (np.bincount(self.edge_dofs.ravel(), self.edge_functions.gradient(*edge)[0].ravel(), size)
                + np.bincount(self.vertex_dofs.ravel(), vertex_gradient.ravel(), size))

    def forces(self, p, q=None, frames: Frames | None = None) -> np.ndarray:
        """Generalized force f = -grad_q E(q, p) + f_gravity (4n-1), N and N m."""
        return self.gravity_forces - self.elastic_gradient(p, q, frames)

    def residual(self, p) -> np.ndarray:
        """c(p) = D^-1 S f(q*, p), unit-free, free rows in strand order."""
        return self.forces(p)[self._free_index] / self._free_row_scale

    def jacobian(self, p) -> sp.csc_matrix:
        """dc/dp as a sparse (free DOFs x parameters) matrix, both axes in strand order (banded)."""
        return self.strand_jacobian(p).tocsc()

    def strand_jacobian(self, p) -> StrandJacobian:
        """dc/dp with compiled products (jacobian module): what the solvers iterate with. The vertex
        stencils' blocks are (dk/dy)^T d(dE/dk)/d(physical) at q* (stencils.FixedShapeFunctions)."""
        edge, vertex = self.stencil_inputs(p, None, None)
        kinematics, transposed = self.kinematics_at_rest
        (by_kinematics,) = self.vertex_fixed_functions.parameter_jacobian(kinematics, *vertex[2:])
        return StrandJacobian(self._jacobian_pattern, self._jacobian_pattern.values(
            self.edge_functions.parameter_jacobian(*edge)[0], transposed @ by_kinematics))

    def _hessian_blocks(self, p, q, frames):
        edge, vertex = self.stencil_inputs(p, q, frames)
        return [(self.edge_dofs, self.edge_functions.hessian(*edge)[0]),
                (self.vertex_dofs, self.vertex_functions.hessian(*vertex)[0])]

    def hessian(self, p, q=None, frames: Frames | None = None) -> sp.csr_matrix:
        """d2E/dq2 (4n-1 square, sparse, half bandwidth 10)."""
        blocks = self._hessian_blocks(p, q, frames)
        rows = np.concatenate([np.repeat(ix, ix.shape[1], axis=1).ravel() for ix, _ in blocks])
        cols = np.concatenate([np.tile(ix, (1, ix.shape[1])).ravel() for ix, _ in blocks])
        values = np.concatenate([h.ravel() for _, h in blocks])
        size = self.q_star.size
        return sp.csr_matrix((values, (rows, cols)), shape=(size, size))

    def hessian_band(self, p, q=None, frames: Frames | None = None) -> np.ndarray:
        """d2E/dq2 in LAPACK lower band storage: band[k, j] = H[j + k, j], k = 0..10.

        Summed from the stencil Hessians in O(n); ``band[:, s:]`` is the trailing block from DOF s
        (the free block: the root prescribes a prefix of q).
        """
        if self._band_scatter is None:
            self._band_scatter = _band_scatter(
                [self.edge_dofs, self.vertex_dofs], self.q_star.size)
        target, lower = self._band_scatter
        values = np.concatenate([h[mask] for (_, h), mask in zip(self._hessian_blocks(p, q, frames), lower)])
        size = self.q_star.size
        return np.bincount(target, values, minlength=(HALF_BANDWIDTH + 1) * size).reshape(-1, size)

    def stability(self, p) -> float:
        """Smallest eigenvalue of the free-DOF energy Hessian at q* (DESIGN 7); > 0: stable rest.

        Linear in n: compiled shift-and-invert Lanczos on the Hessian's band (linalg.eigen); LAPACK's
        banded eigensolver would cost O(n^2).
        """
        return smallest_eigenvalue(self.hessian_band(p)[:, self.first_free:])


def _check_scales(masses, row_scale, bend_stiffness, stretch_stiffness) -> None:
    """Refuse a strand whose material and size make the model's scales zero or overflow in double
    precision (masses, the force scales D of c, the bending and stretch stiffness), which would turn
    c into NaN: such numbers are almost surely in the wrong units."""
    for name, values in (("vertex masses", masses), ("force scales", row_scale),
                         ("bending and twisting stiffness (E, G) pi r^4", bend_stiffness),
                         ("stretch stiffness (E, G) pi r^2", stretch_stiffness)):
        values = np.asarray(values, dtype=float)
        if not np.all(np.isfinite(values) & (values > 1e-290)) or np.any(values > 1e290):
            raise ValueError(f"strand {name} out of double-precision range ({np.min(values):.3g} to "
                             f"{np.max(values):.3g}): check the units of radius (m), moduli (Pa), density "
                             "(kg/m^3) and coordinates (m)")


#: _band_scatter results by (size, stencil DOF indices): the strands of a groom share a few
_BAND_SCATTERS: dict = {}


def _band_scatter(stencil_indices: list[np.ndarray], size: int):
    """For each stencil kind: the lower-triangle mask of its Hessian blocks; overall: the flat index
    into (HALF_BANDWIDTH + 1, size) band storage of every kept entry (~0.15 ms on a 100-vertex
    strand, cached)."""
    key = (size, *(index.shape for index in stencil_indices), *(index.tobytes() for index in stencil_indices))
    if key not in _BAND_SCATTERS:
        if len(_BAND_SCATTERS) >= 16:
            _BAND_SCATTERS.pop(next(iter(_BAND_SCATTERS)))
        _BAND_SCATTERS[key] = _build_band_scatter(stencil_indices, size)
    return _BAND_SCATTERS[key]


def _build_band_scatter(stencil_indices: list[np.ndarray], size: int):
    targets, masks = [], []
    for index in stencil_indices:
        width = index.shape[1]
        row = np.repeat(index, width, axis=1).reshape(-1, width, width)
        col = np.tile(index, (1, width)).reshape(-1, width, width)
        lower = row >= col
        targets.append((row[lower] - col[lower]) * size + col[lower])
        masks.append(lower)
    return np.concatenate(targets), masks
