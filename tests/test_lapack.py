"""LAPACK's band LU called from compiled code (linalg.lapack) is scipy.linalg.lapack's, bit for bit."""
import numpy as np
import scipy.linalg.lapack

from sagfree.linalg import lapack


def _band_system(rng, n, kl, ku):
    """A random n x n matrix with kl sub- and ku superdiagonals, dense and in LAPACK's band storage."""
    dense = sum(np.diag(rng.standard_normal(n - abs(k)), k) for k in range(-kl, ku + 1))
    band = np.zeros((2 * kl + ku + 1, n))
    for j in range(n):
        for i in range(max(0, j - ku), min(n, j + kl + 1)):
            band[kl + ku + i - j, j] = dense[i, j]
    return dense, band


def test_band_lu_and_solve_are_scipys_dgbtrf_and_dgbtrs(rng):
    for n, kl, ku in ((1, 0, 0), (7, 2, 1), (60, 5, 5)):
        dense, band = _band_system(rng, n, kl, ku)
        factors, pivots, info = scipy.linalg.lapack.dgbtrf(band.copy(), kl, ku)
        columns = np.ascontiguousarray(band.T)  # the module's layout: LAPACK's columns as rows
        ours = np.empty(n, dtype=np.int32)
        assert lapack.band_lu(lapack.DGBTRF, columns, kl, ku, ours) == info == 0
        assert np.array_equal(columns.T, factors) and np.array_equal(ours - 1, pivots)  # f2py's are 0-based
        rhs = rng.standard_normal(n)
        expected, _ = scipy.linalg.lapack.dgbtrs(factors, kl, ku, rhs.copy(), pivots)
        solution = rhs.copy()
        assert lapack.band_lu_solve(lapack.DGBTRS, columns, kl, ku, ours, solution) == 0
        assert np.array_equal(solution, expected)
        assert np.abs(dense @ solution - rhs).max() <= 1e-10 * np.abs(rhs).max()


def test_singular_band_reports_its_zero_pivot(rng):
    dense, band = _band_system(rng, 10, 2, 2)
    band[:, 4] = 0.0  # column 4 of the matrix is zero
    columns = np.ascontiguousarray(band.T)
    info = lapack.band_lu(lapack.DGBTRF, columns, 2, 2, np.empty(10, dtype=np.int32))
    assert info == scipy.linalg.lapack.dgbtrf(band.copy(), 2, 2)[2] == 5  # 1-based: column 5


def test_square_column_solve_solves_the_chosen_columns_or_says_none(rng):
    import scipy.sparse as sp

    from sagfree.linalg.square import square_column_solve

    dense, _ = _band_system(rng, 30, 3, 4)
    wide = np.zeros((30, 45))
    kept = np.zeros(45, dtype=bool)
    kept[::3] = kept[1::3] = True  # 30 of 45 columns, in order: still a band
    wide[:, kept] = dense
    wide[:, ~kept] = rng.standard_normal((30, 15))
    rhs = rng.standard_normal(30)
    x = square_column_solve(sp.csc_matrix(wide), kept, rhs)
    assert np.all(x[~kept] == 0.0) and np.abs(wide @ x - rhs).max() <= 1e-10 * np.abs(rhs).max()
    assert square_column_solve(sp.csc_matrix(wide), kept & (np.arange(45) > 0), rhs) is None  # 29 columns
    singular = wide.copy()
    singular[:, np.flatnonzero(kept)[7]] = 0.0
    assert square_column_solve(sp.csc_matrix(singular), kept, rhs) is None
