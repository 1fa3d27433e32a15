"""asc's whole solve of a strand held by its root alone, stabilization included, is one compiled call
(frontend.whole_solve) whose Result is the two calls' (solve_alm's confirmed start, then the
compiled rounds of frontend.stabilize) bit for bit, and which leaves every other strand alone."""
import numpy as np
import pytest

import sagfree
import sagfree.frontend.stabilize as stabilize
from sagfree.solvers import alm, reaction_start
from sagfree.solvers.reaction_start import least_over_reactions
from sagfree.formulation.parameters import STIFFNESS_BLOCKS, STRAND_BLOCK
from sagfree.formulation.problem import Problem
from sagfree.frontend.stabilize import FLOOR_STEPS, MAX_ROUNDS, OVERSHOOT, RELEVANT
from sagfree.frontend.whole_solve import whole_solve

FIELDS = ("status", "message", "min_eigenvalue", "iterations", "history", "objective", "residual_inf", "max_force")


def same_results(a, b) -> bool:
    floors = (a.floors is None and b.floors is None) or np.array_equal(a.floors, b.floors)
    return floors and np.array_equal(a.p, b.p) and all(getattr(a, name) == getattr(b, name) for name in FIELDS)


def counted(monkeypatch) -> list:
    """whole_solve's answers (None where it declined) in the solves that follow."""
    answers = []

    def recording(*args, **kwargs):
        answers.append(whole_solve(*args, **kwargs))
        return answers[-1]

    monkeypatch.setattr(stabilize, "whole_solve", recording)
    return answers


def held(strands):
    """The strands with their tips pinned, every fourth pinned at a third of its length too."""
    return [s.attached(tip="pinned", pins=(len(s.points) // 3,) if i % 4 == 0 else ()) for i, s in enumerate(strands)]


@pytest.mark.parametrize("kind", ["root", "held"])
@pytest.mark.parametrize("options", [{}, {"stabilize": False}, {"min_eigenvalue": 50.0}])
def test_the_whole_solve_is_the_two_calls_result(options, kind, monkeypatch):
    """For strands held at more points the two calls are solve_alm from the reaction search and the
    Python loop of floors (frontend.stabilize.floors_loop), whose re-solves search again."""
    strands = sagfree.scenes.groom(40, 60, seed=0)
    strands = strands if kind == "root" else held(strands)
    answers = counted(monkeypatch)
    whole = [sagfree.solve(Problem(strand, **options)) for strand in strands]
    monkeypatch.setattr(stabilize, "whole_solve", lambda *args, **kwargs: None)
    two_calls = [sagfree.solve(Problem(strand, **options)) for strand in strands]
    assert all(same_results(a, b) for a, b in zip(whole, two_calls))
    assert sum(answer is not None for answer in answers) >= 38  # the path holds for nearly all of them
    assert all(r.status == "converged" for r in whole)
    if options.get("stabilize", True):
        assert sum(r.iterations.get("stabilization", 0) > 0 for r in whole) >= 3 and all(r.stable for r in whole)


def test_the_whole_solve_computes_the_margin_the_problem_does():
    """Where the Rayleigh bound cannot decide, the margin is the unstressed eigenvalue's fraction, the
    same number Problem.stability_margin computes (and the margin the rounds aim at)."""
    for strand in sagfree.scenes.groom(40, 60, seed=0):
        problem = Problem(strand)
        stiffness = problem.layout.block_mask((*STIFFNESS_BLOCKS, STRAND_BLOCK))
        found = whole_solve(problem, stiffness, OVERSHOOT, RELEVANT, FLOOR_STEPS, MAX_ROUNDS, 1e-8, 1e-5)
        if found is not None and found.rounds:
            assert found.margin == Problem(strand).stability_margin
            assert found.margin == pytest.approx(0.1 * problem.stability(problem.p0), rel=1e-6)  # the eigensolver's tolerance
            assert problem.stability(found.p) == found.value >= found.margin
            return
    pytest.fail("no strand was stabilized")


def test_the_whole_solve_leaves_other_strands_to_the_usual_path(monkeypatch):
    """A clamped tip, one stiffness multiplier per strand, or a start that needs asc's outer loop:
    the call declines before anything is kept, and the strand is solved the usual way."""
    strand = sagfree.scenes.groom(1, 60, seed=0)[0]
    answers = counted(monkeypatch)
    for problem in (Problem(strand.attached(tip="clamped")), Problem(strand.attached(tip="pinned"),
                                                                     stiffness="strand")):
        result = sagfree.solve(problem)
        assert result.status == "converged", result.message
    assert answers and all(answer is None for answer in answers)
    loose = Problem(strand)
    stiffness = loose.layout.block_mask((*STIFFNESS_BLOCKS, STRAND_BLOCK))
    assert whole_solve(loose, stiffness, OVERSHOOT, RELEVANT, FLOOR_STEPS, MAX_ROUNDS, 1e-8, 1e-30) is None
    assert loose.remembered("least rest change") is None  # nothing kept: the usual path starts afresh
    result = sagfree.solve(loose, kkt_tol=1e-30)
    assert result.iterations["outer"] > 0


def test_a_declined_held_solve_hands_its_searches_over(monkeypatch):
    """A held strand whose start the call cannot confirm (a tolerance on |c| below c's rounding level
    on the strand: the call holds the start to the tolerance asked, the usual path raises it to 4x
    that level, contract.feasibility): the solve that takes over starts from the call's search,
    without searching again, and its Result is the usual path's, counts of Phi's values included."""
    strand = sagfree.scenes.groom(1, 60, seed=0)[0].attached(tip="pinned")
    sagfree.solve(Problem(strand))  # the process's warm-up (its own searches) first
    answers = counted(monkeypatch)
    searches = []
    monkeypatch.setattr(reaction_start, "least_over_reactions", lambda *args: searches.append(1) or
                        least_over_reactions(*args))
    declined = sagfree.solve(Problem(strand), tol=1e-13)
    assert answers == [None]
    taken = len(searches)  # the stabilization's re-solves' searches, after the call's first one
    monkeypatch.setattr(stabilize, "whole_solve", lambda *args, **kwargs: None)
    usual = sagfree.solve(Problem(strand), tol=1e-13)
    assert len(searches) == 2 * taken + 1 and same_results(declined, usual)
    assert "raised" in declined.message and declined.iterations["reaction_values"] > 0


def test_a_search_that_ends_at_a_kink_is_corrected_to_the_kkt_point(monkeypatch):
    """Budgets cut to 0.2 rad: the reaction search ends 3e-4 from KKT at a kink of Phi; a few SQP
    steps (confirmed_start.corrected) reach the KKT point, in the call as in the Python path, where
    asc's outer loop took 9 outer iterations to the same R."""
    strand = sagfree.scenes.groom(3, 40, seed=2)[0].attached(tip="pinned")
    tight = {"curvature_budget": 0.2, "twist_budget": 0.2}
    answers = counted(monkeypatch)
    whole = sagfree.solve(Problem(strand, bounds=tight))
    assert answers[-1] is not None and whole.status == "converged"
    assert whole.iterations["outer"] == 0 and whole.iterations["sqp"] > 0
    monkeypatch.setattr(stabilize, "whole_solve", lambda *args, **kwargs: None)
    assert same_results(whole, sagfree.solve(Problem(strand, bounds=tight)))
    monkeypatch.setattr(alm, "corrected", lambda *args, **kwargs: None)
    polished = sagfree.solve(Problem(strand, bounds=tight))
    assert polished.status == "converged" and polished.iterations["outer"] > 0
    assert whole.objective == pytest.approx(polished.objective, rel=1e-9)
