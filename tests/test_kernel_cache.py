"""numba's cache of a kernel follows the modules it calls into (sagfree.kernel_cache)."""
import os
import subprocess
import sys

from sagfree import kernel_cache


def test_a_cached_kernel_is_recompiled_when_a_kernel_it_calls_changes(tmp_path):
    # plain numba prints 2 on the second run: the caller's cache holds the old callee (checked by hand)
    package = tmp_path / "kerneldeps"
    package.mkdir()
    (package / "__init__.py").write_text("")
    callee = "import numba\n\n\n@numba.njit(cache=True)\ndef value():\n    return {}\n"
    (package / "inner.py").write_text(callee.format(1))
    (package / "outer.py").write_text("import numba\nfrom .inner import value\n\n\n@numba.njit(cache=True)\n"
                                      "def twice():\n    return 2 * value()\n")
    script = ("import sagfree.kernel_cache as k; k.register('kerneldeps'); from kerneldeps.outer import twice; "
              "print(twice())")
    env = {key: value for key, value in os.environ.items() if key != "NUMBA_CACHE_DIR"}

    def run() -> str:
        return subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                              check=True).stdout.strip()

    assert run() == "2"
    assert list((package / "__pycache__").glob("outer.twice-*.nbi"))  # cached, so the next run would load it
    (package / "inner.py").write_text(callee.format(5))
    assert run() == "10"


def test_the_gauss_newton_loop_depends_on_the_cholesky_factorization():
    modules = kernel_cache._closure("sagfree.solvers.gauss_newton")
    assert {"sagfree.linalg.cholesky", "sagfree.formulation.at_rest", "sagfree.solvers.mprgp"} <= modules
    assert "sagfree.solvers.alm" not in modules  # a package's __init__ counts only for names taken from it
    assert kernel_cache.dependency_digest("sagfree.linalg.eigen") != kernel_cache.dependency_digest("sagfree.linalg.band")
