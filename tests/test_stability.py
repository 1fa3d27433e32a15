"""Stable rest states and best-effort answers (DESIGN section 4): the stabilization loop, its
derivative, the push check, infeasible strands, and a regularizer that does not grow with n."""
import dataclasses

import numpy as np
import pytest
import scipy.linalg

import sagfree
from sagfree.contract.optimality import KKT_TOL, kkt_optimality
from sagfree.formulation.parameters import STIFFNESS_BLOCKS, STRAND_BLOCK
from sagfree.formulation.rest_change import restiffen, stiffest
from sagfree.formulation.simulation import equilibrium, push_check
from sagfree.solvers.least_sag import StaticSag

#: strands of the default groom that are saddle points of the bare problem's optimum (self-weight
#: buckling of strands that point upward)
UNSTABLE = (1, 11)


@pytest.fixture(scope="module")
def groom():
    return sagfree.scenes.default_groom()


@pytest.mark.parametrize("k", UNSTABLE)
def test_unstable_optimum_is_stabilized_and_holds_after_a_push(groom, k):
    problem = sagfree.Problem(groom[k])
    bare = sagfree.solve(problem.with_options(stabilize=False))
    assert bare.status == "converged" and bare.min_eigenvalue < 0 and not bare.stable
    assert "UNSTABLE" in bare.message and bare.floors is None
    result = sagfree.solve(problem)
    assert result.status == "converged", result.message
    assert result.min_eigenvalue >= problem.stability_margin > 0 and result.stable
    assert result.iterations["stabilization"] >= 1 and "stabilized in" in result.message
    # optimal for the problem it solved: the same one with the stiffness floors as lower bounds
    floored = problem.with_lower_bounds(result.floors)
    assert np.abs(problem.residual(result.p)).max() <= 1e-8
    assert np.all(result.p >= floored.lower) and kkt_optimality(floored, result.p) <= KKT_TOL
    stiffness = problem.layout.block_mask((*STIFFNESS_BLOCKS, STRAND_BLOCK))
    assert np.all(result.floors[~stiffness] == problem.lower[~stiffness])  # only stiffness floors rise
    assert result.objective > bare.objective
    # the saddle falls away from q* after a push; the stabilized strand swings back
    assert not push_check(problem, bare.p).holds
    pushed = push_check(problem, result.p)
    assert pushed.holds and pushed.deviation <= 1e-3 and pushed.simulation.converged


def test_floors_are_checked_by_restiffening_before_a_solve(groom):
    """The first-order floors from a strongly unstable optimum fall short (lambda is concave in the
    multipliers); raised again from the restiffened point (c kept, no solve) until restiffening onto
    them is stable, and the solve on them is stable in one round."""
    import sagfree.frontend.stabilize as stabilize
    problem = sagfree.Problem(groom[11])
    bare = sagfree.solve(problem.with_options(stabilize=False))
    margin = problem.stability_margin
    value, mode = problem.stability(bare.p, vector=True)
    assert value < -margin
    stiffness = problem.layout.block_mask((*STIFFNESS_BLOCKS, STRAND_BLOCK))
    first = stabilize._raised_floors(problem, bare.p, value, mode, stiffness)

    def restiffened_stability(floors):
        floored = problem.with_lower_bounds(floors)
        raised = restiffen(floored, bare.p, np.maximum(bare.p, floored.lower))
        assert np.abs(problem.residual(raised)).max() <= 1e-8  # the forces kept: still balanced
        return floored.stability(raised)

    assert restiffened_stability(first) < margin
    checked = stabilize._floors_checked_by_restiffening(problem, bare.p, first, stiffness)
    assert np.all(checked >= first) and np.any(checked > first)
    assert restiffened_stability(checked) >= margin
    result = sagfree.solve(problem)
    assert result.iterations["stabilization"] == 1 and result.min_eigenvalue >= margin
    assert np.array_equal(result.floors, checked)


@pytest.mark.parametrize("options, strands", [(dict(stiffness="strand"), (55, 84)),
                                              (dict(couple_twist=False), (3, 4))])
def test_stabilization_in_strand_mode_and_with_uncoupled_twist(groom, options, strands):
    """One multiplier for the strand (strand mode) is raised as a whole; without the coupling gamma
    stays at G, more optima are saddles, and the bend and twist multipliers rise separately."""
    for k in strands:
        problem = sagfree.Problem(groom[k], **options)
        bare = sagfree.solve(problem.with_options(stabilize=False))
        assert bare.status == "converged" and not bare.stable
        result = sagfree.solve(problem)
        assert result.status == "converged", result.message
        assert result.min_eigenvalue >= problem.stability_margin and result.iterations["stabilization"] >= 1
        assert kkt_optimality(problem.with_lower_bounds(result.floors), result.p) <= KKT_TOL


