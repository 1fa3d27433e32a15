"""The equilibrium problem: residual, forces, Jacobian, parameters (DESIGN sections 3, 4, 10)."""
import numpy as np
import pytest
import scipy.linalg
import scipy.sparse as sp

import sagfree
from sagfree.formulation import dofs, jacobian
from sagfree.formulation.curvature import VARIANTS
from sagfree.formulation.frames import transport_frames
from sagfree.formulation.rest_geometry import RestGeometry, rest_geometry, rest_geometry_numpy
from sagfree.formulation.verification import (gradient_error, jacobian_error, perturbed_parameters,
                                              verification_strands)
from sagfree.linalg.eigen import smallest_eigenpair
from sagfree.linalg.identity import IdentityMemo
from sagfree.scenes.head import HEAD, head_groom

SCENES = {
    "horizontal": lambda: sagfree.scenes.horizontal(n=30),
    "flipped": lambda: sagfree.scenes.flipped(n=30),
    "helix": lambda: sagfree.scenes.helix(n=30),
    "wavy": lambda: sagfree.scenes.wavy(n=30),
    "curly": lambda: sagfree.scenes.curly(n=40),
}


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("scene", SCENES)
def test_residual_at_p0_is_exactly_scaled_gravity(scene, variant):
    pb = sagfree.Problem(SCENES[scene](), curvature=variant)
    gravity = (pb.external_forces / pb.row_scale)[pb.free]
    assert np.array_equal(pb.residual(pb.p0), gravity)
    # every free vertex carries exactly its own weight: -1 on z rows
    z_rows = (4 * np.arange(pb.n_vertices) + 2)[pb.free[4 * np.arange(pb.n_vertices) + 2]]
    assert np.allclose(pb.residual(pb.p0)[np.searchsorted(np.flatnonzero(pb.free), z_rows)], -1, atol=1e-15)


def test_groom_residual_at_p0_is_gravity():
    for strand in sagfree.scenes.groom(20, 40, seed=3):
        pb = sagfree.Problem(strand)
        assert np.array_equal(pb.residual(pb.p0), (pb.external_forces / pb.row_scale)[pb.free])


@pytest.mark.parametrize("variant", VARIANTS)
def test_unloaded_strand_at_p0_has_zero_force(variant):
    for strand in verification_strands(seed=1).values():
        pb = sagfree.Problem(strand, gravity=(0, 0, 0), curvature=variant)
        loads = np.zeros(pb.q_star.size) if strand.loads is None else pb.external_forces  # the loads alone
        assert np.array_equal(pb.forces(pb.p0), loads)
        assert np.array_equal(pb.residual(pb.p0), (loads / pb.row_scale)[pb.free])


@pytest.mark.parametrize("variant", VARIANTS)
def test_forces_are_negative_energy_gradient(variant, rng):
    for strand in verification_strands(seed=2).values():
        pb = sagfree.Problem(strand, curvature=variant)
        p = perturbed_parameters(pb, rng)
        assert gradient_error(pb, p) < 1e-7
        q = pb.q_star + 1e-3 * rng.standard_normal(pb.q_star.size)
        frames = transport_frames(pb.frames, dofs.positions(q))
        assert gradient_error(pb, p, q, frames) < 1e-7  # nonzero reference twist
        assert gradient_error(pb, p, q) < 1e-7          # frames transported from q* in-expression
        assert np.allclose(pb.forces(p, q), pb.external_forces - pb.elastic_gradient(p, q))


