"""The stabilization's floor steps in one compiled call (frontend.floor_steps) are the Python path's,
bit for bit, and so are its rounds in one compiled call (stabilization_rounds); so is the compiled
stiffening gradient (formulation.at_rest) the numpy sums'."""
import numpy as np
import pytest

import sagfree
import sagfree.frontend.stabilize as stabilize
from sagfree.formulation.parameters import STIFFNESS_BLOCKS, STRAND_BLOCK
from sagfree.formulation.problem import Problem
from sagfree.frontend.floor_steps import checked_floors, stabilization_rounds
from sagfree.solvers import alm


def python_rounds(monkeypatch):
    """The loop's turns in Python, each round's floors still one compiled call."""
    monkeypatch.setattr(stabilize, "stabilization_rounds", lambda *args: None)


def python_path(monkeypatch):
    """The loop and its floor steps in Python."""
    python_rounds(monkeypatch)
    monkeypatch.setattr(stabilize, "checked_floors", lambda *args: (False, None))


def same_results(a, b) -> bool:
    return (a.status == b.status and a.message == b.message and np.array_equal(a.p, b.p)
            and np.array_equal(a.floors, b.floors) and a.min_eigenvalue == b.min_eigenvalue
            and a.iterations == b.iterations and a.history == b.history and a.objective == b.objective)


@pytest.fixture(scope="module")
def saddles():
    """Groom strands whose bare optimum is unstable (the loop stabilizes them), with that optimum."""
    found = []
    for strand in sagfree.scenes.groom(40, 60, seed=0):
        problem = Problem(strand, stabilize=False)
        result = sagfree.solve(problem)
        if result.status == "converged" and not problem.meets_margin(result.p):
            found.append((strand, result.p))
    assert len(found) >= 3
    return found[:4]


def round_from(strand, p):
    """(problem, stiffness mask, value, mode) of a stabilization round from the bare optimum p, after
    the bare solve that remembers the least rest change (as the loop's first solve does)."""
    problem = Problem(strand)
    alm.solve_alm(problem)
    value, mode = problem.stability(p, vector=True)
    return problem, problem.layout.block_mask((*STIFFNESS_BLOCKS, STRAND_BLOCK)), value, mode


def test_a_compiled_round_is_the_python_steps(saddles):
    for strand, p in saddles:
        problem, stiffness, value, mode = round_from(strand, p)
        applies, floors = checked_floors(problem, p, value, mode, stiffness, problem.stability_margin,
                                         stabilize.OVERSHOOT, stabilize.RELEVANT, stabilize.FLOOR_STEPS, 1e-8)
        assert applies and floors is not None
        python, *_ = round_from(strand, p)
        first = stabilize._raised_floors(python, p, value, mode, stiffness)
        expected = stabilize._floors_checked_by_restiffening(python, p, first, stiffness)
        assert np.array_equal(floors, expected) and np.all(floors >= problem.layout.lower)
        # the landing's eigenpair is in the memo the re-solve's Result reads: the Python path's
        landing = stabilize._landing(python.with_lower_bounds(expected), p)
        value, mode = python.with_lower_bounds(expected).stability(landing, vector=True)
        remembered, remembered_mode = problem.stability(landing, vector=True)
        assert remembered == value and np.array_equal(remembered_mode, mode)


@pytest.mark.parametrize("python", [python_rounds, python_path])
def test_stabilized_strands_are_the_same_with_and_without_the_compiled_rounds(saddles, monkeypatch, python):
    strands = [strand for strand, _ in saddles]
    compiled = sagfree.optimize(strands, jobs=1)
    python(monkeypatch)
    in_python = sagfree.optimize(strands, jobs=1)
    for strand, a, b in zip(strands, compiled, in_python):
        assert a.status == b.status == "converged" and a.iterations["stabilization"] >= 1
        assert same_results(a, b) and a.min_eigenvalue >= Problem(strand).stability_margin


def test_the_rounds_run_as_one_call_and_leave_no_intermediate_result(saddles):
    strand, p = saddles[0]
    problem = Problem(strand)
    floored, last, rounds, verdict = stabilize.floors_loop(alm.solve_alm, problem, {})
    assert isinstance(last, stabilize.LastSolve) and rounds >= 1 and verdict is None
    assert np.array_equal(floored.layout.lower, np.maximum(problem.layout.lower, floored.layout.lower))
    assert floored.stability(last.p) >= problem.stability_margin and last.iterations["gauss_newton"] == 0
    assert np.abs(floored.residual(last.p)).max() <= 1e-8 and last.objective == floored.objective(last.p)


