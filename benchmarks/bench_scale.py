"""Scaling study: total time against the number of strands, time per strand against strand size, peak
memory, and the ratio to Ipopt and OSQP-SQP measured in the same run.

    python benchmarks/bench_scale.py [--strands 100,1000,10000] [--vertices 25,100,400,1000,2000]
                                     [--size-strands 10] [--baseline-vertices 100]
                                     [--baseline-strands 5] [--head-strands 200] [--jobs N]

1. groom(N, 100 vertices) for each N, all cores: wall time, per-strand time, peak resident memory of
   the whole process tree (this process and its workers, sampled every 50 ms from /proc), statuses
   (the 10K row is the memory goal: at most 1 GB);
2. groom(size_strands, n) for each n, all cores: wall time per strand and per vertex (flat = linear);
3. the first ``baseline_strands`` strands of groom(., n) for each baseline size, one process each:
   asc, ipopt (its NLP compiled to C, formulation.compiled; compiling is setup, not time) and
   osqp per strand, and the baselines' time over ours (in this run): over all strands, and over the
   strands both converged (the common set of optimization benchmarks);
4. head_groom(head_strands, 100 vertices) lying on the head (contact supports, the outer loop), all
   cores: wall time per strand (wall x jobs / strands), mean Result.time, outer iterations and
   Gauss-Newton steps (0 strands: skipped).
"""
from __future__ import annotations

import argparse
import os
import threading
import time
from pathlib import Path

import numpy as np

import sagfree
from sagfree.contract.result import status_summary
from sagfree.scenes.head import HEAD, head_groom


class PeakMemory:
    """Peak of the summed resident set size (MB) of this process and all its descendants."""

    def __init__(self, interval: float = 0.05):
        self.interval, self.peak, self._stop = interval, 0.0, threading.Event()

    @staticmethod
    def _tree_rss() -> float:
        pids, total, frontier = set(), 0.0, [os.getpid()]
        while frontier:
            pid = frontier.pop()
            if pid in pids:
                continue
            pids.add(pid)
            try:
                for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                    if line.startswith("VmRSS:"):
                        total += float(line.split()[1]) / 1024.0
                children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
                frontier.extend(int(c) for c in children)
            except OSError:
                continue
        return total

    def _run(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, self._tree_rss())
            self._stop.wait(self.interval)

    def __enter__(self):
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self._tree_rss())


def strands_table(counts, jobs: int) -> None:
    print(f"1. groom(N, 100 vertices), {jobs} jobs")
    print(f"   {'strands':>8} {'wall s':>8} {'ms/strand':>10} {'strands/s':>10} {'peak MB':>8}  statuses")
    for n in counts:
        groom = sagfree.scenes.groom(n, 100, seed=0)
        with PeakMemory() as memory:
            start = time.perf_counter()
            results = sagfree.optimize(groom, jobs=jobs)
            wall = time.perf_counter() - start
        statuses = {s: sum(r.status == s for r in results) for s in ("converged", "max_iterations", "failed",
                                                                      "infeasible")}
        print(f"   {n:8d} {wall:8.2f} {1e3 * np.mean([r.time for r in results]):10.1f} {n / wall:10.1f} "
              f"{memory.peak:8.0f}  {', '.join(f'{k} {v}' for k, v in statuses.items() if v)}", flush=True)


def sizes_table(sizes, count: int, jobs: int) -> None:
    print(f"\n2. groom({count}, n vertices), {jobs} jobs")
    print(f"   {'vertices':>8} {'wall s':>8} {'ms/strand':>10} {'us/vertex':>10}  statuses")
    for n in sizes:
        start = time.perf_counter()
        results = sagfree.optimize(sagfree.scenes.groom(count, n, seed=0), jobs=jobs)
        wall = time.perf_counter() - start
        per_strand = np.mean([r.time for r in results])
        converged = sum(r.status == "converged" for r in results)
        print(f"   {n:8d} {wall:8.2f} {1e3 * per_strand:10.1f} "
              f"{1e6 * per_strand / n:10.1f}  converged {converged}/{count}", flush=True)


