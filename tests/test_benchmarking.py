"""Solver comparison on common ground: common strands, shifted geometric means, performance profiles."""
import numpy as np
import pytest

import sagfree
from sagfree.reports.benchmarking import (SHIFTS, comparison_rows, performance_profile,
                                          shifted_geometric_mean)
from sagfree.reports.study import run_study


def test_shifted_geometric_mean():
    assert shifted_geometric_mean([2.0, 8.0], 0.0) == pytest.approx(4.0)
    assert shifted_geometric_mean([0.0, 0.0], 1.0) == pytest.approx(0.0)
    assert shifted_geometric_mean([1.0, np.inf, 3.0], 1.0) == pytest.approx(np.sqrt(2 * 4) - 1)


def test_performance_profile_of_a_solver_against_itself_is_a_step_at_one():
    costs = np.array([0.5, 2.0, np.inf, 1.0])
    taus, rho = performance_profile({"a": costs, "b": costs.copy()})
    assert taus[0] == 1.0
    for values in rho.values():
        assert np.all(values == 0.75)   # solves 3 of 4, each at ratio 1
    taus, rho = performance_profile({"fast": np.array([1.0, 1.0]), "slow": np.array([3.0, np.inf])},
                                    taus=np.array([1.0, 2.9, 3.0, 100.0]))
    assert rho["fast"].tolist() == [1.0, 1.0, 1.0, 1.0]
    assert rho["slow"].tolist() == [0.0, 0.0, 0.5, 0.5]


def test_cross_solver_numbers_use_the_strands_every_solver_ran():
    """asc on 4 strands, penalty-gn limited to the first 2: the comparison counts 2 strands for both,
    and asc's mean is over those 2 only."""
    strands = sagfree.scenes.groom(4, 12, seed=6)
    study = run_study({"groom": strands}, ("asc", "penalty-gn"), ("element",), simulate=False, jobs=1,
                      limits={"penalty-gn": 2})
    rows = {row[2]: row for row in comparison_rows(study)}
    assert rows["asc"][3] == rows["penalty-gn"][3] == 2
    asc = study.case("groom", "asc", "element").results
    expected = shifted_geometric_mean([r.time for r in asc[:2]], SHIFTS["time"])
    assert rows["asc"][5] == pytest.approx(1e3 * expected)
    assert rows["asc"][10] == pytest.approx(1.0)


def test_time_split_cell_gives_shares_of_the_summed_time():
    from types import SimpleNamespace

    from sagfree.reports.benchmarking import time_split_cell

    results = [SimpleNamespace(time_split={"model": 1.0, "linear_algebra": 2.0, "other": 1.0}),
               SimpleNamespace(time_split={"model": 3.0, "linear_algebra": 0.0, "other": 1.0}),
               SimpleNamespace(time_split={})]
    assert time_split_cell(results) == "50 / 25 / 25"
    assert time_split_cell(results[2:]) == "-"
