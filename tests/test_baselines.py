"""Baselines against our solver: Ipopt, OSQP-SQP, penalty-gn, naive; the KKT measure they share."""
import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp

import sagfree
from sagfree.formulation.symbolic import SymbolicNLP
from sagfree.contract.optimality import KKT_TOL, kkt_optimality
from sagfree.formulation.parameters import STIFFNESS_BLOCKS

SMALL_AND_MEDIUM = {
    "horizontal": lambda: sagfree.scenes.horizontal(),
    "curly": lambda: sagfree.scenes.curly(n=40),
    "groom strand (100 vertices)": lambda: sagfree.scenes.groom(1, 100, seed=0)[0],
}


def dense_kkt_step(problem, p):
    """Independent dense version of the KKT measure: the equality-constrained step with diag(w) on
    the variables strictly inside their box, and the wrong-signed bound multipliers."""
    J, c, w = problem.jacobian(p).toarray(), problem.residual(p), problem.layout.weights
    free = (p > problem.lower) & (p < problem.upper)
    F = np.flatnonzero(free)
    K = np.block([[np.diag(w[F]), J[:, F].T], [J[:, F], np.zeros((J.shape[0], J.shape[0]))]])
    solution = np.linalg.solve(K, -np.concatenate([w[F] * (p - problem.p0)[F], c]))
    gradient = w * (p - problem.p0) + J.T @ solution[F.size:]
    wrong = np.where(p <= problem.lower, np.maximum(-gradient, 0), np.where(p >= problem.upper,
                                                                           np.maximum(gradient, 0), 0))
    h = w + (J**2).sum(axis=0)
    return max(np.abs(solution[:F.size]).max(), (wrong / h).max())


@pytest.mark.parametrize("stiffness, fixed", [("element", "two"), ("strand", "two"), ("element", "stiffness")])
def test_constrained_step_matches_a_dense_solve(stiffness, fixed, rng):
    """linalg.saddle.constrained_step (band LU of the interleaved saddle system of the free variables;
    SuperLU where the strand multiplier's column is dense) against numpy on the same system, some
    variables on bounds: two, or every stiffness multiplier (the linear start's system)."""
    from sagfree.linalg.saddle import SaddleFactor, constrained_step
    problem = sagfree.Problem(sagfree.scenes.helix(n=25), stiffness=stiffness)
    p = problem.p0 + 0.3 * rng.random(problem.n_parameters) * (problem.upper - problem.p0)
    free = np.ones(problem.n_parameters, dtype=bool)
    if fixed == "two":
        free[[3, 50]] = False  # on a bound: left out of both systems
    else:
        free &= ~problem.layout.block_mask(STIFFNESS_BLOCKS)
    w = problem.layout.weights * rng.uniform(0.5, 2.0, problem.n_parameters)
    J, c, g = problem.strand_jacobian(p), problem.residual(p), rng.standard_normal(problem.n_parameters)
    d, lam = constrained_step(J, w, g, c, free)
    dense, F = J.tocsc().toarray(), np.flatnonzero(free)
    K = np.block([[np.diag(w[F]), dense[:, F].T], [dense[:, F], np.zeros((c.size, c.size))]])
    reference = np.linalg.solve(K, -np.concatenate([g[F], c]))
    assert np.all(d[~free] == 0.0)
    x, b = np.concatenate([d[F], lam]), -np.concatenate([g[F], c])
    assert np.abs(K @ x - b).max() <= 1e-12 * (np.abs(K) @ np.abs(x) + np.abs(b)).max()  # backward stable
    # both pivoted LUs of a system whose columns span ~1e8 in scale: agreement to rounding
    assert np.allclose(x, reference, rtol=1e-6, atol=1e-9 * np.abs(reference).max())
    # the factors kept for another right-hand side (the SQP step's correction) solve it as well
    factor = SaddleFactor(J, w, free)
    g2, c2 = rng.standard_normal(problem.n_parameters), rng.standard_normal(c.size)
    d2, lam2 = factor.solve(g2, c2)
    again = np.linalg.solve(K, -np.concatenate([g2[F], c2]))
    assert np.all(d2[~free] == 0.0)
    assert np.allclose(np.concatenate([d2[F], lam2]), again, rtol=1e-6, atol=1e-9 * np.abs(again).max())
    # too few free variables for the rows: singular, and constrained_step says so with None
    few = np.zeros(problem.n_parameters, dtype=bool)
    few[: c.size - 1] = True
    assert SaddleFactor(J, w, few).singular and constrained_step(J, w, g, c, few) is None


