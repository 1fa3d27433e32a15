"""Long hair the boxes cannot balance: the default groom scaled 5x and 10x (DESIGN section 4, best effort).

    python benchmarks/bench_long_hair.py [--scales 5,10 (or "": none)] [--strands 100] [--jobs N]
                                         [--sizes 50,100,200,400,1000,2000]

Every strand of the default groom is scaled about its root (same radius and material), solved with
``asc`` (element stiffness, default boxes, stabilization on; an infeasible strand gets the least
static sag, solvers.least_sag), and the static sag of its parameters is compared with that of the
naive parameters and of the predecessor (``penalty-gn``), all measured in this run: per scale, the
statuses, the strands whose sag is below naive's (among those whose static solves all converged: a
long strand that flips over can defeat Newton), the mean sag ratios, and how many rest stably
(``Result.stable``: where an infeasible strand rests). On a 2-core machine run it with
OPENBLAS_NUM_THREADS=1: two workers that each start BLAS threads slow each other down several times.

The column "box holds" is the median over strands of the largest root moment the default boxes can
hold without deforming, beta_max E I THETA / L (the bend multiplier at its upper bound times the
whole-strand curvature budget THETA spread along L), over the groomed root moment of gravity
|sum_i (x_i - x_0) x m_i g|. Below 1 no parameters inside the boxes balance the strand, and the sag
cannot stay small: it scales like 1/L^3 with the length. A long strand is solved first, untimed:
the first table's times hold no compilation or kernel loading.

The second table is the best effort's growth with strand size: the default groom's strand 5 at 5
times its length, resampled to each of ``--sizes`` vertices (one core, after a warm-up solve): the
wall time, per vertex (flat = linear growth), the least-sag evaluations, the static sag over naive's
and the process's peak resident memory so far.
"""
from __future__ import annotations

import argparse
import resource
import time
from collections import Counter

import numpy as np

import sagfree
from sagfree.scenes.synthetic import resample
from sagfree.formulation.parameters import BUDGETS, STIFFNESS_BOX
from sagfree.formulation.simulation import equilibrium
from sagfree.frontend.batch import map_strands


def scaled(strand: sagfree.Strand, factor: float) -> sagfree.Strand:
    points = strand.points[0] + factor * (strand.points - strand.points[0])
    return sagfree.Strand(points, radius=strand.radius, youngs_modulus=strand.youngs_modulus,
                          shear_modulus=strand.shear_modulus, density=strand.density)


def box_moment_fraction(strand: sagfree.Strand, gravity=(0.0, 0.0, -9.81)) -> float:
    """beta_max E I THETA / L over the root moment of gravity on the groomed shape (module docstring)."""
    x = strand.points
    edges = np.linalg.norm(np.diff(x, axis=0), axis=1)
    masses = np.zeros(len(x))
    masses[:-1] += edges / 2
    masses[1:] += edges / 2
    masses *= strand.density * np.pi * strand.radius ** 2
    root_moment = np.linalg.norm(np.cross(x - x[0], masses[:, None] * np.asarray(gravity)).sum(axis=0))
    capacity = (STIFFNESS_BOX[1] * strand.youngs_modulus * np.pi * strand.radius ** 4 / 4
                * BUDGETS["curvature_budget"] / edges.sum())
    return capacity / root_moment


def static_sags(strand: sagfree.Strand, p_asc, p_predecessor) -> tuple[float, float, float]:
    """Static sag over L of asc's, naive and the predecessor's parameters (NaN where it fails)."""
    problem = sagfree.Problem(strand)
    out = []
    for p in (p_asc, problem.p0, p_predecessor):
        static = equilibrium(problem, p)
        out.append(static.relative_sag if static.converged else float("nan"))
    return tuple(out)


