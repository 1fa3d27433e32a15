"""asc's start for a strand held by its root alone is the optimum (solvers.statics_start)."""
import numpy as np
import pytest

import sagfree
from sagfree.contract.optimality import kkt_optimality
from sagfree.formulation.problem import Problem
from sagfree.solvers import alm
from sagfree.solvers.statics_start import least_multiplier_scalar, statics_start, unbalanceable


@pytest.mark.parametrize("index", [0, 3, 11])
def test_the_start_of_a_root_held_strand_is_the_optimum_gauss_newton_reaches(index):
    problem = Problem(sagfree.scenes.groom(12, 60, seed=0)[index], stabilize=False)
    start = alm.linear_start(problem)
    assert np.abs(problem.residual(start)).max() <= 1e-10  # balanced: statics fixed every element's stresses
    assert kkt_optimality(problem, start) <= 1e-8           # and each multiplier is its element's optimum
    walked = alm.solve_alm(problem, start="linear")          # Gauss-Newton from the boxed least change
    assert walked.status == "converged" and walked.iterations["gauss_newton"] > 0
    assert problem.objective(start) == pytest.approx(walked.objective, rel=1e-8)
    assert np.abs(start - walked.p).max() <= 1e-3
    started = alm.solve_alm(problem)
    assert started.status == "converged" and started.iterations["gauss_newton"] <= 1


@pytest.mark.parametrize("vertices", [3, 25, 100])
def test_the_square_rest_system_gives_the_saddle_systems_least_change(vertices):
    from sagfree.formulation.parameters import REST_BLOCKS
    from sagfree.linalg.saddle import constrained_step

    for strand in sagfree.scenes.groom(4, vertices, seed=1):
        problem = Problem(strand)
        layout = problem.layout
        J, c = problem.strand_jacobian(layout.p0), problem.residual(layout.p0)
        least, _ = constrained_step(J, layout.weights, np.zeros(problem.n_parameters), c,
                                    layout.block_mask(REST_BLOCKS))
        unique = alm._least_rest_change(problem)  # the band LU of J_R, where the system is square
        assert np.abs(unique - least).max() <= 1e-9 * np.abs(least).max()
        assert np.abs(J @ unique + c).max() <= 1e-9


def test_a_start_at_the_optimum_is_confirmed_without_an_outer_iteration():
    problem = Problem(sagfree.scenes.groom(3, 60, seed=0)[1], stabilize=False)
    result = alm.solve_alm(problem)
    assert result.status == "converged" and result.iterations["outer"] == 0
    assert kkt_optimality(problem, result.p) <= 1e-5
    assert alm.solve_alm(problem, start="linear").iterations["outer"] >= 1  # elsewhere the loop runs


def test_the_start_under_stiffness_floors_is_the_floored_optimum():
    # floors hold the first vertex's multiplier above what its rest box needs: the root edge's rest
    # length must then keep that vertex's rest change inside its box (it oscillated out of it, and
    # the clipped start left |c|_inf = 40 for Gauss-Newton to repair)
    from sagfree.frontend.stabilize import floors_loop

    problem = Problem(sagfree.scenes.groom(60, 100, seed=0)[8])
    floored, result, rounds, verdict = floors_loop(alm.solve_alm, problem, {})
    assert rounds >= 1 and verdict is None
    start = alm.linear_start(floored)
    assert np.abs(floored.residual(start)).max() <= 1e-10 and kkt_optimality(floored, start) <= 1e-8
    assert result.iterations["gauss_newton"] == 0 and floored.objective(start) == pytest.approx(result.objective)


def test_the_edges_choice_counts_their_rest_lengths_cost_on_the_vertices():
    # near a stiffened root the first edges trade stiffness for the vertices' lbar sums: without that
    # coupling the start missed the KKT tolerance (1.01e-5) and Gauss-Newton took 60 outer iterations
    problem = Problem(sagfree.scenes.groom(1900, 100, seed=0)[1278], stabilize=False)
    start = alm.linear_start(problem)
    assert np.abs(problem.residual(start)).max() <= 1e-10 and kkt_optimality(problem, start) <= 1e-8
    assert start[problem.blocks["stretch_stiffness"][1]] > 1.0 + 1e-6
    walked = alm.solve_alm(problem, start="linear")
    assert walked.status == "converged" and problem.objective(start) == pytest.approx(walked.objective, rel=1e-9)


