"""Where a groom strand's solve spends its time, and what batching costs on top.

    python benchmarks/profile_solver.py [--strands 100] [--vertices 100] [--jobs N]

1. One process, the strands one after another, with timers around the parts of ``asc`` (each
   part's time includes what it calls, so nested rows overlap: the SQP steps contain their
   residuals, the Result its residual): share of the total;
2. the same batch on ``jobs`` worker processes: wall time against the one-process time divided by
   the jobs, and against ``jobs`` independent processes (forked, no pool, no results sent back)
   each solving its share side by side: the first difference is what sharing the machine's cores
   costs (on a VM whose vCPUs slow each other down it is most of it), the second what the batch
   runner adds (start-up, transfer, imbalance).
"""
from __future__ import annotations

import argparse
import os
import time

import sagfree
import sagfree.frontend.stabilize as stabilize
import sagfree.solvers.alm as alm
import sagfree.solvers.gauss_newton as gauss_newton
from sagfree.formulation.problem import Problem

PARTS = [
    (alm, "confirmed_start", "start, KKT distance, stability (one compiled call)"),
    (alm, "linear_start", "linear start (one band LU)"),
    (alm, "statics_start", "the start at the optimum (in the linear start)"),
    (gauss_newton, "inner_solve", "Gauss-Newton inner solves (compiled: QPs, J^T J, c, J)"),
    (alm, "solve_box_qp", "MPRGP QPs outside them (least residual, Python loop)"),
    (Problem, "strand_jacobian", "Jacobian dc/dp outside them"),
    (alm, "gram", "Gauss-Newton Hessian J^T J outside them"),
    (Problem, "residual", "residual c(p) outside them"),
    (alm, "make_result", "Result: summaries and stability"),
    (alm, "kkt_optimality", "KKT confirmation (refined SQP LU or band LU)"),
    (alm, "_sqp_step", "SQP steps where the constraint stalls (band LU)"),
    (alm, "_newton_sqp", "Newton-SQP steps (exact Hessian, band LU)"),
    (Problem, "__init__", "Problem construction"),
    (Problem, "_stability_at_rest", "stability at q* (margin at p0, each Result's p)"),
    (stabilize, "floors_loop", "stabilization rounds (floors, re-solves)"),
    (stabilize, "checked_floors", "a round's floors and their checks (one compiled call)"),
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
    alone = side_by_side(strands, args.jobs)
    print(f"\n2. the same batch on {args.jobs} worker processes: wall {wall:.2f} s; one process / {args.jobs} = "
          f"{plain / args.jobs:.2f} s; {args.jobs} independent processes side by side, each its share: "
          f"{alone:.2f} s\n   sharing the cores {alone - plain / args.jobs:+.2f} s, the batch runner "
          f"(start-up, transfer, imbalance) {wall - alone:+.2f} s")


def side_by_side(strands, jobs: int) -> float:
    """Wall seconds of ``jobs`` forked processes each solving a contiguous share of ``strands`` in
    itself (jobs=1), started together: the machine's own parallel speed, without the batch runner
    (NaN where there is no fork)."""
    if not hasattr(os, "fork"):
        return float("nan")
    bounds = [len(strands) * k // jobs for k in range(jobs + 1)]
    start = time.perf_counter()
    children = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        pid = os.fork()
        if pid == 0:  # the child: already warm (forked from this process), solves its share and leaves
            sagfree.optimize(strands[a:b], jobs=1)
            os._exit(0)
        children.append(pid)
    for pid in children:
        os.waitpid(pid, 0)
    return time.perf_counter() - start


if __name__ == "__main__":
    main()