@pytest.mark.parametrize("variant", VARIANTS)
def test_fixed_shape_chain_rule_matches_the_full_stencils(variant, rng):
    """At q*, residual and Jacobian go through the kinematics' chain rule (stencils.FixedShapeFunctions);
    elsewhere through the full stencils. Both at q* agree to rounding."""
    for strand in verification_strands(seed=4).values():
        pb = sagfree.Problem(strand, curvature=variant)
        p = perturbed_parameters(pb, rng)
        full = pb.elastic_gradient(p, pb.q_star.copy(), pb.frames)  # q given: the full stencils
        assert np.allclose(pb.elastic_gradient(p), full, rtol=1e-12, atol=1e-12 * np.abs(full).max())
        edge, vertex = pb.stencil_inputs(p, pb.q_star.copy(), pb.frames)
        (full_jacobian,) = pb.vertex_functions.parameter_jacobian(*vertex)
        kinematics, transposed = pb.kinematics_at_rest
        (by_kinematics,) = pb.vertex_fixed_functions.parameter_jacobian(kinematics, *vertex[2:])
        assert np.allclose(transposed @ by_kinematics, full_jacobian, rtol=1e-12,
                           atol=1e-12 * np.abs(full_jacobian).max())
        # what the solvers evaluate at q*: one compiled call each (formulation.at_rest), and the
        # numpy chain rule it replaces where the stencils are not compiled
        numpy_path = sagfree.Problem(strand, curvature=variant)
        numpy_path.__dict__["_compiled_at_rest"] = None
        for at_rest in (pb, numpy_path):
            forces, full_forces = at_rest.forces(p), at_rest.forces(p, pb.q_star.copy(), pb.frames)
            assert np.allclose(forces, full_forces, rtol=1e-12, atol=1e-12 * np.abs(full_forces).max())
            values = at_rest.strand_jacobian(p).data
            full_values = at_rest.strand_jacobian(p, pb.q_star.copy(), pb.frames).data
            assert np.allclose(values, full_values, rtol=1e-12, atol=1e-12 * np.abs(full_values).max())


def test_gradient_check_detects_a_wrong_gradient(rng):
    pb = sagfree.Problem(sagfree.scenes.helix(n=12))
    p = perturbed_parameters(pb, rng)
    true_gradient = pb.elastic_gradient
    pb.elastic_gradient = lambda *a: 1.01 * true_gradient(*a)
    assert gradient_error(pb, p) > 1e-3


@pytest.mark.parametrize("stiffness, couple", [("element", True), ("element", False), ("strand", True),
                                               ("fixed", True)])
def test_jacobian_matches_finite_differences_for_every_block(stiffness, couple, rng):
    pb = sagfree.Problem(sagfree.scenes.curly(n=20), stiffness=stiffness, couple_twist=couple)
    p = perturbed_parameters(pb, rng)
    for block in pb.blocks:
        assert jacobian_error(pb, p, block) < 1e-7, block


@pytest.mark.parametrize("stiffness", ["element", "strand"])
def test_strand_jacobian_products_match_the_sparse_matrix(stiffness, rng):
    """The solvers' compiled J x, J^T y, column norms and row-ordered view (jacobian module) against
    scipy's products of the matrix Problem.jacobian returns."""
    pb = sagfree.Problem(sagfree.scenes.curly(n=20), stiffness=stiffness)
    p = perturbed_parameters(pb, rng)
    J, fast = pb.jacobian(p), pb.strand_jacobian(p)
    x, y = rng.standard_normal(J.shape[1]), rng.standard_normal(J.shape[0])
    for fast_product, product in ((fast @ x, J @ x), (fast.T @ y, J.T @ y),
                                  (fast.column_norms(), np.asarray(J.multiply(J).sum(axis=0)).ravel())):
        assert np.allclose(fast_product, product, rtol=1e-12, atol=1e-12 * np.abs(product).max())
    indptr, indices, data = fast.csr()
    assert np.array_equal(sp.csr_matrix((data, indices, indptr), shape=J.shape).toarray(), J.toarray())


