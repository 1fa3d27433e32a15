"""Our solver at groom scale, side by side with the code before a change, its growth with strand
size, and the preconditioner ablation.

    python benchmarks/bench_solver.py [--strands 1900] [--vertices 100] [--jobs N] [--before REV]
                                      [--repeats 2] [--sizes 25,100,400,1000,2000] [--size-strands 10]
                                      [--pinned-strands 3] [--ablation 10]

Prints three tables (and 2b), all measured in this run; a count of 0 skips its table (``--strands 0
--ablation 0 --sizes 3,5000,10000 --size-strands 3 --pinned-strands 0``: the size table alone):
1. the whole groom (``groom(1900, 100, seed=0)``, element stiffness, default boxes, stability on) on
   all cores after a warm-up batch: wall time, strands converged and stable, the ratio to the
   predecessor paper's published 11.2 s for 1.9K strands x 100 vertices (measured there on a larger
   CPU; a reference figure, not a run on this machine) and to the same groom solved by the code at
   git revision ``--before`` (installed by pip from a temporary worktree into a folder of its own and
   run in a subprocess, same machine, same cores; skipped outside a git checkout, with --before ""
   or where pip cannot install it). The two codes run alternately ``--repeats`` times (before,
   ours, before, ours, ...) and each row shows its best wall time: on a shared VM whose speed drifts
   by tens of percent within minutes, the best of alternating runs is what compares the codes;
2. time per strand against strand size for the same physical strands, one core: the wall time of
   ``optimize(jobs=1)`` per strand (everything a user waits for: the Problem, the solve, the
   stability of its Result) and per vertex (flat = linear growth), the mean ``Result.time`` (the
   solve alone: solvers are compared on it), Gauss-Newton, SQP and Newton-SQP steps, QP
   factorizations per Gauss-Newton step, converged and stable; 2b. the same with the strands' tips
   pinned (``--pinned-strands`` of them per size): a strand held at both ends starts at the
   optimum over its tip's reaction (solvers/reaction_start.py: a search over 3 unknowns whose
   values of Phi the column ``Phi values`` counts), which asc confirms as it does a root-held
   strand's start;
3. the preconditioner ablation on a subset: active-set Cholesky vs Jacobi vs none, with CG
   iterations, expansions, factorizations, time and the ratio to the active-set Cholesky, along
   the Gauss-Newton path (``start="linear"``: from the statics start a root-held strand needs no QP).
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import time
import warnings

import numpy as np

import sagfree
from revisions import installed_revision  # benchmarks/revisions.py

PREDECESSOR_SECONDS = 11.2  # Takahashi & Batty (CGF), 1.9K strands x 100 vertices


def summary(results) -> dict:
    statuses = {s: sum(r.status == s for r in results) for s in ("converged", "infeasible",
                                                                 "max_iterations", "failed")}
    keys = ("outer", "gauss_newton", "cg", "expansion", "proportioning", "active_set", "interior", "factorizations",
            "factored_rows", "sqp", "newton_sqp", "tightened", "stabilization")
    counts = {k: np.array([r.iterations.get(k, 0) for r in results]) for k in keys}
    return dict(statuses=statuses, counts=counts, solve_time=np.array([r.time for r in results]))


#: The code before issue 21's changes (the revision benchmarks/RESULTS.md compares against).
BEFORE = "61771bb"

#: Run in a subprocess with the install of --before: the groom table's measurement, as JSON (with
#: the file the solvers came from, to check that the run used that install).
_GROOM_SCRIPT = """
import json, sys, time
import sagfree
import sagfree.solvers
strands, vertices, jobs = map(int, sys.argv[1:4])
groom = sagfree.scenes.groom(strands, vertices, seed=0)
sagfree.optimize(groom[:jobs], jobs=1)
start = time.perf_counter()
results = sagfree.optimize(groom, jobs=jobs)
wall = time.perf_counter() - start
print(json.dumps(dict(wall=wall, code=sagfree.solvers.__file__, strands=len(results),
                      converged=sum(r.status == "converged" for r in results),
                      stable=sum(bool(r.stable) for r in results))))
