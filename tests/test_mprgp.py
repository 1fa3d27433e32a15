"""MPRGP and the active-set Cholesky against exact references (DESIGN section 5)."""
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear

import sagfree
import sagfree.solvers.alm as alm
import sagfree.solvers.gauss_newton as gauss_newton
import sagfree.solvers.mprgp as mprgp
from sagfree.linalg.band import bordered_band, gram, matvec
from sagfree.linalg.cholesky import band_cholesky, band_solve, band_solve_many, factor_active, solve_factored
from sagfree.solvers.interior_point import interior_point
from sagfree.solvers.mprgp import PRECONDITIONERS, solve_box_qp


def random_banded_spd(rng, n, width, border, condition=1e3):
    """A random SPD matrix: band of ``width`` plus ``border`` dense trailing rows."""
    B = sp.diags([rng.standard_normal(n - k) for k in range(width + 1)], [-k for k in range(width + 1)])
    H = (B @ B.T).toarray()
    H[np.abs(np.subtract.outer(np.arange(n), np.arange(n))) > width] = 0.0
    nb = n - border
    H[nb:, :] = 0.0
    H[:, nb:] = 0.0
    H[nb:, :nb] = rng.standard_normal((border, nb)) * 0.3
    H[:nb, nb:] = H[nb:, :nb].T
    H = 0.5 * (H + H.T)
    e = np.linalg.eigvalsh(H)
    H += (e.max() / condition - min(e.min(), 0.0)) * np.eye(n)
    scale = np.exp(rng.uniform(-3, 3, n))  # badly scaled variables, as rest length vs stiffness
    H *= np.outer(scale, scale)
    return H


def exact_box_qp(H, b, lower, upper):
    """min 1/2 x^T H x - b^T x in the box, as bounded least squares ||L^T x - L^-1 b|| (BVLS)."""
    L = np.linalg.cholesky(H)
    return lsq_linear(L.T, np.linalg.solve(L, b), bounds=(lower, upper), method="bvls", tol=1e-15).x


@pytest.mark.parametrize("border", [0, 1])
@pytest.mark.parametrize("seed", range(4))
def test_mprgp_matches_an_exact_solution_for_every_preconditioner(seed, border):
    rng = np.random.default_rng(seed)
    n = 50
    H = random_banded_spd(rng, n, 4, border)
    b = rng.standard_normal(n) * 5
    lower, upper = -rng.uniform(0.05, 1, n), rng.uniform(0.05, 1, n)
    lower[rng.uniform(size=n) < 0.1] = -np.inf  # some one-sided and free variables
    upper[rng.uniform(size=n) < 0.1] = np.inf
    reference = exact_box_qp(H, b, np.maximum(lower, -1e10), np.minimum(upper, 1e10))
    assert np.sum((reference <= lower + 1e-12) | (reference >= upper - 1e-12)) > 3  # bounds matter
    for name in PRECONDITIONERS:
        result = solve_box_qp(bordered_band(sp.csr_matrix(H), border), b, lower, upper, rtol=1e-12,
                              max_iterations=20_000, preconditioner=name)
        assert result.status == "converged", name
        assert np.all(result.x >= lower) and np.all(result.x <= upper)
        assert np.abs(result.x - reference).max() < 1e-8 * max(1.0, np.abs(reference).max()), name
    cholesky = solve_box_qp(bordered_band(sp.csr_matrix(H), border), b, lower, upper, rtol=1e-12)
    none = solve_box_qp(bordered_band(sp.csr_matrix(H), border), b, lower, upper, rtol=1e-12,
                        preconditioner="none")
    assert cholesky.cg + cholesky.expansion < none.cg + none.expansion  # what the factor buys


def test_active_set_cholesky_solves_the_restricted_system(rng):
    n, border = 40, 1
    H = random_banded_spd(rng, n, 3, border)
    bb = bordered_band(sp.csr_matrix(H), border)
    free = rng.uniform(size=n) < 0.7
    cols, lborder, lcorner = np.empty(bb.band.shape[::-1]), np.empty_like(bb.border), np.empty_like(bb.corner)
    assert factor_active(bb.band, bb.border, bb.corner, free, cols, lborder, lcorner, 0, 0)
    M = np.where(np.outer(free, free), H, 0.0) + np.diag(~free * 1.0)
    r = rng.standard_normal(n)
    out = np.empty(n)
    solve_factored(cols, lborder, lcorner, r, out)
    assert np.allclose(out, np.linalg.solve(M, r), rtol=1e-10, atol=1e-12)
    y = np.empty(n)
    matvec(bb.band, bb.border, bb.corner, r, y)
    assert np.allclose(y, H @ r)
    assert np.allclose(bb.to_dense(), H)


