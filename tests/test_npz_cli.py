"""Strands and parameters as .npz files, and `sagfree optimize` / `sagfree simulate` on them."""
import json

import numpy as np
import pytest

import sagfree
from sagfree.cli import main
from sagfree.scenes.npz import load_parameters, load_strands, save_parameters, save_strands


def mixed_strands():
    """Different vertex counts, a flipped strand with its angles, a pinned root, another material."""
    return [sagfree.scenes.horizontal(n=12), sagfree.scenes.flipped(n=9),
            sagfree.Strand(sagfree.scenes.curly(n=15).points, radius=4e-5, youngs_modulus=2e9,
                           shear_modulus=7e8, density=1100.0, root="pinned")]


def test_strands_round_trip(tmp_path):
    strands = mixed_strands()
    save_strands(tmp_path / "s.npz", strands)
    back = sagfree.load(tmp_path / "s.npz")
    assert len(back) == len(strands)
    for a, b in zip(strands, back):
        np.testing.assert_array_equal(a.points, b.points)
        np.testing.assert_array_equal(a.theta, b.theta)
        assert (a.radius, a.youngs_modulus, a.shear_modulus, a.density, a.root) == \
               (b.radius, b.youngs_modulus, b.shear_modulus, b.density, b.root)
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


def test_parameters_round_trip_keeps_failed_strands(tmp_path):
    strands = mixed_strands()
    results = sagfree.optimize(strands, jobs=1)
    results[1] = sagfree.contract.result.failed_result("asc", "poisoned on purpose")
    save_parameters(tmp_path / "p.npz", strands, results, "asc", {"stiffness": "element"})
    back = load_parameters(tmp_path / "p.npz")
    assert back.solver == "asc" and back.problem_options == {"stiffness": "element"}
    assert back.status == [r.status for r in results]
    assert back.message[1] == "poisoned on purpose" and back.p[1].size == 0
    back.check_matches(strands)
    for k in (0, 2):
        np.testing.assert_array_equal(back.p[k], results[k].p)
        for name, values in results[k].physical.items():  # named arrays per block, per strand
            np.testing.assert_array_equal(back.physical[name][k], values)
    assert back.physical["rest_length"][1].shape == (strands[1].n_vertices - 1,)
    assert np.isnan(back.physical["bend_modulus"][1]).all()
    summary = json.loads((tmp_path / "p.json").read_text())
    assert [s["status"] for s in summary["strands"]] == back.status
    assert summary["strands"][0]["residual_inf"] == results[0].residual_inf
    assert summary["strands"][1]["residual_inf"] is None  # NaN as null: strict JSON
    with pytest.raises(ValueError, match="strand 0 of the strands has 13 vertices"):
        back.check_matches([sagfree.scenes.horizontal(n=13), *strands[1:]])


def test_save_with_results_writes_the_parameters_simulate_reads(tmp_path, capsys):
    strands = sagfree.scenes.groom(2, 12, seed=8)
    results = sagfree.optimize(strands, jobs=1, stiffness="strand")
    params = sagfree.save(tmp_path / "groom.hair", strands, results, problem_options={"stiffness": "strand"})
    assert params == tmp_path / "groom.params.npz" and (tmp_path / "groom.params.json").exists()
    back = load_parameters(params)
    assert back.solver == "asc" and back.problem_options == {"stiffness": "strand"}
    assert main(["simulate", str(tmp_path / "groom.hair"), "--params", str(params), "--steps", "20", "--jobs", "1",
                 "--quiet"]) == 0
    assert "2/2 strands stay" in capsys.readouterr().out
    # an OBJ file stores no material: simulate takes the one the parameters were computed for (the
    # README's `sagfree simulate groom.obj --params groom.params.npz`), unless the command line gives one
    sagfree.save(tmp_path / "groom.obj", strands)
    assert main(["simulate", str(tmp_path / "groom.obj"), "--params", str(params), "--steps", "20", "--jobs", "1",
                 "--quiet", "--no-push"]) == 0
    assert "2/2 strands stay" in capsys.readouterr().out
    assert main(["simulate", str(tmp_path / "groom.obj"), "--params", str(params), "--quiet", "--radius", "1e-4"]) == 2
    assert "has radius 0.0001, the parameters were computed for" in capsys.readouterr().err


