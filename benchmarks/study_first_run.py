"""What a machine's first run compiles, and how long: priming's two children, and numba's time per kernel.

    python benchmarks/study_first_run.py              # the two priming children, at once, as a first run
    python benchmarks/study_first_run.py --kernels    # in one process: each kernel's compile time

Each run uses a new, empty numba cache (a temporary NUMBA_CACHE_DIR), so everything compiles; the
C stencils come from $SAGFREE_CACHE as usual (compile them once first, or their compile is counted).
The default mode runs frontend.priming's two children at once, as ``primed_in_child`` does, and
prints each one's wall time: the first run waits for the longer one, so the two should take about
as long. ``--kernels`` compiles asc's warm-up, its warm paths and the forward check in this process
and prints, from numba's compile events, each kernel's compile time without its callees' (numba
optimizes and emits each kernel with its whole call tree linked in, so a kernel deep in many trees
costs in each of them: this is where a kernel's own share shows) and with them, and how many
specializations it got (more than one: a caller passed a literal, tests/test_kernel_calls.py).
"""
from __future__ import annotations

import argparse
import collections
import os
import pickle
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor

#: set in the process that compiles for ``--kernels`` (a new one, with an empty numba cache)
_COMPILING = "SAGFREE_STUDY_COMPILING"


def priming_children() -> None:
    from sagfree.frontend import priming
    arguments = pickle.dumps((sys.path, ("asc", None, {})))
    with tempfile.TemporaryDirectory() as cache:
        environment = {**os.environ, priming.CHILD: "1", "NUMBA_CACHE_DIR": cache}

        def child(code: str) -> tuple[int, float]:
            start = time.perf_counter()
            run = subprocess.run([sys.executable, "-c", code], input=arguments, env=environment, cwd=cache,
                                 capture_output=True, check=False)
            return run.returncode, time.perf_counter() - start

        start = time.perf_counter()
        with ThreadPoolExecutor(2) as pool:
            first, second = pool.map(child, (priming._CHILD_CODE, priming._PATHS_CODE))
    print(f"first child (asc's warm-up, forward check): exit {first[0]}, {first[1]:.1f} s")
    print(f"second child (warm paths, the least sag's loop): exit {second[0]}, {second[1]:.1f} s")
    print(f"first run's wait: {time.perf_counter() - start:.1f} s")


def kernel_times(rows: int) -> None:
    from numba.core import event
    with event.install_recorder("numba:compile") as recorder:
        start = time.perf_counter()
        from sagfree.frontend import warm
        warm.warm_up("asc", None, {}, paths=False)
        warm.warm_paths("asc", None, {})
        warm.warm_check({})
        total = time.perf_counter() - start
    own, inclusive = collections.Counter(), collections.Counter()
    signatures = collections.defaultdict(set)
    open_compiles = []  # [name, start, seconds of nested compiles]
    for stamp, compile_event in recorder.buffer:
        function = compile_event.data["dispatcher"].py_func
        name = f"{function.__module__}.{function.__qualname__}"
        if compile_event.is_start:
            open_compiles.append([name, stamp, 0.0])
            signatures[name].add(str(compile_event.data["args"]))
            continue
        name, began, nested = open_compiles.pop()
        seconds = stamp - began
        own[name] += seconds - nested
        inclusive[name] += seconds
        if open_compiles:
            open_compiles[-1][2] += seconds
    print(f"warm-up, warm paths and forward check compiled in {total:.1f} s, "
          f"numba's compiles {sum(own.values()):.1f} s")
    print(f"{'own s':>7} {'with callees':>12} {'versions':>8}  kernel")
    for name, seconds in own.most_common(rows):
        print(f"{seconds:7.1f} {inclusive[name]:12.1f} {len(signatures[name]):8d}  {name}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kernels", action="store_true", help="each kernel's compile time, in this process")
    parser.add_argument("--rows", type=int, default=25)
    args = parser.parse_args()
    if not args.kernels:
        priming_children()
        return
    if os.environ.get(_COMPILING) == "1":
        kernel_times(args.rows)
        return
    with tempfile.TemporaryDirectory() as cache:  # numba reads its cache folder at import: a new process
        environment = {**os.environ, "NUMBA_CACHE_DIR": cache, "SAGFREE_PRIMING_CHILD": "1", _COMPILING: "1"}
        subprocess.run([sys.executable, __file__, "--kernels", "--rows", str(args.rows)], env=environment,
                       check=True)


if __name__ == "__main__":
    main()
