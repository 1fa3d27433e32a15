"""Our solver at groom scale, its growth with strand size, and the preconditioner ablation.

    python benchmarks/bench_solver.py [--strands 1900] [--vertices 100] [--jobs N] [--ablation 20]

Prints three tables, all measured in this run:
1. the whole groom on all cores: wall time, mean time per strand, statuses and iteration counts,
   with the ratio to the predecessor paper's published 11.2 s for 1.9K strands x 100 vertices
   (measured there on a larger CPU; a reference figure, not a run on this machine);
2. time per strand against strand size (25 to 400 vertices) for the same physical strands, the
   time per vertex (flat = linear growth) and the factorizations per Gauss-Newton step (flat = the
   QPs do not need more active-set changes on longer strands);
3. the preconditioner ablation on a subset: active-set Cholesky vs Jacobi vs none, with CG
   iterations, expansions, factorizations, time and the ratio to the active-set Cholesky.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

import sagfree

PREDECESSOR_SECONDS = 11.2  # Takahashi & Batty (CGF), 1.9K strands x 100 vertices


def summary(results) -> dict:
    statuses = {s: sum(r.status == s for r in results) for s in ("converged", "infeasible",
                                                                 "max_iterations", "failed")}
    keys = ("outer", "gauss_newton", "cg", "expansion", "proportioning", "active_set", "interior", "factorizations",
            "factored_rows", "sqp", "tightened")
    counts = {k: np.array([r.iterations.get(k, 0) for r in results]) for k in keys}
    return dict(statuses=statuses, counts=counts, solve_time=np.array([r.time for r in results]))


def groom_table(strands: int, vertices: int, jobs: int) -> None:
    groom = sagfree.scenes.groom(strands, vertices, seed=0)
    sagfree.optimize(groom[:jobs], jobs=1)  # compile / load caches outside the timing
    start = time.perf_counter()
    results = sagfree.optimize(groom, jobs=jobs)
    wall = time.perf_counter() - start
    s = summary(results)
    print(f"1. groom {strands} strands x {vertices} vertices, {jobs} jobs")
    print(f"   wall time {wall:.2f} s   (predecessor, published: {PREDECESSOR_SECONDS} s; "
          f"ratio {wall / PREDECESSOR_SECONDS:.2f})")
    print(f"   mean solve time per strand {s['solve_time'].mean() * 1e3:.1f} ms "
          f"(max {s['solve_time'].max() * 1e3:.1f} ms); statuses {s['statuses']}")
    print(f"   {'count':16} {'mean':>9} {'max':>9}")
    for k, v in s["counts"].items():
        print(f"   {k:16} {v.mean():9.1f} {v.max():9d}")


def size_table(strands: int) -> None:
    print(f"\n2. time per strand against strand size ({strands} groom strands per size, one core)")
    print(f"   {'vertices':>8} {'ms/strand':>10} {'us/vertex':>10} {'GN steps':>9} {'factor./GN':>11} "
          f"{'converged':>10}")
    for n in (25, 50, 100, 200, 400):
        groom = sagfree.scenes.groom(strands, n, seed=0)
        sagfree.optimize(groom[:1], jobs=1)
        results = sagfree.optimize(groom, jobs=1)
        t = np.mean([r.time for r in results])
        steps = np.mean([r.iterations["gauss_newton"] for r in results])
        factorizations = np.mean([r.iterations["factorizations"] for r in results])
        ok = sum(r.status == "converged" for r in results)
        print(f"   {n:8d} {t * 1e3:10.1f} {t / n * 1e6:10.1f} {steps:9.1f} {factorizations / steps:11.1f} "
              f"{ok:>6}/{len(results)}")


def ablation_table(strands: int, vertices: int) -> None:
    groom = sagfree.scenes.groom(strands, vertices, seed=0)
    print(f"\n3. preconditioner ablation ({strands} strands x {vertices} vertices, one core)")
    print(f"   {'preconditioner':15} {'time s':>8} {'vs ASC':>7} {'CG':>9} {'expansion':>10} "
          f"{'proport.':>9} {'factor.':>8} {'converged':>10}")
    reference = None
    for name in ("cholesky", "jacobi", "none"):
        start = time.perf_counter()
        results = sagfree.optimize(groom, jobs=1, solver_options=dict(preconditioner=name))
        t = time.perf_counter() - start
        reference = reference or t
        s = summary(results)
        c = s["counts"]
        print(f"   {name:15} {t:8.2f} {t / reference:7.2f} {c['cg'].sum():9d} {c['expansion'].sum():10d} "
              f"{c['proportioning'].sum():9d} {c['factorizations'].sum():8d} "
              f"{s['statuses']['converged']:>6}/{len(results)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--strands", type=int, default=1900)
    parser.add_argument("--vertices", type=int, default=100)
    parser.add_argument("--jobs", type=int, default=os.cpu_count())
    parser.add_argument("--size-strands", type=int, default=20, help="strands per size in table 2")
    parser.add_argument("--ablation", type=int, default=10, help="strands in table 3")
    args = parser.parse_args()
    groom_table(args.strands, args.vertices, args.jobs)
    size_table(args.size_strands)
    ablation_table(args.ablation, args.vertices)


if __name__ == "__main__":
    main()
