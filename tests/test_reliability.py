"""Reliability: bad input is named, one bad strand never stops a batch, interrupted runs resume to the
same result, solver failures and hangs end as `failed` strands."""
import dataclasses
import subprocess
import sys
import time

import numpy as np
import pytest

import sagfree
from sagfree.cli import main
from sagfree.formulation.strand import InvalidStrand
from sagfree.frontend.batch import chunk_starts
from sagfree.scenes.npz import load_parameters, save_strands

LINE = np.column_stack([np.linspace(0, 0.1, 6), np.zeros(6), np.zeros(6)])


def with_row(k, value):
    points = LINE.copy()
    points[k] = value
    return points


@pytest.mark.parametrize("points, options, message", [
    (with_row(3, [np.nan, 0, 0]), {}, r"vertex 3 has a non-finite coordinate"),
    (LINE[:2], {}, r"at least 3 vertices, got 2"),
    (with_row(2, LINE[1]), {}, r"edge 1 \(vertices 1 and 2\) has zero length: duplicate vertex"),
    (with_row(3, LINE[1]), {}, r"vertex 2 turns by 180\.0 degrees"),
    (LINE, {"radius": 0.0}, r"radius must be positive"),
    (LINE, {"youngs_modulus": -1e9}, r"youngs_modulus must be positive"),
    (LINE, {"density": np.inf}, r"density must be positive and finite"),
    (LINE, {"theta": np.zeros(3)}, r"one angle per edge \(5\)"),
    (LINE, {"root": "glued"}, r"root must be one of"),
])
def test_bad_strands_are_named(points, options, message):
    with pytest.raises(ValueError, match=message):
        sagfree.Strand(points, **options)


@pytest.mark.parametrize("options, message", [
    ({"bounds": {"bend_stiffness": (2.0, 1.0)}}, r"block 'bend_stiffness', entry 0: lower bound above upper"),
    ({"bounds": {"bend_stiffness": (2.0, 3.0)}}, r"block 'bend_stiffness', entry 0: p0 outside its bounds"),
    ({"bounds": {"bend": (0.0, 1.0)}}, r"bounds given for 'bend', which is not an optimized block"),
    ({"curvature": "3d"}, r"unknown curvature variant '3d'"),
    ({"stiffness": "vertex"}, r"stiffness"),
])
def test_bad_problem_options_are_named(options, message):
    with pytest.raises(ValueError, match=message):
        sagfree.Problem(sagfree.scenes.horizontal(n=8), **options)


