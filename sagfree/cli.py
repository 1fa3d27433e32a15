"""The ``sagfree`` command line (DESIGN section 10).

Exit codes: 0 success; 1 a check failed; 2 bad usage (argparse).
"""
from __future__ import annotations

import argparse
import sys

from sagfree.solvers.registry import SOLVERS


def _solver_list(text: str) -> str:
    unknown = [s for s in (t.strip() for t in text.split(",")) if s and s not in SOLVERS]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown solver(s) {', '.join(unknown)}; choose from "
                                         f"{', '.join(SOLVERS)}")
    return text


def _demo(args) -> int:
    from sagfree.reports.demo import run_demo

    solvers = [s.strip() for s in args.solvers.split(",") if s.strip()]
    summary = run_demo(args.out, progress=not args.quiet, jobs=args.jobs, solvers=solvers,
                       baseline_strands=args.baseline_strands)
    print(f"groom: {summary.strands} strands, {summary.vertices} vertices")
    for solver, statuses in summary.statuses.items():
        counts = ", ".join(f"{k} {v}" for k, v in statuses.items() if v)
        print(f"{solver:10} {summary.wall_time[solver]:7.2f} s   {counts}")
    print(f"derivative checks: {summary.checks_passed}/{summary.checks_total} passed")
    print(f"wrote {summary.report}")
    return 0 if summary.checks_passed == summary.checks_total else 1


def _check(args) -> int:
    from sagfree.formulation.curvature import VARIANTS
    from sagfree.formulation.verification import FD_TOLERANCE, HAND_TOLERANCE, verify

    rows = verify(variants=tuple(args.variant or VARIANTS), seed=args.seed, n=args.vertices)
    header = f"{'term':8} {'quantity':26} {'variant':11} {'AD vs hand':>11} {'AD vs FD':>10}  result"
    print(header)
    print("-" * len(header))
    for r in rows:
        quantity = r.quantity + (" (zero)" if r.structural_zero else "")
        print(f"{r.term:8} {quantity:26} {r.variant:11} {r.hand_error:11.2e} {r.fd_error:10.2e}  "
              f"{'pass' if r.passed else 'FAIL'}")
    failed = [r for r in rows if not r.passed]
    print(f"\n{len(rows) - len(failed)}/{len(rows)} passed (tolerances: AD vs hand {HAND_TOLERANCE:g}, "
          f"AD vs finite differences {FD_TOLERANCE:g}, relative)")
    return 1 if failed else 0


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="sagfree", description="Sag-free Discrete Elastic Rods: choose "
                                  "rest shape and stiffness so that a groomed strand is in equilibrium.")
    sub = top.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="the main job on the embedded default groom, with a report",
                          description="Solve every strand of the embedded default groom with our solver "
                          "and the naive baseline, the other baselines on the first strands, verify the "
                          "derivatives, write report.md.")
    demo.add_argument("--out", default="sagfree-demo", help="output directory (default: sagfree-demo)")
    demo.add_argument("--jobs", type=int, default=None, help="worker processes (default: all cores)")
    demo.add_argument("--quiet", action="store_true", help="no progress bars")
    demo.add_argument("--solvers", default=",".join(SOLVERS), type=_solver_list,
                      help=f"comma-separated solvers (default: all: {','.join(SOLVERS)}); asc always runs")
    demo.add_argument("--baseline-strands", type=int, default=6,
                      help="strands the baselines other than naive solve (default 6)")
    demo.set_defaults(run=_demo)

    check = sub.add_parser("check", help="Jacobian verification table; non-zero exit on any mismatch",
                           description="Compare CasADi AD forces and parameter Jacobians with the "
                           "hand-derived formulas S(7)-(19) and with finite differences, for every energy "
                           "term, parameter block and curvature variant on random strands.")
    check.add_argument("--variant", action="append", choices=("4d", "2d-average", "2d-slerp"),
                       help="curvature variant to check (repeatable; default: all)")
    check.add_argument("--seed", type=int, default=0, help="seed of the random strands (default 0)")
    check.add_argument("--vertices", type=int, default=12, help="vertices per random strand (default 12)")
    check.set_defaults(run=_check)
    return top


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
