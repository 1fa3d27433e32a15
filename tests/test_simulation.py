"""Forward simulation (DESIGN section 7): naive strands sag, optimized ones stand still, Newton is
quadratic, and the supplement's section IV experiments (flipped frames, curvature variants)."""
import numpy as np
import pytest
import scipy.linalg

import sagfree
from sagfree.formulation import dofs
from sagfree.formulation import simulation as S
from sagfree.formulation.curvature import VARIANTS
from sagfree.reports import experiments
from sagfree.scenes.synthetic import resample

SCENES = {
    "horizontal": lambda **kw: sagfree.scenes.horizontal(**kw),
    "curly": lambda **kw: sagfree.scenes.curly(n=40, **kw),
}


@pytest.fixture(scope="module", params=list(SCENES))
def solved(request):
    problem = sagfree.Problem(SCENES[request.param]())
    return problem, sagfree.solve(problem, solver="asc")


def test_naive_parameters_sag_more_than_one_percent(solved):
    problem, _ = solved
    run = sagfree.simulate(problem, problem.p0, steps=200, dt=1e-3)
    assert run.converged
    assert run.relative_sag > 0.01
    assert run.sag == pytest.approx(run.relative_sag * problem.strand.length)
    assert run.trajectory.shape == (201, problem.n_vertices, 3)
    static = sagfree.equilibrium(problem, problem.p0)
    assert static.converged, static.newton.message
    assert static.relative_sag > 0.01
    # the root does not move
    np.testing.assert_array_equal(run.trajectory[:, :2], np.broadcast_to(problem.strand.points[:2], (201, 2, 3)))


def test_optimized_parameters_do_not_move(solved):
    problem, result = solved
    assert result.status == "converged"
    # tol below the round-off floor: Newton must actually step, and still nothing moves
    run = sagfree.simulate(problem, result.p, steps=200, dt=1e-3, tol=1e-14)
    assert run.converged and np.all(run.newton_iterations >= 1)
    assert run.relative_sag <= 1e-6
    static = sagfree.equilibrium(problem, result.p, tol=1e-14)
    assert static.converged and static.newton.steps >= 1
    assert static.relative_sag <= 1e-6


def test_optimized_equilibria_are_stable(solved):
    problem, result = solved
    assert result.min_eigenvalue > 0 and result.stable
    assert problem.stability(result.p) == pytest.approx(result.min_eigenvalue)
    assert result.min_eigenvalue >= problem.stability_margin
    # the mass-normalized eigenvalue of the free-DOF Hessian: compare with a dense solver
    h = problem.hessian(result.p).toarray()[np.ix_(problem.free, problem.free)]
    dense = scipy.linalg.eigh(h, np.diag(problem.dof_masses[problem.free]), eigvals_only=True)[0]
    assert result.min_eigenvalue == pytest.approx(dense, rel=1e-6)


def _quadratic_pairs(residuals, floor=1e-8, start=0.5):
    """(r_k, r_k+1) of a Newton residual sequence where it decreases, r_k below ``start`` and
    r_k+1 above the round-off ``floor``."""
    return [(a, b) for a, b in zip(residuals[:-1], residuals[1:]) if b < a and a <= start and b >= floor]


@pytest.mark.parametrize("scene", SCENES)
def test_newton_converges_quadratically_near_equilibrium(scene):
    # A soft cable (E = 1e6 Pa) rather than hair: the round-off floor of the scaled residual grows
    # with E/(rho g L) (~1e-7 for hair, ~1e-10 here), and hair leaves one step between 1e-2 and it.
    problem = sagfree.Problem(SCENES[scene](youngs_modulus=1e6))
    static = sagfree.equilibrium(problem, problem.p0, tol=1e-14)
    run = sagfree.simulate(problem, problem.p0, steps=3, dt=1e-3, tol=1e-14)
    sequences = [static.newton.residuals] + [s.residuals for s in run.newton]
    pairs = [pair for seq in sequences for pair in _quadratic_pairs(seq)]
    assert len(pairs) >= 4
    for a, b in pairs:  # r_{k+1} <= C r_k^2, C = 10: a linear rate 0.1 fails from r_k = 1e-2 on
        assert b <= 10 * a * a, (a, b)
    for seq in sequences:  # once below 1e-2, the round-off floor is at most two steps away
        below = next(k for k, r in enumerate(seq) if r <= 1e-2)
        assert seq[min(below + 2, len(seq) - 1)] <= 1e-8, seq


