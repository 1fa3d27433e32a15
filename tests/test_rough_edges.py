"""The rough edges a new user hit on a fresh clone (issue 22), one test each: Ctrl-C, file
permissions, a far-off point, command-line values, empty files, refused saves, bounds, cyHair
thickness and material options, abandoned worker processes, geometry against parameters."""
import gc
import multiprocessing
import os
import signal
import stat
import struct
import subprocess
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

import sagfree
from sagfree.cli import main
from sagfree.frontend.batch import _kill_workers, map_strands
from sagfree.scenes.npz import load_parameters

HORIZONTAL = sagfree.scenes.horizontal(n=10)


def sagfree_command(*args, cwd, **kwargs):
    return subprocess.Popen([sys.executable, "-m", "sagfree.cli", *args], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kwargs)


def test_ctrl_c_stops_cleanly_keeps_the_solved_strands_and_prints_the_resume_command(tmp_path):
    # enough strands that the batch is far from done when its first chunk is on disk
    sagfree.save(tmp_path / "g.npz", sagfree.scenes.groom(800, 40, seed=2))
    # a terminal's Ctrl-C signals the whole foreground process group: the parent and its workers. The
    # command gets Ctrl-C's default action even where this test runs with SIGINT ignored (a
    # background job of a non-interactive shell), as a terminal's foreground command has it
    run = sagfree_command("optimize", "g.npz", "-o", "out.npz", "--jobs", "2", cwd=tmp_path, start_new_session=True,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    partial, deadline = tmp_path / "out.npz.partial", time.time() + 120
    while time.time() < deadline and not (partial.exists() and any(partial.glob("chunk-*.pkl"))):
        time.sleep(0.05)
    os.killpg(run.pid, signal.SIGINT)
    out, err = run.communicate(timeout=60)
    assert run.returncode == 130, out + err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert "sagfree optimize g.npz -o out.npz --jobs 2 --resume" in err
    assert any(partial.glob("chunk-*.pkl")) and not (tmp_path / "out.npz").exists()
    time.sleep(0.5)
    assert subprocess.run(["pgrep", "-f", "-g", str(run.pid)], capture_output=True).stdout == b""  # no orphan workers
    resumed = sagfree_command("optimize", "g.npz", "-o", "out.npz", "--jobs", "2", "--resume", "--quiet", cwd=tmp_path)
    out, err = resumed.communicate(timeout=300)
    assert resumed.returncode == 0 and "resuming:" in out and "converged 800" in out, out + err


@pytest.mark.parametrize("mask", [0o022, 0o077])
def test_written_files_follow_the_umask(tmp_path, mask):
    strands = [HORIZONTAL]
    results = sagfree.optimize(strands, jobs=1)
    old = os.umask(mask)
    try:
        sagfree.save(tmp_path / "g.obj", strands, results)
        sagfree.save(tmp_path / "g.hair", strands)
        sagfree.save(tmp_path / "g.npz", strands)
    finally:
        os.umask(old)
    for name in ("g.obj", "g.params.npz", "g.params.json", "g.hair", "g.npz"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o666 & ~mask, name


@pytest.mark.parametrize("value, vertex", [(1e30, 4), (1e200, 4), (1e30, 0), (1e30, 9)])
def test_a_far_off_point_is_named_by_its_vertex(value, vertex):
    points = HORIZONTAL.points.copy()
    points[vertex] = value
    with pytest.raises(ValueError, match=rf"^vertex {vertex} at \[{value:g}, {value:g}, {value:g}\]".replace("+", r"\+")):
        sagfree.Strand(points)


@pytest.mark.parametrize("argv, message", [
    (["optimize", "horizontal", "-o", "x.npz", "--jobs", "0"], "argument --jobs: must be at least 1, got 0"),
    (["optimize", "horizontal", "-o", "x.npz", "--jobs", "-3"], "argument --jobs: must be at least 1, got -3"),
    (["optimize", "horizontal", "-o", "x.csv"], "'x.csv': the output must end in .npz"),
    (["simulate", "horizontal", "--params", "x.npz", "--dt", "-1"], "argument --dt: must be positive"),
    (["simulate", "horizontal", "--params", "x.npz", "--steps", "0"], "argument --steps: must be at least 1"),
    (["simulate", "horizontal", "--params", "x.npz", "--damping", "nan"], "argument --damping: must be non-negative"),
])
def test_bad_command_line_values_are_usage_errors(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2 and message in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_an_empty_file_is_an_error_not_zero_strands(tmp_path, capsys):
    (tmp_path / "empty.obj").write_text("# nothing\n")
    assert main(["optimize", str(tmp_path / "empty.obj"), "-o", str(tmp_path / "p.npz"), "--quiet"]) == 2
    assert "empty.obj: the file holds no strands (no 'l' polyline elements)" in capsys.readouterr().err
    assert not (tmp_path / "p.npz").exists()


def test_a_refused_save_writes_nothing(tmp_path):
    strands = sagfree.scenes.groom(3, 10, seed=0)
    results = sagfree.optimize(strands, jobs=1)
    with pytest.raises(ValueError, match="2 strands but 3 results; nothing written"):
        sagfree.save(tmp_path / "g.obj", strands[:2], results)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("bounds, message", [
    ({"bend_stiffness": (np.ones(3), np.full(3, 100.0))},
     r"lower bound of 'bend_stiffness' must be a scalar or one value per entry of the block \(8 entries here\), "
     r"got an array of shape \(3,\)"),
    ({"rest_length": (-0.1, np.full(2, 0.1))}, r"upper bound of 'rest_length' .* \(9 entries here\)"),
    ({"bend_stiffness": 5.0}, r"bounds of 'bend_stiffness' must be a pair \(lower, upper\), got 5.0"),
    ({"curvature_budget": -1}, r"curvature_budget must be a non-negative number of radians"),
    ({"twist_budget": "wide"}, r"twist_budget must be a number of radians, got 'wide'"),
])
def test_bad_bounds_name_their_block(bounds, message):
    with pytest.raises(ValueError, match=message):
        sagfree.Problem(HORIZONTAL, bounds=bounds)


@pytest.mark.parametrize("bound, message", [("curvature_budget=-1", "curvature_budget must be a non-negative"),
                                             ("bend_stiffness=5,1", "lower bound 5 above upper bound 1")])
def test_bad_bounds_on_the_command_line_stop_before_any_strand(bound, message, tmp_path, capsys):
    assert main(["optimize", "horizontal", "-o", str(tmp_path / "p.npz"), "--bound", bound, "--quiet"]) == 2
    assert message in capsys.readouterr().err and not (tmp_path / "p.npz").exists()


def test_bad_weights_name_their_block():
    with pytest.raises(ValueError, match=r"weight of 'rest_twist' must be a scalar or one value per entry"):
        sagfree.Problem(HORIZONTAL, weights={"rest_twist": np.ones(2)})


def thick_hair(tmp_path, thickness: float):
    """A cyHair file of 3 groom strands whose thickness array says ``thickness`` (cm) everywhere."""
    strands = sagfree.scenes.groom(3, 20, seed=0)
    sagfree.save(tmp_path / "g.hair", strands)
    data = bytearray((tmp_path / "g.hair").read_bytes())
    points = sum(s.n_vertices for s in strands)
    data[len(data) - 4 * points:] = np.full(points, thickness, "<f4").tobytes()
    (tmp_path / "thick.hair").write_bytes(bytes(data))
    return tmp_path / "thick.hair"


def test_an_implausible_cyhair_thickness_is_named_and_the_command_line_sets_the_radius(tmp_path, capsys):
    path = thick_hair(tmp_path, 1.0)  # a rendering width of 1 in a cm file: r = 5 mm on 8 cm hair
    with pytest.warns(UserWarning, match=r"thick.hair: the thickness gives 3 strand\(s\) an implausible radius "
                      r"\(strand 0: thickness 1 -> radius 0.005 m, .*--radius M"):
        sagfree.load(path, keep_invalid=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the radius given: nothing implausible left
        strands = sagfree.load(path, radius=4e-5)
    assert all(s.radius == 4e-5 for s in strands)
    out = tmp_path / "p.npz"
    assert main(["optimize", str(path), "-o", str(out), "--radius", "4e-5", "--youngs-modulus", "3e9",
                 "--density", "1100", "--jobs", "1", "--quiet"]) == 0
    params = load_parameters(out)
    assert np.allclose(params.material["radius"], 4e-5) and np.allclose(params.material["youngs_modulus"], 3e9)
    assert np.allclose(params.material["density"], 1100) and np.allclose(params.material["shear_modulus"], 4e8)
    capsys.readouterr()
    assert main(["optimize", "horizontal", "-o", str(out), "--radius", "1e-4"]) == 2  # a scene has its own
    assert "a built-in scene has its own units and material" in capsys.readouterr().err


def test_a_batch_joins_its_worker_processes():
    """Workers abandoned at exit (shutdown without waiting) raced the pool's manager thread:
    "Exception ignored ... OSError: [Errno 9] Bad file descriptor" after `sagfree simulate`."""
    assert map_strands(abs, [(-k,) for k in range(8)], jobs=2) == list(range(8))
    assert multiprocessing.active_children() == []


def _frozen_objects(_):
    return gc.get_freeze_count()


def test_a_batch_keeps_this_processs_heap_from_the_collector_and_leaves_it_as_it_was():
    """While a batch runs, the objects this process held before are frozen out of the cyclic
    garbage collector (its full collections scanned them all as the Results piled up); after it,
    the collector is as it was, also when the caller had frozen objects itself."""
    assert gc.get_freeze_count() == 0
    assert all(count > 0 for count in map_strands(_frozen_objects, [(k,) for k in range(3)], jobs=1))
    assert map_strands(abs, [(-k,) for k in range(8)], jobs=2) == list(range(8))
    assert gc.get_freeze_count() == 0
    gc.freeze()
    try:
        frozen = gc.get_freeze_count()
        assert map_strands(_frozen_objects, [(k,) for k in range(3)], jobs=1) == [frozen] * 3
        assert gc.get_freeze_count() == frozen
    finally:
        gc.unfreeze()


def test_killed_workers_release_a_manager_thread_waiting_for_a_half_sent_result():
    """A worker killed while sending a chunk's results left a partial message on the result pipe;
    the pool's manager thread waited for the rest forever, and so did interpreter exit (a Ctrl-C
    that printed the resume command and never returned). Here the partial message is written by hand."""
    pool = ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context("fork"))
    assert pool.submit(abs, -1).result() == 1
    manager, writer = pool._executor_manager_thread, pool._result_queue._writer
    try:
        os.write(writer.fileno(), struct.pack("!i", 1000) + b"partial")  # a header for 1000 bytes, 7 sent
        time.sleep(0.2)
        assert manager.is_alive()  # blocked in recv()
        _kill_workers(pool)
        pool.shutdown(wait=False, cancel_futures=True)
        manager.join(timeout=10)
        assert not manager.is_alive()
    finally:
        writer.close()  # unblocks the thread if the assertion failed, so that pytest can exit


def test_simulate_says_how_far_the_geometry_is_from_the_parameters(tmp_path, capsys):
    strands = sagfree.scenes.groom(2, 12, seed=8)
    results = sagfree.optimize(strands, jobs=1)
    sagfree.save(tmp_path / "g.npz", strands, results)  # parameters of the float64 geometry
    sagfree.save(tmp_path / "g.hair", strands)          # the same groom in float32
    params = str(tmp_path / "g.params.npz")
    assert main(["simulate", str(tmp_path / "g.hair"), "--params", params, "--no-push", "--steps", "5",
                 "--jobs", "1", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "note: strand 0 of" in err and "from where it was when the parameters were computed; within 1e-06 L" in err
    moved = [s.replaced(points=s.points + np.array([0, 0, 1e-4])[None] * np.linspace(0, 1, s.n_vertices)[:, None])
             for s in strands]
    sagfree.save(tmp_path / "moved.npz", moved)
    assert main(["simulate", str(tmp_path / "moved.npz"), "--params", params, "--quiet"]) == 2
    assert "strand 0 of" in capsys.readouterr().err
