"""Every solver on the reference scenes and a groom, measured in one run (DESIGN section 6).

    python benchmarks/bench_baselines.py [--groom 20] [--vertices 100] [--stiffness element]

For each case (horizontal, helix, wavy, curly, and a groom of --groom strands x --vertices) and each
solver: statuses, mean iteration counts of each kind, mean time per strand, its ratio to ours
(``asc``) on the same strands, the largest |c|_inf, and R(p*) relative to ours (mean over strands
that both converged). One core, strands solved one after another, compile caches warmed first;
times are Result.time (a solver's one-time setup per strand size, Ipopt compiling its NLP, is
Result.setup_time, printed apart as "setup s").
"""
from __future__ import annotations

import argparse

import numpy as np

import sagfree
from sagfree.contract.result import iteration_summary

SOLVERS = ("asc", "ipopt", "osqp", "penalty-gn", "naive")


def cases(groom: int, vertices: int) -> dict:
    scenes = sagfree.scenes
    return {"horizontal": [scenes.horizontal()], "helix": [scenes.helix()], "wavy": [scenes.wavy()],
            "curly": [scenes.curly()],
            f"groom {groom}x{vertices}": scenes.groom(groom, vertices, seed=0)}


def run(strands, solver: str, stiffness: str) -> tuple[list, float, float]:
    """(results, mean Result.time per strand, summed setup time), s."""
    problems = [sagfree.Problem(s, stiffness=stiffness) for s in strands]
    results = [sagfree.solve(p, solver) for p in problems]
    return results, float(np.mean([r.time for r in results])), sum(r.setup_time for r in results)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--groom", type=int, default=20, help="groom strands")
    parser.add_argument("--vertices", type=int, default=100, help="vertices per groom strand")
    parser.add_argument("--stiffness", default="element", choices=("element", "strand"))
    args = parser.parse_args()
    warm = sagfree.scenes.horizontal(n=12)
    for solver in SOLVERS:  # compile / build caches outside the timing
        sagfree.solve(sagfree.Problem(warm, stiffness=args.stiffness), solver)
    print(f"stiffness = {args.stiffness!r}; times per strand on one core; ratio = time / time of asc\n")
    print(f"{'case':18} {'solver':11} {'statuses':26} {'ms/strand':>10} {'ratio':>8} {'setup s':>8} {'max |c|':>9} "
          f"{'R / R_asc - 1':>14}  iterations (mean per strand)")
    for name, strands in cases(args.groom, args.vertices).items():
        reference, reference_time = None, None
        for solver in SOLVERS:
            results, per_strand, setup = run(strands, solver, args.stiffness)
            if solver == "asc":
                reference, reference_time = results, per_strand
            statuses = ", ".join(f"{s} {n}" for s in ("converged", "max_iterations", "failed", "infeasible")
                                 if (n := sum(r.status == s for r in results)))
            both = [(r.objective, a.objective) for r, a in zip(results, reference)
                    if r.status == a.status == "converged" and a.objective > 0]
            gap = f"{np.mean([o / a - 1 for o, a in both]):14.1e}" if both else f"{'-':>14}"
            print(f"{name:18} {solver:11} {statuses:26} {per_strand * 1e3:10.1f} "
                  f"{per_strand / reference_time:8.1f} {setup:8.1f} {max(r.residual_inf for r in results):9.1e} "
                  f"{gap}  {iteration_summary(results)}")
        print()


if __name__ == "__main__":
    main()
