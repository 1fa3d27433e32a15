"""Stable rest states: the stabilization on whole grooms, checked by pushing every strand (DESIGN 4, 7).

    python benchmarks/bench_stability.py [--grooms default,200x100] [--jobs N] [--duration 5]

For each groom, ``asc`` with the stabilization (the default) and without it (``stabilize=False``, the
paper's bare problem), measured in this run: statuses, strands the stabilization touched, the
smallest eigenvalue over its margin, the R the stability costs, and two forward checks per strand of
``duration`` seconds of implicit Euler: from rest at q* (does it leave by itself?) and after a push of
1e-3 L along its softest mode (does it come back within the push?).
"""
from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np

import sagfree
from sagfree.formulation.simulation import CHECK_TOLERANCE, PUSH, push_check, simulate
from sagfree.frontend.batch import map_strands

GROOMS = {"default": lambda: sagfree.scenes.default_groom(),
          "200x100": lambda: sagfree.scenes.groom(200, 100, seed=1)}


def forward(strand, p, duration: float) -> tuple[float, float]:
    """(deviation / L at the end of a run from rest at q*, deviation / L at the end after a push)."""
    problem = sagfree.Problem(strand)
    # Newton tolerance below the round-off floor: every step moves, so rounding can grow along a saddle
    rest = simulate(problem, p, steps=int(round(duration / 1e-2)), dt=1e-2, tol=CHECK_TOLERANCE)
    pushed = push_check(problem, p, duration=duration)
    return float(rest.displacement[-1] / strand.length), pushed.deviation


def _unchecked(message: str):
    return (float("nan"), float("nan"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grooms", default="default,200x100")
    parser.add_argument("--jobs", type=int, default=None)
    parser.add_argument("--duration", type=float, default=5.0)
    args = parser.parse_args()
    for name in args.grooms.split(","):
        strands = GROOMS[name]()
        start = time.perf_counter()
        stable = sagfree.optimize(strands, jobs=args.jobs)
        wall = time.perf_counter() - start
        bare = sagfree.optimize(strands, jobs=args.jobs, stabilize=False)
        margins = np.array([r.min_eigenvalue / sagfree.Problem(s).stability_margin for s, r in zip(strands, stable)])
        touched = [k for k, r in enumerate(stable) if r.iterations.get("stabilization", 0)]
        added = sum(r.objective for r in stable) / sum(r.objective for r in bare) - 1
        print(f"\n{name} groom: {len(strands)} strands x {strands[0].n_vertices} vertices; asc {wall:.1f} s on "
              f"{args.jobs or 'all'} cores")
        print(f"  stabilized: {dict(Counter(r.status for r in stable))}; bare: {dict(Counter(r.status for r in bare))}")
        print(f"  unstable without stabilization: {sum(not r.stable for r in bare)} "
              f"(eigenvalues {min(r.min_eigenvalue for r in bare):.3g} to "
              f"{max((r.min_eigenvalue for r in bare if not r.stable), default=float('nan')):.3g} s^-2)")
        print(f"  strands the stabilization raised floors on: {len(touched)} ({touched}); rounds "
              f"{dict(Counter(stable[k].iterations['stabilization'] for k in touched))}")
        print(f"  smallest eigenvalue / margin over the converged: {margins[[r.success for r in stable]].min():.3f}; "
              f"R of the groom {sum(r.objective for r in stable):.4g} against {sum(r.objective for r in bare):.4g} "
              f"bare ({added:+.2%})")
        for label, results in (("stabilized", stable), ("bare", bare)):
            checks = np.array(map_strands(forward, [(s, r.p, args.duration) for s, r in zip(strands, results)],
                                          jobs=args.jobs, on_crash=_unchecked))
            rest, pushed = checks.T
            print(f"  {label:10}: {args.duration:g} s from rest: max deviation {np.nanmax(rest):.2e} L, "
                  f"{np.sum(rest > PUSH)} leave by themselves; pushed by {PUSH:g} L: "
                  f"{np.sum(pushed <= PUSH)}/{len(strands)} hold (max end deviation {np.nanmax(pushed):.2e} L)")


if __name__ == "__main__":
    main()
