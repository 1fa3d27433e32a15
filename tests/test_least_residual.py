"""asc's best effort (solvers.least_residual): its compiled run against its Python form, step for
step; and what the run is for: a point of least residual force in the box, stationary there."""
import numpy as np
import pytest

import sagfree
from sagfree.formulation.problem import Problem
from sagfree.linalg.band import column_norms, gram
from sagfree.scenes.head import head_groom
from sagfree.solvers import least_residual as module
from sagfree.solvers.alm import zero_counts
from sagfree.solvers.mprgp import solve_box_qp



def lengthened(strand, factor=5.0):
    """The strand ``factor`` times as long from its root: too heavy for its boxes."""
    return sagfree.Strand(strand.points[0] + factor * (strand.points - strand.points[0]), radius=strand.radius)


INFEASIBLE = {
    "over-tight-box": lambda: Problem(sagfree.scenes.horizontal(), bounds={"bend_stiffness": (1.0, 2.0)}),
    "long-hair": lambda: Problem(lengthened(head_groom(2, 60, seed=3)[1])),
    "strand-stiffness": lambda: Problem(lengthened(sagfree.scenes.groom(2, 40, seed=0)[0]), stiffness="strand"),
}


def runs(problem, start, **options):
    """(compiled, Python) runs from ``start``: each (p, objective, counts)."""
    out = []
    for run in (module._run_compiled, module._run_python):
        counts = zero_counts()
        p, value = run(problem, np.clip(start, problem.layout.lower, problem.layout.upper), counts,
                       module.LEAST_RESIDUAL_QP_RTOL, 100, **options)
        out.append((p, value, counts))
    return out


@pytest.mark.parametrize("name", INFEASIBLE)
def test_compiled_and_python_runs_take_the_same_steps(name):
    problem = INFEASIBLE[name]()
    assert problem.at_rest_kernels is not None
    (p, value, counts), (p_python, value_python, counts_python) = runs(problem, problem.p0)
    assert counts["least_residual"] > 1 and counts["factorizations"] > 0
    assert np.array_equal(p, p_python) and value == value_python
    assert counts == counts_python
    # the compiled run leaves its last point's c and dc/dp with the problem, as computed from scratch
    assert np.array_equal(problem.residual(p), problem.with_options().residual(p))


def test_a_second_run_stops_where_it_cannot_beat_the_first():
    """The second start's run ends once its rate cannot reach the first run's value (``beat``), both
    ways alike."""
    problem = INFEASIBLE["long-hair"]()
    (_, value, counts), _ = runs(problem, problem.p0)
    (p, _, beaten), (p_python, _, beaten_python) = runs(problem, problem.p0, beat=0.5 * value)
    assert np.array_equal(p, p_python) and beaten == beaten_python
    assert beaten["least_residual"] < counts["least_residual"]


@pytest.mark.parametrize("name", INFEASIBLE)
def test_the_least_residual_point_is_stationary_in_the_box(name):
    """At the end no box-constrained Levenberg-Marquardt step (the run's own model, tightly solved)
    lowers 1/2 |c|^2 + eps R by more than a small share: the run stopped at a least-residual point,
    not partway."""
    problem = INFEASIBLE[name]()
    counts = zero_counts()
    p = module.least_residual(problem, [problem.p0], counts)
    lower, upper = problem.layout.lower, problem.layout.upper
    eps, w = module.LEAST_RESIDUAL_TIEBREAK, problem.layout.weights
    c, J = problem.residual(p), problem.strand_jacobian(p)
    value = 0.5 * c @ c + eps * problem.objective(p)
    gradient = J.T @ c + eps * w * (p - problem.layout.p0)
    border = 1 if "strand_stiffness" in problem.blocks else 0
    qp = solve_box_qp(gram(J, eps * w + 1e-12 + 1e-11 * column_norms(J), 1.0, border), -gradient, lower - p,
                      upper - p, rtol=1e-12)
    model_decrease = -(gradient @ qp.x + 0.5 * np.sum((J @ qp.x) ** 2))
    assert model_decrease < 0.05 * value
    assert value < 0.9 * (0.5 * np.sum(problem.residual(problem.p0) ** 2))  # and it did reduce the force