def _pattern_by_numpy(free_row, n_rows, n_parameters, stencils):
    """jacobian._structure's arrays by np.unique and scipy's CSR conversion (its former code)."""
    rows, cols, sources, coefficients, dofs_, offset, coefficient_offset = [], [], [], [], [], 0, 0
    for dof_index, slots in stencils:
        count, width = dof_index.shape
        shape = (count, width, slots.index.shape[1])
        row = np.broadcast_to(free_row[dof_index][:, :, None], shape)
        col = np.broadcast_to(slots.index[:, None, :], shape)
        keep = (row >= 0) & (col >= 0)
        rows.append(row[keep])
        cols.append(col[keep])
        sources.append(offset + np.flatnonzero(keep.ravel()))
        stencil, _, slot = np.nonzero(keep)
        coefficients.append(coefficient_offset + stencil * shape[2] + slot)
        dofs_.append(np.broadcast_to(dof_index[:, :, None], shape)[keep])
        offset += keep.size
        coefficient_offset += count * shape[2]
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    unique, target = np.unique(cols.astype(np.int64) * n_rows + rows, return_inverse=True)
    indices = unique % n_rows
    indptr = np.searchsorted(unique // n_rows, np.arange(n_parameters + 1))
    order = sp.csc_matrix((np.arange(unique.size, dtype=float), indices, indptr), shape=(n_rows, n_parameters)).tocsr()
    order.sort_indices()
    return (target, np.concatenate(sources), indices, indptr, order.indptr, order.indices, order.data.astype(int),
            (np.concatenate(coefficients), np.concatenate(dofs_)))


@pytest.mark.parametrize("make", [
    lambda: sagfree.Problem(sagfree.scenes.groom(1, 40, seed=2)[0]),
    lambda: sagfree.Problem(head_groom(1, 60, seed=5)[0], bodies=[HEAD], friction=0.5),
    lambda: sagfree.Problem(sagfree.Strand(sagfree.scenes.curly(n=30).points, tip="pinned", pins=[7])),
    lambda: sagfree.Problem(sagfree.scenes.groom(1, 40, seed=1)[0], stiffness="strand"),
    lambda: sagfree.Problem(sagfree.scenes.groom(1, 3, seed=0)[0]),
], ids=["groom", "head-friction", "pinned", "strand", "three-vertices"])
def test_the_compiled_jacobian_pattern_is_numpys(make, monkeypatch):
    """jacobian._structure (counting sorts, compiled) against np.unique and scipy's CSR, entry by
    entry, on a fresh pattern of each kind (a strand on a body has contact columns of its own)."""
    calls = []
    monkeypatch.setattr(jacobian, "_STRUCTURES", {})
    monkeypatch.setattr(jacobian, "_STRUCTURES_BY_ARRAYS", IdentityMemo())
    compiled = jacobian._structure
    monkeypatch.setattr(jacobian, "_structure", lambda *args: calls.append(args) or compiled(*args))
    make()
    assert len(calls) == 1
    mine, reference = jacobian._structure(*calls[0]), _pattern_by_numpy(*calls[0])
    for a, b in zip((*mine[:7], *mine[7]), (*reference[:7], *reference[7])):
        assert a.dtype == np.int64 and np.array_equal(a, b)


def test_energies_are_invariant_under_rigid_rotation(rng):
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(1.1) * k + (1 - np.cos(1.1)) * k @ k
    base = verification_strands(seed=4)["twisted"]
    rotated = sagfree.Strand(base.points @ R.T, theta=base.theta)
    for variant in VARIANTS:
        a = sagfree.Problem(base, curvature=variant)
        b = sagfree.Problem(rotated, gravity=R @ np.array([0, 0, -9.81]), curvature=variant)
        assert np.allclose(a.p0, b.p0, atol=1e-12)
        p = perturbed_parameters(a, rng)
        q = a.q_star + 1e-3 * rng.standard_normal(a.q_star.size)
        qb = q.copy()
        qb[dofs.position_index(a.n_vertices)] = dofs.positions(q) @ R.T
        assert b.energy(p, qb) == pytest.approx(a.energy(p, q), rel=1e-10)
        fa, fb = a.elastic_gradient(p, q), b.elastic_gradient(p, qb)
        pos = dofs.position_index(a.n_vertices)
        assert np.allclose(fb[pos], fa[pos] @ R.T, rtol=1e-8, atol=1e-10 * np.abs(fa).max())
        th = dofs.theta_index(a.n_vertices)
        assert np.allclose(fb[th], fa[th], rtol=1e-8, atol=1e-10 * np.abs(fa).max())


def bent(problem):
    """The strand of ``problem`` bent down into a quarter-ish circular arc, angles unchanged."""
    q = problem.q_star.copy()
    x = dofs.positions(q)
    s = x[:, 0]
    radius = 0.08
    q[dofs.position_index(len(x))] = np.column_stack(
        [radius * np.sin(s / radius), 0 * s, radius * (np.cos(s / radius) - 1)])
    return q


def test_flipped_frames_2d_average_has_no_bending_while_4d_matches_unflipped():
    """Supplement Fig. 2: (b) 2d-average offers no bending resistance with flipped frames,
    (d) 4d behaves as without the flips."""
    flipped, plain = sagfree.scenes.flipped(), sagfree.scenes.horizontal()
    avg = sagfree.Problem(flipped, curvature="2d-average", energies=("bend",))
    q = bent(avg)
    assert avg.energy(avg.p0, q) < 1e-25
    assert np.abs(avg.elastic_gradient(avg.p0, q)).max() < 1e-20
    avg_plain = sagfree.Problem(plain, curvature="2d-average", energies=("bend",))
    assert avg_plain.energy(avg_plain.p0, bent(avg_plain)) > 1e-9  # it does bend without flips

    four, four_plain = (sagfree.Problem(s, curvature="4d", energies=("bend",)) for s in (flipped, plain))
    e, e_plain = four.energy(four.p0, q), four_plain.energy(four_plain.p0, bent(four_plain))
    assert e > 1e-9 and e == pytest.approx(e_plain, rel=1e-12)
    assert np.allclose(four.elastic_gradient(four.p0, q), four_plain.elastic_gradient(four_plain.p0, q),
                       rtol=1e-10, atol=1e-12 * e)
    slerp = sagfree.Problem(flipped, curvature="2d-slerp", energies=("bend",))
    assert slerp.energy(slerp.p0, q) == pytest.approx(e_plain, rel=1e-12)  # unit frames bend too


def test_variants_agree_when_frames_are_not_flipped(rng):
    strand = sagfree.scenes.helix(n=20)
    energies = []
    for variant in VARIANTS:
        pb = sagfree.Problem(strand, curvature=variant)
        q = pb.q_star.copy()
        q[dofs.position_index(pb.n_vertices)] *= 1.001  # a stretched, bent state, untwisted
        energies.append(pb.energy(pb.p0, q))
    assert np.allclose(energies, energies[0], rtol=1e-4)


def test_memoized_forces_and_jacobians_are_the_evaluations_and_safe_to_modify(rng):
    """Problem.forces and strand_jacobian at q* remember their last few p (and share them with the
    stabilization's twins): what they return equals a fresh evaluation, a caller modifying the
    returned forces does not change the next answer, and a new p is evaluated anew."""
    problem = sagfree.Problem(sagfree.scenes.groom(2, 30, seed=4)[1])
    p = problem.p0 + 0.1 * rng.random(problem.n_parameters) * (problem.upper - problem.p0)
    fresh = sagfree.Problem(problem.strand)
    first = problem.forces(p)
    first[:] = np.nan  # a caller writing into its copy
    assert np.array_equal(problem.forces(p), fresh.forces(p))
    assert np.array_equal(problem.residual(p), fresh.residual(p))
    assert np.array_equal(problem.strand_jacobian(p).data, fresh.strand_jacobian(p).data)
    other = p.copy()
    other[0] += 1e-3 * (problem.upper[0] - p[0])
    assert not np.array_equal(problem.residual(other), problem.residual(p))
    assert np.array_equal(problem.residual(other), fresh.residual(other))
    twin = problem.with_lower_bounds(problem.lower)
    assert twin.strand_jacobian(p) is problem.strand_jacobian(p)  # shared, not evaluated again
    first = twin.bound_independent("start", lambda: "twin's")
    assert first == problem.bound_independent("start", lambda: "again") == "twin's"
    # away from q* nothing is remembered: another state gives other forces
    q = problem.q_star + 1e-4 * rng.standard_normal(problem.q_star.size)
    assert not np.array_equal(problem.forces(p, q), problem.forces(p))


def test_locate_names_every_entry_of_p():
    problem = sagfree.Problem(sagfree.scenes.horizontal(n=6), bodies=())
    layout = problem.layout
    named = {index: layout.locate(index) for index in range(layout.size)}
    for block, ix in layout.blocks.items():
        assert all(named[int(i)][0] == block for i in ix)
    assert named[int(layout.blocks["rest_length"][2])] == ("rest_length", "edge 2")
    assert named[int(layout.blocks["rest_curvature"][3])] == ("rest_curvature", "vertex 2")
    assert named[int(layout.blocks["bend_stiffness"][0])] == ("bend_stiffness", "vertex 1")
    with pytest.raises(IndexError):
        layout.locate(layout.size)


@pytest.mark.parametrize("stiffness", ["element", "strand"])
def test_element_numbers_agree_with_locate(stiffness):
    """element_numbers (the stabilization's note on many floors at once) names each entry as locate."""
    layout = sagfree.Problem(sagfree.scenes.horizontal(n=7), stiffness=stiffness).layout
    everything = np.random.default_rng(0).permutation(layout.size)
    by_block = layout.element_numbers(everything)
    assert list(by_block) == list(layout.blocks)  # BLOCKS order
    for block, numbers in by_block.items():
        entries = everything[np.isin(everything, layout.blocks[block])]  # in the order given
        labels = [layout.locate(int(i))[1] for i in entries]  # "edge 2", "vertex 3" or "strand"
        assert numbers.tolist() == [0 if label == "strand" else int(label.split()[1]) for label in labels]
    with pytest.raises(IndexError):
        layout.element_numbers([0, layout.size])


def test_parameter_layout_and_physical_values():
    strand = sagfree.scenes.horizontal(n=10)
    pb = sagfree.Problem(strand)
    assert set(pb.blocks) == {"rest_length", "rest_curvature", "rest_twist", "stretch_stiffness",
                              "bend_stiffness"}  # twist follows bend by default
    assert sorted(np.concatenate(list(pb.blocks.values())).tolist()) == list(range(pb.n_parameters))
    for ix in pb.blocks.values():
        assert np.all(np.diff(ix) > 0)  # strand order
    phys = pb.physical(pb.p0)
    assert np.allclose(phys["rest_length"], strand.edge_lengths)
    assert np.allclose(phys["bend_modulus"], 1e9) and np.allclose(phys["twist_modulus"], 4e8)
    p = pb.p0
    p[pb.blocks["bend_stiffness"]] = 3.0
    p[pb.blocks["rest_length"]] = 0.01
    phys = pb.physical(p)
    assert np.allclose(phys["twist_modulus"], 1.2e9) and np.allclose(phys["bend_modulus"], 3e9)
    assert np.allclose(phys["rest_length"], 1.01 * strand.edge_lengths)
    # default boxes (DESIGN section 4)
    lv = 0.5 * (strand.edge_lengths[:-1] + strand.edge_lengths[1:])
    width = pb.upper[pb.blocks["rest_curvature"]] - pb.lower[pb.blocks["rest_curvature"]]
    assert np.allclose(width, 2 * 2.0 * np.repeat(lv, 2) / strand.length)
    assert np.allclose(pb.lower[pb.blocks["stretch_stiffness"]], 1)
    assert np.allclose(pb.upper[pb.blocks["stretch_stiffness"]], 100)
    assert pb.objective(pb.p0) == 0.0


def test_stiffness_modes():
    strand = sagfree.scenes.horizontal(n=10)
    strand_mode = sagfree.Problem(strand, stiffness="strand")
    assert strand_mode.blocks["strand_stiffness"].tolist() == [strand_mode.n_parameters - 1]
    p = strand_mode.p0
    p[-1] = 4.0
    phys = strand_mode.physical(p)
    assert np.allclose(phys["stretch_modulus"], 4e9) and np.allclose(phys["twist_modulus"], 1.6e9)
    fixed = sagfree.Problem(strand, stiffness="fixed")
    assert set(fixed.blocks) == {"rest_length", "rest_curvature", "rest_twist"}
    uncoupled = sagfree.Problem(strand, couple_twist=False)
    assert "twist_stiffness" in uncoupled.blocks


def test_jacobian_is_banded_with_width_independent_of_n():
    widths = []
    for n in (20, 40, 80):
        pb = sagfree.Problem(sagfree.scenes.helix(n=n))
        JtJ = (pb.jacobian(pb.p0).T @ pb.jacobian(pb.p0)).tocoo()
        widths.append(np.abs(JtJ.row - JtJ.col).max())
    assert widths[0] == widths[1] == widths[2] and widths[0] < 30


@pytest.mark.parametrize("bounds, message", [
    ({"rest_length": (0.1, -0.1)}, "lower bound above upper bound"),
    ({"stretch_stiffness": (2.0, 10.0)}, "p0 outside its bounds"),
    ({"rest_volume": (0, 1)}, "not an optimized block"),
])
def test_inconsistent_bounds_are_clear_errors(bounds, message):
    with pytest.raises(ValueError, match=message):
        sagfree.Problem(sagfree.scenes.horizontal(n=8), bounds=bounds)


def test_user_bounds_weights_and_budgets():
    pb = sagfree.Problem(sagfree.scenes.horizontal(n=8), bounds={"rest_length": (-0.01, 0.02),
                         "curvature_budget": 1.0}, weights={"bend_stiffness": 5.0})
    assert np.all(pb.upper[pb.blocks["rest_length"]] == 0.02)
    default = sagfree.Problem(sagfree.scenes.horizontal(n=8))
    ix = pb.blocks["rest_curvature"]
    assert np.allclose(pb.upper[ix] - pb.lower[ix], 0.5 * (default.upper[ix] - default.lower[ix]))
    p = pb.p0
    p[pb.blocks["bend_stiffness"][0]] = 2.0
    # the weight times vertex 1's share of the strand's length (its Voronoi length over L)
    share = 0.5 * (pb.edge_lengths[0] + pb.edge_lengths[1]) / pb.edge_lengths.sum()
    assert pb.objective(p) == pytest.approx(0.5 * 5.0 * share)
    with pytest.raises(ValueError, match="unknown parameter blocks"):
        sagfree.Problem(sagfree.scenes.horizontal(n=8), optimize=("rest_lenght",))
    with pytest.raises(ValueError, match="unknown curvature variant"):
        sagfree.Problem(sagfree.scenes.horizontal(n=8), curvature="3d")


@pytest.mark.parametrize("contacts", [(), (1, 5, 11)])  # 11: the tip of a 12-vertex strand
def test_the_default_layout_is_its_rules_entry_by_entry(contacts):
    """p0, box, share and weight of every entry as parameters' module docstring states them (each
    element's share of L: edges l_e / L, vertices their Voronoi length, a contact its vertex's half
    edges), here by numpy block by block, there by one compiled pass over the structure's recipe."""
    from sagfree.formulation.parameters import (BUDGETS, CONTACT_MAX, CONTACT_WEIGHT, RELATIVE_LENGTH_BOX,
                                                STIFFNESS_BOX, ParameterLayout)
    rng = np.random.default_rng(1)
    n, width = 12, 4
    l0 = rng.uniform(0.5e-3, 2e-3, n - 1)
    kappa, twist = rng.normal(size=(n - 2, 2)), rng.normal(size=n - 2)
    layout = ParameterLayout(n, l0, kappa, twist, 2e9, 7e8, contacts=np.array(contacts, dtype=int),
                             contact_width=width)
    L = l0.sum()
    edge, vertex = l0 / L, 0.5 * (l0[:-1] + l0[1:]) / L
    expected = {  # block: (p0, half width of the box or its bounds, share)
        "rest_length": (0.0, (-RELATIVE_LENGTH_BOX, RELATIVE_LENGTH_BOX), edge),
        "stretch_stiffness": (1.0, STIFFNESS_BOX, edge),
        "rest_curvature": (kappa.ravel(), np.repeat(BUDGETS["curvature_budget"] * vertex, 2), np.repeat(vertex, 2)),
        "rest_twist": (twist, BUDGETS["twist_budget"] * vertex, vertex),
        "bend_stiffness": (1.0, STIFFNESS_BOX, vertex),
    }
    for block, (p0, box, share) in expected.items():
        ix = layout.blocks[block]
        lower, upper = (p0 - box, p0 + box) if isinstance(box, np.ndarray) else (p0 * 0 + box[0], p0 * 0 + box[1])
        assert np.array_equal(layout.p0[ix], np.broadcast_to(p0, ix.shape)), block
        assert np.array_equal(layout.lower[ix], np.broadcast_to(lower, ix.shape)), block
        assert np.array_equal(layout.upper[ix], np.broadcast_to(upper, ix.shape)), block
        assert np.array_equal(layout.share[ix], share) and np.array_equal(layout.weights[ix], share), block
    if contacts:
        ix = layout.blocks["contact_force"]
        half = np.repeat([0.5 * (l0[v - 1] + (l0[v] if v < n - 1 else 0.0)) / L for v in contacts], width)
        assert np.array_equal(layout.share[ix], half) and np.array_equal(layout.weights[ix], half * CONTACT_WEIGHT)
        assert np.all(layout.p0[ix] == 0) and np.all(layout.lower[ix] == 0) and np.all(layout.upper[ix] == CONTACT_MAX)
    else:
        assert "contact_force" not in layout.blocks
    assert sum(ix.size for ix in layout.blocks.values()) == layout.size  # every entry has its rule


def dense_stability(pb, p):
    """Smallest eigenvalue of H_F v = lambda M_F v, dense (scipy), and its eigenvector."""
    dense = pb.hessian(p)[pb.free][:, pb.free].toarray()
    values, vectors = scipy.linalg.eigh(dense, np.diag(pb.dof_masses[pb.free]))
    return values[0], vectors[:, 0]


@pytest.mark.parametrize("curvature", ["4d", "2d-average", "2d-slerp"])
def test_unstressed_hessian_by_the_chain_rule_equals_the_stencils(curvature):
    """At q* and p0 the vertex stencils' Hessians come from (dk/dy)^T d2E/dk2 dk/dy (dE/dk = 0 there):
    the same as the stencils' own d2E/dy2 to rounding, for every curvature variant; a p off p0
    (stressed) takes the stencils' Hessian."""
    pb = sagfree.Problem(sagfree.scenes.curly(n=15), curvature=curvature)
    p0 = pb.p0
    _, vertex = pb.stencil_inputs(p0, None, None)
    (direct,) = pb.vertex_functions.hessian(*vertex)
    chain = pb._hessian_blocks(p0, None, None)[1][1]
    assert np.abs(chain - direct).max() <= 1e-12 * np.abs(direct).max()
    assert pb.stability(p0) == pytest.approx(dense_stability(pb, p0)[0], rel=1e-6)
    p = p0.copy()
    p[pb.blocks["rest_curvature"]] += 0.5
    _, vertex = pb.stencil_inputs(p, None, None)
    assert np.array_equal(pb._hessian_blocks(p, None, None)[1][1], pb.vertex_functions.hessian(*vertex)[0])


@pytest.mark.parametrize("variant", VARIANTS)
def test_compiled_hessian_band_and_eigenpair_are_the_numpy_sums(variant, rng):
    """Problem.stability at q* is two compiled calls: the Hessian band from the stencils' drivers
    (at_rest.hessian_band) and the free block's scaled eigenpair (eigen.scaled_block_eigenpair).
    They take the numpy path's steps bit for bit: the same band, eigenvalue and mode, for stressed,
    strongly perturbed (indefinite: the shifted Cholesky) and unstressed parameters."""
    for strand in verification_strands(seed=4).values():
        pb = sagfree.Problem(strand, curvature=variant)
        numpy_path = sagfree.Problem(strand, curvature=variant)
        numpy_path.__dict__["_compiled_hessian"] = None
        assert pb._compiled_hessian is not None
        compressed = pb.p0.copy()
        compressed[pb.blocks["rest_length"]] = 0.05
        for p in (perturbed_parameters(pb, rng), compressed, pb.p0):
            band = pb.hessian_band(p)
            assert np.array_equal(band, numpy_path.hessian_band(p))
            scale, row_scale, column_scale = pb._mass_scaling
            value, mode = smallest_eigenpair(pb.free_band(band) * row_scale * column_scale)
            compiled_value, compiled_mode = pb.stability(p, vector=True)
            assert compiled_value == value and np.array_equal(compiled_mode[pb.free_index], mode * scale)
        assert pb.stability(compressed) < 0


@pytest.mark.parametrize("variant", VARIANTS)
def test_compiled_rest_geometry_is_the_numpy_path(variant):
    """A Problem's geometry at q* (frames, q*, the stencils' inputs, l0, kappa, twist, kinematics) is
    one compiled call (formulation.rest_geometry) taking the numpy path's steps bit for bit, on the
    verification strands (bent, twisted, a kink) and a 3-vertex strand (one vertex stencil)."""
    strands = [*verification_strands(seed=4).values(), sagfree.scenes.horizontal(n=3)]
    for strand in strands:
        pb = sagfree.Problem(strand, curvature=variant)
        arguments = (strand.points, strand.theta, pb.frames.a1[0], strand.radius, pb.edge_functions,
                     pb.vertex_functions, pb.vertex_fixed_functions)
        compiled, numpy_path = rest_geometry(*arguments), rest_geometry_numpy(*arguments)
        for name in RestGeometry._fields:
            mine, theirs = getattr(compiled, name), getattr(numpy_path, name)
            if name == "frames":
                mine = np.concatenate([mine.tangents.ravel(), mine.a1.ravel(), mine.reference_twist])
                theirs = np.concatenate([theirs.tangents.ravel(), theirs.a1.ravel(), theirs.reference_twist])
            assert mine.shape == theirs.shape and np.array_equal(mine, theirs), name
        assert np.array_equal(compiled.q_star, pb.q_star)
        assert np.allclose(compiled.l0, np.linalg.norm(np.diff(strand.points, axis=0), axis=1), rtol=1e-14)


def test_compiled_unstressed_form_is_the_stencil_sum(rng):
    """meets_margin's bound v^T H(p0) v (Problem._unstressed_form) in one compiled call equals the
    numpy sum over the stencils to rounding, and the assembled Hessian's form."""
    for strand in verification_strands(seed=4).values():
        pb = sagfree.Problem(strand)
        numpy_path = sagfree.Problem(strand)
        numpy_path.__dict__["_compiled_at_rest"] = None
        v = rng.standard_normal(pb.q_star.size)
        reference = numpy_path._unstressed_form(v)
        assert pb._unstressed_form(v) == pytest.approx(reference, rel=1e-12)
        assert reference == pytest.approx(v @ (pb.hessian(pb.p0) @ v), rel=1e-9)

def test_stability_of_the_straight_rest_state():
    """Mass-normalized: omega^2 of the slowest mode, the Euler-Bernoulli cantilever's 1.875^4 E I /
    (rho A L^4) with the clamped length measured from the middle of the clamped first edge."""
    pb = sagfree.Problem(sagfree.scenes.horizontal(n=12))
    value, _ = dense_stability(pb, pb.p0)
    assert value > 0 and pb.stability(pb.p0) == pytest.approx(value, rel=1e-6)
    strand = pb.strand
    free_length = strand.length - 0.5 * pb.edge_lengths[0]
    beam = 1.875**4 * strand.youngs_modulus * strand.radius**2 / (4 * strand.density * free_length**4)
    assert pb.stability(pb.p0) == pytest.approx(beam, rel=0.01)


def test_stability_mode_is_the_mass_normalized_eigenvector():
    pb = sagfree.Problem(sagfree.scenes.curly(n=15))
    p = pb.p0.copy()
    p[pb.blocks["rest_length"]] = 0.02
    value, mode = pb.stability(p, vector=True)
    dense_value, dense_mode = dense_stability(pb, p)
    assert value == pytest.approx(dense_value, rel=1e-6)
    assert np.all(mode[~pb.free] == 0)
    assert mode @ (pb.dof_masses * mode) == pytest.approx(1.0)
    assert abs(mode[pb.free] @ (pb.dof_masses[pb.free] * dense_mode)) == pytest.approx(1.0, rel=1e-6)


def test_stability_of_a_compressed_rest_state_is_its_negative_eigenvalue():
    """Rest lengths 5% above the edges compress the strand: the Hessian is indefinite, and the shifted
    Lanczos of Problem.stability finds its most negative eigenvalue."""
    pb = sagfree.Problem(sagfree.scenes.horizontal(n=12))
    p = pb.p0.copy()
    p[pb.blocks["rest_length"]] = 0.05
    smallest, _ = dense_stability(pb, p)
    assert smallest < 0
    assert pb.stability(p) == pytest.approx(smallest, rel=1e-6)
