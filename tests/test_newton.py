"""The simulation's Newton solve compiled (formulation.newton) against its Python loop.

The two run the same formulas in the same order, so every solve must agree: the same steps, the
same messages, the same states (to rounding; on this machine bit for bit), the frames re-based at
the same steps.
"""
import numpy as np
import pytest

from sagfree.bodies import Capsule, Sphere
from sagfree.formulation.contact import contact_penalty
from sagfree.formulation.problem import Problem
from sagfree.formulation.simulation import equilibrium, simulate
from sagfree.formulation.strand import Strand
from sagfree.scenes import default_groom
from sagfree.scenes.head import HEAD, head_groom, icosphere


def _twins(strand: Strand, **options) -> tuple[Problem, Problem]:
    """The strand's Problem with the compiled Newton solve and one held to the Python loop."""
    compiled, python = Problem(strand, **options), Problem(strand, **options)
    python.__dict__["newton_kernels"] = None  # newton_solve's Python loop
    assert compiled.newton_kernels is not None
    return compiled, python


def _same_solve(a, b) -> None:
    assert (a.steps, a.line_search, a.rejected, a.indefinite, a.converged, a.message) == \
        (b.steps, b.line_search, b.rejected, b.indefinite, b.converged, b.message)
    np.testing.assert_allclose(a.residuals, b.residuals, rtol=1e-9, atol=0)


def _long(strand: Strand, factor: float) -> Strand:
    return Strand(strand.points[0] + factor * (strand.points - strand.points[0]))


@pytest.mark.parametrize("case", ["groom", "long", "pinned tip"])
def test_the_compiled_static_solve_is_the_python_one(case):
    strand = {"groom": default_groom()[1], "long": _long(default_groom()[0], 5.0),
              "pinned tip": default_groom()[1].attached(tip="pinned")}[case]
    compiled, python = _twins(strand)
    a, b = equilibrium(compiled, compiled.p0), equilibrium(python, python.p0)
    assert a.converged and a.newton.steps > 5
    _same_solve(a.newton, b.newton)
    scale = compiled.strand.length
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(a.frames.reference_twist, b.frames.reference_twist, rtol=0, atol=1e-12)
    if case == "long":  # a sag of 1.5 L turns tangents far: the frames were re-based, as in Python
        assert a.relative_sag > 1.0
        assert not np.allclose(a.frames.tangents, compiled.frames.tangents)
        np.testing.assert_allclose(a.frames.tangents, b.frames.tangents, rtol=0, atol=1e-12)


def test_the_compiled_implicit_euler_steps_are_the_python_ones():
    compiled, python = _twins(default_groom()[2])
    a, b = (simulate(problem, problem.p0, steps=40, dt=1e-3, damping=2.0) for problem in (compiled, python))
    assert a.converged and a.relative_sag > 1e-3  # the naive strand falls
    for x, y in zip(a.newton, b.newton):
        _same_solve(x, y)
    np.testing.assert_allclose(a.trajectory, b.trajectory, rtol=0, atol=1e-12 * compiled.strand.length)


def test_a_failing_solve_reports_as_the_python_one():
    compiled, python = _twins(_long(default_groom()[0], 5.0))
    a, b = (equilibrium(problem, problem.p0, max_steps=3) for problem in (compiled, python))
    assert not a.converged and a.newton.message.startswith("no convergence in 3 Newton steps")
    _same_solve(a.newton, b.newton)


@pytest.mark.parametrize("kind", ["sphere", "capsule", "mesh"])
def test_the_compiled_contact_penalty_is_the_python_one(kind):
    """A strand of a head groom settling onto each kind of body: the penalty acts (its energy at the
    end is positive), and the compiled solve is the Python one."""
    body = {"sphere": HEAD, "capsule": Capsule([0, 0, -0.02], [0, 0, 0.02], 0.08), "mesh": icosphere()}[kind]
    compiled, python = _twins(head_groom(2, 60, seed=0)[1], bodies=[body])
    a, b = equilibrium(compiled, compiled.p0), equilibrium(python, python.p0)
    assert a.converged and contact_penalty(compiled.contacts, a.positions, compiled.free_vertices)[0] > 0
    _same_solve(a.newton, b.newton)
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-12 * compiled.strand.length)
    runs = [simulate(problem, problem.p0, steps=10, dt=1e-3) for problem in (compiled, python)]
    np.testing.assert_allclose(runs[0].trajectory, runs[1].trajectory, rtol=0, atol=1e-12)


def test_other_bodies_and_friction_keep_the_python_loop():
    class Slab(Sphere):  # a body kind the compiled penalty does not know
        pass

    assert Problem(head_groom(1, 30, seed=0)[0], bodies=[Slab([0, 0, 0], 0.1)]).newton_kernels is None
    problem = Problem(head_groom(1, 30, seed=0)[0], bodies=[HEAD], friction=0.5)  # lagged friction: numpy
    assert problem.newton_kernels is not None and equilibrium(problem, problem.p0).converged