def baselines_table(sizes, count: int) -> None:
    print(f"\n3. baselines on the first {count} strands, one process; ratio = time / time of asc, over all "
          "strands and over those both converged (a baseline stopped at its iteration limit weighs on the "
          "first)")
    print(f"   {'vertices':>8} {'solver':>8} {'ms/strand':>10} {'ratio':>8} {'common':>8} {'strands':>8}  statuses")
    for n in sizes:
        strands = sagfree.scenes.groom(count, n, seed=0)
        reference = None
        for solver in ("asc", "ipopt", "osqp"):
            sagfree.optimize(strands[:1], solver=solver, jobs=1)  # compile / load its model first
            results = sagfree.optimize(strands, solver=solver, jobs=1)
            times = np.array([r.time for r in results])
            converged = np.array([r.status == "converged" for r in results])
            reference = reference or (times, converged)
            common = converged & reference[1]
            ratio = times.mean() / reference[0].mean()
            on_common = times[common].sum() / reference[0][common].sum() if common.any() else float("nan")
            statuses = {s: sum(r.status == s for r in results) for s in ("converged", "max_iterations", "failed",
                                                                          "infeasible")}
            print(f"   {n:8d} {solver:>8} {1e3 * times.mean():10.1f} {ratio:8.1f} {on_common:8.1f} "
                  f"{int(common.sum()):8d}  {', '.join(f'{k} {v}' for k, v in statuses.items() if v)}", flush=True)


def head_table(count: int, jobs: int) -> None:
    """Long hair lying on a head (scenes.head): every strand rests on the sphere, so contact supports
    join the unknowns and each solve runs the augmented Lagrangian's outer loop."""
    print(f"\n4. head_groom({count}, 100 vertices) lying on the head, {jobs} jobs")
    print(f"   {'strands':>8} {'wall s':>8} {'ms/strand':>10} {'solve ms':>9} {'outer':>6} {'GN':>5}  statuses, stable")
    strands = head_groom(count, 100, seed=0)
    sagfree.optimize(strands[:1], jobs=1, bodies=[HEAD])  # the contact kernels, outside the timing
    start = time.perf_counter()
    results = sagfree.optimize(strands, jobs=jobs, bodies=[HEAD])
    wall = time.perf_counter() - start
    outer, steps = (np.mean([r.iterations.get(k, 0) for r in results]) for k in ("outer", "gauss_newton"))
    print(f"   {count:8d} {wall:8.2f} {1e3 * wall * jobs / count:10.1f} {1e3 * np.mean([r.time for r in results]):9.1f} "
          f"{outer:6.1f} {steps:5.1f}  {status_summary(results)}, "
          f"stable {sum(r.stable for r in results)}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--strands", default="100,1000,10000")
    parser.add_argument("--vertices", default="25,100,400,1000,2000")
    parser.add_argument("--size-strands", type=int, default=10)
    parser.add_argument("--baseline-vertices", default="100")
    parser.add_argument("--baseline-strands", type=int, default=5)
    parser.add_argument("--head-strands", type=int, default=200)
    parser.add_argument("--jobs", type=int, default=os.cpu_count())
    args = parser.parse_args()
    sagfree.optimize(sagfree.scenes.groom(2, 25, seed=0), jobs=1)  # compile / load the model first
    strands_table([int(x) for x in args.strands.split(",")], args.jobs)
    sizes = [int(x) for x in args.vertices.split(",")]
    sizes_table(sizes, args.size_strands, args.jobs)
    baselines_table([int(x) for x in args.baseline_vertices.split(",")], args.baseline_strands)
    if args.head_strands:
        head_table(args.head_strands, args.jobs)


if __name__ == "__main__":
    main()