@pytest.mark.parametrize("stiffness", ["element", "strand"])
def test_saddle_with_curvature_matches_a_dense_solve(stiffness, rng, capfd):
    """linalg.saddle.SaddleFactor with the exact Hessian of the Lagrangian, W = diag(w) +
    sum lam_r c_r'' (asc's Newton-SQP: band LU with the curvature in the band; SuperLU where the
    strand multiplier's column is dense) against numpy on the same system; a system with a zero
    constraint row is singular, and says so without printing anything (SuperLU's BLAS printed
    errors for some singular systems)."""
    from sagfree.linalg.saddle import SaddleFactor
    problem = sagfree.Problem(sagfree.scenes.helix(n=25), stiffness=stiffness)
    p = problem.p0 + 0.3 * rng.random(problem.n_parameters) * (problem.upper - problem.p0)
    free = np.ones(problem.n_parameters, dtype=bool)
    free[[3, 50]] = False
    w, J, c = problem.layout.weights, problem.strand_jacobian(p), problem.residual(p)
    # multipliers of the size the solver meets (least-squares ones at this helix's optimum: 2e-3 to 3e-2 rms)
    lam, g = 1e-3 * rng.standard_normal(c.size), rng.standard_normal(problem.n_parameters)
    curvature = problem.constraint_hessian(p, lam)
    assert curvature.nnz > problem.n_parameters  # off-diagonal couplings that widen the band
    d, multipliers = SaddleFactor(J, w, free, curvature).solve(g, c)
    dense, F = J.tocsc().toarray(), np.flatnonzero(free)
    W = np.diag(w) + curvature.toarray()
    K = np.block([[W[np.ix_(F, F)], dense[:, F].T], [dense[:, F], np.zeros((c.size, c.size))]])
    reference = np.linalg.solve(K, -np.concatenate([g[F], c]))
    assert np.all(d[~free] == 0.0)
    x, b = np.concatenate([d[F], multipliers]), -np.concatenate([g[F], c])
    assert np.abs(K @ x - b).max() <= 1e-11 * (np.abs(K) @ np.abs(x) + np.abs(b)).max()  # backward stable
    assert np.allclose(x, reference, rtol=1e-6, atol=1e-9 * np.abs(reference).max())
    # the curvature as the triplets Newton-SQP passes (duplicates summed by the factorization)
    d_entries, multipliers_entries = SaddleFactor(J, w, free, problem.constraint_hessian_entries(p, lam)).solve(g, c)
    assert np.allclose(np.concatenate([d_entries[F], multipliers_entries]), x, rtol=1e-10,
                       atol=1e-12 * np.abs(x).max())
    capfd.readouterr()
    singular = sp.csc_matrix(J.tocsc().toarray() * (np.arange(c.size) != 5)[:, None])  # row 5 empty
    assert SaddleFactor(singular, w, free, curvature).singular
    assert capfd.readouterr() == ("", "")


def test_kkt_measure_frees_near_bound_variables_when_too_few_are_free():
    """At this strand's optimum, the variables farther than ``near`` from their bounds are one fewer
    than the constraints: the KKT system on them is singular, and the measure was infinite (so the
    solver ran into max_outer). It then solves on the variables not on a bound."""
    problem = sagfree.Problem(sagfree.scenes.groom(6, 400, seed=13)[1])
    result = sagfree.solve(problem)
    assert result.status == "converged", result.message
    layout = problem.layout
    slack = 1e-6 * (layout.upper - layout.lower)
    near = (result.p - layout.lower <= slack) | (layout.upper - result.p <= slack)
    assert (~near).sum() < problem.residual(result.p).size
    assert kkt_optimality(problem, result.p) <= KKT_TOL


def test_symbolic_nlp_is_the_problem_constraint():
    problem = sagfree.Problem(sagfree.scenes.helix(n=20))
    nlp = SymbolicNLP.for_problem(problem)
    f = ca.Function("f", [nlp.p, nlp.data], [nlp.constraint, nlp.objective, ca.jacobian(nlp.constraint, nlp.p)])
    p = problem.p0 + 0.3 * np.random.default_rng(0).random(problem.n_parameters) * (problem.upper - problem.p0)
    c, objective, J = (np.asarray(v) for v in f(p, nlp.data_vector(problem)))
    residual = problem.residual(p)
    assert np.abs(c.ravel() - residual).max() <= 1e-12 * np.abs(residual).max()
    assert objective.item() == pytest.approx(problem.objective(p))
    reference = problem.jacobian(p).toarray()
    assert np.abs(J - reference).max() <= 1e-12 * np.abs(reference).max()
    # a strand of the same size and options reuses the expression
    other = sagfree.Problem(sagfree.scenes.helix(n=20, radius=0.02))
    assert SymbolicNLP.for_problem(other) is nlp