def test_damped_motion_comes_to_rest_at_the_static_equilibrium():
    problem = sagfree.Problem(sagfree.scenes.curly(n=30))
    static = sagfree.equilibrium(problem, problem.p0)
    run = sagfree.simulate(problem, problem.p0, steps=100, dt=1e-2, damping=50.0)
    assert run.converged and static.converged
    gap = np.linalg.norm(run.trajectory[-1] - static.positions, axis=1).max()
    assert gap <= 1e-8 * problem.strand.length
    assert static.relative_sag > 0.1


def test_pinned_root_swings_down_and_keeps_its_root():
    problem = sagfree.Problem(sagfree.scenes.horizontal(root="pinned", youngs_modulus=1e10))
    static = sagfree.equilibrium(problem, problem.p0)
    assert static.converged
    # a pinned strand hangs straight down from its root: the tip ends sqrt(2) L from where it was
    assert static.relative_sag == pytest.approx(np.sqrt(2), rel=1e-3)
    np.testing.assert_array_equal(static.positions[0], problem.strand.points[0])
    assert not np.allclose(static.positions[1], problem.strand.points[1])


def _long_hair(n_vertices: int = 100) -> sagfree.Problem:
    """Strand 5 of the default groom, five times as long: its naive parameters let it fall to hang."""
    strand = sagfree.scenes.default_groom()[5]
    points = strand.points[0] + 5.0 * (strand.points - strand.points[0])
    return sagfree.Problem(strand.replaced(points=resample(points, n_vertices), theta=None))


def test_length_keeping_step_has_the_straight_steps_tangent_and_turns_edges_without_stretching_them():
    problem = _long_hair(30)
    q, free, n = problem.q_star, problem.free_index, problem.n_vertices
    rng = np.random.default_rng(0)
    d = rng.standard_normal(free.size) * 1e-2
    anchor = 1  # the clamped root: x_0, x_1 prescribed
    h = 1e-6
    tangent = (S.length_keeping_step(q, free, h, d, anchor) - S.length_keeping_step(q, free, -h, d, anchor)) / (2 * h)
    np.testing.assert_allclose(tangent[free], d, rtol=0, atol=1e-8 * np.abs(d).max())
    # a rigid turn of the tail about x_1 (infinitesimal: the straight step stretches every edge)
    x = dofs.positions(q)
    turn = np.zeros_like(q)
    turn[dofs.position_index(n)] = np.cross([0.0, 0.3, 0.1], x - x[1])
    lengths = np.linalg.norm(np.diff(x, axis=0), axis=1)
    curved = dofs.positions(S.length_keeping_step(q, free, 1.0, turn[free], anchor))
    straight = dofs.positions(S.length_keeping_step(q, free, 1.0, turn[free], n - 1))
    np.testing.assert_allclose(np.linalg.norm(np.diff(curved, axis=0), axis=1), lengths, rtol=1e-12)
    stretched = np.linalg.norm(np.diff(straight, axis=0), axis=1)[1:] / lengths[1:]
    assert np.all(stretched > 1.0) and stretched.max() > 1.04
    np.testing.assert_array_equal(curved[:2], x[:2])
    # a held tip (anchor n - 1) steps straight: nothing can be summed towards it
    np.testing.assert_array_equal(S.length_keeping_step(q, free, 0.5, d, n - 1)[free], q[free] + 0.5 * d)


def test_a_long_strand_falls_to_hang_in_few_newton_steps():
    # Along straight Newton steps this strand's fall from q* took 1,928 steps (turning edges
    # stretched, the line search and the damping kept the steps short); the equilibrium is the same.
    problem = _long_hair(100)
    static = sagfree.equilibrium(problem, problem.p0)
    assert static.converged, static.newton.message
    assert static.relative_sag > 1.0  # it hangs
    assert static.newton.steps <= 200
    # the rest state a damped implicit-Euler motion from q* comes to (still creeping at 1e-4 L)
    run = sagfree.simulate(problem, problem.p0, steps=400, dt=2e-2, damping=20.0)
    assert run.converged
    assert np.linalg.norm(run.trajectory[-1] - static.positions, axis=1).max() <= 1e-3 * problem.strand.length


def test_flipped_frames_2d_average_has_no_bending_resistance_4d_is_unaffected():
    runs = {(r.scene, r.curvature): r for r in experiments.frame_averaging(steps=200)}
    plain, flipped = runs["horizontal", "4d"], runs["flipped", "4d"]
    # Fig. 2b: averaged frames are zero, so bending a flipped strand costs nothing
    assert runs["flipped", "2d-average"].bending_energy <= 1e-30
    assert runs["horizontal", "2d-average"].bending_energy > 1e-9
    # ... and it falls like a chain, far below the unflipped strand
    assert runs["flipped", "2d-average"].sag > 2 * runs["horizontal", "2d-average"].sag
    # Fig. 2d: 4d with flipped frames behaves exactly as unflipped
    assert flipped.bending_energy == pytest.approx(plain.bending_energy, rel=1e-9)
    length = sagfree.scenes.horizontal().length
    assert np.abs(flipped.simulation.trajectory - plain.simulation.trajectory).max() <= 1e-9 * length
    assert flipped.static_sag == pytest.approx(plain.static_sag, rel=1e-6)