def test_bad_files_give_errors_that_name_file_and_strand(tmp_path):
    damaged = tmp_path / "damaged.npz"
    damaged.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(ValueError, match="damaged.npz: not a readable .npz strands file"):
        load_strands(damaged)
    points = np.zeros((4, 3))
    points[:, 0] = [0.0, 0.01, 0.01, 0.02]  # vertex 2 duplicates vertex 1
    np.savez(tmp_path / "dup.npz", points=np.r_[sagfree.scenes.horizontal(n=5).points, points],
             offsets=np.array([0, 5, 9]))
    with pytest.raises(ValueError, match=r"dup.npz: strand 1: edge 1 .* zero length"):
        load_strands(tmp_path / "dup.npz")
    np.savez(tmp_path / "offsets.npz", points=points, offsets=np.array([0, 7]))
    with pytest.raises(ValueError, match="'offsets' must be non-decreasing integers from 0 to 4"):
        load_strands(tmp_path / "offsets.npz")
    with pytest.raises(ValueError, match="not a strands file .* nor a built-in scene"):
        sagfree.load(tmp_path / "strands.txt")


def test_optimize_then_simulate_on_the_command_line(tmp_path, capsys):
    strands = [*sagfree.scenes.groom(2, 20, seed=3), sagfree.scenes.horizontal(n=15)]
    save_strands(tmp_path / "in.npz", strands)
    out = tmp_path / "params.npz"
    assert main(["optimize", str(tmp_path / "in.npz"), "-o", str(out), "--jobs", "1", "--quiet"]) == 0
    assert "converged 3" in capsys.readouterr().out
    assert main(["simulate", str(tmp_path / "in.npz"), "--params", str(out), "--jobs", "1", "--quiet",
                 "--steps", "50"]) == 0
    text = capsys.readouterr().out
    assert "3/3 strands stay within 1e-06" in text and "moves" not in text
    assert "3/3 hold after a push" in text and "falls after a push" not in text

    naive = tmp_path / "naive.npz"
    assert main(["optimize", str(tmp_path / "in.npz"), "-o", str(naive), "--solver", "naive", "--jobs", "1",
                 "--quiet"]) == 1
    capsys.readouterr()
    assert main(["simulate", str(tmp_path / "in.npz"), "--params", str(naive), "--jobs", "1", "--quiet",
                 "--steps", "50"]) == 1
    rows = [line for line in capsys.readouterr().out.splitlines() if "  moves" in line]
    assert len(rows) == 3


def test_simulate_reports_unreadable_input_with_exit_code_2(tmp_path, capsys):
    assert main(["simulate", "horizontal", "--params", str(tmp_path / "missing.npz")]) == 2
    assert "missing.npz: no such file" in capsys.readouterr().err


def test_bounds_on_the_command_line_reach_the_problem_and_the_simulation(tmp_path, capsys):
    """The box an infeasible strand's message asks to relax can be set where the user is: --bound.
    A tight rest-curvature budget and no stiffening leave the horizontal strand infeasible (exit 1,
    the message suggests --bound); relaxed, it converges, and simulate rebuilds the same boxes."""
    out = tmp_path / "tight.npz"
    assert main(["optimize", "horizontal", "-o", str(out), "--jobs", "1", "--quiet", "--bound",
                 "curvature_budget=0.01", "--bound", "bend_stiffness=1,1"]) == 1
    text = capsys.readouterr().out
    assert "infeasible" in text and "--bound" in text
    assert load_parameters(out).problem_options["bounds"] == {"curvature_budget": 0.01, "bend_stiffness": [1, 1]}
    relaxed = tmp_path / "relaxed.npz"
    assert main(["optimize", "horizontal", "-o", str(relaxed), "--jobs", "1", "--quiet", "--bound",
                 "bend_stiffness=1,1000"]) == 0
    assert main(["simulate", "horizontal", "--params", str(relaxed), "--jobs", "1", "--quiet", "--steps", "20"]) == 0
    capsys.readouterr()
    for bad in ("bend=1,2", "bend_stiffness=1", "curvature_budget=a", "rest_length"):
        with pytest.raises(SystemExit) as exit_:
            main(["optimize", "horizontal", "-o", str(tmp_path / "x.npz"), "--bound", bad])
        assert exit_.value.code == 2
        assert "--bound" in capsys.readouterr().err
