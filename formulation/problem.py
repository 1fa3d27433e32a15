"""The equilibrium problem of one strand (DESIGN sections 3, 4 and 10).

    minimize R(p)  subject to  c(p) = D^-1 S f(q*, p) = 0,  lower <= p <= upper,

f = -grad_q E(q*, p) + f_ext (gravity and the strand's loads), S selects the free DOFs (those the
root, tip and pins do not prescribe), D scales each row by a characteristic
force (dofs.row_scales), so |c|_inf is relative and unit-free. c is evaluated by the compiled stencil
functions; dc/dp is assembled from their exact parameter Jacobians into a sparse matrix whose rows
(free DOFs) and columns (parameters) are both in strand order, hence banded.
"""
from __future__ import annotations

import copy
import functools
import math

import numba
import numpy as np
import scipy.sparse as sp

from sagfree.linalg.band import add_vertex_blocks, lower_band, principal_band, principal_band_gather
from sagfree.linalg.eigen import projected_eigenpair, scaled_block_eigenpair, smallest_eigenpair, start_vector
from sagfree.linalg import timing
from sagfree.linalg.timing import LINEAR_ALGEBRA, MODEL, timed

from . import at_rest, dofs
from .curvature import check_variant
from .energies import TERMS
from .frames import Frames, default_director, first_tangent, project_director
from .jacobian import JacobianPattern, StrandJacobian, scatter_values
from .newton import contact_table
from .bodies import parse_body
from .contact import Contacts, contact_penalty, find_contacts
from .rest_geometry import reference_data, rest_geometry
from .parameters import BLOCKS, CONTACT_BLOCK, STRAND_BLOCK, ParameterLayout, SlotMap
from .stencils import edge_stencil, parameter_hessians, vertex_fixed_shape, vertex_stencil
from .strand import InvalidStrand, Strand

#: Half bandwidth of every DOF Hessian: a vertex stencil spans 11 consecutive DOFs (dofs module).
HALF_BANDWIDTH = 10
#: Default stability margin: this share of the unstressed strand's smallest eigenvalue (Problem).
STABILITY_FRACTION = 0.1
#: stability results kept per problem (Problem.stability)
STABILITY_MEMO = 4
#: ... and of forces and dc/dp at q* (Problem.forces, Problem.strand_jacobian)
AT_REST_MEMO = 2


