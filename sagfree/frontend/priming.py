"""The first compile of a machine runs in a child process, so that no solving process carries it.

numba compiles sagfree's kernels on the first run of a machine (or after an edit of the package) and
keeps what LLVM needed for it in the compiling process: a process whose warm-up compiled them held
756 MB resident, one whose warm-up loaded them from the cache 259 MB. A batch forks its workers from
that process, and each worker's resident set counts the parent's pages again, so a first run broke
the 1 GB goal of a 10K-strand groom that later runs met (benchmarks/RESULTS.md). So before a
process's first warm-up, ``primed_in_child`` runs asc's warm-up (whose kernels every solver's
stabilization uses) and the solver's in a fresh interpreter, which compiles and stores the kernels
and then exits, and the process itself loads them from the cache. Two children compile at once,
each its own share of the kernels: the second asc's warm paths (frontend.warm.warm_paths: the
compiled outer loop, which nothing else calls) and the least sag's compiled loop, the first all the
rest, the forward check and, first of all, the least sag's model kernel with the static solve it
calls, which the second then loads (the longer child took 142 s on a 2-core machine, 150 s with
the least sag's model and the forward check in the second; benchmarks/RESULTS.md).
The first child's exit status decides: where the second fails, the process compiles what it
missed in place, as without priming. What tells that this machine's caches already hold them is a
stamp file under ``$SAGFREE_CACHE/primed``, named by a digest of what
the cached code depends on (``code_digest``: the package's sources, numba, Python, the host CPU and
the numba cache directory): a new digest (an upgrade, an edit, another install) primes again, once.
Once per code, not per solver and options: a child costs a few seconds even when it finds
everything compiled, and the kernels are shared (the model options change the C stencils, which
compile in a C compiler's process anyway); what a later solver or option adds compiles in place.
A stamp whose numba cache was deleted since only costs the old behaviour (the process compiles in
place). A child that fails leaves no stamp and costs nothing else: the process warms up in place.
Inside an application that embeds Python (a DCC whose ``sys.executable`` is the application itself)
no child is started: running that executable with ``-c`` could start the application.
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import pickle
import platform
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numba

from sagfree.formulation.compiled import cache_dir

#: set in the child's environment, so that its own warm-up compiles in place instead of priming again
CHILD = "SAGFREE_PRIMING_CHILD"
#: the package's source directories whose modules hold or feed compiled kernels
_SOURCE_PACKAGES = ("sagfree", "sagfree.formulation", "sagfree.solvers", "sagfree.baselines",
                    "sagfree.contract", "sagfree.frontend", "sagfree.linalg", "sagfree.scenes")
#: the names of a Python interpreter's executable (python, python3.11, pypy3, python.exe)
_INTERPRETER = re.compile(r"(python|pypy)[\d.]*(\.exe)?", re.IGNORECASE)
#: each child takes this process's import path and the arguments (pickled on stdin), then compiles its share
_CHILD_START = ("import pickle, sys; path, (solver, options, model) = pickle.loads(sys.stdin.buffer.read()); "
                "sys.path[:] = path; from sagfree.frontend import warm; ")
#: the first child: asc's warm-up but its warm paths, the forward check's, the solver's
_CHILD_CODE = _CHILD_START + ("warm.warm_up('asc', None, model, paths=False); warm.warm_check(model); "
                              "warm.warm_up(solver, options, model)")
#: the second child, at the same time: asc's warm paths (its compiled outer loop), the least sag's loop
_PATHS_CODE = _CHILD_START + "warm.warm_paths('asc', None, model)"


def primed_in_child(solver: str, solver_options: dict | None, problem_options: dict | None) -> bool:
    """Run asc's and ``solver``'s warm-up (``warm_up(solver, solver_options, problem_options)``) in
    two child interpreters at once (module docstring) unless the stamp says this machine has done
    so for this code; returns whether the first child ran and succeeded. Never raises."""
    if os.environ.get(CHILD) or not _INTERPRETER.fullmatch(Path(sys.executable or "").name):
        return False
    try:
        stamp = stamp_path()
        if stamp.exists():
            return False
        arguments = pickle.dumps((sys.path, (solver, solver_options, problem_options)))
        stamp.parent.mkdir(parents=True, exist_ok=True)
    except Exception:  # noqa: BLE001 - an unpicklable body, an unwritable cache: warm up in place
        return False
    # in the stamp's folder, with this process's import path: from a checkout's root, `python -c`
    # would put the root first and import its sagfree/ folder (the source tree, not the install)
    def child(code: str) -> int:
        return subprocess.run([sys.executable, "-c", code], input=arguments, env={**os.environ, CHILD: "1"},
                              cwd=stamp.parent, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              check=False).returncode

    try:
        with ThreadPoolExecutor(2) as pool:  # both children at once (module docstring)
            first, _ = pool.map(child, (_CHILD_CODE, _PATHS_CODE))
    except OSError:  # no interpreter to start: warm up in place
        return False
    if first != 0:
        return False
    try:
        stamp.write_text(f"{solver}\n")
    except OSError:
        pass
    return True


def stamp_path() -> Path:
    """The stamp file of this code on this machine."""
    return cache_dir() / "primed" / f"{code_digest()[:32]}.stamp"


def code_digest() -> str:
    """SHA-256 over the paths and contents of the package's source files (the directories of
    ``_SOURCE_PACKAGES``, read from disk, so the digest does not depend on what is imported), the
    versions of numba and Python, the host CPU and ``NUMBA_CACHE_DIR``: what makes numba's cache
    entries valid and where they are (kernel_cache stamps each kernel by the contents of the modules
    it imports; numba keeps them beside the sources, or under NUMBA_CACHE_DIR by their path)."""
    digest = hashlib.sha256()
    for part in (numba.__version__, sys.version, platform.machine(), _host_cpu(),
                 os.environ.get("NUMBA_CACHE_DIR", "")):
        digest.update(part.encode() + b"\0")
    for path in _source_files():  # by full path: numba caches each install's kernels apart
        digest.update(str(path).encode() + b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _source_files() -> list[Path]:
    files = set()
    for package in _SOURCE_PACKAGES:
        spec = importlib.util.find_spec(package)
        for directory in (spec.submodule_search_locations or []) if spec else []:
            files.update(Path(directory).resolve().glob("*.py"))
    return sorted(files)


def _host_cpu() -> str:
    try:
        from llvmlite import binding
        return binding.get_host_cpu_name() + binding.get_host_cpu_features().flatten()
    except Exception:  # noqa: BLE001 - an llvmlite without them: the machine name must do
        return ""
