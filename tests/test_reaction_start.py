"""asc's start for strands held at points besides their root (solvers.reaction_start)."""
import numpy as np
import pytest

import sagfree
from sagfree.contract.optimality import kkt_optimality
from sagfree.formulation import Problem
from sagfree.solvers import alm, reaction_start
from sagfree.solvers.reaction_start import applies, reaction_family

#: Ipopt's optimum R on groom(4, 400, seed=1)[3] pinned at vertex 200 without stabilization
#: (``sagfree.solve(problem, "ipopt")``, 2026-12-05: converged, 72 iterations; 19 s with its
#: compilation, too long to repeat here); asc from p0 ended max_iterations at R 0.357644
MIDDLE_PIN_IPOPT = 0.3329770320670391
#: Ipopt's R on groom(3, 3000, seed=0)[1] with its tip pinned (Solved_To_Acceptable_Level, 45 s;
#: benchmarks/RESULTS.md, 2026-12-04), where asc from p0 ended max_iterations after 600 steps
PINNED_TIP_IPOPT = 1.2737e-7


@pytest.mark.parametrize("held", [{"tip": "pinned"}, {"pins": [9]}, {"tip": "pinned", "pins": [6, 13]}])
def test_every_change_of_the_family_balances_the_held_strand_to_first_order(held):
    """J_R (d0 + N F) = -c(p0) on the held strand's free rows for any reactions F, and on the
    companion's held rows the change leaves exactly the force F (module docstring)."""
    strand = sagfree.scenes.groom(2, 20, seed=4)[1].attached(**held)
    problem = Problem(strand, stabilize=False)
    d0, N, scale = reaction_family(problem)
    assert N.shape == (problem.n_parameters, 3 * (len(held.get("pins", [])) + ("tip" in held)))
    assert np.all(scale > 0)
    J, c = problem.strand_jacobian(problem.p0), problem.residual(problem.p0)
    for F in np.random.default_rng(0).standard_normal((3, N.shape[1])) * scale:
        change = d0 + N @ F
        assert np.abs(J @ change + c).max() <= 1e-9 * (1.0 + np.abs(J @ (N @ F)).max())


def test_the_search_applies_to_points_held_and_nothing_else():
    strand = sagfree.scenes.groom(1, 20, seed=0)[0]
    assert applies(Problem(strand.attached(tip="pinned"))) and applies(Problem(strand.attached(pins=[5])))
    assert not applies(Problem(strand))  # root alone: statics_start's
    assert not applies(Problem(strand.attached(tip="clamped")))  # a held twist is no point's reaction
    assert not applies(Problem(strand.attached(tip="pinned"), stiffness="strand"))
    assert reaction_start.reaction_start(Problem(strand.attached(tip="clamped"))) is None


def test_a_strand_pinned_at_its_middle_starts_at_ipopts_optimum():
    """From p0 (the default before this start) and from the linear start asc crawled at feasible
    points on this strand (KKT distance 1.81 and 1.42); the search over the pin's reaction lands on
    Ipopt's optimum, which asc confirms without an outer iteration."""
    problem = Problem(sagfree.scenes.groom(4, 400, seed=1)[3].attached(pins=[200]), stabilize=False)
    result = sagfree.solve(problem)
    assert result.status == "converged", result.message
    assert result.iterations["outer"] == 0 and result.iterations["gauss_newton"] == 0
    assert result.objective == pytest.approx(MIDDLE_PIN_IPOPT, rel=1e-6)
    assert kkt_optimality(problem, result.p) <= 1e-5


def test_a_long_strand_with_a_pinned_tip_converges():
    """3000 vertices, tip pinned: asc from p0 ended max_iterations after 600 Gauss-Newton steps at
    |c|_inf 5e-6; from the search it converges at once, at Ipopt's R."""
    problem = Problem(sagfree.scenes.groom(3, 3000, seed=0)[1].attached(tip="pinned"), stabilize=False)
    result = sagfree.solve(problem)
    assert result.status == "converged", result.message
    assert result.iterations["gauss_newton"] == 0
    assert result.objective == pytest.approx(PINNED_TIP_IPOPT, rel=1e-3)