class Problem:
    """Sag-free parameter problem of one strand.

    gravity: m/s^2 vector. curvature: "4d" | "2d-average" | "2d-slerp".
    optimize: parameter blocks to optimize (parameters module). stiffness: "element" | "strand" |
    "fixed". couple_twist: gamma follows the bend multiplier. bounds, weights: parameters module.
    energies: elastic terms included (all by default; a subset serves verification and experiments).
    stabilize: a solution must be a STABLE rest state, ``stability(p) >= stability_margin`` (DESIGN
    4; frontend.stabilize raises stiffness where needed); False gives the paper's bare problem.
    min_eigenvalue: that margin in s^-2; None: STABILITY_FRACTION of the unstressed strand's
    smallest eigenvalue (``stability(p0)``: at p0 the rest shape is q*, so nothing is stressed).
    bodies: rigid bodies the strand may rest on (bodies module; Body objects or their specs such as
    "sphere:0,0,0,0.1"); each vertex of q* within contact_distance (m; None: contact.CONTACT_RADII
    strand radii) of one gets a non-negative support force along the body's normal, one more block
    of p (parameters.CONTACT_BLOCK), so c(p) = D^-1 S (f(q*, p) + sum_i n_i D_i l_i) (contact module).
    friction: Coulomb coefficient mu >= 0; with mu > 0 a resting vertex's support is any force of
    the friction pyramid, four supports along its generators (contact.Contacts.directions), and the
    simulation holds resting vertices by friction too (contact module).

    Public members beyond the API of DESIGN section 10, for the model's own modules (symbolic,
    simulation, verification) and for tests: ``edge_functions`` / ``vertex_functions`` (the compiled
    stencil functions of stencils.edge_stencil / vertex_stencil: geometry, energy, gradient, Hessian,
    parameter Jacobian), ``vertex_fixed_functions`` (the same through the vertex kinematics at q*,
    stencils.vertex_fixed_shape), ``edge_dofs`` / ``vertex_dofs`` (each stencil's DOF indices into q,
    dofs module), ``kinematics_at_rest`` (k and (dk/dy)^T at q*), ``stencil_inputs`` and
    ``check_parameters``.
    """

    def __init__(self, strand: Strand, gravity=(0.0, 0.0, -9.81), curvature="4d", optimize=BLOCKS,
                 stiffness="element", couple_twist=True, bounds=None, weights=None, energies=TERMS,
                 stabilize=True, min_eigenvalue=None, bodies=(), contact_distance=None, friction=0.0):
        if not isinstance(strand, Strand):
            raise ValueError(strand.message if isinstance(strand, InvalidStrand) else
                             f"expected a sagfree.Strand, got {type(strand).__name__}")
        check_variant(curvature)
        self.gravity = np.array(gravity, dtype=float).reshape(-1)
        if self.gravity.shape != (3,) or not all(map(math.isfinite, self.gravity.tolist())):
            raise ValueError(f"gravity must be a finite 3-vector, got {gravity!r}")
        unknown = set(energies) - set(TERMS)
        if unknown:
            raise ValueError(f"unknown energy terms {sorted(unknown)}; choose from {TERMS}")
        self.strand, self.curvature, self.energies = strand, curvature, tuple(energies)
        if min_eigenvalue is not None and not np.isfinite(min_eigenvalue):
            raise ValueError(f"min_eigenvalue must be a finite number of s^-2 or None, got {min_eigenvalue!r}")
        self.stabilize, self.min_eigenvalue = bool(stabilize), min_eigenvalue
        self.options = dict(gravity=gravity, curvature=curvature, optimize=optimize, stiffness=stiffness,
                            couple_twist=couple_twist, bounds=bounds, weights=weights, energies=energies,
                            stabilize=stabilize, min_eigenvalue=min_eigenvalue, bodies=bodies,
                            contact_distance=contact_distance, friction=friction)
        self.friction = float(friction)
        if not (np.isfinite(self.friction) and self.friction >= 0):
            raise ValueError(f"friction must be a coefficient >= 0, got {friction!r}")
        self.bodies = tuple(parse_body(b) for b in (bodies or ()))
        n = self.n_vertices = strand.n_vertices
        points = strand.points
        first = first_tangent(points)
        a1 = (default_director(first, self.gravity) if strand.director is None
              else project_director(first, strand.director))
        self.edge_functions = edge_stencil("stretch" in energies)
        vertex_terms = tuple(t for t in ("bend", "twist") if t in energies)
        self.vertex_functions = vertex_stencil(curvature, vertex_terms)
        self.vertex_fixed_functions = vertex_fixed_shape(curvature, vertex_terms)
        self.edge_dofs = dofs.edge_stencil_index(n)
        self.vertex_dofs = dofs.vertex_stencil_index(n)

        # input geometry through the same compiled expressions as the energies, so that the strains,
        # curvature and twist differences vanish exactly at p0 (one compiled call: rest_geometry)
        r = strand.radius
        rest = rest_geometry(points, strand.theta, a1, r, self.edge_functions, self.vertex_functions,
                             self.vertex_fixed_functions)
        self.frames: Frames = rest.frames
        self.q_star = rest.q_star
        l0, kappa, twist = rest.l0, rest.kappa, rest.twist
        self.edge_lengths, self.twist_star = l0, twist
        self._edge_geometry, self._vertex_geometry = rest.edge_geometry, rest.vertex_geometry
        half_edges = _vertex_sums(l0)  # l_{i-1} + l_i, one edge at the ends
        with np.errstate(all="ignore"):
            masses = 0.5 * strand.density * np.pi * np.float64(r) ** 2 * half_edges
            self.row_scale = dofs.row_scales(masses, l0, strand.density, r, self.gravity, strand.loads)
            moduli = np.array([strand.youngs_modulus, strand.shear_modulus])
            _check_scales(masses, self.row_scale, moduli * np.pi * np.float64(r) ** 4,
                          moduli * np.pi * np.float64(r) ** 2)
        self.masses = masses
        self.external_forces = dofs.external_forces(masses, self.gravity, strand.loads)
        self.free, self.free_index, free_row = _free_dofs(n, strand.root, strand.tip,
                                                         tuple(np.asarray(strand.pins, dtype=int).tolist()))
        if not self.free.any():
            raise ValueError(f"{strand!r}: its attachments prescribe every DOF; nothing is left to balance")
        vertex_scale = self.row_scale[dofs.position_index(n)[:, 0]]
        # the contact penalty's stiffness: the stretch stiffness E pi r^2 / lv_i of the vertex's own length
        voronoi = 0.5 * half_edges
        self.contacts: Contacts = find_contacts(points, r, self.bodies, strand.prescribed_vertices,
                                                strand.youngs_modulus * np.pi * r**2 / voronoi, contact_distance,
                                                self.friction)
        self.layout = ParameterLayout(n, l0, kappa[:, :2], twist, strand.youngs_modulus,
                                      strand.shear_modulus, optimize, stiffness, couple_twist, bounds,
                                      weights, self.contacts.vertices, self.contacts.directions.shape[1])
        # a contact is a "stencil" on its vertex's 3 positions with a slot per support g_ij: its
        # parameter Jacobian is constant, -D_i d_ij (JacobianPattern scales by -1/D: dc/dg_ij = d_ij)
        width = self.contacts.directions.shape[1]
        if self.contacts.count:
            contact_dofs = dofs.position_index(n)[self.contacts.vertices]
            contact_index = self.layout.blocks[CONTACT_BLOCK].reshape(-1, width)
            contact_slots = SlotMap(contact_index, np.ones(contact_index.shape), np.zeros(contact_index.shape))
        else:
            contact_dofs, contact_slots = _no_contacts(width)
        self._contact_jacobian = -(self.contacts.directions.transpose(0, 2, 1)
                                   * vertex_scale[self.contacts.vertices, None, None])
        self._jacobian_pattern = JacobianPattern(
            free_row, self.row_scale, int(self.free.sum()), self.layout.size,
            [(self.edge_dofs, self.layout.edge_map), (self.vertex_dofs, self.layout.vertex_map),
             (contact_dofs, contact_slots)])
        # the stencils' inputs at q* that do not depend on p (residual and Jacobian evaluate only there)
        self._at_rest = (rest.edge_q, rest.vertex_q, rest.reference)
        # the vertex kinematics k and dk/dy at q* (stencils.FixedShapeFunctions), dk/dy transposed
        self.kinematics_at_rest = (rest.kinematics, rest.kinematics_jacobian)
        self._free_row_scale = self.row_scale[self.free_index]
        self._free_gather = _free_gather(self.free_index, self.q_star.size)
        # what depends on p but not on the bounds, by p, shared with the with_lower_bounds twins: the
        # last few (lambda, mode) of stability at q* (a solver's Result, the stabilization loop and
        # the final Result ask for the same p), forces and dc/dp at q* (a solver's convergence test,
        # its KKT confirmation and its Result evaluate the same p: 44% of a groom strand's force
        # evaluations repeated the previous one; the Jacobians are shared objects, their users only
        # read them) and the ``bound_independent`` quantities
        self._memos: dict[str, dict] = {"stability": {}, "forces": {}, "jacobian": {}, "bound_independent": {}}

    def with_options(self, **changes) -> "Problem":
        """The same strand's Problem with some constructor options changed."""
        return Problem(self.strand, **{**self.options, **changes})

    def with_lower_bounds(self, lower: np.ndarray) -> "Problem":
        """A copy whose lower bounds are max(lower bounds, ``lower``) (capped at the upper bounds):
        the stiffness floors of the stabilization. p0 may then lie outside the box."""
        twin = copy.copy(self)
        twin.layout = copy.copy(self.layout)
        twin.layout.lower = np.minimum(np.maximum(self.layout.lower, lower), self.layout.upper)
        return twin

    def bound_independent(self, key: str, build):
        """``build()``, computed once for this problem and its ``with_lower_bounds`` twins: for the
        solvers' quantities that do not depend on the bounds (asc's least rest-shape change at p0,
        which every solve of the stabilization's floored twins would otherwise factor again)."""
        return _memo(self._memos["bound_independent"], key, build)

    def remembered(self, key: str):
        """The ``bound_independent`` quantity ``key`` if this problem or a twin computed it, else None."""
        return self._memos["bound_independent"].get(key)

    def _by_p(self, kind: str, p, build, limit: int):
        """``build()`` remembered in the ``kind`` memo by p's values (the last ``limit`` p)."""
        return _memo(self._memos[kind], self.check_parameters(p).tobytes(), build, limit)

    @functools.cached_property
    def stability_margin(self) -> float:
        """The smallest eigenvalue (s^-2) a stable solution must reach: ``min_eigenvalue``, or
        STABILITY_FRACTION of the unstressed strand's. A tenth keeps the slowest mode within a
        factor ~3 in frequency of the unstressed strand's, so a pushed strand swings back within a
        few of its natural periods and no nearby model of the same strand loses its stability."""
        if self.min_eigenvalue is not None:
            return float(self.min_eigenvalue)
        return STABILITY_FRACTION * self.unstressed_stability()

    def unstressed_stability(self) -> float:
        """``stability(p0)``, the unstressed strand's smallest eigenvalue (s^-2) that sets
        ``stability_margin``: where the stencils are compiled, the compiled call of every other p
        (at_rest.stability), which asc's compiled solve of a strand held by its root alone
        (frontend.whole_solve) also makes, so that both decide on the same margin; the numpy path
        (``stability``) sums the unstressed vertex Hessians instead, the same to rounding."""
        kernels = self.stability_kernels
        if kernels is None or timing.CLOCK is None:
            return self.stability(self.p0)
        p0 = self.layout.p0.copy()  # writable, as the compiled callers pass it (read-only: a second compile)
        seconds = np.zeros(2)
        value = at_rest.stability(p0, *kernels, *timing.CLOCK, seconds)[0]
        timing.add(MODEL, seconds[0])
        timing.add(LINEAR_ALGEBRA, seconds[1])
        return float(value)

    def meets_margin(self, p) -> bool:
        """``stability(p) >= stability_margin`` at q*, deciding without the margin's own eigenvalue
        where a bound can: for the mode v of p the Rayleigh quotient gives lambda_0 <= v^T H(p0) v /
        v^T M v, so lambda(p) >= STABILITY_FRACTION times that quotient proves the margin (with
        1e-6 to spare for the eigensolver's tolerance and the rounding of v^T H(p0) v, ~1e-7 of it
        where the soft mode's terms cancel, so the verdict is the exact comparison's). A converged
        strand usually clears it by far, and the quotient (``_unstressed_form``) costs a seventh of
        the Lanczos run it saves."""
        value, mode = self.stability(p, vector=True)
        if self.min_eigenvalue is None and "stability_margin" not in self.__dict__:
            curvature = self._unstressed_form(mode)
            if value >= STABILITY_FRACTION * curvature / (self.dof_masses @ mode**2) * (1.0 + 1e-6):
                return True
        return value >= self.stability_margin

    def _unstressed_form(self, v) -> float:
        """v^T H(p0) v at q*, summed over the stencils without assembling H (half the band's cost;
        dE/dk = 0 at p0, so ``_unstressed_vertex_forms`` applies); one compiled call
        (at_rest.unstressed_form) where the stencils are compiled."""
        arguments = self.unstressed_form_kernel
        if arguments is not None:
            return at_rest.unstressed_form(np.ascontiguousarray(v, dtype=float), *arguments)
        edge, vertex = self.stencil_inputs(self.layout.p0, None, None)
        return float(self._edge_forms(v, edge[2]).sum()
                     + self._unstressed_vertex_forms(self._kinematics_motion(v), vertex[3]).sum())

    @functools.cached_property
    def unstressed_form_kernel(self):
        """at_rest.unstressed_form's arguments after v (p0, the stencils' inputs at q*, their DOFs and
        the Hessian drivers), or None where those Hessians are not compiled."""
        compiled = self._compiled_at_rest
        hessians = (self.edge_functions.hessian, self.vertex_fixed_functions.hessian)
        if compiled is None or not all(function.compiled for function in hessians):
            return None
        inputs = compiled[0]  # slots, edge q and geometry, kinematics, vertex geometry, dk/dy: its arguments
        return (self.layout.p0, *inputs, self.edge_dofs, self.vertex_dofs, *(f.address for f in hessians))

    def _edge_forms(self, v, edge_physical) -> np.ndarray:
        """v_s^T H_s v_s per edge stencil at q* (H_s its d2E/dy2 with the physical parameters given)."""
        (hessians,) = self.edge_functions.hessian(self._at_rest[0], self._edge_geometry, edge_physical)
        local = v[self.edge_dofs]
        return np.einsum("si,sij,sj->s", local, hessians, local)

    def _kinematics_motion(self, v) -> np.ndarray:
        """u_s = dk/dy v_s per vertex stencil, the kinematics at q* (``kinematics_at_rest``)."""
        return np.einsum("sij,si->sj", self.kinematics_at_rest[1], v[self.vertex_dofs])

    def _unstressed_vertex_forms(self, motion, vertex_physical) -> np.ndarray:
        """v_s^T H_s v_s per vertex stencil at q* where its dE/dk = 0 (an unstressed rest shape):
        H_s = (dk/dy)^T d2E/dk2 dk/dy, so the form is u^T d2E/dk2 u with u = ``motion`` (no second
        derivatives of the frames and transports, as in ``_hessian_blocks`` at p0)."""
        (hessians,) = self.vertex_fixed_functions.hessian(self.kinematics_at_rest[0], self._vertex_geometry,
                                                          vertex_physical)
        return np.einsum("si,sij,sj->s", motion, hessians, motion)

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
        """Regularizer R(p) = 1/2 sum_j w_b(j) a_j (p_j - p0_j)^2 (dimensionless; a_j the element's share
        of the strand's length, parameters module)."""
        return self.layout.regularizer(self.check_parameters(p))

    def objective_gradient(self, p) -> np.ndarray:
        return self.layout.regularizer_gradient(self.check_parameters(p))

    def physical(self, p) -> dict[str, np.ndarray]:
        """Physical parameters: rest lengths (m), rest curvatures (n-2, 2), rest twists (rad), moduli
        alpha (per edge), beta and gamma (per interior vertex) in Pa, as contiguous arrays (strided
        columns of the slot maps' tables pickle at half the speed, and every Result carries them
        across a process boundary)."""
        p = self.check_parameters(p)
        edge, vertex = self.layout.edge_map.evaluate(p).T, self.layout.vertex_map.evaluate(p).T.copy()
        return {
            "rest_length": self.edge_lengths * (1.0 + edge[0]),
            "rest_curvature": vertex[2:4].T.copy(),
            "rest_twist": vertex[4],
            "stretch_modulus": edge[1].copy(),
            "bend_modulus": vertex[5],
            "twist_modulus": vertex[6],
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
            reference = reference_data(self.frames if frames is None else frames)
        edge = (edge_q, self._edge_geometry, self.layout.edge_map.evaluate(p))
        vertex = (vertex_q, reference, self._vertex_geometry, self.layout.vertex_map.evaluate(p))
        return edge, vertex

    @timed(MODEL)
    def energy(self, p, q=None, frames: Frames | None = None) -> float:
        """Elastic energy E(q, p), J; reference frames time-transported from those of q* (or
        ``frames``) inside the expression."""
        edge, vertex = self.stencil_inputs(p, q, frames)
        return float(self.edge_functions.energy(*edge)[0].sum() + self.vertex_functions.energy(*vertex)[0].sum())

    @timed(MODEL)
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

    @timed(MODEL)
    def forces(self, p, q=None, frames: Frames | None = None) -> np.ndarray:
        """Generalized force f = -grad_q E(q, p) + f_ext (4n-1), N and N m; f_ext = gravity on the
        lumped masses plus the strand's loads; at q* (q and frames None) plus the bodies' supports
        of p (``contact_forces``). Away from q* the supports of p mean nothing: the simulation
        has its own contact model (contact module)."""
        if q is None and frames is None:
            return self._by_p("forces", p, lambda: self._forces_at_rest(p), AT_REST_MEMO).copy()
        return self.external_forces - self.elastic_gradient(p, q, frames)

    def _forces_at_rest(self, p) -> np.ndarray:
        """``forces(p)`` at q*, uncached (one compiled call, at_rest, where the stencils are compiled)."""
        compiled = self._compiled_at_rest
        if compiled is None:
            f = self.external_forces - self.elastic_gradient(p)
        else:
            inputs, (gradients, _), _ = compiled
            return at_rest.forces(self.check_parameters(p), *inputs, self.edge_dofs, self.vertex_dofs,
                                  self.external_forces, *gradients, *self._contact_pushes)
        if self.contacts.count:
            f[dofs.position_index(self.n_vertices)] += self.contact_forces(p)
        return f

    @functools.cached_property
    def _contact_pushes(self):
        """at_rest.forces' contact arguments: (index of g in p (K, width), directions d (K, width, 3),
        position DOFs of the contact vertices (K, 3), their force scales D (K,)); K = 0 without bodies."""
        width = self.contacts.directions.shape[1]
        if not self.contacts.count:
            return _no_pushes(width)
        rows = dofs.position_index(self.n_vertices)[self.contacts.vertices].astype(np.int64)
        # copies: a read-only view of the layout's blocks is another numba type, and the compiled loops
        # that take these (gauss_newton._inner) were compiled a second time for strands on bodies
        return (np.array(self.layout.blocks[CONTACT_BLOCK].reshape(-1, width), dtype=np.int64),
                np.array(self.contacts.directions, dtype=float), np.ascontiguousarray(rows),
                np.array(self.row_scale[rows[:, 0]]))

    def contact_forces(self, p) -> np.ndarray:
        """(n, 3) force of the bodies on each vertex at q*, N: D_i sum_j g_ij d_ij on the contact
        vertices (d: contact.Contacts.directions)."""
        p = self.check_parameters(p)
        out = np.zeros((self.n_vertices, 3))
        if self.contacts.count:
            index, directions, _, scale = self._contact_pushes
            out[self.contacts.vertices] = np.einsum("kj,kjd->kd", p[index], directions) * scale[:, None]
        return out

    @timed(MODEL)
    def residual(self, p) -> np.ndarray:
        """c(p) = D^-1 S f(q*, p), unit-free, free rows in strand order."""
        return self.forces(p)[self.free_index] / self._free_row_scale

    @timed(MODEL)
    def jacobian(self, p) -> sp.csc_matrix:
        """dc/dp as a sparse (free DOFs x parameters) matrix, both axes in strand order (banded)."""
        return self.strand_jacobian(p).tocsc()

    @timed(MODEL)
    def strand_jacobian(self, p, q=None, frames: Frames | None = None) -> StrandJacobian:
        """dc/dp with compiled products (jacobian module): what the solvers iterate with. At q* (q and
        frames None) the vertex stencils' blocks are (dk/dy)^T d(dE/dk)/d(physical) at q*
        (stencils.FixedShapeFunctions), and a support's column its direction (contact.Contacts.directions);
        at another state q (frames as in ``energy``), the derivative of c(q, p) = D^-1 S f(q, p) there
        (the best effort's static sag, solvers.least_sag)."""
        if q is None and frames is None:
            return self._by_p("jacobian", p, lambda: self._strand_jacobian(p, q, frames), AT_REST_MEMO)
        return self._strand_jacobian(p, q, frames)

    @functools.cached_property
    def _slot_arrays(self) -> tuple[tuple, tuple]:
        """The edge and vertex SlotMaps' ``arrays``, C-contiguous: how compiled kernels map p to the
        stencils' physical parameters (at_rest)."""
        return tuple(tuple(np.ascontiguousarray(a) for a in slot_map.arrays)
                     for slot_map in (self.layout.edge_map, self.layout.vertex_map))

    @functools.cached_property
    def _compiled_at_rest(self):
        """(inputs, (gradient drivers, parameter Jacobian drivers), contact blocks) of the at_rest
        kernels, or None where a stencil function is not compiled (CasADi's virtual machine)."""
        functions = (self.edge_functions.gradient, self.vertex_fixed_functions.gradient,
                     self.edge_functions.parameter_jacobian, self.vertex_fixed_functions.parameter_jacobian)
        if not all(function.compiled for function in functions):
            return None
        kinematics, transposed = self.kinematics_at_rest
        # C order throughout: the drivers read the arrays' data as contiguous blocks
        inputs = (*self._slot_arrays, *(np.ascontiguousarray(a) for a in (
            self._at_rest[0], self._edge_geometry, kinematics, self._vertex_geometry, transposed.transpose(0, 2, 1))))
        drivers = tuple(function.address for function in functions)
        return inputs, (drivers[:2], drivers[2:]), np.ascontiguousarray(self._contact_jacobian).ravel()

    @functools.cached_property
    def at_rest_kernels(self):
        """What a compiled loop needs to evaluate c(p) and dc/dp at q* without Python (asc's
        Gauss-Newton loop, solvers.gauss_newton), or None where the stencils are not compiled: a
        tuple (forces arguments after p, the bodies' supports among them, Jacobian arguments after
        p, free index, free rows' scales, (J's CSC indptr and indices, its CSR indptr, indices and
        value order)). c = at_rest.forces(p, *forces_args)[free]
        / scales and the CSC values of dc/dp at_rest.jacobian_values(p, *jacobian_args) are what
        ``residual`` and ``strand_jacobian`` give."""
        compiled = self._compiled_at_rest
        if compiled is None:
            return None
        inputs, (gradients, jacobians), contact = compiled
        pattern = self._jacobian_pattern
        return ((*inputs, self.edge_dofs, self.vertex_dofs, self.external_forces, *gradients, *self._contact_pushes),
                (*inputs, contact, *jacobians, *pattern.scatter_plan), self.free_index, self._free_row_scale,
                (pattern.indptr, pattern.indices, pattern.csr_indptr, pattern.csr_indices, pattern.csr_order))

    @functools.cached_property
    def stability_kernels(self):
        """What a compiled call needs to evaluate ``stability(p, vector=True)`` at q* off p0 without
        Python (at_rest.stability, from solvers.confirmed_start and frontend.floor_steps), or None
        where the stencils are not compiled or bodies may support the strand: (at_rest.hessian_band's
        arguments after p, linalg.eigen.block_eigenpair's after the band, the mass scale s and the
        free DOFs' indices: v[free] = mode * s)."""
        if self._compiled_hessian is None or self.contacts.count:
            return None
        scale, row_scale, column_scale = self._mass_scaling
        return ((*self._compiled_hessian, *self._band_plan, HALF_BANDWIDTH + 1, self.q_star.size),
                (*self._free_gather, scale.size, row_scale, column_scale, start_vector(scale.size)), scale,
                self.free_index)

    @functools.cached_property
    def newton_kernels(self):
        """What newton.newton_kernel needs of the strand to run the simulation's Newton solve in one
        compiled call, or None where a stencil function is not compiled or the bodies are not
        spheres, capsules and at most one mesh: (the slot maps' arrays, (edge geometry, vertex
        geometry, edge DOFs, vertex DOFs), the drivers of the edge energy, gradient and Hessian and of
        the vertex ones, the band plan (target, source, ones, rows), the free block's gather (target,
        source, size), the free DOFs, f_ext, the bodies (newton.contact_table))."""
        functions = (self.edge_functions, self.vertex_functions)
        bodies = contact_table(self.bodies, self.contacts, self.free_vertices)
        if bodies is None or not all(getattr(f, kind).compiled for f in functions
                                     for kind in ("energy", "gradient", "hessian")):
            return None
        strand = (*(np.ascontiguousarray(a, dtype=float) for a in (self._edge_geometry, self._vertex_geometry)),
                  *(np.ascontiguousarray(a, dtype=np.int64) for a in (self.edge_dofs, self.vertex_dofs)))
        drivers = tuple(getattr(f, kind).address for f in functions for kind in ("energy", "gradient", "hessian"))
        return (self._slot_arrays, strand, drivers, (*self._band_plan, HALF_BANDWIDTH + 1),
                (*self._free_gather, self.free_index.size), np.ascontiguousarray(self.free_index, dtype=np.int64),
                np.ascontiguousarray(self.external_forces, dtype=float), bodies)

    @functools.cached_property
    def state_jacobian_kernels(self):
        """What at_state.jacobian_values needs besides p, the state's stencil DOFs and its frames'
        reference data, to give the CSC values of ``strand_jacobian(p, q, frames)`` (the least sag's
        linearizations, solvers.least_sag_loop), or None where the stencils' parameter Jacobians are
        not compiled: ((edge slots, vertex slots), edge geometry, vertex geometry, the supports'
        entry count, the drivers' addresses (edge, vertex), the pattern's scatter_plan, its CSR
        (indptr, indices, order))."""
        functions = (self.edge_functions.parameter_jacobian, self.vertex_functions.parameter_jacobian)
        if not all(function.compiled for function in functions):
            return None
        pattern = self._jacobian_pattern
        return (self._slot_arrays, *(np.ascontiguousarray(a) for a in (self._edge_geometry, self._vertex_geometry)),
                int(self._contact_jacobian.size), tuple(function.address for function in functions),
                pattern.scatter_plan, (pattern.csr_indptr, pattern.csr_indices, pattern.csr_order))

    def remember_stability(self, p, value: float, v: np.ndarray) -> None:
        """Store ``stability(p, vector=True)`` at q*, computed by a compiled call from
        ``stability_kernels``, in the memo ``stability`` reads."""
        self._by_p("stability", p, lambda: (value, v), STABILITY_MEMO)

    def remember_at_rest(self, p, forces: np.ndarray, jacobian_values: np.ndarray) -> None:
        """Store f(q*, p) and the CSC values of dc/dp at p, computed by a compiled loop from
        ``at_rest_kernels``, in the memos ``forces`` and ``strand_jacobian`` read (the solver's
        convergence test and KKT check evaluate its last point again)."""
        self._by_p("forces", p, lambda: forces, AT_REST_MEMO)
        self._by_p("jacobian", p, lambda: StrandJacobian(self._jacobian_pattern, jacobian_values), AT_REST_MEMO)

    def _strand_jacobian(self, p, q, frames) -> StrandJacobian:
        """``strand_jacobian``, uncached."""
        compiled = self._compiled_at_rest if q is None and frames is None else None
        if compiled is not None:
            inputs, (_, jacobians), contact = compiled
            return StrandJacobian(self._jacobian_pattern, at_rest.jacobian_values(
                self.check_parameters(p), *inputs, contact, *jacobians, *self._jacobian_pattern.scatter_plan))
        edge, vertex = self.stencil_inputs(p, q, frames)
        if q is None and frames is None:
            kinematics, transposed = self.kinematics_at_rest
            (by_kinematics,) = self.vertex_fixed_functions.parameter_jacobian(kinematics, *vertex[2:])
            vertex_jacobian, contact_jacobian = transposed @ by_kinematics, self._contact_jacobian
        else:  # the supports act at q* only (``forces``)
            (vertex_jacobian,) = self.vertex_functions.parameter_jacobian(*vertex)
            contact_jacobian = np.zeros_like(self._contact_jacobian)
        return StrandJacobian(self._jacobian_pattern, self._jacobian_pattern.values(
            self.edge_functions.parameter_jacobian(*edge)[0], vertex_jacobian, contact_jacobian))

    @timed(MODEL)
    def constraint_hessian(self, p, lam) -> sp.csr_matrix:
        """sum_r lam_r d2c_r/dp2 at q* (n_parameters square, sparse, symmetric): the curvature of the
        constraints that the Lagrangian's Hessian adds to the regularizer's (asc's Newton-SQP phase).

        lam^T c = -mu^T grad_q E(q*, physical(p)) + const with mu = lam / D on the free rows (0 on the
        prescribed), so per stencil it is -d2(u . dE/dk)/d(physical)^2 with u = (dk/dy) mu_y
        (stencils.ParameterHessianFunctions), mapped to p through the slot maps (physical = constant +
        coefficient * p[index]): each element's block couples its stiffness and rest-shape entries.
        """
        rows, cols, values = self.constraint_hessian_entries(p, lam)
        size = self.n_parameters
        return sp.csr_matrix((values, (rows, cols)), shape=(size, size))

    @timed(MODEL)
    def constraint_hessian_entries(self, p, lam) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``constraint_hessian`` as (rows, columns, values) triplets, one per stencil slot pair,
        duplicates not summed (linalg.saddle.SaddleFactor adds them into its band: a 2000-vertex
        strand's sparse matrix and its conversions cost 3 ms per Newton-SQP step)."""
        p = self.check_parameters(p)
        lam = np.asarray(lam, dtype=float).reshape(-1)
        if lam.shape != (self.free_index.size,):
            raise ValueError(f"lam must have one entry per free DOF ({self.free_index.size}), got {lam.size}")
        if self.curvature_kernels is not None:  # one compiled call (what asc's compiled outer loop calls)
            return at_rest.constraint_hessian_entries(p, lam, *self.curvature_kernels)
        mu = np.zeros(self.q_star.size)
        mu[self.free_index] = lam / self._free_row_scale
        functions = parameter_hessians(self.curvature, self.energies)
        edge, vertex = self.stencil_inputs(p, None, None)
        kinematics, transposed = self.kinematics_at_rest
        (edge_blocks,) = functions.edge(*edge, mu[self.edge_dofs])
        (vertex_blocks,) = functions.vertex(kinematics, *vertex[2:],
                                            np.einsum("sij,si->sj", transposed, mu[self.vertex_dofs]))
        edge_map, vertex_map = self.layout.edge_map, self.layout.vertex_map
        return at_rest.slot_pair_entries(edge_map.index, edge_map.coefficient, np.ascontiguousarray(edge_blocks),
                                         vertex_map.index, vertex_map.coefficient,
                                         np.ascontiguousarray(vertex_blocks))

    @functools.cached_property
    def curvature_kernels(self):
        """The arguments after (p, lam) of at_rest.constraint_hessian_entries, which evaluates
        ``constraint_hessian_entries`` in one compiled call, or None where its stencils or the
        at_rest kernels are not compiled. Built on first use (asc's compiled outer loop takes them
        for its Newton-SQP; the warm-up loads their library in every process that solves)."""
        compiled = self._compiled_at_rest
        functions = parameter_hessians(self.curvature, self.energies)
        if compiled is None or not (functions.edge.compiled and functions.vertex.compiled):
            return None
        edge_map, vertex_map = self.layout.edge_map, self.layout.vertex_map
        return (*compiled[0], self.edge_dofs, self.vertex_dofs, self.free_index, self._free_row_scale,
                self.q_star.size, functions.edge.address, functions.vertex.address,
                *(np.ascontiguousarray(a) for a in (edge_map.index, edge_map.coefficient, vertex_map.index,
                                                    vertex_map.coefficient)))

    def _hessian_blocks(self, p, q, frames):
        """[(stencil DOF indices, stencil Hessians d2E/dy2)] of the edge and vertex stencils. At q* and
        p0 (the unstressed strand, whose smallest eigenvalue sets ``stability_margin``) the vertex
        stencils' dE/dk vanishes to rounding (the rest curvatures and twists are q*'s own), so their
        Hessians are (dk/dy)^T d2E/dk2 dk/dy with the kinematics at q* (stencils.FixedShapeFunctions):
        no second derivative of the frames and transports (0.35 -> 0.09 ms with the edge stencils'
        at 100 vertices)."""
        edge, vertex = self.stencil_inputs(p, q, frames)
        if q is None and frames is None and np.array_equal(p, self.layout.p0):
            kinematics, transposed = self.kinematics_at_rest
            (by_kinematics,) = self.vertex_fixed_functions.hessian(kinematics, *vertex[2:])
            vertex_hessians = transposed @ by_kinematics @ transposed.transpose(0, 2, 1)
        else:
            (vertex_hessians,) = self.vertex_functions.hessian(*vertex)
        return [(self.edge_dofs, self.edge_functions.hessian(*edge)[0]), (self.vertex_dofs, vertex_hessians)]

    @timed(MODEL)
    def hessian(self, p, q=None, frames: Frames | None = None) -> sp.csr_matrix:
        """d2E/dq2 (4n-1 square, sparse, half bandwidth 10)."""
        blocks = self._hessian_blocks(p, q, frames)
        rows = np.concatenate([np.repeat(ix, ix.shape[1], axis=1).ravel() for ix, _ in blocks])
        cols = np.concatenate([np.tile(ix, (1, ix.shape[1])).ravel() for ix, _ in blocks])
        values = np.concatenate([h.ravel() for _, h in blocks])
        size = self.q_star.size
        return sp.csr_matrix((values, (rows, cols)), shape=(size, size))

    def free_band(self, band: np.ndarray) -> np.ndarray:
        """The free-DOF block (rows and columns ``free_index``) of a full band from ``hessian_band``,
        in the same band storage (attachments may prescribe DOFs anywhere along q)."""
        return principal_band(band, self._free_gather, self.free_index.size)

    @timed(MODEL)
    def hessian_band(self, p, q=None, frames: Frames | None = None) -> np.ndarray:
        """d2E/dq2 in LAPACK lower band storage: band[k, j] = H[j + k, j], k = 0..10.

        Summed from the stencil Hessians in O(n); ``free_band`` extracts the free block. At q* off p0
        (every stability evaluation of a solution) one compiled call, at_rest.hessian_band, with the
        same sums.
        """
        target, source, ones = self._band_plan
        size = self.q_star.size
        compiled = self._compiled_hessian if q is None and frames is None else None
        if compiled is not None and not np.array_equal(p, self.layout.p0):  # p0: _hessian_blocks' shortcut
            p = self.check_parameters(p)  # writable, as the compiled callers pass it (read-only: a second compile)
            return at_rest.hessian_band(p if p.flags.writeable else p.copy(), *compiled, target, source, ones,
                                        HALF_BANDWIDTH + 1, size)
        entries = np.concatenate([h.ravel() for _, h in self._hessian_blocks(p, q, frames)])
        return scatter_values(target, source, ones, entries, (HALF_BANDWIDTH + 1) * size).reshape(-1, size)

    @functools.cached_property
    def _band_plan(self):
        """(target, source, ones): how hessian_band scatters the stencil Hessians into the band
        (_band_scatter, shared by the strands of a size); made on first use."""
        return _band_scatter(self.n_vertices)

    @functools.cached_property
    def _compiled_hessian(self):
        """The arguments of at_rest.hessian_band after p and before the scatter (the stencils' inputs
        at q*, their Hessian drivers), or None where those are not compiled."""
        functions = (self.edge_functions.hessian, self.vertex_functions.hessian)
        if not all(function.compiled for function in functions):
            return None
        edge_q, vertex_q, reference = self._at_rest
        return (*self._slot_arrays, edge_q, np.ascontiguousarray(self._edge_geometry), vertex_q, reference,
                np.ascontiguousarray(self._vertex_geometry), *(function.address for function in functions))

    def contact_matrix(self) -> sp.csc_matrix:
        """The supports' part of dc/dp (free DOFs x parameters, constant): each support's direction
        (the normal, or a friction pyramid generator) on its vertex's position rows, in its column (c is
        linear in the supports; the Ipopt baseline's NLP adds it as C p, formulation.symbolic)."""
        jacobian = StrandJacobian(self._jacobian_pattern, self._jacobian_pattern.values(
            np.zeros((len(self.edge_dofs), 6, self.layout.edge_map.index.shape[1])),
            np.zeros((len(self.vertex_dofs), 11, self.layout.vertex_map.index.shape[1])), self._contact_jacobian))
        matrix = jacobian.tocsc()
        matrix.eliminate_zeros()
        return matrix

    @functools.cached_property
    def dof_masses(self) -> np.ndarray:
        """Lumped inertia per DOF (4n-1): the vertex mass m_i (kg) on positions, the edge's polar
        moment rho pi r^4 l0_j / 2 (kg m^2) on th_j (what the simulation integrates). Computed once
        (every stability evaluation and simulation step reads it); do not modify."""
        return _dof_masses(self.masses, 0.5 * self.strand.density * np.pi * self.strand.radius**4, self.edge_lengths)

    def stability(self, p, vector: bool = False, q=None, frames: Frames | None = None):
        """Smallest eigenvalue omega^2 (s^-2) of the free-DOF energy Hessian at q* (or at the state q,
        frames as in ``energy``: where an infeasible strand rests), mass-normalized:
        the smallest lambda of H_F v = lambda M_F v with M the lumped inertia of ``dof_masses`` (DESIGN
        7). omega^2 of the slowest mode if positive (a stable rest state); if negative, a push grows
        like exp(sqrt(-lambda) t). Twist DOFs enter with their rotational inertia, as in the
        simulation, so lambda is the linearized dynamics of the simulated strand. (The raw Hessian
        mixes N/m and N m/rad^2; its smallest eigenvalue says little.)

        With ``vector``: (lambda, v), v the mode on all DOFs (zero on the prescribed ones),
        normalized so that v^T M v = 1. Linear in n: compiled shift-and-invert Lanczos on the scaled
        band M^-1/2 H M^-1/2 (linalg.eigen).
        """
        if q is None and frames is None:
            value, v = self._by_p("stability", p, lambda: self._stability_at_rest(p), STABILITY_MEMO)
            return (value, v.copy()) if vector else value
        return self._stability_of_band(self.static_hessian_band(p, q, frames), vector)

    def _stability_at_rest(self, p) -> tuple[float, np.ndarray]:
        """``stability(p, vector=True)`` at q*, uncached."""
        if self.contacts.count:
            supports = self.check_parameters(p)[self.layout.blocks[CONTACT_BLOCK]].reshape(self.contacts.count, -1)
            if np.any(supports > 0):
                return self._stability_on_bodies(p, np.flatnonzero(np.any(supports > 0, axis=1)), True)
        return self._stability_of_band(self.static_hessian_band(p), True)

    def _stability_of_band(self, full_band: np.ndarray, vector: bool):
        """(lambda, v) or lambda of the mass-normalized free block of a full Hessian band (``stability``)."""
        scale, row_scale, column_scale = self._mass_scaling
        value, mode = scaled_block_eigenpair(full_band, self._free_gather, scale.size, row_scale, column_scale)
        if not vector:
            return value
        v = np.zeros(self.q_star.size)
        v[self.free_index] = mode * scale
        return value, v

    @functools.cached_property
    def _mass_scaling(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, R, C) with s = M_F^-1/2 on the free DOFs and R[k, j] = s[j + k], C[k, j] = s[j] in the
        free band's storage (0 past the end of a diagonal): the band of M^-1/2 H_F M^-1/2 is
        band * R * C."""
        return _mass_scaling(self.dof_masses, self.free_index, HALF_BANDWIDTH + 1)

    @functools.cached_property
    def free_vertices(self) -> np.ndarray:
        """(n,) True for the vertices whose positions are not prescribed (those a body can touch)."""
        free = np.ones(self.n_vertices, dtype=bool)
        free[self.strand.prescribed_vertices] = False
        return free

    def static_hessian_band(self, p, q=None, frames: Frames | None = None) -> np.ndarray:
        """``hessian_band`` plus, with bodies and a state q, the Hessian of the simulation's contact
        penalty there (contact module): the curvature of the static potential whose minimum the
        simulation and the best effort settle in (at q* the penalty is zero, and the supports of p
        hold the strand instead)."""
        band = self.hessian_band(p, q, frames)
        if self.bodies and q is not None:
            add_vertex_blocks(band, contact_penalty(self.contacts, dofs.positions(self._state(q)),
                                                    self.free_vertices)[2])
        return band

    def normal_forces(self, p) -> np.ndarray:
        """(K,) the push of each contact's support along its body's normal at q* (N)."""
        forces = self.contact_forces(p)[self.contacts.vertices]
        return np.einsum("kd,kd->k", forces, self.contacts.normals)

    def _stability_on_bodies(self, p, resting: np.ndarray, vector: bool):
        """``stability`` at q* with the contacts ``resting`` (indices into self.contacts, support > 0).

        Frictionless, or at the edge of the friction pyramid (|f.t1| + |f.t2| = mu f.n: it would slip),
        a resting vertex moves only in its body's tangent plane (a pressed contact stays closed under
        a small push) and its normal force F adds -F K (K = d2 phi/dx2) to its block: the Hessian of
        the Lagrangian E - f.q - sum F phi restricted to the constraints' tangent space (a strand
        pressed onto a convex body is less stable than one held at the same points). Strictly inside
        the pyramid it sticks: all three positions are held. The basis: the free DOFs with each
        resting vertex's 3 positions replaced by its tangents (or by nothing when it sticks), kept in
        strand order so the reduced Hessian stays banded. Where the stencils are compiled, the
        Hessian's band is projected onto it and solved in one compiled call, O(n)
        (linalg.eigen.projected_eigenpair; the sparse products B^T H B dominated a strand's solve on
        a body); elsewhere sparse matrices (the same eigenpair to rounding: tests/test_contact.py)."""
        vertices = self.contacts.vertices[resting]
        forces = self.contact_forces(p)[vertices]
        normal_force = np.einsum("kd,kd->k", forces, self.contacts.normals[resting])
        slip = np.abs(np.einsum("kjd,kd->kj", self.contacts.tangents[resting], forces)).sum(axis=1)
        sticks = (self.friction > 0) & (slip < self.friction * normal_force * (1 - 1e-9))
        positions = dofs.position_index(self.n_vertices)[vertices]               # (m, 3)
        # -F K on the blocks of the vertices that may slide
        sliding = ~sticks
        blocks = -normal_force[sliding, None, None] * self.contacts.curvature[resting[sliding]]
        # reduced coordinates, each with the DOF it sits at (sort key): kept free DOFs, then tangents
        excluded = np.zeros(self.q_star.size, dtype=bool)
        excluded[positions.ravel()] = True
        kept = self.free_index[~excluded[self.free_index]]  # np.setdiff1d's (sorted), without its sort
        tangents = self.contacts.tangents[resting[sliding]]                       # (s, 2, 3)
        keys = np.concatenate([kept, np.repeat(positions[sliding, 0], 2) + np.tile([0.0, 0.5], sliding.sum())])
        order = np.empty(keys.size, dtype=int)
        order[np.argsort(keys, kind="stable")] = np.arange(keys.size)
        if self._compiled_hessian is not None:  # the band and the projection compiled, O(n)
            band = self.hessian_band(p)
            add_vertex_blocks(band, blocks, vertices[sliding])
            support, coefficients = np.full((keys.size, 3), -1, dtype=np.int64), np.zeros((keys.size, 3))
            support[order[:kept.size], 0], coefficients[order[:kept.size], 0] = kept, 1.0
            support[order[kept.size:]] = np.repeat(positions[sliding], 2, axis=0)
            coefficients[order[kept.size:]] = tangents.reshape(-1, 3)
            value, v = projected_eigenpair(band, support, coefficients, self.dof_masses)
            return (value, v) if vector else value
        block_rows = np.repeat(positions[sliding], 3, axis=1)
        block_cols = np.tile(positions[sliding], (1, 3))
        hessian = (self.hessian(p) + sp.csr_matrix((blocks.ravel(), (block_rows.ravel(), block_cols.ravel())),
                                                   shape=(self.q_star.size,) * 2)).tocsc()
        rows = np.concatenate([kept, np.repeat(positions[sliding], 2, axis=0).ravel()])
        columns = np.concatenate([np.arange(kept.size), kept.size + np.repeat(np.arange(2 * sliding.sum()), 3)])
        values = np.concatenate([np.ones(kept.size), tangents.reshape(-1)])
        basis = sp.csc_matrix((values, (rows, order[columns])), shape=(self.q_star.size, keys.size))
        mass = basis.T @ sp.diags(self.dof_masses) @ basis       # diagonal: isotropic vertex masses
        scale = 1.0 / np.sqrt(mass.diagonal())
        reduced = sp.diags(scale) @ (basis.T @ hessian @ basis) @ sp.diags(scale)
        value, mode = smallest_eigenpair(lower_band(reduced))
        if not vector:
            return value
        return value, basis @ (mode * scale)

    @functools.cached_property
    def stiffening_kernel(self):
        """at_rest.stiffening_gradient's arguments after (mode, p), or None where the stencils'
        Hessians are not compiled (``stiffening_gradient`` then sums them in numpy)."""
        compiled = self._compiled_at_rest
        hessians = (self.edge_functions.hessian, self.vertex_fixed_functions.hessian)
        if compiled is None or not all(function.compiled for function in hessians):
            return None
        _, vertex_slots, edge_q, edge_geometry, kinematics, vertex_geometry, kinematics_jacobian = compiled[0]
        blocks, empty = self.layout.blocks, np.zeros(0, dtype=np.int64)
        # writable copies: the layout's blocks may be read-only, the missing ones are not, and each
        # mix of the two was another numba type, so the kernel compiled up to four times
        index = [np.array(blocks.get(block, empty), dtype=np.int64)
                 for block in ("stretch_stiffness", "bend_stiffness", "twist_stiffness", STRAND_BLOCK)]
        return (vertex_slots, edge_q, edge_geometry, kinematics, vertex_geometry, kinematics_jacobian,
                self.edge_dofs, self.vertex_dofs, *(function.address for function in hessians),
                float(self.strand.youngs_modulus), float(self.strand.shear_modulus), *index,
                bool(self.layout.couple_twist))

    def stiffening_gradient(self, p, mode: np.ndarray) -> np.ndarray:
        """d lambda / d k_j for each stiffness multiplier k_j of p (zero on the other entries): the
        growth of the eigenvalue of ``mode`` (from ``stability(p, vector=True)``) when k_j rises while
        the element's rest shape moves to keep its forces at q* (rest_change.restiffen: k (kbar -
        kappa*), k (mbar - m*), k strain held).

        Along that move the stress term of the Hessian (moment x curvature of kappa) is fixed by
        statics and only the element's unstressed term k G_j grows, G_j the Hessian of its energy at
        unit multiplier with its rest shape equal to q* (PSD). So d lambda / d k_j = v^T G_j v >= 0
        for v^T M v = 1 (first-order perturbation of a simple eigenvalue), and lambda is concave in
        the multipliers along such moves.

        A vertex stencil's G_j comes by the chain rule (``_unstressed_vertex_forms``: dE/dk = 0 at
        the unstressed rest shape), without the second derivatives of the frames and transports (two
        0.23 ms Hessians of a 100-vertex strand); one compiled call where the stencils are compiled
        (at_rest.stiffening_gradient, the same numbers).
        """
        p = self.check_parameters(p)
        if self.stiffening_kernel is not None:
            return at_rest.stiffening_gradient(np.ascontiguousarray(mode, dtype=float), p, *self.stiffening_kernel)
        strand = self.strand
        geometry, physical = self._vertex_geometry, self.layout.vertex_map.evaluate(p)
        unstressed = physical.copy()
        unstressed[:, 2:4] = geometry[:, 4:6]  # kbar = kappa* (the 4d map adds the rotated pair)
        unstressed[:, 4] = geometry[:, 3]      # mbar = m*
        motion = self._kinematics_motion(mode)
        forms = {}
        for name, moduli in (("bend", (strand.youngs_modulus, 0.0)), ("twist", (0.0, strand.shear_modulus))):
            unstressed[:, 5:7] = moduli
            forms[name] = self._unstressed_vertex_forms(motion, unstressed)
        edges = len(self.edge_dofs)
        forms["stretch"] = self._edge_forms(mode, np.column_stack([np.zeros(edges),
                                                                   np.full(edges, strand.youngs_modulus)]))
        gradient = np.zeros(self.n_parameters)
        blocks = self.layout.blocks
        per_block = {"stretch_stiffness": forms["stretch"], "twist_stiffness": forms["twist"],
                     "bend_stiffness": forms["bend"] + (forms["twist"] if self.layout.couple_twist else 0.0)}
        for block, values in per_block.items():
            if block in blocks:
                gradient[blocks[block]] = values
        if STRAND_BLOCK in blocks:
            gradient[blocks[STRAND_BLOCK]] = sum(float(values.sum()) for values in forms.values())
        return gradient


@numba.njit(cache=True)
def _dof_masses(masses, polar, edge_lengths):  # pragma: no cover - compiled
    """Problem.dof_masses: m_i on vertex i's positions 4i..4i+2, polar l0_j on th_j (4j + 3)."""
    mass = np.empty(4 * masses.size - 1)
    for i in range(masses.size):
        mass[4 * i], mass[4 * i + 1], mass[4 * i + 2] = masses[i], masses[i], masses[i]
    for j in range(edge_lengths.size):
        mass[4 * j + 3] = polar * edge_lengths[j]
    return mass


