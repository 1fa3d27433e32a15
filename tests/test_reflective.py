"""The trust-region reflective least squares of solvers.reflective (the least sag's minimizer)
against scipy.optimize.least_squares(method="trf"), whose method it ports."""
import numpy as np
import pytest
import scipy.optimize

from sagfree.solvers.reflective import reflective_least_squares


class DenseLinearization:
    """J as a dense matrix; the Gauss-Newton direction by a dense regularized solve."""

    def __init__(self, jacobian):
        self.jacobian = jacobian

    def product(self, v):
        return self.jacobian @ v

    def transposed_product(self, u):
        return self.jacobian.T @ u

    def direction(self, d, damping, f):
        scaled = self.jacobian * d
        return np.linalg.solve(scaled.T @ scaled + np.diag(damping), -scaled.T @ f)


def rosenbrock(x):
    """Extended Rosenbrock residuals (minimum 0 at x = 1; bounds below keep it from there)."""
    return np.concatenate([10 * (x[1:] - x[:-1] ** 2), 1 - x[:-1]])


def rosenbrock_jacobian(x):
    n = x.size
    jacobian = np.zeros((2 * (n - 1), n))
    for i in range(n - 1):
        jacobian[i, i], jacobian[i, i + 1] = -20 * x[i], 10
        jacobian[n - 1 + i, i] = -1
    return jacobian


@pytest.mark.parametrize("upper", [2.0, 0.5])
def test_reflective_least_squares_reaches_scipys_minimum(upper):
    """From the same start, in the same box and scales: the same path as scipy's trf with LSMR (the
    same evaluations and ending) to the same minimum (an interior one with upper 2, one on the
    bounds with upper 0.5), every iterate inside the box."""
    x0 = np.array([-1.2, 1.0, -0.5, 0.8, 0.3, -0.9])
    lower, upper = np.full(x0.size, -2.0), np.full(x0.size, upper)
    x0 = np.clip(x0, lower, upper)
    visited = []

    def residuals(x):
        visited.append(x.copy())
        return rosenbrock(x)

    ours = reflective_least_squares(residuals, lambda x: DenseLinearization(rosenbrock_jacobian(x)),
                                    lambda x: np.linalg.norm(rosenbrock_jacobian(x), axis=0), x0, lower, upper,
                                    max_evaluations=500, rescale_every=10**9)
    scipys = scipy.optimize.least_squares(rosenbrock, x0, jac=rosenbrock_jacobian, bounds=(lower, upper), method="trf",
                                          x_scale=1 / np.linalg.norm(rosenbrock_jacobian(x0), axis=0), max_nfev=500,
                                          tr_solver="lsmr")
    assert ours.status == scipys.status > 0 and ours.evaluations == scipys.nfev
    assert ours.cost == pytest.approx(scipys.cost, rel=1e-6, abs=1e-12)
    np.testing.assert_allclose(ours.x, scipys.x, atol=1e-5)
    assert all(np.all((x >= lower) & (x <= upper)) for x in visited)


def test_a_variable_with_equal_bounds_stays_where_it_is(recwarn):
    """lower == upper (a parameter a user fixed): scipy refuses such bounds; here the variable
    keeps its value, the others are minimized, and nothing divides by its zero distance."""
    x0 = np.array([-1.2, 1.0, -0.5, 0.8, 0.3, -0.9])
    lower, upper = np.full(x0.size, -2.0), np.full(x0.size, 2.0)
    lower[2] = upper[2] = x0[2]
    ours = reflective_least_squares(rosenbrock, lambda x: DenseLinearization(rosenbrock_jacobian(x)),
                                    lambda x: np.linalg.norm(rosenbrock_jacobian(x), axis=0), x0, lower, upper,
                                    max_evaluations=500, rescale_every=10**9)
    assert ours.x[2] == x0[2] and ours.status > 0 and ours.cost < 0.5 * float(rosenbrock(x0) @ rosenbrock(x0))
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
