"""The least sag (every solver's best effort for a strand the boxes cannot balance): its compiled
minimization (solvers.least_sag_loop) against its Python form (StaticSag through
solvers.reflective), step for step."""
import numpy as np
import pytest

import sagfree
from sagfree.formulation.problem import Problem
from sagfree.scenes.head import HEAD, head_groom
from sagfree.solvers import least_sag as module


def lengthened(strand, factor=5.0):
    """The strand ``factor`` times as long from its root: too heavy for its boxes."""
    return sagfree.Strand(strand.points[0] + factor * (strand.points - strand.points[0]), radius=strand.radius)


INFEASIBLE = {
    "long-groom-strand": lambda: Problem(lengthened(sagfree.scenes.groom(3, 60, seed=1)[0])),
    "fixed-stretch-block": lambda: Problem(lengthened(sagfree.scenes.groom(3, 40, seed=2)[1]),
                                           bounds={"stretch_stiffness": (1, 1)}),
    "strand-stiffness": lambda: Problem(lengthened(sagfree.scenes.groom(2, 40, seed=0)[0]), stiffness="strand"),
    "long-hair-on-the-head": lambda: Problem(lengthened(head_groom(2, 50, seed=3)[1], 3.0), bodies=[HEAD]),
}


def both_ways(problem, monkeypatch, **options):
    """(compiled, Python) least sags from the box's clip of p0."""
    start = np.clip(problem.p0, problem.lower, problem.upper)
    compiled = module.least_sag(problem, start, **options)
    with monkeypatch.context() as patch:
        patch.setattr(module, "compiled_least_sag", lambda problem: False)
        python = module.least_sag(problem, start, **options)
    return compiled, python


@pytest.mark.parametrize("name", INFEASIBLE)
def test_compiled_and_python_least_sags_take_the_same_steps(name, monkeypatch):
    problem = INFEASIBLE[name]()
    assert module.compiled_least_sag(problem)
    compiled, python = both_ways(problem, monkeypatch)
    assert compiled.evaluations > module.RESCALE_EVALUATIONS  # rescaled, and linearized more than once
    assert (compiled.evaluations, compiled.newton) == (python.evaluations, python.newton)
    assert np.array_equal(compiled.p, python.p) and np.array_equal(compiled.rest.q, python.rest.q)
    # and it did its work: inside the box, resting stably and sagging less than where it started
    assert np.all(compiled.p >= problem.lower) and np.all(compiled.p <= problem.upper)
    assert compiled.rest.converged and compiled.rest.relative_sag < compiled.start.relative_sag
    rest = compiled.rest
    assert problem.stability(compiled.p, q=rest.q, frames=rest.frames) >= problem.stability_margin


def test_compiled_least_sag_stops_at_its_evaluation_budget(monkeypatch):
    problem = INFEASIBLE["long-groom-strand"]()
    compiled, python = both_ways(problem, monkeypatch, max_evaluations=7)
    assert compiled.evaluations == python.evaluations == 7 and np.array_equal(compiled.p, python.p)


def test_friction_takes_the_python_least_sag():
    """The lagged friction is numpy code: a strand with friction on a body minimizes in Python."""
    strand = head_groom(1, 30, seed=2)[0]
    assert not module.compiled_least_sag(Problem(strand, bodies=[HEAD], friction=0.5))
    assert module.compiled_least_sag(Problem(strand, bodies=[HEAD]))


def test_priming_compiles_the_model_kernel_with_the_loops_argument_types(monkeypatch):
    """compile_model (priming's first child) must compile least_sag_loop._model exactly as the loop
    calls it, or the sibling child, compiling the loop, compiles the model a second time: the types
    of its call are the loop's own arguments and the arrays the loop makes (x, the linearization)."""
    import numba

    from sagfree.solvers import least_sag_loop

    problem = INFEASIBLE["long-groom-strand"]()
    module.least_sag(problem, np.clip(problem.p0, problem.lower, problem.upper), max_evaluations=3)
    module.compile_model(problem)
    assert len(least_sag_loop._model.signatures) == 1
    (loop,), (model,) = least_sag_loop.least_sag_loop.signatures, least_sag_loop._model.signatures
    memory, factor, data, fixed = loop[3], loop[4], loop[5], loop[6]
    vector = numba.typeof(np.zeros(3))
    assert model == (numba.types.boolean, vector, *memory.types[:3],
                     numba.types.Tuple((memory.types[3], factor, data)), fixed)