def test_every_curvature_variant_gives_the_same_results_without_flipped_frames():
    strand = sagfree.scenes.horizontal(youngs_modulus=1e10)
    runs, solved = {}, {}
    for variant in VARIANTS:
        problem = sagfree.Problem(strand, curvature=variant)
        runs[variant] = sagfree.simulate(problem, problem.p0, steps=100, dt=1e-3)
        solved[variant] = sagfree.solve(problem)
    reference = runs["4d"].trajectory
    assert runs["4d"].relative_sag > 0.05
    for variant in VARIANTS:
        assert np.abs(runs[variant].trajectory - reference).max() <= 1e-9 * strand.length, variant
        assert solved[variant].status == "converged"
        assert solved[variant].objective == pytest.approx(solved["4d"].objective, rel=1e-6)
        np.testing.assert_allclose(solved[variant].p, solved["4d"].p, rtol=1e-6, atol=1e-9)


def test_slerp_experiment_matches_4d_on_flipped_frames():
    runs = {(r.curvature, r.youngs_modulus): r for r in experiments.slerp(steps=50)}
    for modulus in (1e8, 1e9):
        slerp, four = runs["2d-slerp", modulus], runs["4d", modulus]
        assert slerp.converged and four.converged
        assert slerp.bending_energy == pytest.approx(four.bending_energy, rel=1e-9)
        assert slerp.sag == pytest.approx(four.sag, rel=1e-6)
    # the softer strand sags more
    assert runs["4d", 1e8].static_sag > runs["4d", 1e9].static_sag


def test_stiffness_modes_experiment_section_v():
    runs = {r.mode: r for r in experiments.stiffness_modes(steps=150)}
    assert runs["naive"].sag > 0.5 and runs["naive"].static_sag > 0.5
    for mode in ("strand", "element"):
        assert runs[mode].result.status == "converged"
        assert runs[mode].sag <= 1e-6 and runs[mode].static_sag <= 1e-6
    assert runs["strand"].bend_max == pytest.approx(runs["element"].bend_max, rel=0.05)
    assert runs["strand"].tail_max > 4 and runs["element"].tail_max < 1.01
    # one stiffness for the whole strand makes it answer a root motion more stiffly
    assert runs["element"].root_response > runs["strand"].root_response


def test_simulation_rejects_bad_arguments():
    problem = sagfree.Problem(sagfree.scenes.horizontal(n=5))
    with pytest.raises(ValueError, match="dt > 0"):
        sagfree.simulate(problem, problem.p0, steps=3, dt=0.0)
    with pytest.raises(ValueError, match="entries"):
        sagfree.simulate(problem, problem.p0[:-1])


def test_generalized_masses_sum_to_the_strand_mass():
    from sagfree.formulation.simulation import generalized_masses
    problem = sagfree.Problem(sagfree.scenes.curly(n=20))
    mass = generalized_masses(problem)
    strand = problem.strand
    total = strand.density * np.pi * strand.radius**2 * strand.length
    assert mass[dofs.position_index(20)[:, 0]].sum() == pytest.approx(total)
    assert np.all(mass > 0)


def test_a_time_step_newton_cannot_finish_is_taken_in_sub_steps(monkeypatch):
    """With too few Newton steps for a whole step of the falling strand, the step is split (here into
    up to 4) and the run follows the fall: where a run with 8x finer steps and ample Newton steps
    ends. Without sub-steps the same run stops at the step that fails."""
    problem = sagfree.Problem(sagfree.scenes.horizontal())
    run = S.simulate(problem, problem.p0, steps=50, dt=2e-3, max_newton=3)
    assert run.converged and len(run.times) == 51
    assert max(solve.substeps for solve in run.newton) > 1
    fine = S.simulate(problem, problem.p0, steps=400, dt=2.5e-4)
    assert run.displacement[-1] == pytest.approx(fine.displacement[-1], rel=0.01)
    monkeypatch.setattr(S, "SUBSTEP_HALVINGS", 0)
    whole = S.simulate(problem, problem.p0, steps=50, dt=2e-3, max_newton=3)
    assert not whole.converged and len(whole.times) == len(whole.newton) < 51
    assert not whole.newton[-1].converged
