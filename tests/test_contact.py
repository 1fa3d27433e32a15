"""Strands resting on bodies: the bodies' geometry, contact unknowns in the equilibrium, every solver
on them, the stability with resting vertices, and the simulation's contact model."""
import numpy as np
import pytest
import scipy.linalg

import sagfree
from sagfree.bodies import Capsule, Mesh, Sphere, parse_body
from sagfree.formulation import dofs
from sagfree.formulation.mesh_tree import closest_on_triangle, solid_angle
from sagfree.formulation.parameters import CONTACT_BLOCK
from sagfree.formulation.simulation import equilibrium, push_check
from sagfree.scenes.head import HEAD, head_groom, icosphere


def _ball_mesh(subdivisions: int = 2) -> Mesh:
    """An icosphere of radius 1 (outward faces)."""
    return icosphere(1.0, subdivisions)


@pytest.mark.parametrize("body", [Sphere([0.1, -0.2, 0.3], 0.5), Capsule([0, 0, 0], [0.2, 0.1, 1.0], 0.3),
                                  _ball_mesh()], ids=["sphere", "capsule", "mesh"])
def test_body_normal_and_curvature_match_finite_differences(body):
    x = np.random.default_rng(0).standard_normal((100, 3)) * 0.8
    phi, normal, curvature = body.evaluate(x)
    h, unit = 1e-6, np.eye(3)
    gradient = np.stack([(body.signed_distance(x + h * e) - body.signed_distance(x - h * e)) / (2 * h) for e in unit], 1)
    hessian = np.stack([(body.normal(x + h * e) - body.normal(x - h * e)) / (2 * h) for e in unit], 2)
    assert np.abs(gradient - normal).max() < 1e-7
    assert np.abs(hessian - curvature).max() < 1e-5 * max(1.0, np.abs(curvature).max())
    assert (phi < 0).any() and (phi > 0).any()


