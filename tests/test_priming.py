"""A machine's first compile runs in child processes, once per code (frontend.priming)."""
import os
import pickle
import subprocess
import sys

import pytest

from sagfree.frontend import priming, warm


@pytest.fixture
def stamps(tmp_path, monkeypatch):
    """Stamps in a folder of their own (the child still uses this machine's model and numba caches)."""
    monkeypatch.setattr(priming, "cache_dir", lambda: tmp_path)
    return tmp_path


def _no_child(*args, **kwargs):
    raise AssertionError("a child process was started")


def test_a_missing_stamp_primes_once_in_a_child(stamps, monkeypatch):
    assert priming.primed_in_child("naive", None, {})
    assert priming.stamp_path().exists()
    monkeypatch.setattr(priming.subprocess, "run", _no_child)
    assert not priming.primed_in_child("naive", None, {})
    assert not priming.primed_in_child("asc", None, {"curvature": "2d-average"})  # once per code, not per options


def test_a_failed_child_leaves_no_stamp(stamps):
    assert not priming.primed_in_child("no-such-solver", None, {})  # the child's warm_up raises
    assert not priming.stamp_path().exists()


def test_the_child_itself_does_not_prime(stamps, monkeypatch):
    monkeypatch.setenv(priming.CHILD, "1")
    monkeypatch.setattr(priming.subprocess, "run", _no_child)
    assert not priming.primed_in_child("naive", None, {})


@pytest.mark.parametrize("executable", ["/opt/blender/blender", "/opt/hfs/bin/houdini", ""])
def test_no_child_where_the_executable_is_not_python(stamps, monkeypatch, executable):
    """An application embedding Python: its executable with -c could start the application."""
    monkeypatch.setattr(priming.sys, "executable", executable)
    monkeypatch.setattr(priming.subprocess, "run", _no_child)
    assert not priming.primed_in_child("naive", None, {})


def test_the_digest_follows_sources_and_numba_cache(tmp_path, monkeypatch):
    source = tmp_path / "kernels.py"
    source.write_text("x = 1\n")
    monkeypatch.setattr(priming, "_source_files", lambda: [source])
    before = priming.code_digest()
    assert priming.code_digest() == before
    source.write_text("x = 2\n")
    edited = priming.code_digest()
    assert edited != before
    moved = tmp_path / "elsewhere"  # another install of the same code: its own numba cache
    moved.mkdir()
    (moved / "kernels.py").write_text("x = 2\n")
    monkeypatch.setattr(priming, "_source_files", lambda: [moved / "kernels.py"])
    assert priming.code_digest() != edited
    monkeypatch.setattr(priming, "_source_files", lambda: [source])
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert priming.code_digest() != edited


def test_the_digest_reads_every_package_folder():
    names = {path.parent.name + "/" + path.name for path in priming._source_files()}
    for expected in ("solvers/gauss_newton.py", "formulation/at_rest.py", "linalg/band.py",
                     "frontend/floor_steps.py", "sagfree/kernel_cache.py"):
        assert any(name.endswith(expected) for name in names), expected


def test_a_process_first_warm_up_primes_before_it_warms_in_place(stamps, monkeypatch):
    """warm_up asks for the child before its own solve (which then loads), once for all solvers."""
    calls = []

    def child(command, **kwargs):
        calls.append((kwargs["env"].get(priming.CHILD), command[-1]))
        return priming.subprocess.CompletedProcess(command, 0)

    monkeypatch.setattr(priming.subprocess, "run", child)
    monkeypatch.setattr(warm, "_WARM", set())
    both = [("1", priming._CHILD_CODE), ("1", priming._PATHS_CODE)]
    assert warm.warm_up("naive") > 0 and sorted(calls) == sorted(both)
    assert priming.stamp_path().exists()
    assert warm.warm_up("naive") == 0.0 and warm.warm_up("asc", None, {"curvature": "2d-average"}) > 0
    assert sorted(calls) == sorted(both)


def test_the_second_child_runs_asc_warm_paths(stamps):
    """What the first child's success does not show: the second child's own code runs."""
    arguments = pickle.dumps((sys.path, ("naive", None, {})))
    done = subprocess.run([sys.executable, "-c", priming._PATHS_CODE], input=arguments, cwd=stamps,
                          env={**os.environ, priming.CHILD: "1"}, capture_output=True, check=False)
    assert done.returncode == 0, done.stderr.decode()[-2000:]


def test_the_two_children_share_the_whole_warm_up(monkeypatch):
    """The first child's warm-up without the warm paths and the second child's paths are, together,
    the solves of one whole warm-up: the split loses none."""
    solved = []
    monkeypatch.setattr(warm, "solve_stabilized", lambda function, problem, options: solved.append(options))
    monkeypatch.setattr(warm, "primed_in_child", lambda *args: False)
    monkeypatch.setattr(warm, "_WARM", set())
    warm.warm_up("asc")
    whole, solved[:] = list(solved), []
    monkeypatch.setattr(warm, "_WARM", set())
    warm.warm_up("asc", paths=False)
    first, solved[:] = list(solved), []
    warm.warm_paths("asc")
    assert first and solved and sorted(map(repr, first + solved)) == sorted(map(repr, whole))
