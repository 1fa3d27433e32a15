"""Strands held at more points than their root: which of asc's two starts converges, and at what R.

    python benchmarks/study_held_starts.py [--sizes 30,100,400] [--strands 10] [--jobs N]

asc begins a strand with a pinned tip or pins at the optimum over the held points' reactions
(solvers/reaction_start.py; at p0 where that search does not apply, as with a clamped tip, or finds
none) and one held by its root alone at the linear start; a default solve that ends
``max_iterations`` begins again from the other start (solvers/alm.py, Start). This study solves,
per size and seed 0, 1, 2, groom strands
with one pin at the middle vertex and with two pins at the thirds (``--strands`` per seed, 4 at 400
vertices and more), and ``horizontal(n)`` and ``cable(n)`` strands pinned at the middle, three ways:
the default, from the linear start alone (``start="linear"``) and from p0 alone (``start="p0"``),
each with ``optimize`` (stability on). It prints, per set and way, the strands converged and stable
and the wall time, and where two ways both converge on a strand, the range of their ratio of R.
"""
from __future__ import annotations

import argparse
import os
import time

import sagfree

WAYS = {"default": {}, "linear": {"start": "linear"}, "p0": {"start": "p0"}}


def strand_sets(sizes: list[int], strands: int):
    """(name, strands) of the study (module docstring)."""
    for n in sizes:
        for seed in (0, 1, 2):
            groom = sagfree.scenes.groom(strands if n < 400 else 4, n, seed=seed)
            yield f"groom n={n} seed {seed}, pin at the middle", [s.attached(pins=(n // 2,)) for s in groom]
            yield f"groom n={n} seed {seed}, pins at the thirds", [s.attached(pins=(n // 3, 2 * n // 3))
                                                                   for s in groom]
    yield "horizontal n=50-400, pin at the middle", [sagfree.scenes.horizontal(n=n, pins=[n // 2])
                                                    for n in (50, 100, 200, 400)]
    yield "cable n=30-300, pin at the middle", [sagfree.scenes.cable(n=n).attached(pins=(n // 2,))
                                               for n in (30, 100, 300)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="30,100,400")
    parser.add_argument("--strands", type=int, default=10)
    parser.add_argument("--jobs", type=int, default=os.cpu_count())
    args = parser.parse_args()
    sizes = [int(size) for size in args.sizes.split(",")]
    sagfree.optimize(sagfree.scenes.groom(2, 30, seed=0), jobs=args.jobs)  # compile / load first
    totals = {way: [0, 0, 0.0] for way in WAYS}
    print(f"{'set':44s} {'way':8s} {'converged':>10s} {'stable':>7s} {'wall s':>7s}  R / R(default)")
    for name, strands in strand_sets(sizes, args.strands):
        results = {}
        for way, options in WAYS.items():
            start = time.perf_counter()
            results[way] = sagfree.optimize(strands, jobs=args.jobs, solver_options=options)
            wall = time.perf_counter() - start
            converged = sum(r.status == "converged" for r in results[way])
            totals[way][0] += converged
            totals[way][1] += len(strands)
            totals[way][2] += wall
            ratios = [r.objective / d.objective for r, d in zip(results[way], results["default"])
                      if r.status == d.status == "converged" and d.objective > 0]
            spread = f"{min(ratios):.4f}-{max(ratios):.4f}" if ratios and way != "default" else ""
            print(f"{name:44s} {way:8s} {converged:>6d}/{len(strands):<3d} {sum(r.stable for r in results[way]):>7d} "
                  f"{wall:7.2f}  {spread}", flush=True)
    print()
    for way, (converged, count, wall) in totals.items():
        print(f"{way:8s} converged {converged}/{count}, {wall:.1f} s")


if __name__ == "__main__":
    main()
