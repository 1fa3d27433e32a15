"""asc's start and its KKT confirmation in one compiled call (solvers.confirmed_start) are the Python
path's, bit for bit; so is the compiled loop of the KKT distance (contract.optimality)."""
import numpy as np
import pytest

import sagfree
from sagfree.contract.optimality import kkt_optimality
from sagfree.formulation.bodies import Sphere
from sagfree.formulation.problem import Problem
from sagfree.linalg.saddle import SaddleFactor
from sagfree.solvers import alm
from sagfree.solvers.confirmed_start import confirmed_start


def python_kkt_distance(problem, p):
    """kkt_optimality by its Python loop: an unusable ``nearby`` factorization (singular) is skipped,
    and the loop factors every working set itself, as the compiled loop does."""
    nothing_free = SaddleFactor(problem.strand_jacobian(p), problem.layout.weights, np.zeros(p.size, dtype=bool))
    assert nothing_free.singular
    return kkt_optimality(problem, p, nearby=nothing_free)


@pytest.mark.parametrize("vertices", [3, 25, 100])
def test_the_compiled_start_and_distance_are_the_python_paths(vertices):
    for strand in sagfree.scenes.groom(6, vertices, seed=2):
        compiled, python = Problem(strand), Problem(strand)
        p, distance, _, start_violation, violation = confirmed_start(compiled)
        start = np.clip(alm.linear_start(python), python.layout.lower, python.layout.upper)
        assert np.array_equal(p, start)
        assert distance == python_kkt_distance(python, start) <= 1e-8  # the start is the optimum
        value, mode = python.stability(p, vector=True)  # its Result's stability, remembered
        assert compiled._memos["stability"] and np.isfinite(value)
        remembered, remembered_mode = compiled.stability(p, vector=True)
        assert remembered == value and np.array_equal(remembered_mode, mode)
        p0 = python.layout.p0  # the memos it filled hold what the Python path computes
        for point in (p0, p):
            assert np.array_equal(compiled.residual(point), python.residual(point))
            assert np.array_equal(compiled.strand_jacobian(point).data, python.strand_jacobian(point).data)
        assert start_violation == np.abs(python.residual(p0)).max() and violation == np.abs(python.residual(p)).max()
        assert np.array_equal(compiled.bound_independent("least rest change", lambda: None),
                              alm._least_rest_change(python))
        floors = python.layout.lower.copy()  # a stabilization's twin: from the remembered least change
        floors[python.layout.blocks["bend_stiffness"][:3]] = 1.5
        p, distance, measured, start_violation, _ = confirmed_start(compiled.with_lower_bounds(floors))
        assert measured == 0 and np.isnan(start_violation)  # a twin's start: from its landing
        twin = python.with_lower_bounds(floors)
        start = np.clip(alm.linear_start(twin), twin.layout.lower, twin.layout.upper)
        assert np.array_equal(p, start) and distance == python_kkt_distance(twin, start)


def test_asc_solves_a_groom_strand_the_same_with_and_without_the_compiled_start(monkeypatch):
    strand = sagfree.scenes.groom(3, 60, seed=0)[1]
    compiled = sagfree.solve(Problem(strand, stabilize=False), "asc")
    monkeypatch.setattr(alm, "confirmed_start", lambda *args: None)
    python = sagfree.solve(Problem(strand, stabilize=False), "asc")
    assert compiled.status == python.status == "converged"
    assert np.array_equal(compiled.p, python.p) and compiled.message == python.message
    assert compiled.history == python.history and compiled.iterations == python.iterations


def test_where_the_statics_start_does_not_apply_there_is_no_compiled_start():
    strand = sagfree.scenes.groom(1, 30, seed=0)[0]
    assert confirmed_start(Problem(strand, stiffness="strand")) is None
    resting = sagfree.scenes.horizontal(n=20)  # on a ball under vertex 12: supports in p
    ball = Sphere(resting.points[12] - [0, 0, 0.2 + resting.radius], 0.2)
    assert confirmed_start(Problem(resting, bodies=[ball])) is None
    pinned = sagfree.scenes.horizontal(n=20, tip="pinned")
    assert confirmed_start(Problem(pinned)) is None


def test_the_compiled_kkt_distance_is_the_python_loops_away_from_an_optimum():
    strand = sagfree.scenes.groom(2, 40, seed=3)[0]
    problem = Problem(strand)
    lower, upper = problem.layout.lower, problem.layout.upper
    rng = np.random.default_rng(0)
    for size in (1e-6, 1e-3, 1e-1):
        p = np.clip(problem.layout.p0 + size * rng.standard_normal(lower.size) * (upper - lower), lower, upper)
        assert kkt_optimality(problem, p) == python_kkt_distance(problem, p) > 0