@pytest.mark.parametrize("options", [dict(), dict(couple_twist=False), dict(stiffness="strand")])
def test_stiffening_gradient_matches_finite_differences_along_restiffen(groom, options):
    """d lambda / d k along the moment-preserving move (Problem.stiffening_gradient) against central
    differences of Problem.stability; the move itself keeps c."""
    problem = sagfree.Problem(groom[1], stabilize=False, **options)
    p = sagfree.solve(problem).p
    value, mode = problem.stability(p, vector=True)
    gradient = problem.stiffening_gradient(p, mode)
    stiffness = problem.layout.block_mask((*STIFFNESS_BLOCKS, STRAND_BLOCK))
    assert np.all(gradient[~stiffness] == 0) and np.all(gradient[stiffness] >= -1e-6 * gradient.max())
    relevant = stiffness & (gradient > 1e-3 * gradient.max())  # the multipliers the loop raises
    direction = np.where(relevant, np.random.default_rng(1).uniform(0.0, 1.0, p.size), 0.0)
    # lambda carries ~1e-7 relative rounding (the mass-scaled Hessian's spread): at h = 1e-4 that
    # is ~1e-3 of the quotient, which rounding-level changes of the Hessian moved by 2e-3; at 1e-3
    # rounding and the concavity's truncation error are each ~2e-4 of it
    h = 1e-3
    moved = [restiffen(problem, p, p + s * h * direction) for s in (1, -1)]
    for q in moved:  # exact for bend and twist; the stretch term's rest lengths move the bend prefactor
        assert np.abs(problem.residual(q)).max() <= 1e-2 * h
    finite = (problem.stability(moved[0]) - problem.stability(moved[1])) / (2 * h)
    assert finite == pytest.approx(gradient @ direction, rel=2e-3)


def test_margin_is_a_tenth_of_the_unstressed_strands_eigenvalue_unless_given():
    strand = sagfree.scenes.horizontal(n=20)
    problem = sagfree.Problem(strand)
    assert problem.stability_margin == pytest.approx(0.1 * problem.stability(problem.p0))
    assert sagfree.Problem(strand, min_eigenvalue=3.0).stability_margin == 3.0
    with pytest.raises(ValueError, match="min_eigenvalue"):
        sagfree.Problem(strand, min_eigenvalue=float("nan"))


def test_margin_bound_gives_the_exact_verdict(groom):
    """meets_margin decides by the Rayleigh bound where it can, with the verdict of the exact
    comparison: on stable bare optima (the bound decides) and on saddles (it cannot)."""
    decided_by_bound = 0
    for k in (0, 1, 2, 3, 11):
        problem = sagfree.Problem(groom[k], stabilize=False)
        p = sagfree.solve(problem).p
        verdict = problem.meets_margin(p)
        decided_by_bound += "stability_margin" not in problem.__dict__
        assert verdict == (problem.stability(p) >= problem.stability_margin)
        mode = problem.stability(p, vector=True)[1]
        form = mode @ (problem.hessian(problem.p0) @ mode)
        assert problem._unstressed_form(mode) == pytest.approx(form, rel=1e-6)  # summed per stencil
        quotient = form / (problem.dof_masses @ mode**2)
        assert quotient >= problem.stability(problem.p0) * (1 - 1e-9)  # the bound it rests on
    assert decided_by_bound == 3  # 1 and 11 are saddles: the margin was computed for them


def test_every_solver_reaches_the_same_stabilized_optimum(groom):
    """Ipopt runs the same loop (frontend.stabilize) around its own solves and reaches ours."""
    problem = sagfree.Problem(groom[11])
    ours, ipopt = sagfree.solve(problem, "asc"), sagfree.solve(problem, "ipopt")
    for result in (ours, ipopt):
        assert result.status == "converged", result.message
        assert result.min_eigenvalue >= problem.stability_margin
        assert result.iterations["stabilization"] >= 1
    assert ipopt.objective == pytest.approx(ours.objective, rel=1e-6)


@pytest.fixture(scope="module")
def long_strand(groom):
    """The default groom's strand 5 at 5 times its length (60 cm), same radius and material."""
    strand = groom[5]
    return sagfree.Strand(strand.points[0] + 5.0 * (strand.points - strand.points[0]), radius=strand.radius,
                          youngs_modulus=strand.youngs_modulus, shear_modulus=strand.shear_modulus,
                          density=strand.density)


