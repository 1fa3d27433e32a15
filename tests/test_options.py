"""One options vocabulary: the common names in every solver, meaning the same; bad options refused once,
before any strand is solved (solve, optimize, Dask, the CLI)."""
import inspect

import numpy as np
import pytest

import sagfree
import sagfree.frontend.batch as batch
from sagfree.cli import main
from sagfree.contract.options import COMMON
from sagfree.frontend.options import InvalidOption, parse_option


@pytest.mark.parametrize("name", list(sagfree.SOLVERS))
def test_every_solver_takes_the_common_options(name):
    options = sagfree.SOLVERS[name].options
    assert set(COMMON) <= set(options)
    assert list(inspect.signature(sagfree.SOLVERS[name].function).parameters)[0] == "problem"


@pytest.fixture
def no_batch(monkeypatch):
    """Fails the test if any strand reaches the batch runner."""
    def refuse(*args, **kwargs):
        raise AssertionError("a strand was solved before the options were checked")
    monkeypatch.setattr(batch, "map_strands", refuse)


@pytest.mark.parametrize("scheduler", [None, "local"])
def test_a_misspelled_option_is_refused_once_before_any_work(no_batch, scheduler):
    strands = sagfree.scenes.groom(5, 20, seed=0)
    with pytest.raises(InvalidOption) as error:
        sagfree.optimize(strands, solver="asc", solver_options={"max_iteration": 5}, scheduler=scheduler)
    message = str(error.value)
    assert "'max_iteration'" in message and "did you mean 'max_iterations'" in message
    assert "tol, kkt_tol, max_iterations, max_seconds, p_start" in message  # what it accepts


def test_misspelled_problem_options_and_bad_values_are_refused_before_any_work(no_batch):
    strands = sagfree.scenes.groom(3, 20, seed=0)
    with pytest.raises(InvalidOption, match="Problem has no option 'stifness'.*did you mean 'stiffness'"):
        sagfree.optimize(strands, stifness="strand")
    with pytest.raises(InvalidOption, match="'tol' must be a positive number"):
        sagfree.optimize(strands, solver="ipopt", solver_options={"tol": "1e-9"})
    with pytest.raises(InvalidOption, match="solver 'naive' has no option 'eps'"):
        sagfree.optimize(strands, solver="naive", solver_options={"eps": 1e-3})


def test_solve_refuses_an_option_of_another_solver():
    problem = sagfree.Problem(sagfree.scenes.horizontal(n=10))
    with pytest.raises(InvalidOption, match="solver 'ipopt' has no option 'gradient_tol'"):
        sagfree.solve(problem, "ipopt", gradient_tol=1e-6)


def test_common_options_mean_the_same_for_every_solver():
    """max_iterations and max_seconds stop each solver with status max_iterations; p_start is where
    each starts (naive returns it, so naive at asc's optimum is converged by the common rule)."""
    # strand stiffness: asc needs Gauss-Newton steps (a root-held element-mode strand starts at its optimum)
    problem = sagfree.Problem(sagfree.scenes.horizontal(n=12), stiffness="strand")
    best = sagfree.solve(problem, "asc")
    assert best.status == "converged"
    for name in ("asc", "ipopt", "osqp"):
        assert sagfree.solve(problem, name, max_iterations=1).status == "max_iterations", name
        assert sagfree.solve(problem, name, max_seconds=1e-9).status == "max_iterations", name
    at_optimum = sagfree.solve(problem, "naive", p_start=best.p)
    assert at_optimum.status == "converged" and np.array_equal(at_optimum.p, best.p)
    assert sagfree.solve(problem, "naive").status == "failed"  # p0 leaves gravity unbalanced
    assert sagfree.solve(problem, "naive", tol=2.0).status == "failed"  # |c| <= tol, but not optimal
    for name in ("asc", "ipopt", "osqp"):
        warm = sagfree.solve(problem, name, p_start=best.p)
        assert warm.status == "converged", name
        assert warm.objective == pytest.approx(best.objective, rel=1e-6), name
    assert sagfree.solve(problem, "osqp", p_start=best.p).iterations["sqp"] == 0  # already optimal


def test_parse_option_types_values_like_the_default():
    assert parse_option("tol=1e-9", "ipopt") == ("tol", 1e-9)
    assert parse_option("max_iterations=100", "asc") == ("max_iterations", 100)
    assert parse_option("max_seconds=inf", "osqp") == ("max_seconds", float("inf"))
    assert parse_option("preconditioner=jacobi", "asc") == ("preconditioner", "jacobi")
    with pytest.raises(InvalidOption, match="max_iterations.*non-negative integer"):
        parse_option("max_iterations=2.5", "asc")
    with pytest.raises(InvalidOption, match="NAME=VALUE"):
        parse_option("tol", "asc")


def test_cli_passes_options_and_refuses_misspelled_ones(tmp_path, capsys):
    out = tmp_path / "params.npz"
    code = main(["optimize", "horizontal", "-o", str(out), "--solver", "ipopt", "--option", "tol=1e-9",
                 "--quiet", "--jobs", "1"])
    assert code == 0 and out.exists(), capsys.readouterr()
    assert main(["optimize", "horizontal", "-o", str(out), "--option", "max_iteration=5", "--quiet"]) == 2
    error = capsys.readouterr().err
    assert "no option 'max_iteration'" in error and "did you mean 'max_iterations'" in error


def test_study_options_apply_to_one_solver_or_to_every_solver():
    from sagfree.cli import study_options

    options = study_options(["tol=1e-9", "osqp:max_seconds=20", "asc:gradient_tol=1e-7"], ["asc", "osqp"])
    assert options == {"asc": {"tol": 1e-9, "gradient_tol": 1e-7}, "osqp": {"tol": 1e-9, "max_seconds": 20.0}}
    with pytest.raises(InvalidOption, match="solver 'osqp' has no option 'gradient_tol'"):
        study_options(["gradient_tol=1e-7"], ["asc", "osqp"])  # not every solver takes it
    with pytest.raises(InvalidOption, match="'ipopt' is not a solver of this study"):
        study_options(["ipopt:tol=1e-9"], ["asc", "osqp"])


def test_readme_options_table_matches_the_defaults():
    """The README's table of common options states each solver's default as the code has it."""
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    header = next(line for line in readme.splitlines() if line.startswith("| option | meaning |"))
    solvers = [cell.strip() for cell in header.strip("|").split("|")[2:]]
    assert solvers == list(sagfree.SOLVERS)
    for name in COMMON:
        row = next(line for line in readme.splitlines() if line.startswith(f"| `{name}` |"))
        cells = [cell.strip() for cell in row.strip("|").replace("\\|", "").split("|")[2:]]
        for solver, cell in zip(solvers, cells):
            default = sagfree.SOLVERS[solver].options[name]
            if cell in ("-", "p0", "linear start"):
                assert name in ("max_iterations", "max_seconds", "p_start"), (name, solver)
                continue
            assert float(cell) == default, (name, solver, cell, default)