@numba.njit(cache=True)
def _mass_scaling(masses, free_index, diagonals):  # pragma: no cover - compiled
    """Problem._mass_scaling from the DOF masses: s = 1 / sqrt(m_F), R[k, j] = s[j + k], C[k, j] =
    s[j] (0 past the end of a diagonal; a 3-vertex strand has fewer free DOFs than diagonals)."""
    size = free_index.size
    scale = np.empty(size)
    for j in range(size):
        scale[j] = 1.0 / np.sqrt(masses[free_index[j]])
    row_scale, column_scale = np.zeros((diagonals, size)), np.zeros((diagonals, size))
    for k in range(min(diagonals, size)):
        for j in range(size - k):
            row_scale[k, j], column_scale[k, j] = scale[j + k], scale[j]
    return scale, row_scale, column_scale


def _vertex_sums(edge_lengths: np.ndarray) -> np.ndarray:
    """(n,) l_{i-1} + l_i per vertex (l_{-1} = l_{n-1} = 0): twice its Voronoi length (as
    np.r_[l, 0] + np.r_[0, l], without np.r_'s ~10 us)."""
    out = np.zeros(edge_lengths.size + 1)
    out[:-1] = edge_lengths
    out[1:] += edge_lengths
    return out


def _check_scales(masses, row_scale, bend_stiffness, stretch_stiffness) -> None:
    """Refuse a strand whose material and size make the model's scales zero or overflow in double
    precision (masses, the force scales D of c, the bending and stretch stiffness), which would turn
    c into NaN: such numbers are almost surely in the wrong units."""
    for name, values in (("vertex masses", masses), ("force scales", row_scale),
                         ("bending and twisting stiffness (E, G) pi r^4", bend_stiffness),
                         ("stretch stiffness (E, G) pi r^2", stretch_stiffness)):
        values = np.asarray(values, dtype=float)
        if not _in_range(values, 1e-290, 1e290):
            raise ValueError(f"strand {name} out of double-precision range ({np.min(values):.3g} to "
                             f"{np.max(values):.3g}): check the units of radius (m), moduli (Pa), density "
                             "(kg/m^3) and coordinates (m)")


