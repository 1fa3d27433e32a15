"""This checkout against the code at another git revision, strand by strand, in one process.

    python benchmarks/compare_revisions.py [--before REV] [--strands 200] [--vertices 100] [--rounds 3]
                                           [--longer 5]

The shared VM this project measures on drifts by tens of percent within minutes, so two whole-batch
runs cannot resolve a change of a few percent (bench_solver.py's groom table, best of alternating
runs, is for the large ratios). Here the revision is installed apart (benchmarks/revisions.py), its
package copied as ``sagfree_before`` with its imports rewritten, and both codes solve each strand of
``groom(strands, vertices, seed=0)`` in turn (``optimize([strand], jobs=1)``, stabilization on), the
order flipped from strand to strand and round to round, so the drift hits both alike. Prints the
process time per strand of each, the ratio of the totals and the median of the per-strand ratios,
and whether both found the same solutions bit for bit (p, status, smallest eigenvalue): a change
meant to keep the arithmetic must say yes; otherwise the statuses that differ, the stable counts
and the largest relative difference of R tell whether both reached the same optima. The copy
compiles its numba kernels on first use (about a minute and a half), outside the timing.
``--longer F`` stretches every strand F times from its root: at 5 the default boxes cannot balance
most of them, so the comparison is of the best effort (least residual, least sag) of infeasible strands.
"""
from __future__ import annotations

import argparse
import collections
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

import sagfree
from revisions import installed_revision, renamed_copy  # benchmarks/revisions.py

BEFORE_NAME = "sagfree_before"


def stretched(code, strands: int, vertices: int, longer: float) -> list:
    """groom(strands, vertices, seed=0) of ``code``, each strand ``longer`` times as long from its root."""
    return [code.Strand(s.points[0] + longer * (s.points - s.points[0]), radius=s.radius)
            for s in code.scenes.groom(strands, vertices, seed=0)]


def compare(before, strands: int, vertices: int, rounds: int, longer: float = 1.0) -> None:
    codes = {"before": before, "this checkout": sagfree}
    grooms = {name: stretched(code, strands, vertices, longer) for name, code in codes.items()}
    for name, code in codes.items():  # compile / load every kernel outside the timing
        code.optimize(grooms[name][:2], jobs=1)
    seconds = {name: np.zeros(strands) for name in codes}
    results = {}
    for round_ in range(rounds):
        for i in range(strands):
            order = list(codes) if (i + round_) % 2 == 0 else list(codes)[::-1]
            for name in order:
                start = time.process_time()
                results[name, i] = codes[name].optimize([grooms[name][i]], jobs=1)[0]
                seconds[name][i] += time.process_time() - start
    stretch = f" {longer:g} times as long" if longer != 1 else ""
    print(f"groom({strands}, {vertices}, seed=0){stretch}, {rounds} rounds, each strand solved by both codes in turn "
          "(process time, one core)")
    statuses = collections.Counter(results["this checkout", i].status for i in range(strands))
    print(f"   statuses now: {dict(statuses)}")
    for name in codes:
        print(f"   {name:14} {1e3 * seconds[name].sum() / (strands * rounds):8.2f} ms per strand")
    total = seconds["this checkout"].sum() / seconds["before"].sum()
    median = float(np.median(seconds["this checkout"] / seconds["before"]))
    print(f"   this checkout / before: {total:.3f} (total), {median:.3f} (median of the strands)")
    same = all(np.array_equal(results["before", i].p, results["this checkout", i].p)
               and results["before", i].status == results["this checkout", i].status
               and results["before", i].min_eigenvalue == results["this checkout", i].min_eigenvalue
               for i in range(strands))
    print(f"   the same p, statuses and eigenvalues bit for bit: {'yes' if same else 'no'}")
    if not same:  # a change of the algorithm: are they the same optima?
        pairs = [(results["before", i], results["this checkout", i]) for i in range(strands)]
        statuses = sum(a.status != b.status for a, b in pairs)
        stable = [sum(bool(r.stable) for r in side) for side in zip(*pairs)]
        relative = max(abs(b.objective - a.objective) / max(abs(a.objective), 1e-300) for a, b in pairs)
        print(f"   statuses differ on {statuses} strands; stable {stable[0]} before, {stable[1]} now; largest "
              f"relative difference of R {relative:.2e}")
        sags = np.array([(a.static_sag, b.static_sag) for a, b in pairs
                         if np.isfinite(a.static_sag) and np.isfinite(b.static_sag)])
        if sags.size:  # strands that rest elsewhere (infeasible): the best effort's sag, now over before
            ratio = sags[:, 1] / sags[:, 0]
            print(f"   static sag now / before on {len(ratio)} strands: median {np.median(ratio):.3f}, geometric "
                  f"mean {np.exp(np.mean(np.log(ratio))):.3f}, {np.sum(ratio > 1.05)} above 1.05, "
                  f"{np.sum(ratio < 0.95)} below 0.95; sum {sags[:, 0].sum():.3f} -> {sags[:, 1].sum():.3f} L")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", default="HEAD~1", help="git revision to compare against")
    parser.add_argument("--strands", type=int, default=200)
    parser.add_argument("--vertices", type=int, default=100)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--longer", type=float, default=1.0, help="stretch each strand this many times from its root")
    args = parser.parse_args()
    warnings.simplefilter("ignore")  # the same warnings twice (radius above an edge at 2000 vertices)
    with installed_revision(args.before) as site, tempfile.TemporaryDirectory() as copies:
        if site is None:
            sys.exit(f"cannot install {args.before!r} (outside a git checkout, or pip failed)")
        sys.path.insert(0, str(renamed_copy(site, BEFORE_NAME, Path(copies))))
        before = __import__(BEFORE_NAME)
        print(f"before: {args.before} ({Path(before.__file__).parent}); this checkout: {Path(sagfree.__file__).parent}")
        compare(before, args.strands, args.vertices, args.rounds, args.longer)


if __name__ == "__main__":
    main()