def _every_triangle(mesh: Mesh, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unsigned distance, winding number) at each point, summed over every triangle."""
    corners = mesh.vertices[mesh.faces]
    distance, winding = np.empty(len(points)), np.empty(len(points))
    for k, p in enumerate(points):
        distance[k] = min(np.linalg.norm(p - closest_on_triangle(p, *abc)[0]) for abc in corners)
        winding[k] = sum(solid_angle(p, *abc) for abc in corners) / (4 * np.pi)
    return distance, winding


@pytest.mark.parametrize("shape", ["ball", "dented", "cracked"])
def test_mesh_search_tree_gives_every_triangles_distance_and_sign(shape):
    """The tree's nearest triangle is the nearest of all (the same distance), and its winding
    number (far boxes by their dipoles) classifies inside and outside as the sum over every
    triangle does: on a ball, a non-convex ball (its top pushed in) and a ball with two triangles
    missing (a crack), at random points and at points 0.1% of the radius off the surface."""
    ball = _ball_mesh(3)
    vertices, faces = ball.vertices.copy(), ball.faces
    if shape == "dented":
        vertices *= (1 - 0.5 * np.clip(vertices[:, 2], 0, None) ** 2)[:, None]
    if shape == "cracked":
        faces = faces[2:]
    mesh = Mesh(vertices, faces)
    rng = np.random.default_rng(3)
    near = vertices[rng.integers(len(vertices), size=60)] * (1 + 1e-3 * rng.choice([-1, 1], size=60))[:, None]
    points = np.vstack([rng.uniform(-1.5, 1.5, size=(140, 3)), near + 1e-4 * rng.standard_normal((60, 3))])
    distance, winding = _every_triangle(mesh, points)
    phi = mesh.signed_distance(points)
    np.testing.assert_allclose(np.abs(phi), distance, rtol=1e-12, atol=0)
    clear = np.abs(winding - 0.5) > 0.1  # a point in the crack's mouth is neither in nor out
    assert clear.sum() >= 190
    np.testing.assert_array_equal((phi < 0)[clear], (winding > 0.5)[clear])
    assert np.any(phi < 0) and np.any(phi > 0)


def test_mesh_from_obj_is_signed_like_the_sphere_it_approximates(tmp_path):
    ball = _ball_mesh(3)
    lines = [f"v {a} {b} {c}" for a, b, c in ball.vertices] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in ball.faces]
    (tmp_path / "ball.obj").write_text("\n".join(lines))
    mesh = Mesh.load(tmp_path / "ball.obj")
    x = np.random.default_rng(1).standard_normal((200, 3))
    assert np.abs(mesh.signed_distance(x) - (np.linalg.norm(x, axis=1) - 1)).max() < 0.02
    assert parse_body(mesh.spec).faces.shape == mesh.faces.shape
    (tmp_path / "empty.obj").write_text("v 0 0 0\n")
    with pytest.raises(ValueError, match="no faces"):
        Mesh.load(tmp_path / "empty.obj")


def test_body_specs_round_trip_and_bad_specs_are_named():
    for body in (Sphere([0, 0, 1], 0.1), Capsule([0, 0, 0], [0, 0, 1], 0.05)):
        again = parse_body(body.spec)
        x = np.random.default_rng(2).standard_normal((5, 3))
        assert np.array_equal(again.signed_distance(x), body.signed_distance(x))
    with pytest.raises(ValueError, match="body 'sphere:1,2'"):
        parse_body("sphere:1,2")
    with pytest.raises(ValueError, match="radius must be positive"):
        parse_body("sphere:0,0,0,-1")


def test_a_vertex_inside_a_body_is_an_error_naming_it():
    strand = sagfree.scenes.horizontal(n=20)
    with pytest.raises(ValueError, match="vertex 12 is inside ball"):
        sagfree.Problem(strand, bodies=[Sphere(strand.points[12] - [0, 0, 0.01], 0.02, name="ball")])


@pytest.fixture(scope="module")
def resting():
    """`horizontal` resting on a ball of 20 cm under vertex 12 (its neighbours are within 2 radii too).
    (On a ball of 2 cm the bare optimum is unstable: frictionless, the strand slides off sideways,
    and the stabilization has to stiffen it more than the ball saves.)"""
    strand = sagfree.scenes.horizontal(n=20)
    ball = Sphere(strand.points[12] - [0, 0, 0.2 + strand.radius], 0.2)
    problem = sagfree.Problem(strand, bodies=[ball])
    return problem, sagfree.solve(problem)


def test_resting_strand_converges_with_nonnegative_supports_that_balance_the_weight(resting):
    problem, result = resting
    assert result.status == "converged", result.message
    assert problem.contacts.vertices.tolist() == [11, 12, 13]
    forces = result.contact_forces
    assert np.all(result.p[problem.blocks[CONTACT_BLOCK]] >= 0)
    away = ~np.isin(np.arange(20), [11, 12, 13])
    assert np.all(forces[away] == 0) and np.all(forces[~away] @ [0, 0, 1] > 0)
    # supports + the root's reaction + the weight sum to zero
    positions = dofs.position_index(problem.n_vertices)
    total = problem.forces(result.p)        # residual on free DOFs, root reaction's negative on the root's
    weight = problem.masses.sum() * 9.81
    root = -total[positions[:2]].sum(axis=0)
    weights = problem.external_forces[positions].sum(axis=0)
    assert np.linalg.norm(forces.sum(axis=0) + root + weights) <= 1e-8 * weight
    assert 0 < result.support < 1 and result.support == pytest.approx(forces[:, 2].sum() / weight, rel=1e-9)
    # the body lets the root stiffen far less than the same strand alone
    alone = sagfree.solve(sagfree.Problem(problem.strand))
    assert result.objective < 0.1 * alone.objective


def test_ipopt_and_ours_reach_the_same_optimum_on_a_resting_strand(resting):
    problem, _ = resting
    bare = problem.with_options(stabilize=False)
    ours, ipopt = sagfree.solve(bare), sagfree.solve(bare, "ipopt")
    assert ours.status == ipopt.status == "converged"
    assert ours.objective == pytest.approx(ipopt.objective, rel=1e-6)


def test_stability_on_a_body_matches_a_dense_constrained_eigensolve(resting):
    """The resting vertex moves in its tangent plane only and the support F adds -F K: a dense
    eigenproblem on the null space of the normal constraint."""
    problem, result = resting
    p = result.p
    hessian = problem.hessian(p).toarray()
    positions = dofs.position_index(problem.n_vertices)
    constraint = np.zeros((3, problem.q_star.size))
    for k, vertex in enumerate(problem.contacts.vertices):
        rows = positions[vertex]
        force = np.linalg.norm(result.contact_forces[vertex])
        hessian[np.ix_(rows, rows)] -= force * problem.contacts.curvature[k]
        constraint[k, rows] = problem.contacts.normals[k]
    free = problem.free_index
    basis = scipy.linalg.null_space(constraint[:, free])
    reduced = basis.T @ hessian[np.ix_(free, free)] @ basis
    mass = basis.T @ np.diag(problem.dof_masses[free]) @ basis
    expected = scipy.linalg.eigh(reduced, mass, eigvals_only=True)[0]
    assert result.min_eigenvalue == pytest.approx(expected, rel=1e-7)
    assert result.stable and result.min_eigenvalue >= problem.stability_margin


def _sparse_stability(problem, p):
    """stability(p, vector=True) on the bodies by the sparse path (the one without compiled stencils)."""
    twin = problem.with_options()
    twin.__dict__["_compiled_hessian"] = None
    supports = p[twin.blocks[CONTACT_BLOCK]].reshape(twin.contacts.count, -1)
    return twin._stability_on_bodies(p, np.flatnonzero(np.any(supports > 0, axis=1)), True)


@pytest.mark.parametrize("case", ["head", "sliding", "sticking"])
def test_compiled_stability_on_bodies_is_the_sparse_path(case, tilted):
    """The band of the Hessian on the tangent planes, projected and solved in one compiled call, gives
    the sparse matrices' eigenpair: a strand lying on the head (many resting vertices), the tilted
    ball frictionless (its vertex slides: -F K on its block) and with friction (it sticks)."""
    if case == "head":
        problem = sagfree.Problem(head_groom(1, 60, seed=4)[0], bodies=[HEAD], stabilize=False)
    else:
        strand, ball = tilted
        problem = sagfree.Problem(strand, bodies=[ball], friction=0.5 if case == "sticking" else 0.0,
                                  stabilize=False)
    p = sagfree.solve(problem).p
    value, mode = problem.stability(p, vector=True)
    expected, expected_mode = _sparse_stability(problem, p)
    assert problem._compiled_hessian is not None and value == pytest.approx(expected, rel=1e-10)
    assert abs(mode @ (problem.dof_masses * expected_mode)) == pytest.approx(1.0, abs=1e-8)
    assert np.all(mode[problem.strand.prescribed_vertices * 4] == 0)


def test_resting_strand_stays_and_holds_after_a_push_in_the_simulation(resting):
    problem, result = resting
    rest = equilibrium(problem, result.p)
    assert rest.converged and rest.relative_sag <= 1e-6   # sinks into the ball as one edge stretches
    assert push_check(problem, result.p).holds
    assert equilibrium(problem, problem.p0).relative_sag > 1e-2


def test_long_hair_lies_on_the_head_and_is_infeasible_without_it():
    strands = head_groom(3, 60, seed=4)
    for strand in strands:
        on_head = sagfree.Problem(strand, bodies=[HEAD])
        result = sagfree.solve(on_head)
        assert result.status == "converged" and result.stable, result.message
        assert result.stiffening["bend_stiffness"]["max"] < 1.1 and result.support > 0
        assert equilibrium(on_head, result.p).relative_sag <= 1e-6
        alone = sagfree.solve(sagfree.Problem(strand))
        assert alone.status == "infeasible" or alone.stiffening["bend_stiffness"]["max"] > 10
    assert push_check(on_head, result.p).holds


def test_bodies_travel_through_the_command_line(tmp_path, capsys):
    from sagfree.cli import main

    out = str(tmp_path / "head.npz")
    assert main(["optimize", "horizontal", "--body", "sphere:0.05,0,-0.02005,0.02", "-o", out, "--jobs", "1",
                 "--quiet"]) == 0
    assert main(["simulate", "horizontal", "--params", out, "--jobs", "1", "--quiet", "--steps", "5",
                 "--no-push"]) == 0
    params = sagfree.scenes.npz.load_parameters(out)
    assert params.problem_options["bodies"] == ["sphere:0.05,0,-0.02005,0.02"]


def test_friction_keeps_the_support_inside_the_pyramid_and_matches_ipopt(tilted):
    strand, ball = tilted
    problem = sagfree.Problem(strand, bodies=[ball], friction=0.5, stabilize=False)
    assert problem.blocks[CONTACT_BLOCK].size == 4            # the pyramid's generators
    ours, ipopt = sagfree.solve(problem), sagfree.solve(problem, "ipopt")
    assert ours.status == ipopt.status == "converged"
    assert ours.objective == pytest.approx(ipopt.objective, rel=1e-6)
    force = ours.contact_forces[12]
    normal, (t1, t2) = problem.contacts.normals[0], problem.contacts.tangents[0]
    assert abs(force @ t1) + abs(force @ t2) <= 0.5 * (force @ normal) * (1 + 1e-12)
    assert abs(force @ t1) + abs(force @ t2) > 0.05 * (force @ normal)   # friction is used
    frictionless = sagfree.solve(sagfree.Problem(strand, bodies=[ball], stabilize=False))
    assert frictionless.objective > ours.objective and not frictionless.stable


def test_a_strand_held_by_friction_is_stable_and_stays_in_the_simulation(tilted):
    strand, ball = tilted
    problem = sagfree.Problem(strand, bodies=[ball], friction=0.5)
    result = sagfree.solve(problem)
    assert result.status == "converged" and result.stable
    assert result.iterations.get("stabilization", 0) == 0     # sticking: no stiffening needed
    rest = equilibrium(problem, result.p)
    assert rest.converged and rest.relative_sag <= 1e-6
    assert push_check(problem, result.p).holds


def test_friction_jacobian_matches_finite_differences(tilted):
    strand, ball = tilted
    problem = sagfree.Problem(strand, bodies=[ball], friction=0.3)
    rng = np.random.default_rng(5)
    p = np.clip(problem.p0 + 0.05 * rng.uniform(-1, 1, problem.n_parameters), problem.lower, problem.upper)
    direction = rng.standard_normal(p.size) * 1e-7
    difference = 0.5 * (problem.residual(p + direction) - problem.residual(p - direction))
    assert np.linalg.norm(problem.jacobian(p) @ direction - difference) <= 1e-8 * np.linalg.norm(difference)


def test_every_solver_runs_on_the_contact_problem(resting):
    """Every solver of the table sees the supports: non-negative, and a converged one agrees with asc."""
    problem, _ = resting
    bare = problem.with_options(stabilize=False)
    ours = sagfree.solve(bare)
    block = problem.blocks[CONTACT_BLOCK]
    for name in sagfree.SOLVERS:
        result = sagfree.solve(bare, name)
        assert result.p.shape == ours.p.shape, name
        assert np.all(result.p[block] >= -1e-12), name
        if result.status == "converged":
            assert result.objective == pytest.approx(ours.objective, rel=1e-5), name