def _unchecked(message: str):
    return (float("nan"),) * 3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scales", default="5,10")
    parser.add_argument("--strands", type=int, default=100)
    parser.add_argument("--jobs", type=int, default=None)
    parser.add_argument("--sizes", default="50,100,200,400,1000,2000")
    args = parser.parse_args()
    groom = sagfree.scenes.default_groom()[: args.strands]
    if args.scales:  # warm (kernels compiled or loaded) before the timed rows: the first row's time took it in
        sagfree.optimize([scaled(groom[0], 5.0)], jobs=args.jobs)
        print("scale  lengths (cm)   asc statuses                     time s  sag < naive  "
              "mean sag/naive  mean sag / mean naive  mean sag/penalty-gn  stable  worst sag/naive  box holds")
    for factor in (float(s) for s in args.scales.split(",") if s):
        strands = [scaled(s, factor) for s in groom]
        start = time.perf_counter()
        ours = sagfree.optimize(strands, jobs=args.jobs)
        wall = time.perf_counter() - start
        predecessor = sagfree.optimize(strands, solver="penalty-gn", jobs=args.jobs)
        sags = np.array(map_strands(static_sags, [(s, a.p, b.p) for s, a, b in zip(strands, ours, predecessor)],
                                    jobs=args.jobs, on_crash=_unchecked))
        asc, naive, pgn = sags.T
        both = np.isfinite(asc) & np.isfinite(naive)
        statuses = ", ".join(f"{k} {v}" for k, v in Counter(r.status for r in ours).items())
        lengths = [s.length * 100 for s in strands]
        with np.errstate(invalid="ignore"):  # 0 / 0 where both sags vanish (converged strands)
            ratio_to_predecessor = np.nanmean(asc / pgn)
        print(f"{factor:5g}  {min(lengths):5.0f}-{max(lengths):<5.0f}   {statuses:32} {wall:7.1f}  "
              f"{np.sum(asc[both] < naive[both]):4d}/{np.sum(both):<4d}  {np.mean(asc[both] / naive[both]):14.3f}  "
              f"{np.mean(asc[both]) / np.mean(naive[both]):21.3f}  {ratio_to_predecessor:19.3f}  "
              f"{sum(r.stable for r in ours)}/{len(ours)}  {np.max(asc[both] / naive[both]):15.3f}  "
              f"{np.median([box_moment_fraction(s) for s in strands]):9.3f}")
    if args.sizes:
        size_table([int(n) for n in args.sizes.split(",")])


def size_table(sizes: list[int]) -> None:
    """The second table of the module docstring."""
    long = scaled(sagfree.scenes.default_groom()[5], 5.0)
    print(f"\n{'vertices':>8} {'status':>11} {'wall s':>8} {'us/vertex':>10} {'least-sag evals':>16} "
          f"{'sag/naive':>10} {'stable':>6} {'peak MB':>8}")
    sagfree.optimize([_resampled(long, 30)], jobs=1)  # warm
    for n in sizes:
        strand = _resampled(long, n)
        start = time.perf_counter()
        (result,) = sagfree.optimize([strand], jobs=1)
        wall = time.perf_counter() - start
        problem = sagfree.Problem(strand)
        naive = equilibrium(problem, problem.p0)
        sag = result.static_sag if result.static_sag is not None else float("nan")  # converged: rests at q*
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"{n:8d} {result.status:>11} {wall:8.2f} {1e6 * wall / n:10.0f} "
              f"{result.iterations.get('least_sag', 0):16d} {sag / naive.relative_sag:10.3f} "
              f"{str(result.stable):>6} {peak:8.0f}", flush=True)


def _resampled(strand: sagfree.Strand, n: int) -> sagfree.Strand:
    """``strand`` at n vertices along its polyline, same radius and material."""
    return sagfree.Strand(resample(strand.points, n), radius=strand.radius, youngs_modulus=strand.youngs_modulus,
                          shear_modulus=strand.shear_modulus, density=strand.density)


if __name__ == "__main__":
    main()