def test_best_effort_for_a_strand_the_boxes_cannot_balance(long_strand):
    """The default groom's strand 5 at 5 times its length (60 cm): infeasible, with the least static
    sag the box allows; it sags clearly less than naive and than the predecessor, and rests stably."""
    problem = sagfree.Problem(long_strand)
    result = sagfree.solve(problem)
    assert result.status == "infeasible"
    assert "need a bend_stiffness above its upper bound 100" in result.message and "least static sag" in result.message
    assert result.iterations["outer"] == 0  # certified infeasible at the start: the best effort at once
    assert result.iterations["least_sag"] > 1
    # least_residual's runs stop once they cannot gain (here each ran its 100 steps before, for a
    # start of the least sag that rested no lower)
    assert result.iterations["least_residual"] < 100
    assert np.all(result.p >= problem.lower) and np.all(result.p <= problem.upper)
    naive = sagfree.solve(problem, "naive")
    predecessor = sagfree.solve(problem, "penalty-gn")
    rests = [equilibrium(problem, p) for p in (result.p, naive.p, predecessor.p)]
    sags = [rest.relative_sag for rest in rests]
    assert all(rest.converged for rest in rests)
    assert result.static_sag == pytest.approx(sags[0], rel=1e-6)
    assert sags[0] < 0.5 * sags[1] and sags[0] < 0.5 * sags[2]
    # stable where it rests: a dense eigenvalue solve with an explicit mass matrix, and a push
    free = problem.free_index
    hessian = problem.hessian(result.p, rests[0].q, rests[0].frames).toarray()[np.ix_(free, free)]
    mass = np.diag(problem.dof_masses[free])
    spectrum = scipy.linalg.eigh(hessian, mass, eigvals_only=True)
    # both solvers resolve lambda_min only to ~eps lambda_max (1.4e12 s^-2 here: 3e-4 s^-2, 1e-5 of it)
    assert spectrum[0] == pytest.approx(result.min_eigenvalue, abs=10 * np.finfo(float).eps * spectrum[-1])
    assert result.min_eigenvalue >= problem.stability_margin


def test_static_sag_jacobian_matches_finite_differences(long_strand):
    """The least-sag phase's derivative of the static equilibrium, K^-1 D dc/dp at q_s (away from q*,
    through Problem.strand_jacobian(p, q, frames)), against central differences of the continued
    equilibrium along a random direction."""
    problem = sagfree.Problem(long_strand)
    p = stiffest(problem, problem.p0)
    model = StaticSag(problem, equilibrium(problem, p))
    model.residuals(p)
    jacobian = model.linearization(p)
    direction = np.random.default_rng(0).standard_normal(p.size) * 1e-6
    difference = 0.5 * (model.residuals(p + direction) - model.residuals(p - direction))
    assert np.linalg.norm(jacobian.product(direction) - difference) <= 1e-5 * np.linalg.norm(difference)


def test_least_sag_through_the_operator(long_strand):
    """The Jacobian never formed, the scales re-estimated every RESCALE_EVALUATIONS: inside the box,
    stable where it rests, sagging well below its start (a wrong transposed product leaves it at
    the start)."""
    from sagfree.solvers import least_sag

    problem = sagfree.Problem(long_strand)
    start = stiffest(problem, problem.p0)
    effort = least_sag.least_sag(problem, start)
    assert effort.evaluations > least_sag.RESCALE_EVALUATIONS and effort.rest.converged  # more than one round
    assert np.all(effort.p >= problem.lower) and np.all(effort.p <= problem.upper)
    # its start (the stiffest p0) sags 0.41 of the strand's length, naive 1.03: the steps did the work
    assert effort.rest.relative_sag < 0.5 * effort.start.relative_sag
    assert problem.stability(effort.p, q=effort.rest.q, frames=effort.rest.frames) >= problem.stability_margin


def test_gauss_newton_direction_solves_the_regularized_least_squares(long_strand):
    """The trust region's Gauss-Newton direction on the least-sag operator (compiled CGLS,
    sag_operator.cgls): the transposed product is the dense matrix's, and on a few scaled columns
    (conjugate gradients are exact in as many iterations) the direction is the dense solution of
    min |J diag(d) p + f|^2 + |damping^(1/2) p|^2; columns with d = 0 stay at zero."""
    from sagfree.solvers import sag_operator

    problem = sagfree.Problem(long_strand)
    p = stiffest(problem, problem.p0)
    model = StaticSag(problem, equilibrium(problem, p))
    residuals = model.residuals(p)
    operator = model.operator(p)
    dense = np.array([sag_operator.sag_product(*operator, column) for column in np.eye(p.size)]).T
    pulled = sag_operator.sag_transposed_product(*operator, residuals)
    np.testing.assert_allclose(pulled, dense.T @ residuals, rtol=0, atol=1e-9 * np.abs(pulled).max())
    rng = np.random.default_rng(2)
    norms = np.linalg.norm(dense, axis=0)
    chosen = rng.choice(np.flatnonzero(norms > 0), 8, replace=False)
    d = np.zeros(p.size)
    d[chosen] = np.exp(rng.uniform(-2, 2, chosen.size)) / norms[chosen]
    damping = np.full(p.size, 1e-3)
    direction = sag_operator.cgls(*operator, d, np.sqrt(damping), residuals, 50, 1e-14)
    scaled = dense * d
    exact = np.linalg.solve(scaled.T @ scaled + np.diag(damping), -scaled.T @ residuals)
    np.testing.assert_allclose(direction, exact, rtol=1e-6, atol=1e-9 * np.abs(exact).max())
    assert np.all(direction[d == 0] == 0)


