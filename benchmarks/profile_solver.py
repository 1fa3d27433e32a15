"""Where a groom strand's solve spends its time, and what batching costs on top.

    python benchmarks/profile_solver.py [--strands 100] [--vertices 100] [--jobs N]

1. One process, the strands one after another, with timers around the parts of ``asc`` (each
   part's time includes what it calls, so nested rows overlap: the SQP steps contain their
   residuals, the Result its residual): share of the total;
2. the same batch on ``jobs`` worker processes: wall time against the one-process time divided by
   the jobs; the difference is process start-up, serialization and imbalance.
"""
from __future__ import annotations

import argparse
import os
import time

import sagfree
import sagfree.frontend.stabilize as stabilize
import sagfree.solvers.alm as alm
from sagfree.formulation.problem import Problem

PARTS = [
    (alm, "linear_start", "linear start (one band LU)"),
    (alm, "solve_box_qp", "MPRGP QPs with the active-set Cholesky"),
    (Problem, "strand_jacobian", "Jacobian dc/dp (compiled stencils + assembly)"),
    (alm, "gram", "Gauss-Newton Hessian J^T J (banded)"),
    (Problem, "residual", "residual c(p)"),
    (alm, "make_result", "Result: summaries and stability"),
    (alm, "kkt_optimality", "KKT confirmation (refined SQP LU or band LU)"),
    (alm, "_sqp_step", "SQP steps where the constraint stalls (band LU)"),
    (alm, "_newton_sqp", "Newton-SQP steps (exact Hessian, band LU)"),
    (Problem, "__init__", "Problem construction"),
    (Problem, "_stability_at_rest", "stability at q* (margin at p0, each Result's p)"),
    (stabilize, "floors_loop", "stabilization rounds (floors, re-solves)"),
    (stabilize, "_floors_checked_by_restiffening", "floors checked by restiffening (in the rounds)"),
]


def timed(totals: dict, key: str, function):
    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            totals[key] = totals.get(key, 0.0) + time.perf_counter() - start
    return wrapper


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--strands", type=int, default=100)
    parser.add_argument("--vertices", type=int, default=100)
    parser.add_argument("--jobs", type=int, default=os.cpu_count())
    args = parser.parse_args()
    strands = sagfree.scenes.groom(args.strands, args.vertices, seed=0)
    sagfree.optimize(strands[:2], jobs=1)  # compile / load the model first

    start = time.perf_counter()
    sagfree.optimize(strands, jobs=1)
    plain = time.perf_counter() - start

    totals: dict[str, float] = {}
    originals = [(owner, name, getattr(owner, name)) for owner, name, _ in PARTS]
    for owner, name, label in PARTS:
        setattr(owner, name, timed(totals, label, getattr(owner, name)))
    try:
        start = time.perf_counter()
        sagfree.optimize(strands, jobs=1)
        instrumented = time.perf_counter() - start
    finally:
        for owner, name, function in originals:
            setattr(owner, name, function)

    n = args.strands
    print(f"1. groom({n}, {args.vertices}) in one process: {1e3 * plain / n:.1f} ms per strand "
          f"({1e3 * instrumented / n:.1f} ms with the timers)")
    print(f"   {'part':54} {'ms/strand':>10} {'share':>6}")
    for _, _, label in PARTS:
        spent = totals.get(label, 0.0)
        print(f"   {label:54} {1e3 * spent / n:10.2f} {100 * spent / instrumented:5.0f}%")

    start = time.perf_counter()
    sagfree.optimize(strands, jobs=args.jobs)
    wall = time.perf_counter() - start
    print(f"\n2. the same batch on {args.jobs} worker processes: wall {wall:.2f} s; one process / {args.jobs} = "
          f"{plain / args.jobs:.2f} s; overhead (start-up, transfer, imbalance) {wall - plain / args.jobs:+.2f} s")


if __name__ == "__main__":
    main()