@numba.njit(cache=True)
def _in_range(values, low, high) -> bool:  # pragma: no cover - compiled
    """low < every value < high (False for a NaN): _check_scales' test in one pass."""
    for value in values:
        if not (low < value < high):
            return False
    return True


@functools.lru_cache(maxsize=4)
def _no_contacts(width: int) -> tuple[np.ndarray, SlotMap]:
    """The contact "stencils" of a strand without contacts (DOF index and SlotMap of ``width`` slots,
    all empty, read-only), one object for all (JacobianPattern then knows its structure by identity)."""
    index, dof_index = np.zeros((0, width), dtype=int), np.zeros((0, 3), dtype=int)
    slots = SlotMap(index, np.ones(index.shape), np.zeros(index.shape))
    for array in (index, dof_index, slots.coefficient, slots.constant):
        array.flags.writeable = False
    return dof_index, slots


@functools.lru_cache(maxsize=4)
def _no_pushes(width: int) -> tuple:
    """Problem._contact_pushes without contacts: empty arrays of the types numba compiled for (shared:
    nothing can be written into them; read-only flags would make numba compile the kernels again)."""
    return (np.zeros((0, width), dtype=np.int64), np.zeros((0, width, 3)), np.zeros((0, 3), dtype=np.int64),
            np.zeros(0))