def test_least_sag_with_a_fixed_parameter_block(long_strand):
    """Bounds that fix a block (stretch stiffness at 1: lower == upper) leave the others to minimize
    over: scipy's least_squares refused such bounds, and the least sag stopped at its start."""
    from sagfree.solvers import least_sag

    problem = sagfree.Problem(long_strand, bounds={"stretch_stiffness": (1, 1)})
    start = stiffest(problem, problem.p0)
    effort = least_sag.least_sag(problem, start)
    assert effort.evaluations > least_sag.RESCALE_EVALUATIONS and effort.rest.converged
    fixed = problem.lower == problem.upper
    assert fixed.any() and np.array_equal(effort.p[fixed], start[fixed])
    assert effort.rest.relative_sag < 0.5 * effort.start.relative_sag


def test_least_sag_without_a_converged_static_solve_keeps_its_start(long_strand, monkeypatch):
    """Where neither the start's static solve nor p0's converges there is no equilibrium to
    continue from: the start comes back at once, no minimization step taken, and the Result says
    the sag is unknown."""
    from sagfree.formulation import simulation
    from sagfree.frontend.best_effort import with_least_sag
    from sagfree.solvers import least_sag

    problem = sagfree.Problem(long_strand)
    monkeypatch.setattr(least_sag, "equilibrium", lambda problem, p, **options: simulation.equilibrium(
        problem, p, **{**options, "max_steps": 2}))  # every static solve runs out of Newton steps
    start = stiffest(problem, problem.p0)
    effort = least_sag.least_sag(problem, start)
    assert effort.evaluations == 0 and not effort.rest.converged and not effort.naive.converged
    np.testing.assert_array_equal(effort.p, start)
    result = sagfree.solve(problem, solver="naive")
    result = with_least_sag(problem, dataclasses.replace(result, status="infeasible"))
    assert result.status == "infeasible" and "sag unknown" in result.message and result.iterations["least_sag"] == 0


def test_static_sag_operator_transpose_and_column_norms(long_strand):
    """The least-sag Jacobian as an operator (long strands: never a dense 3n x parameters matrix)
    applies the same matrix by columns as its transpose does by rows, its transpose product is the
    adjoint of its product, and the column norms that scale the trust region estimate the matrix's."""
    problem = sagfree.Problem(long_strand)
    p = stiffest(problem, problem.p0)
    model = StaticSag(problem, equilibrium(problem, p))
    residuals = model.residuals(p)
    jacobian = model.linearization(p)
    rng = np.random.default_rng(1)
    v, u = rng.standard_normal(p.size), rng.standard_normal(residuals.size)
    assert u @ jacobian.product(v) == pytest.approx(v @ jacobian.transposed_product(u), rel=1e-8)  # K^-1: ~1e-10
    # the matrix by rows, through the transpose's solves (B^T K^-1 P^T W), against its columns
    dense = np.array([jacobian.transposed_product(row) for row in np.eye(residuals.size)])
    by_columns = np.column_stack([jacobian.product(column) for column in np.eye(p.size)])
    assert np.allclose(by_columns, dense, rtol=0, atol=1e-9 * np.abs(dense).max())
    norms = np.linalg.norm(dense, axis=0)
    assert np.any(norms > 0)
    # Hutchinson's estimate: unbiased (many probes: within 20% on every column), and with the
    # default probes within a factor 2 on every column, where the norms span ~1e7 between blocks
    acting = norms > 0
    many = model.estimated_column_norms(p, probes=2000)
    assert np.all(many[~acting] == 0) and np.allclose(many[acting], norms[acting], rtol=0.2, atol=0)
    ratio = model.estimated_column_norms(p)[acting] / norms[acting]
    assert np.all((ratio > 0.5) & (ratio < 2.0)) and norms[acting].max() > 1e5 * norms[acting].min()


def test_regularizer_converges_with_resolution():
    """R weighs each element by its share of the length: the same strand's R at 200 and 400
    vertices agrees within 5% (a per-element sum doubled with n)."""
    values = [sagfree.solve(sagfree.Problem(sagfree.scenes.curly(n=n))).objective for n in (200, 400)]
    assert values[1] == pytest.approx(values[0], rel=0.05)