def test_a_default_solve_that_crawls_begins_again_from_the_other_start(monkeypatch):
    """Where the search finds nothing, a held strand starts from p0: horizontal(400, pins=[200])
    ends max_iterations there, and the default solve begins again from the linear start, converges,
    and counts both solves. The search's own start reaches the same optimum at once."""
    problem = Problem(sagfree.scenes.horizontal(n=400, pins=[200]), stabilize=False)
    searched = sagfree.solve(problem)
    assert searched.status == "converged" and searched.iterations["outer"] == 0
    with monkeypatch.context() as patch:
        patch.setattr(alm, "reaction_start", lambda problem, counts=None: None)
        from_p0 = sagfree.solve(problem, start="p0")
        assert from_p0.status == "max_iterations"
        result = sagfree.solve(problem)
    assert result.status == "converged", result.message
    assert "from the linear start (p0 ended max_iterations)" in result.message
    assert result.iterations["outer"] > from_p0.iterations["outer"]
    assert result.objective == pytest.approx(searched.objective, rel=1e-9)


def test_where_no_multiplier_fits_at_zero_reactions_the_search_starts_where_the_boxes_admit_one():
    """Curvature and twist budgets cut to 0.05 rad: at F = 0 (the root carrying everything) some box
    admits no multiplier (Phi = inf, the boxes' violation V > 0); Nelder-Mead on V finds reactions
    where V = 0, and the search goes on from there to the optimum asc reaches from p0."""
    strand = sagfree.scenes.groom(3, 40, seed=1)[2].attached(tip="pinned")
    problem = Problem(strand, stabilize=False, bounds={"curvature_budget": 0.05, "twist_budget": 0.05})
    change, basis, scale = reaction_family(problem)
    layout = problem.layout
    args = (change, basis, scale, layout.p0, layout.weights, layout.lower, layout.upper,
            *reaction_start.statics_indices(problem), problem.edge_lengths, np.empty(layout.p0.size))
    zero = np.zeros(basis.shape[1])
    assert reaction_start.reaction_value(zero, *args)[0] == np.inf
    assert reaction_start.reaction_violation(zero, *args) > 0
    p = reaction_start.reaction_start(problem)
    assert p is not None
    result, from_p0 = sagfree.solve(problem), sagfree.solve(problem, start="p0")
    assert result.status == from_p0.status == "converged", result.message
    assert result.iterations["outer"] == 0
    assert problem.objective(p) == pytest.approx(from_p0.objective, rel=1e-6)


@pytest.mark.parametrize("budget", [2.0, 0.2])
def test_the_gradient_of_phi_is_its_central_difference(budget):
    """reaction_gradient (statics_start.optimum_gradient: each element's envelope) against central
    differences of Phi, at reactions off the search's end and off Phi's kinks (small steps), with
    the default budgets and with budgets cut to 0.2 rad (many vertices held at their rest box)."""
    bounds = {"curvature_budget": budget, "twist_budget": budget}
    checked = 0
    for held in ({"tip": "pinned"}, {"pins": [20]}, {"tip": "pinned", "pins": [15]}):
        for strand in sagfree.scenes.groom(3, 40, seed=5):
            problem = Problem(strand.attached(**held), stabilize=False, bounds=bounds)
            change, basis, scale = reaction_family(problem)
            layout = problem.layout
            args = (change, basis, scale, layout.p0, layout.weights, layout.lower, layout.upper,
                    *reaction_start.statics_indices(problem), problem.edge_lengths, np.empty(layout.p0.size))
            end = reaction_start.least_over_reactions(np.zeros(basis.shape[1]), *args[:-1])[1]
            for offset in np.random.default_rng(1).standard_normal((2, end.size)) * 0.05:
                x = end + offset
                value, p = reaction_start.reaction_value(x, *args)
                if not np.isfinite(value):
                    continue
                gradient = reaction_start.reaction_gradient(x, p, *args)
                central = np.array([(reaction_start.reaction_value(x + h, *args)[0]
                                     - reaction_start.reaction_value(x - h, *args)[0]) / 2e-7
                                    for h in np.eye(end.size) * 1e-7])
                assert gradient == pytest.approx(central, rel=1e-5, abs=1e-6 * np.abs(central).max())
                checked += 1
    assert checked >= 12