@pytest.mark.parametrize("border", [0, 1])
def test_partial_refactorization_equals_a_full_one(rng, border):
    """factor_active from the first changed index (rows above it kept) gives the full factor."""
    n = 60
    bb = bordered_band(sp.csr_matrix(random_banded_spd(rng, n, 4, border)), border)
    nb = n - border
    for start, border_changed in ((0, False), (17, False), (nb - 3, False), (nb, True), (25, True)):
        free = rng.uniform(size=n) < 0.7
        factors = [np.empty(bb.band.shape[::-1]), np.empty_like(bb.border), np.empty_like(bb.corner)]
        assert factor_active(bb.band, bb.border, bb.corner, free, *factors, 0, 0)
        changed = free.copy()
        changed[start:nb] = rng.uniform(size=nb - start) < 0.5
        if border_changed and border:
            changed[nb:] = ~changed[nb:]
        fresh = [np.empty(bb.band.shape[::-1]), np.empty_like(bb.border), np.empty_like(bb.corner)]
        assert factor_active(bb.band, bb.border, bb.corner, changed, *fresh, 0, 0)
        assert factor_active(bb.band, bb.border, bb.corner, changed, *factors, min(start, nb),
                             0 if border_changed else min(start, nb))
        for mine, reference in zip(factors, fresh):
            assert np.allclose(mine, reference, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("rows", [11, 13, 19])
def test_factor_of_a_compiled_width_equals_the_general_loop(rng, rows):
    """The default model's band widths are eliminated with the width a compile-time constant
    (cholesky._eliminate_next): the factor is the general loop's bit for bit, full and partial,
    with an active set. The same band with one more (zero) diagonal takes the general loop."""
    n = 80
    bb = bordered_band(sp.csr_matrix(random_banded_spd(rng, n, rows - 1, 0)), 0)
    assert bb.band.shape[0] == rows
    padded = np.vstack([bb.band, np.zeros((1, n))])
    empty, corner = np.zeros((0, n)), np.zeros((0, 0))
    first, second = rng.uniform(size=n) < 0.8, rng.uniform(size=n) < 0.8
    second[:30] = first[:30]
    factors = []
    for band in (bb.band, padded):
        cols = np.empty((n, band.shape[0]))
        assert factor_active(band, empty, corner, first, cols, empty, corner, 0, 0)
        full = cols.copy()
        assert factor_active(band, empty, corner, second, cols, empty, corner, 30, 30)  # from the first change
        factors.append((full, cols))
    for mine, general in zip(factors[0], factors[1]):
        assert np.array_equal(mine, general[:, :rows]) and not general[:, rows].any()


@pytest.mark.parametrize("width, border", [(19, 0), (13, 0), (13, 1)])
def test_gram_of_a_compiled_width_adds_in_the_pair_by_pair_order(rng, width, border):
    """gram's rows of the default model's widths go through a dense copy and a constant-width outer
    product (band._add_row_outer): the band is the pair-by-pair sum, rows ascending, bit for bit,
    on rows with gaps, rows at the band's end and a dense last column (the strand multiplier)."""
    rows, n = 70, 60
    J = np.zeros((rows, n))
    nb = n - border
    for r in range(rows):
        lo = min(r * (nb - width) // rows + rng.integers(0, 2), nb - 1)
        span = np.arange(lo, min(lo + width, nb))
        kept = rng.uniform(size=span.size) < 0.8
        kept[[0, -1]] = True  # the row spans the whole band width where it fits
        J[r, span[kept]] = rng.standard_normal(int(kept.sum()))
    J[rows - 1, nb - 2:nb] = 1.5  # a row that reaches the band's last column
    if border:
        J[:, -1] = rng.standard_normal(rows)
    d, scale = rng.uniform(1.0, 2.0, n), 3.0
    band = gram(sp.csr_matrix(J), d, scale, border)
    assert band.band.shape[0] == width
    reference = np.zeros_like(band.band)
    reference[0] = d[:nb]
    for r in range(rows):
        entries = np.flatnonzero(J[r, :nb])
        for i, a in enumerate(entries):
            va = scale * J[r, a]
            for b in entries[i:]:
                reference[b - a, a] += va * J[r, b]
    assert np.array_equal(band.band, reference)


def test_many_right_hand_sides_solve_as_one_at_a_time(rng):
    H = random_banded_spd(rng, 40, 10, 0)
    band = np.array([np.r_[np.diag(H, -k), np.zeros(k)] for k in range(11)])
    factor = band_cholesky(band)
    rhs = rng.standard_normal((40, 7))
    many = band_solve_many(factor, rhs)
    np.testing.assert_allclose(many, np.linalg.solve(H, rhs), rtol=1e-9, atol=1e-12 * np.abs(many).max())
    one_at_a_time = np.column_stack([band_solve(factor, column) for column in rhs.T])
    np.testing.assert_allclose(many, one_at_a_time, rtol=1e-13, atol=1e-15 * np.abs(many).max())


def test_indefinite_matrix_is_reported(rng):
    H = -np.eye(6)
    result = solve_box_qp(bordered_band(sp.csr_matrix(H), 0), np.ones(6), -np.ones(6), np.ones(6))
    assert result.status == "not_positive_definite"


@pytest.mark.parametrize("border", [0, 1])
def test_gram_is_the_banded_gauss_newton_hessian(rng, border):
    """linalg.band.gram(J, d, s, border) = diag(d) + s J^T J, for a banded J with a dense last column
    (the strand multiplier) given with each row's entries in reverse order."""
    rows, n = 30, 25
    J = rng.standard_normal((rows, n))
    J[np.abs(np.subtract.outer(np.arange(rows) * n / rows, np.arange(n))) > 3] = 0.0
    if border:
        J[:, -1] = rng.standard_normal(rows)
    indices = [np.flatnonzero(row)[::-1] for row in J]
    reverse = sp.csr_matrix((np.concatenate([J[r, ix] for r, ix in enumerate(indices)]), np.concatenate(indices),
                             np.cumsum([0] + [ix.size for ix in indices])), shape=J.shape)
    assert not reverse.has_sorted_indices
    d = rng.uniform(1.0, 2.0, n)
    H = gram(reverse, d, 3.0, border).to_dense()
    assert np.allclose(H, np.diag(d) + 3.0 * J.T @ J, rtol=1e-13, atol=1e-12)


def scaled_projected_gradient(H, b, lower, upper, x):
    """||g^P||_2 of 1/2 x^T H x - b^T x at x, in the variables scaled to a unit diagonal."""
    g = H @ x - b
    ulps = 4e-16 * np.maximum(np.abs(lower), np.abs(upper))  # x = s * y is rounded once
    g = np.where(x <= lower + ulps, np.minimum(g, 0.0), np.where(x >= upper - ulps, np.maximum(g, 0.0), g))
    g[lower == upper] = 0.0  # fixed variables
    g[np.abs(g) <= 1e-13 * (np.abs(H) @ np.abs(x) + np.abs(b))] = 0.0  # the rounding of H x - b
    return float(np.linalg.norm(g / np.sqrt(np.diag(H))))


def python_loop(monkeypatch):
    """asc's Gauss-Newton QPs through alm.solve_box_qp, where a test can capture them: the Python
    inner loop (the compiled one, step for step the same, calls mprgp.box_qp inside)."""
    monkeypatch.setattr(gauss_newton, "available", lambda problem: False)


def test_active_set_prelude_cuts_the_factorizations_of_groom_gauss_newton_qps(monkeypatch):
    """On the element-stiffness Gauss-Newton QPs of 200-vertex groom strands, the primal-dual
    active-set prelude reaches the KKT point as MPRGP alone does, with fewer factorizations."""
    captured = []

    def capture(H, b, lower, upper, **options):
        captured.append((H, b, lower, upper, options))
        return solve_box_qp(H, b, lower, upper, **options)

    monkeypatch.setattr(alm, "solve_box_qp", capture)
    python_loop(monkeypatch)
    for strand in sagfree.scenes.groom(3, 200, seed=1):
        assert sagfree.solve(sagfree.Problem(strand), start="linear").status == "converged"
    banded = [qp for qp in captured if qp[0].corner.shape[0] == 0]
    assert len(banded) >= 5
    totals = {0: 0, None: 0}
    for H, b, lower, upper, options in banded:
        dense = H.to_dense()
        start = np.clip(options.get("x0", np.zeros(b.size)), lower, upper)
        initial = scaled_projected_gradient(dense, b, lower, upper, start)
        for steps in totals:
            result = solve_box_qp(H, b, lower, upper, **{**options, "active_set_steps": steps})
            assert result.status == "converged"
            assert (steps == 0) == (result.active_set == 0)
            assert np.all(result.x >= lower) and np.all(result.x <= upper)
            # the stopping test of solve_box_qp (rtol = 1e-10), recomputed here
            assert scaled_projected_gradient(dense, b, lower, upper, result.x) <= 1e-9 * initial
            totals[steps] += result.factorizations
    assert totals[None] < 0.8 * totals[0], totals


@pytest.mark.parametrize("border", [0, 1])
@pytest.mark.parametrize("seed", range(3))
def test_interior_point_matches_an_exact_solution(seed, border):
    """Mehrotra's method on random box QPs with two-sided, one-sided, free and fixed variables."""
    rng = np.random.default_rng(seed)
    n = 40
    H = random_banded_spd(rng, n, 3, border)
    s = 1.0 / np.sqrt(np.diag(H))
    H = H * np.outer(s, s)  # the unit diagonal solve_box_qp hands over
    b = rng.standard_normal(n) * 5
    lower, upper = -rng.uniform(0.05, 1, n), rng.uniform(0.05, 1, n)
    lower[:4] = -np.inf
    upper[2:6] = np.inf
    lower[6:8] = upper[6:8] = 0.3  # fixed
    rest = lower < upper  # the reference takes the fixed variables out: b_R - H_RF x_F
    reference = np.full(n, 0.3)
    reference[rest] = exact_box_qp(H[np.ix_(rest, rest)], b[rest] - H[np.ix_(rest, ~rest)] @ reference[~rest],
                                   np.maximum(lower[rest], -1e10), np.minimum(upper[rest], 1e10))
    bb = bordered_band(sp.csr_matrix(H), border)
    x = np.empty(n)
    iterations, factorizations = interior_point(bb.band, bb.border, bb.corner, b, lower, upper, x, 1e-12)
    assert 0 < iterations == factorizations < 60
    assert np.all(x >= lower - 1e-12) and np.all(x <= upper + 1e-12)  # inside, up to the rounding of x + dx
    assert np.abs(x - reference).max() < 1e-6 * max(1.0, np.abs(reference).max())


def test_a_walking_qp_goes_to_the_interior_point_method(monkeypatch):
    """The second Gauss-Newton QP of strand 6 of groom(10, 400, seed=1) in strand mode moves its
    binding rest-curvature bound from vertex 1 to vertex 142 one proportioning step at a time (mprgp
    module docstring): MPRGP alone needs ~280 factorizations, with the fallback a fraction of them,
    to the same KKT point."""
    captured = []

    class Captured(Exception):
        pass

    def capture(H, b, lower, upper, **options):
        captured.append((H, b, lower, upper, options))
        if len(captured) == 2:
            raise Captured  # the rest of the solve is not needed
        return solve_box_qp(H, b, lower, upper, **options)

    monkeypatch.setattr(alm, "solve_box_qp", capture)
    python_loop(monkeypatch)
    with pytest.raises(Captured):
        # solve_alm itself: sagfree.solve would first warm up on a small strand, whose QPs the
        # capture would take instead when this test runs first in its process
        alm.solve_alm(sagfree.Problem(sagfree.scenes.groom(10, 400, seed=1)[6], stiffness="strand"))
    H, b, lower, upper, options = captured[1]
    assert H.corner.shape == (1, 1)  # the strand multiplier's border
    fallback = solve_box_qp(H, b, lower, upper, **options)
    monkeypatch.setattr(mprgp, "WALKING", 10**9)
    alone = solve_box_qp(H, b, lower, upper, **options)
    assert alone.status == fallback.status == "converged"
    assert alone.interior == 0 < fallback.interior
    assert fallback.factorizations < 0.25 * alone.factorizations, (fallback.factorizations, alone.factorizations)
    dense = H.to_dense()
    initial = scaled_projected_gradient(dense, b, lower, upper, np.clip(options["x0"], lower, upper))
    for result in (alone, fallback):
        assert scaled_projected_gradient(dense, b, lower, upper, result.x) <= 1e-9 * initial
