"""Long strands are held to c's own rounding level where that is above tol (contract.feasibility)."""
import numpy as np
import pytest

import sagfree
from sagfree.baselines.naive import solve_naive
from sagfree.contract.feasibility import ROUNDING_MULTIPLE, feasibility_tolerance, rounding_level
from sagfree.contract.optimality import KKT_TOL, TOL, kkt_optimality
from sagfree.solvers.alm import linear_start


@pytest.fixture(scope="module")
def long_strand():
    """groom(1, 5000, seed=0)[0]: c's rounding level at its optimum is 1.4e-8, above TOL."""
    return sagfree.Problem(sagfree.scenes.groom(1, 5000, seed=0)[0])


def test_the_rounding_level_is_what_one_ulp_of_p_moves_c_by(long_strand):
    """The level is eps sum_j |dc_r/dp_j| |p_j|: moving p by one ulp per entry (random signs) moves c
    by the same order, and an exact optimum (asc's start of a root-held strand) is no closer to c = 0."""
    p = linear_start(long_strand)
    level, c = rounding_level(long_strand, p), long_strand.residual(p)
    moved = long_strand.residual(p * (1 + np.finfo(float).eps * np.random.default_rng(0).choice([-1, 1], p.size)))
    assert 0.3 * level < np.abs(moved - c).max() < ROUNDING_MULTIPLE * level
    assert np.abs(c).max() < ROUNDING_MULTIPLE * level and ROUNDING_MULTIPLE * level > 2 * TOL
    assert feasibility_tolerance(long_strand, p, TOL) == ROUNDING_MULTIPLE * level


def test_short_strands_keep_the_requested_tolerance():
    problem = sagfree.Problem(sagfree.scenes.groom(1, 100, seed=0)[0])
    assert ROUNDING_MULTIPLE * rounding_level(problem, problem.p0) < 1e-3 * TOL
    assert feasibility_tolerance(problem, problem.p0, TOL) == TOL


def test_a_strand_whose_rounding_is_above_tol_converges_at_once(long_strand):
    """asc started from the exact optimum, |c|_inf 1.2e-8 > TOL, and crawled 60 outer iterations (58 s)
    to max_iterations; held to c's rounding level, it confirms the start, says so, and the strand
    rests stably there. Another solver's status, on the same point, follows the same rule."""
    result = sagfree.solve(long_strand)
    assert result.status == "converged", result.message
    assert result.iterations["outer"] == 0 and result.iterations["gauss_newton"] == 0
    assert result.residual_inf <= feasibility_tolerance(long_strand, result.p, TOL)
    if result.residual_inf > TOL:  # 1.2e-8 here (the start's rounding, which another machine may place lower)
        assert "raised to" in result.message and "rounding level of c" in result.message
    assert kkt_optimality(long_strand, result.p) <= KKT_TOL
    assert result.stable and result.min_eigenvalue >= long_strand.stability_margin
    measured = solve_naive(long_strand, p_start=result.p)
    assert measured.status == "converged"
    assert ("raised to" in measured.message) == (measured.residual_inf > TOL)


def test_a_tolerance_below_rounding_is_raised_to_it():
    """tol = 1e-30 asks what no stored p can give: the solve holds c to its rounding level (asc's
    confirmed start, at once) and says so, where it would crawl to max_iterations."""
    problem = sagfree.Problem(sagfree.scenes.groom(1, 60, seed=0)[0])
    result = sagfree.solve(problem, tol=1e-30)
    assert result.status == "converged" and result.iterations["outer"] == 0
    assert result.residual_inf <= feasibility_tolerance(problem, result.p, 1e-30) < 1e-3 * TOL
    assert "tol 1e-30 raised to" in result.message