def test_kkt_measure_from_a_nearby_factorization_is_the_fresh_one():
    """kkt_optimality with ``nearby`` (the factorization of asc's last SQP step, refined:
    linalg.saddle.SaddleFactor.solve_nearby) gives the distance of a fresh factorization to its
    accuracy, and refuses a factorization that does not fit: another free set, or one so far from p
    that the refinement does not converge (then it factors afresh, with the same answer)."""
    import sagfree.solvers.alm as alm
    from sagfree.contract.optimality import REFINED_DISTANCE, working_set
    from sagfree.linalg.saddle import SaddleFactor
    problem = sagfree.Problem(sagfree.scenes.groom(1, 100, seed=0)[0], stabilize=False)
    optimum = alm.solve_alm(problem).p
    w, lower, upper = problem.layout.weights, problem.lower, problem.upper
    # the SQP step's situation: factored a step before the optimum, on the same working set
    before = optimum - 1e-6 * (optimum - problem.p0) * working_set(optimum, lower, upper)
    factor = SaddleFactor(problem.strand_jacobian(before), w, working_set(optimum, lower, upper))
    fresh = kkt_optimality(problem, optimum)
    assert fresh < 1e-6
    refined = kkt_optimality(problem, optimum, nearby=factor)
    assert abs(refined - fresh) <= 2 * REFINED_DISTANCE
    J, c, g = problem.strand_jacobian(optimum), problem.residual(optimum), w * (optimum - problem.p0)
    assert factor.solve_nearby(J, g, c, REFINED_DISTANCE) is not None  # it was refined, not refactored
    # at a point far away the refinement diverges or stalls: None, and the measure factors afresh
    far = SaddleFactor(problem.strand_jacobian(problem.p0), w, working_set(optimum, lower, upper))
    assert far.solve_nearby(J, g, c, REFINED_DISTANCE) is None
    assert kkt_optimality(problem, optimum, nearby=far) == fresh
    # another free set: not used
    smaller = working_set(optimum, lower, upper)
    smaller[np.flatnonzero(smaller)[0]] = False
    other = SaddleFactor(J, w, smaller)
    assert kkt_optimality(problem, optimum, nearby=other) == fresh


def test_kkt_measure_matches_a_dense_reference_and_separates_optimal_from_feasible():
    problem = sagfree.Problem(sagfree.scenes.curly(n=30), stiffness="strand")
    optimum = sagfree.solve(problem).p
    # feasible but not optimal: the optimum of a different regularizer
    other = sagfree.solve(problem.with_options(weights={"rest_twist": 1e4})).p
    assert np.abs(problem.residual(other)).max() <= 1e-8
    for p in (optimum, other):
        assert kkt_optimality(problem, p) == pytest.approx(dense_kkt_step(problem, p), rel=1e-4, abs=1e-9)
    assert kkt_optimality(problem, optimum) < 1e-6
    assert kkt_optimality(problem, other) > 1e-3


@pytest.mark.parametrize("stiffness", ["element", "strand"])
@pytest.mark.parametrize("scene", SMALL_AND_MEDIUM)
def test_ipopt_and_ours_reach_the_same_optimum(scene, stiffness):
    problem = sagfree.Problem(SMALL_AND_MEDIUM[scene](), stiffness=stiffness)
    ours, ipopt = sagfree.solve(problem, "asc"), sagfree.solve(problem, "ipopt")
    for result in (ours, ipopt):
        assert result.status == "converged", result.message
        assert np.abs(problem.residual(result.p)).max() <= 1e-8
    assert np.all(ours.p >= problem.lower) and np.all(ours.p <= problem.upper)
    rounding = 1e-14 * (problem.upper - problem.lower)  # Ipopt's x is kept as returned
    assert np.all(ipopt.p >= problem.lower - rounding) and np.all(ipopt.p <= problem.upper + rounding)
    assert ipopt.objective == pytest.approx(ours.objective, rel=1e-6)
    assert ipopt.iterations["ipopt"] > 0 and ipopt.iterations["hessian_evaluations"] > 0
    assert "Ipopt:" in ipopt.message