"""


class RevisionRunner:
    """The groom measurement of ``_GROOM_SCRIPT`` by the code at git ``revision``, installed apart
    (benchmarks/revisions.py) and run in a subprocess whose PYTHONPATH puts that install first (a
    context manager; ``run()`` once per measurement). ``available`` is False outside a git
    checkout or where pip cannot install the revision."""

    def __init__(self, revision: str, strands: int, vertices: int, jobs: int):
        self.revision, self.arguments = revision, [str(strands), str(vertices), str(jobs)]
        self._stack = contextlib.ExitStack()

    def __enter__(self) -> "RevisionRunner":
        self.site = self._stack.enter_context(installed_revision(self.revision))
        self.available = self.site is not None
        if not self.available and self.revision:
            print(f"(no `before` row for {self.revision})")
        return self

    def run(self) -> dict:
        out = subprocess.run([sys.executable, "-c", _GROOM_SCRIPT, *self.arguments], cwd=self.site.parent,
                             env={**os.environ, "PYTHONPATH": str(self.site)}, check=True, capture_output=True,
                             text=True).stdout
        measured = json.loads(out.strip().splitlines()[-1])
        if not measured["code"].startswith(str(self.site)):
            raise RuntimeError(f"the run of {self.revision} imported {measured['code']}, not its own install")
        return measured

    def __exit__(self, *exc) -> None:
        self._stack.close()


def groom_table(strands: int, vertices: int, jobs: int, before: str, repeats: int) -> None:
    groom = sagfree.scenes.groom(strands, vertices, seed=0)
    sagfree.optimize(groom[:jobs], jobs=1)  # compile / load caches outside the timing
    previous, walls = [], []
    with RevisionRunner(before, strands, vertices, jobs) as runner:
        for _ in range(repeats):  # alternately (module docstring)
            if runner.available:
                previous.append(runner.run())
            start = time.perf_counter()
            results = sagfree.optimize(groom, jobs=jobs)
            walls.append(time.perf_counter() - start)
    wall = min(walls)
    best = min(previous, key=lambda run: run["wall"]) if previous else None
    s = summary(results)
    stable = sum(bool(r.stable) for r in results)
    runs = lambda seconds: " / ".join(f"{t:.2f}" for t in seconds)  # noqa: E731
    print(f"1. groom {strands} strands x {vertices} vertices, {jobs} jobs, stability on; best of {repeats} "
          f"alternating runs")
    print(f"   {'code':24} {'wall s':>8} {'converged':>10} {'stable':>7} {'/ 11.2 s':>9} {'/ before':>9}  runs")
    if best is not None:
        print(f"   {'before (' + before + ')':24} {best['wall']:8.2f} {best['converged']:>10} "
              f"{best['stable']:>7} {best['wall'] / PREDECESSOR_SECONDS:9.2f} {1.0:9.2f}  "
              f"{runs(run['wall'] for run in previous)}")
    ratio = f"{wall / best['wall']:9.2f}" if best is not None else f"{'-':>9}"
    print(f"   {'this checkout':24} {wall:8.2f} {s['statuses']['converged']:>10} {stable:>7} "
          f"{wall / PREDECESSOR_SECONDS:9.2f} {ratio}  {runs(walls)}")
    print(f"   (predecessor, published: {PREDECESSOR_SECONDS} s for 1.9K x 100 on its machine)")
    print(f"   mean solve time per strand {s['solve_time'].mean() * 1e3:.1f} ms "
          f"(max {s['solve_time'].max() * 1e3:.1f} ms); statuses {s['statuses']}")
    print(f"   {'count':16} {'mean':>9} {'max':>9}")
    for k, v in s["counts"].items():
        print(f"   {k:16} {v.mean():9.1f} {v.max():9d}")


def size_table(sizes, strands: int, tip: str | None = None, title: str = "2.") -> None:
    """The size table: ``strands`` groom strands per size, held by their root alone or (``tip``)
    with that tip attachment too (a pinned tip: the search over its reaction, whose values of Phi
    the table counts)."""
    held = f", tips {tip}" if tip else ""
    print(f"\n{title} time per strand against strand size ({strands} groom strands per size{held}, one core)")
    print(f"   {'vertices':>8} {'ms/strand':>10} {'us/vertex':>10} {'solve ms':>9} {'GN steps':>9} {'SQP':>5} "
          f"{'Newton':>7} {'factor./GN':>11} {'Phi values':>11} {'converged':>10} {'stable':>7}")
    notes = []  # warnings (the radius above an edge length of some long groom strands), after the table
    for n in sizes:
        groom = sagfree.scenes.groom(strands, n, seed=0)
        groom = [strand.attached(tip=tip) for strand in groom] if tip else groom
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the warm-up's: the batch's own are recorded below
            sagfree.optimize(groom[:1], jobs=1)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            start = time.perf_counter()
            results = sagfree.optimize(groom, jobs=1)
            t = (time.perf_counter() - start) / len(groom)
        notes += [f"{n} vertices: {warning.message}" for warning in caught]
        solve = np.mean([r.time for r in results])
        steps = np.mean([r.iterations.get("gauss_newton", 0) for r in results])
        factorizations = np.mean([r.iterations.get("factorizations", 0) for r in results])
        sqp, newton, values = (np.mean([r.iterations.get(k, 0) for r in results])
                               for k in ("sqp", "newton_sqp", "reaction_values"))
        ok = sum(r.status == "converged" for r in results)
        stable = sum(bool(r.stable) for r in results)
        print(f"   {n:8d} {t * 1e3:10.1f} {t / n * 1e6:10.1f} {solve * 1e3:9.1f} {steps:9.1f} {sqp:5.1f} {newton:7.1f} "
              f"{factorizations / max(steps, 1):11.1f} {values:11.0f} "
              f"{ok:>6}/{len(results)} {stable:>7}", flush=True)
    for note in dict.fromkeys(notes):
        print(f"   ({note})")


def ablation_table(strands: int, vertices: int) -> None:
    groom = sagfree.scenes.groom(strands, vertices, seed=0)
    print(f"\n3. preconditioner ablation ({strands} strands x {vertices} vertices, one core, start='linear')")
    print(f"   {'preconditioner':15} {'time s':>8} {'vs ASC':>7} {'CG':>9} {'expansion':>10} "
          f"{'proport.':>9} {'factor.':>8} {'converged':>10}")
    reference = None
    for name in ("cholesky", "jacobi", "none"):
        start = time.perf_counter()
        # the Gauss-Newton path: from the statics start a root-held strand needs no QP at all
        results = sagfree.optimize(groom, jobs=1, solver_options=dict(preconditioner=name, start="linear"))
        t = time.perf_counter() - start
        reference = reference or t
        s = summary(results)
        c = s["counts"]
        print(f"   {name:15} {t:8.2f} {t / reference:7.2f} {c['cg'].sum():9d} {c['expansion'].sum():10d} "
              f"{c['proportioning'].sum():9d} {c['factorizations'].sum():8d} "
              f"{s['statuses']['converged']:>6}/{len(results)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--strands", type=int, default=1900, help="groom strands of table 1 ('0' = skip)")
    parser.add_argument("--vertices", type=int, default=100)
    parser.add_argument("--jobs", type=int, default=os.cpu_count())
    parser.add_argument("--before", default=BEFORE, help="git revision to run side by side ('' = skip)")
    parser.add_argument("--repeats", type=int, default=2, help="alternating runs of each code in table 1")
    parser.add_argument("--sizes", default="25,100,400,1000,2000", help="strand sizes of table 2")
    parser.add_argument("--size-strands", type=int, default=10, help="strands per size in table 2 ('0' = skip)")
    parser.add_argument("--pinned-strands", type=int, default=3, help="strands per size in table 2b ('0' = skip)")
    parser.add_argument("--ablation", type=int, default=10, help="strands in table 3 ('0' = skip)")
    args = parser.parse_args()
    if args.strands:
        groom_table(args.strands, args.vertices, args.jobs, args.before, args.repeats)
    sizes = [int(n) for n in args.sizes.split(",")]
    if args.size_strands:
        size_table(sizes, args.size_strands)
    if args.pinned_strands:
        size_table(sizes, args.pinned_strands, tip="pinned", title="2b.")
    if args.ablation:
        ablation_table(args.ablation, args.vertices)


if __name__ == "__main__":
    main()