def _memo(cache: dict, key, build, limit: int = 16):
    """cache[key], made by build() when missing; beyond ``limit`` entries the oldest goes (the strands
    of a groom share a few structures)."""
    if key not in cache:
        if len(cache) >= limit:
            cache.pop(next(iter(cache)))
        cache[key] = build()
    return cache[key]


@functools.lru_cache(maxsize=64)
def _free_dofs(n_vertices: int, root: str, tip, pins: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(free mask, free DOF indices, each DOF's row in c or -1) of a strand's attachments, shared
    read-only by the strands of a groom."""
    free = dofs.free_mask(n_vertices, root, tip, pins)
    free_index = np.flatnonzero(free)
    free_row = np.full(free.size, -1)
    free_row[free] = np.arange(free_index.size)
    for array in (free, free_index, free_row):
        array.flags.writeable = False
    return free, free_index, free_row


#: principal_band_gather maps of the free DOFs by (size, free DOFs)
_FREE_GATHERS: dict = {}


def _free_gather(free_index: np.ndarray, size: int):
    return _memo(_FREE_GATHERS, (size, free_index.tobytes()),
                 lambda: principal_band_gather(free_index, size, HALF_BANDWIDTH))


@functools.lru_cache(maxsize=16)
def _band_scatter(n_vertices: int):
    """(target, source, ones) of jacobian.scatter_values from the edge and vertex stencils' raveled
    Hessian blocks (dofs.edge_stencil_index, vertex_stencil_index), concatenated in that order, to
    (HALF_BANDWIDTH + 1, 4n - 1) band storage: the lower-triangle entries, each kind's in C order,
    as the np.bincount of their values did (the same sums in the same order, faster); built once
    per strand size."""
    return _build_band_scatter([dofs.edge_stencil_index(n_vertices), dofs.vertex_stencil_index(n_vertices)],
                               4 * n_vertices - 1)


def _build_band_scatter(stencil_indices: list[np.ndarray], size: int):
    targets, sources, offset = [], [], 0
    for index in stencil_indices:
        width = index.shape[1]
        row = np.repeat(index, width, axis=1).reshape(-1, width, width)
        col = np.tile(index, (1, width)).reshape(-1, width, width)
        lower = row >= col
        targets.append((row[lower] - col[lower]) * size + col[lower])
        sources.append(offset + np.flatnonzero(lower.ravel()))
        offset += lower.size
    target, source = np.concatenate(targets).astype(np.int64), np.concatenate(sources).astype(np.int64)
    return target, source, np.ones(target.size)
