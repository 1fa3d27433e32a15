"""Every solver on the same stabilized problem: do they reach the same optimum? (DESIGN section 4)

    python benchmarks/bench_same_optimum.py [--strands 1,6,11,15,22,...] [--osqp-seconds 60]

``horizontal``, ``curly`` and the default groom's strands that are saddle points of the bare
optimum (unstable without the stabilization), each solved by ``asc``, ``ipopt`` and ``osqp`` on the
stabilized problem (the default; the stiffness floors come from asc's loop, frontend.stabilize),
measured in this run: statuses, stabilization rounds, the smallest eigenvalue over its margin, and
R relative to asc's.
"""
from __future__ import annotations

import argparse
import time

import sagfree

UNSTABLE = (1, 6, 7, 11, 15, 16, 22, 39, 55, 63, 84, 87, 88, 94)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--strands", default=",".join(map(str, UNSTABLE)))
    parser.add_argument("--osqp-seconds", type=float, default=60.0)
    args = parser.parse_args()
    groom = sagfree.scenes.default_groom()
    cases = {"horizontal": sagfree.scenes.horizontal(), "curly": sagfree.scenes.curly(n=40)}
    cases.update({f"groom {k}": groom[k] for k in map(int, args.strands.split(","))})
    options = {"osqp": {"max_seconds": args.osqp_seconds}}
    print(f"{'case':12} {'solver':6} {'status':15} {'rounds':>6} {'lambda/margin':>13} {'R':>12} "
          f"{'R/R_asc - 1':>12} {'time s':>8}")
    for name, strand in cases.items():
        problem = sagfree.Problem(strand)
        reference = None
        for solver in ("asc", "ipopt", "osqp"):
            start = time.perf_counter()
            result = sagfree.solve(problem, solver, **options.get(solver, {}))
            wall = time.perf_counter() - start
            reference = result.objective if solver == "asc" else reference
            print(f"{name:12} {solver:6} {result.status:15} {result.iterations.get('stabilization', 0):6d} "
                  f"{result.min_eigenvalue / problem.stability_margin:13.3f} {result.objective:12.6g} "
                  f"{result.objective / reference - 1:12.2e} {wall:8.2f}", flush=True)


if __name__ == "__main__":
    main()