def test_a_re_solve_that_asc_must_polish_hands_the_loop_back_to_python(monkeypatch):
    """groom(300, 100, seed=0)[183]: its first floored problem's statics optimum is feasible but 1.7e-4
    from a KKT point, so asc's outer loop polishes it (11 outer iterations): the compiled rounds
    hand the whole loop back, and the result is the Python loop's."""
    strand = sagfree.scenes.groom(300, 100, seed=0)[183]
    problem = Problem(strand)
    result = alm.solve_alm(problem)
    value, mode = problem.stability(result.p, vector=True)
    stiffness = problem.layout.block_mask((*STIFFNESS_BLOCKS, STRAND_BLOCK))
    assert stabilization_rounds(problem, result.p, value, mode, stiffness, problem.stability_margin,
                                stabilize.OVERSHOOT, stabilize.RELEVANT, stabilize.FLOOR_STEPS, stabilize.MAX_ROUNDS,
                                1e-8, 1e-5) is None
    compiled = sagfree.solve(Problem(strand))
    python_path(monkeypatch)
    python = sagfree.solve(Problem(strand))
    assert compiled.status == "converged" and compiled.iterations["outer"] >= 1 and same_results(compiled, python)


def test_a_loop_out_of_rounds_says_so_on_both_paths(saddles, monkeypatch):
    monkeypatch.setattr(stabilize, "MAX_ROUNDS", 0)
    strand, _ = saddles[0]
    compiled = sagfree.solve(Problem(strand))
    python_path(monkeypatch)
    python = sagfree.solve(Problem(strand))
    assert compiled.status == "max_iterations" and "not stable after 0 rounds" in compiled.message
    assert same_results(compiled, python)


def test_a_strand_that_cannot_be_stabilized_says_so_on_both_paths(saddles, monkeypatch):
    """Unit stiffness and wide rest curvatures: balanced by the rest shape alone, with no multiplier
    left to raise (those strands that the rest shape alone cannot balance are infeasible anyway)."""
    capped = dict(bounds={"bend_stiffness": (1, 1), "stretch_stiffness": (1, 1), "rest_curvature": (-100, 100)})
    compiled = [sagfree.solve(Problem(strand, **capped)) for strand, _ in saddles]
    python_path(monkeypatch)
    python = [sagfree.solve(Problem(strand, **capped)) for strand, _ in saddles]
    unstabilizable = 0
    for a, b in zip(compiled, python):
        assert same_results(a, b)
        unstabilizable += "cannot be stabilized inside the boxes" in a.message and a.status == "infeasible"
    assert unstabilizable >= 1


def test_where_the_statics_start_does_not_apply_the_round_is_left_to_python(saddles):
    strand, p = saddles[0]
    problem = Problem(strand, stiffness="strand")  # one multiplier: no statics start
    value, mode = problem.stability(problem.p0, vector=True)
    stiffness = problem.layout.block_mask((*STIFFNESS_BLOCKS, STRAND_BLOCK))
    assert checked_floors(problem, problem.p0, value, mode, stiffness, 1.0, 1.05, 1e-3, 3, 1e-8) == (False, None)
    fresh = Problem(strand)  # no least rest change remembered yet
    assert checked_floors(fresh, p, value, mode, stiffness, 1.0, 1.05, 1e-3, 3, 1e-8) == (False, None)


@pytest.mark.parametrize("options", [dict(), dict(couple_twist=False), dict(stiffness="strand")])
def test_the_compiled_stiffening_gradient_is_the_numpy_sums(saddles, options):
    strand, _ = saddles[1]
    problem = Problem(strand, stabilize=False, **options)
    p = sagfree.solve(problem).p
    mode = problem.stability(p, vector=True)[1]
    compiled = problem.stiffening_gradient(p, mode)
    problem.__dict__["stiffening_kernel"] = None  # the numpy sums
    numpy = problem.stiffening_gradient(p, mode)
    assert np.any(compiled != 0) and np.array_equal(compiled, numpy)