def test_truncated_npz_is_named(tmp_path):
    save_strands(tmp_path / "s.npz", sagfree.scenes.groom(2, 10, seed=1))
    data = (tmp_path / "s.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="cut.npz: not a readable .npz strands file"):
        sagfree.load(tmp_path / "cut.npz")


def poisoned_groom(tmp_path):
    """Six strands in a file; strand 3 has a NaN vertex."""
    strands = sagfree.scenes.groom(6, 14, seed=5)
    save_strands(tmp_path / "groom.npz", strands)
    arrays = dict(np.load(tmp_path / "groom.npz"))
    arrays["points"][3 * 14 + 7] = np.nan
    np.savez(tmp_path / "groom.npz", **arrays)
    return strands


def test_a_poisoned_strand_never_stops_the_others(tmp_path, capsys):
    clean = sagfree.optimize(poisoned_groom(tmp_path), jobs=1)
    loaded = sagfree.load(tmp_path / "groom.npz", keep_invalid=True)
    assert isinstance(loaded[3], InvalidStrand) and "strand 3: vertex 7 has a non-finite" in loaded[3].message
    out = tmp_path / "params.npz"
    assert main(["optimize", str(tmp_path / "groom.npz"), "-o", str(out), "--jobs", "2", "--quiet"]) == 1
    assert "strand 3: failed: invalid strand or options:" in capsys.readouterr().out
    params = load_parameters(out)
    assert params.status[3] == "failed" and "vertex 7 has a non-finite coordinate" in params.message[3]
    for k in (0, 1, 2, 4, 5):
        assert params.status[k] == "converged"
        np.testing.assert_array_equal(params.p[k], clean[k].p)
    assert main(["simulate", str(tmp_path / "groom.npz"), "--params", str(out), "--steps", "20", "--jobs", "2",
                 "--quiet"]) == 1
    text = capsys.readouterr().out
    assert "5/6 strands stay" in text and "vertex 7 has a non-finite" in text


def test_an_interrupted_run_resumes_to_the_same_result(tmp_path):
    sagfree.save(tmp_path / "g.npz", sagfree.scenes.groom(48, 60, seed=3))
    command = [sys.executable, "-m", "sagfree.cli", "optimize", str(tmp_path / "g.npz"), "--jobs", "1", "--quiet"]
    # cwd: from a clone's root, "python -m" would import the source tree instead of the installed package
    proc = subprocess.Popen([*command, "-o", str(tmp_path / "p.npz")], stdout=subprocess.DEVNULL, cwd=tmp_path)
    partial = tmp_path / "p.npz.partial"
    deadline = time.time() + 120
    while not list(partial.glob("chunk-*.pkl")) and time.time() < deadline and proc.poll() is None:
        time.sleep(0.005)
    proc.kill()
    proc.wait()
    assert not (tmp_path / "p.npz").exists(), "the run finished before it could be interrupted"
    written = len(list(partial.glob("chunk-*.pkl")))
    starts = chunk_starts(48, 1)  # 12, 9, 6, ... strands: a fast machine may finish two before the kill
    assert 1 <= written < len(starts) - 1
    resumed = subprocess.run([*command, "-o", str(tmp_path / "p.npz"), "--resume"], capture_output=True, text=True,
                             cwd=tmp_path)
    assert resumed.returncode == 0 and f"resuming: {starts[written]} of 48 strands" in resumed.stdout
    assert not partial.exists()
    subprocess.run([*command, "-o", str(tmp_path / "q.npz")], check=True, stdout=subprocess.DEVNULL, cwd=tmp_path)
    a, b = np.load(tmp_path / "p.npz"), np.load(tmp_path / "q.npz")
    for key in a.files:
        np.testing.assert_array_equal(a[key], b[key])


def test_resume_refuses_a_checkpoint_of_other_input(tmp_path, capsys):
    sagfree.save(tmp_path / "a.npz", sagfree.scenes.groom(2, 10, seed=1))
    (tmp_path / "p.npz.partial").mkdir()
    (tmp_path / "p.npz.partial" / "manifest.json").write_text('{"fingerprint": "other"}')
    assert main(["optimize", str(tmp_path / "a.npz"), "-o", str(tmp_path / "p.npz"), "--resume", "--quiet"]) == 2
    assert "from a run with other strands" in capsys.readouterr().err


def test_solver_errors_and_hangs_end_as_failed_strands(monkeypatch):
    strands = sagfree.scenes.groom(4, 10, seed=2)
    real = sagfree.SOLVERS["naive"].function

    def troubled(problem, **options):
        height = problem.strand.points[-1, 2]
        if height == strands[1].points[-1, 2]:
            raise np.linalg.LinAlgError("singular factorization")
        if height == strands[2].points[-1, 2]:
            time.sleep(120)  # a hang
        return real(problem, **options)

    monkeypatch.setitem(sagfree.SOLVERS, "naive", dataclasses.replace(sagfree.SOLVERS["naive"], function=troubled))
    start = time.perf_counter()
    results = sagfree.optimize(strands, solver="naive", jobs=2, strand_timeout=3.0)
    assert time.perf_counter() - start < 60
    assert results[1].status == "failed" and "LinAlgError: singular factorization" in results[1].message
    assert results[2].status == "failed" and "timed out" in results[2].message
    assert results[0].status == results[3].status == "failed"  # naive: gravity unbalanced, but solved
    assert "gravity residual" in results[0].message and "gravity residual" in results[3].message


def test_a_result_survives_pickling_with_and_without_contact_forces():
    """Worker processes send Results through a pipe; the zeros of contact_forces travel as a shape."""
    import pickle

    import numpy as np

    import sagfree

    result, other = sagfree.optimize(sagfree.scenes.groom(2, 20, seed=0), jobs=1)
    # without bodies: one read-only array of zeros per strand size, not a copy per Result
    assert result.contact_forces is other.contact_forces and not result.contact_forces.flags.writeable
    assert pickle.loads(pickle.dumps(other)).contact_forces is result.contact_forces
    for forces in (result.contact_forces, np.arange(60.0).reshape(20, 3)):
        result.contact_forces = forces
        copy = pickle.loads(pickle.dumps(result))
        assert copy.contact_forces.shape == forces.shape and np.array_equal(copy.contact_forces, forces)
        assert np.array_equal(copy.p, result.p) and copy.physical.keys() == result.physical.keys()
        assert copy.message == result.message and copy.iterations == result.iterations
        assert repr(copy).startswith("Result(solver='asc', status=")
