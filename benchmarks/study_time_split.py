"""Where each kind of strand's solve time goes: model evaluation, linear algebra, and the rest.

    python benchmarks/study_time_split.py [--strands 40]

For issue 21, item 1 (no Python between the compiled kernels), per kind of strand: one process, after
the untimed warm-up, ``solve_strand`` on each strand (everything a user waits for per strand) and
the mean ``Result.time`` (the solve, without the Result's own stability measurement), split by
``Result.time_split`` into model evaluation (c, dc/dp, Hessian bands: inside the compiled kernels
too, on their clocks), linear algebra (band LUs and solves, QPs, eigenpairs) and the rest: the
Python between the kernels and around them, and the compiled code that is neither (the kernels'
own loops and bookkeeping), so the rest bounds what compiling the remaining Python could save.
The kinds: a plain groom (held by its root alone: one compiled call per strand,
frontend.whole_solve), the same strands with their tips pinned (asc's compiled outer loop; the
stabilization's rounds run in Python around it), long hair lying on a head (contact supports), and
the default groom at 5 times its length, which the boxes cannot balance (the best effort's least
residual and least static sag, in Python and scipy).
"""
from __future__ import annotations

import argparse
import time
import warnings

from sagfree.contract.result import status_summary
from sagfree.formulation.strand import Strand
from sagfree.frontend.batch import solve_strand
from sagfree.frontend.warm import warm_up
from sagfree.scenes import default_groom, groom
from sagfree.scenes.head import HEAD, head_groom


def kinds(count: int) -> dict[str, tuple[list, dict]]:
    """name -> (strands, problem options)."""
    long = [Strand(s.points[0] + 5.0 * (s.points - s.points[0])) for s in default_groom()[:max(1, count // 4)]]
    return {
        f"groom({count}, 100), root-held": (groom(count, 100, seed=0), {}),
        f"groom({count}, 100), tips pinned": ([s.attached(tip="pinned") for s in groom(count, 100, seed=0)], {}),
        f"head_groom({count}, 100) on the head": (head_groom(count, 100, seed=0), {"bodies": [HEAD]}),
        f"default groom x5 ({len(long)}), infeasible": (long, {}),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--strands", type=int, default=40)
    args = parser.parse_args()
    warnings.simplefilter("ignore")  # the long strands' thickness warnings
    print("one core, after the warm-up; ms per strand; shares of Result.time")
    print(f"   {'strands':40s} {'wall':>7} {'solve':>7} {'model':>6} {'linalg':>6} {'rest':>6} {'stab.':>5}  statuses")
    for name, (strands, options) in kinds(args.strands).items():
        warm_up("asc", {}, options)
        for strand in strands[:2]:  # the first solves of a path load its kernels
            solve_strand(strand, **options)
        start = time.perf_counter()
        results = [solve_strand(strand, **options) for strand in strands]
        wall = (time.perf_counter() - start) / len(strands)
        total = sum(r.time for r in results)
        model = sum(r.time_split.get("model", 0.0) for r in results) / total
        algebra = sum(r.time_split.get("linear_algebra", 0.0) for r in results) / total
        stabilized = sum(r.iterations.get("stabilization", 0) > 0 for r in results)
        print(f"   {name:40s} {1e3 * wall:7.1f} {1e3 * total / len(results):7.1f} {model:6.0%} {algebra:6.0%} "
              f"{1.0 - model - algebra:6.0%} {stabilized:5d}  {status_summary(results)}", flush=True)


if __name__ == "__main__":
    main()