@pytest.mark.parametrize("scene", SMALL_AND_MEDIUM)
def test_osqp_sqp_converges_to_our_optimum(scene):
    problem = sagfree.Problem(SMALL_AND_MEDIUM[scene]())
    ours, sqp = sagfree.solve(problem, "asc"), sagfree.solve(problem, "osqp")
    assert sqp.status == "converged", sqp.message
    assert np.abs(problem.residual(sqp.p)).max() <= 1e-8
    assert sqp.objective == pytest.approx(ours.objective, rel=1e-6)
    assert kkt_optimality(problem, sqp.p) <= KKT_TOL
    assert sqp.iterations["sqp"] > 1 and sqp.iterations["admm"] > sqp.iterations["sqp"]


def test_osqp_sqp_is_reproducible():
    """OSQP's default rho adaptation follows wall time; a fixed interval makes runs identical."""
    problem = sagfree.Problem(sagfree.scenes.curly(n=30))
    first, second = sagfree.solve(problem, "osqp"), sagfree.solve(problem, "osqp")
    assert np.array_equal(first.p, second.p) and first.iterations == second.iterations


@pytest.mark.parametrize("scene", ["horizontal", "curly"])
def test_penalty_gn_leaves_a_residual_between_ours_and_naive(scene):
    problem = sagfree.Problem(SMALL_AND_MEDIUM[scene]())
    ours, predecessor, naive = (sagfree.solve(problem, s) for s in ("asc", "penalty-gn", "naive"))
    assert ours.residual_inf < predecessor.residual_inf < naive.residual_inf
    assert ours.max_force < predecessor.max_force < naive.max_force
    assert predecessor.status == "failed" and "residual" in predecessor.message
    # rest shape only: every stiffness multiplier keeps its specified value
    assert all(s["max"] == 1.0 and s["stiffened"] == 0.0 for s in predecessor.stiffening.values())
    assert predecessor.rest_change["rest_curvature"]["max"] > 0
    assert predecessor.iterations["gauss_newton"] > 0


def test_naive_residual_is_gravity():
    problem = sagfree.Problem(sagfree.scenes.horizontal())
    naive = sagfree.solve(problem, "naive")
    assert np.array_equal(naive.p, problem.p0)
    assert naive.residual_inf == pytest.approx(1.0)  # c = D^-1 f_gravity on a free vertex
    assert naive.status == "failed"


def test_missing_plugin_is_reported_before_any_work(monkeypatch):
    import sagfree.baselines.ipopt as ipopt_module

    monkeypatch.setattr(ipopt_module, "available", lambda: False)
    problem = sagfree.Problem(sagfree.scenes.horizontal())
    with pytest.raises(sagfree.SolverUnavailable, match="Ipopt plugin.*pip install"):
        sagfree.solve(problem, "ipopt")
    with pytest.raises(sagfree.SolverUnavailable, match="ipopt"):
        sagfree.optimize([sagfree.scenes.horizontal()], solver="ipopt", jobs=1)
    with pytest.raises(ValueError, match="unknown solver 'ipop'.*asc, ipopt, osqp, penalty-gn, naive"):
        sagfree.solve(problem, "ipop")


@pytest.mark.parametrize("solver", list(sagfree.SOLVERS))
def test_every_solver_runs_through_optimize(solver):
    strands = [sagfree.scenes.horizontal(n=12), sagfree.scenes.helix(n=12)]
    results = sagfree.optimize(strands, solver=solver, jobs=2)
    assert [r.solver for r in results] == [solver, solver]
    for strand, result in zip(strands, results):
        problem = sagfree.Problem(strand)
        assert result.p.shape == (problem.n_parameters,)
        assert result.residual_inf == pytest.approx(np.abs(problem.residual(result.p)).max())


def test_ipopt_compiled_model_takes_the_same_iterates_and_its_time_is_split():
    problem = sagfree.Problem(sagfree.scenes.horizontal(8), stabilize=False)
    interpreted = sagfree.solve(problem, "ipopt", model="casadi")
    compiled = sagfree.solve(problem, "ipopt", model="compiled")
    assert compiled.status == interpreted.status == "converged"
    assert compiled.iterations == interpreted.iterations
    np.testing.assert_allclose(compiled.p, interpreted.p, rtol=1e-9, atol=1e-12)
    for result in (compiled, interpreted):
        split = result.time_split
        assert split["model"] > 0 and split["other"] >= 0
        assert sum(split.values()) == pytest.approx(result.time, rel=1e-6)


@pytest.mark.parametrize("solver", ["asc", "osqp", "penalty-gn"])
def test_time_split_counts_model_evaluation_and_linear_algebra(solver):
    result = sagfree.solve(sagfree.Problem(sagfree.scenes.horizontal(20)), solver)
    split = result.time_split
    assert split["model"] > 0 and split["linear_algebra"] > 0 and split["other"] >= 0
    assert sum(split.values()) == pytest.approx(result.time, rel=1e-6)