def test_the_start_needs_the_root_alone_to_hold_the_strand():
    strand = sagfree.scenes.horizontal(40)
    change = np.zeros(Problem(strand).n_parameters)
    for held in (strand.attached(tip="pinned"), strand.attached(pins=[20])):
        assert statics_start(Problem(held), change) is None
    assert statics_start(Problem(strand, stiffness="strand"), change) is None


def test_least_multiplier_minimizes_its_convex_share_inside_the_box():
    grid = np.linspace(1.0, 10.0, 200001)
    x = least_multiplier_scalar(2.0, 1.0, 1.0, 1.0, 10.0)
    assert x == pytest.approx(grid[np.argmin(2.0 / grid**2 + (grid - 1.0) ** 2)], abs=1e-4)
    assert -2 * 2.0 / x**3 + 2 * (x - 1.0) == pytest.approx(0.0, abs=1e-12)
    assert least_multiplier_scalar(2.0, 1.0, 1.0, 2.0, 10.0) == 2.0  # the optimum (1.54) below the box: its bound
    assert least_multiplier_scalar(0.0, 1.0, 1.0, 0.5, 10.0) == 1.0  # no rest change: the centre
    assert least_multiplier_scalar(0.0, 0.0, 1.0, 3.0, 100.0) == 3.0  # neither: the lowest, not NaN


def test_a_box_that_admits_no_multiplier_leaves_the_boxed_least_change():
    problem = Problem(sagfree.scenes.groom(3, 40, seed=0)[1], bounds={"bend_stiffness": (1.0, 1.0001)})
    change = np.zeros(problem.n_parameters)
    change[problem.blocks["rest_curvature"]] = 1e3  # no multiplier up to 1.0001 brings it into its box
    assert statics_start(problem, change) is None


def test_a_multiplier_without_weight_stays_finite():
    problem = Problem(sagfree.scenes.groom(3, 40, seed=0)[1], weights={"bend_stiffness": 0.0})
    start = alm.linear_start(problem)
    assert np.all(np.isfinite(start)) and kkt_optimality(problem, start) <= 1e-8


def _needs(problem: Problem):
    return unbalanceable(problem, alm._least_rest_change(problem))


def test_the_infeasibility_certificate_is_tight():
    """A bend bound below the stiffest multiplier the balance needs is certified infeasible, and the
    strand's solve goes straight to the best effort naming those vertices; at the bound the message
    suggests, the certificate is silent and asc converges (exact both ways: it claims nothing it
    cannot prove, and its suggestion holds)."""
    strand = sagfree.scenes.horizontal()
    tight = Problem(strand, bounds={"bend_stiffness": (1.0, 2.0)})
    message = _needs(tight)
    assert message.startswith("10 vertices (1-10) need a bend_stiffness above its upper bound 2 to keep")
    suggested = float(message.split("an upper bound of ")[1].split()[0])
    assert 2.0 < suggested < 100.0
    result = sagfree.solve(tight)
    assert result.status == "infeasible" and message in result.message
    assert result.iterations["outer"] == 0 and result.iterations["gauss_newton"] == 0
    assert result.iterations["least_residual"] > 0
    below = Problem(strand, bounds={"bend_stiffness": (1.0, suggested * (1.0 - 1e-3))})
    assert _needs(below).startswith("1 vertex (1) needs a bend_stiffness")
    at = Problem(strand, bounds={"bend_stiffness": (1.0, suggested)})
    assert _needs(at) is None
    assert sagfree.solve(at).status == "converged"


def test_the_certificate_is_silent_on_the_default_groom_and_where_it_does_not_apply():
    """Every strand of the default groom is balanced (asc converges on each): no certificate; a pinned
    tip (reactions unknown, the rest system not square) gets none either."""
    for strand in sagfree.scenes.default_groom()[:20]:
        assert _needs(Problem(strand)) is None
    pinned = Problem(sagfree.scenes.horizontal(tip="pinned"), bounds={"bend_stiffness": (1.0, 1.0001)})
    assert unbalanceable(pinned, np.zeros(pinned.n_parameters)) is None
