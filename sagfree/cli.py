"""The ``sagfree`` command line (DESIGN section 10).

Exit codes: 0 success; 1 a check failed (``demo``, ``check``: a derivative mismatch; ``optimize``:
a strand did not converge; ``simulate``: a strand moved more than ``--max-sag`` or was not checked);
2 bad usage or unreadable input.
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
    print("forward check (sag <= 1e-6 L): " + ", ".join(f"{name} {still}/{total} still"
                                                          for name, (still, total) in summary.still.items()))
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


def _problem_options(args) -> dict:
    return {"stiffness": args.stiffness, "curvature": args.curvature}


def _optimize(args) -> int:
    import time

    from sagfree.scenes import load
    from sagfree.scenes.npz import save_parameters
    from sagfree.solvers.batch import optimize

    strands = load(args.input)
    options = _problem_options(args)
    start = time.perf_counter()
    results = optimize(strands, solver=args.solver, jobs=args.jobs, progress=not args.quiet, **options)
    wall = time.perf_counter() - start
    save_parameters(args.output, results, args.solver, options)
    counts = {}
    for r in results:
        counts[r.status] = counts.get(r.status, 0) + 1
    print(f"{len(results)} strands with {args.solver} in {wall:.2f} s: "
          + ", ".join(f"{k} {v}" for k, v in counts.items()))
    for k, r in enumerate(results):
        if r.status != "converged":
            print(f"  strand {k}: {r.status}: {r.message}")
    print(f"wrote {args.output}")
    return 0 if counts.get("converged", 0) == len(results) else 1


def _simulate(args) -> int:
    from sagfree.scenes import load
    from sagfree.scenes.npz import load_parameters
    from sagfree.solvers.batch import simulate_strands

    strands = load(args.input)
    params = load_parameters(args.params)
    if len(params.p) != len(strands):
        raise ValueError(f"{args.params} holds parameters of {len(params.p)} strands, {args.input} has "
                         f"{len(strands)}")
    checks = simulate_strands(strands, params.p, args.steps, args.dt, args.damping, jobs=args.jobs,
                              progress=not args.quiet, **params.problem_options)
    header = (f"{'strand':>6} {'vertices':>8} {'optimized':>10} {'sag (m)':>10} {'sag / L':>9} "
              f"{'static / L':>10} {'newton':>6}  verdict")
    print(f"{len(strands)} strands, {args.steps} implicit-Euler steps of {args.dt:g} s from rest, "
          f"then the static equilibrium; parameters by {params.solver}")
    print(header)
    print("-" * len(header))
    moving = 0
    for k, (strand, status, check) in enumerate(zip(strands, params.status, checks)):
        verdict = "moves" if check.sags(args.max_sag) else "still"
        moving += verdict == "moves"
        print(f"{k:>6} {strand.n_vertices:>8} {status:>10} {check.sag:>10.3g} {check.relative_sag:>9.2e} "
              f"{check.static_sag:>10.2e} {check.newton:>6.1f}  {verdict}"
              + (f" ({check.message})" if check.message else ""))
    print(f"\n{len(strands) - moving}/{len(strands)} strands stay within {args.max_sag:g} of their length")
    return 1 if moving else 0


def parser() -> argparse.ArgumentParser:
    from sagfree.formulation.curvature import VARIANTS

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
    check.add_argument("--variant", action="append", choices=VARIANTS,
                       help="curvature variant to check (repeatable; default: all)")
    check.add_argument("--seed", type=int, default=0, help="seed of the random strands (default 0)")
    check.add_argument("--vertices", type=int, default=12, help="vertices per random strand (default 12)")
    check.set_defaults(run=_check)

    opt = sub.add_parser("optimize", help="solve many strands; write their parameters to a .npz file",
                         description="Choose rest shape and stiffness so that every strand of INPUT is "
                         "in static equilibrium; write the parameters (and each strand's status) to OUT. "
                         "Exit code 1 if a strand did not converge.")
    opt.add_argument("input", metavar="INPUT", help="strands file (.npz) or built-in scene name "
                     "(default-groom, horizontal, flipped, helix, wavy, curly)")
    opt.add_argument("-o", "--output", required=True, metavar="OUT", help="parameters file to write (.npz)")
    opt.add_argument("--solver", default="asc", choices=SOLVERS, help="solver (default asc)")
    opt.add_argument("--stiffness", default="element", choices=("element", "strand", "fixed"),
                     help="stiffness per element, one per strand, or fixed (default element)")
    opt.add_argument("--curvature", default="4d", choices=VARIANTS, help="curvature variant (default 4d)")
    opt.add_argument("--jobs", type=int, default=None, help="worker processes (default: all cores)")
    opt.add_argument("--quiet", action="store_true", help="no progress bar")
    opt.set_defaults(run=_optimize)

    sim = sub.add_parser("simulate", help="forward-check optimized parameters: sag per strand",
                         description="Simulate every strand of INPUT with the parameters written by "
                         "'sagfree optimize' (implicit Euler from rest, then the static equilibrium) and "
                         "print its sag. Exit code 1 if a strand moves more than --max-sag of its length.")
    sim.add_argument("input", metavar="INPUT", help="strands file or built-in scene name, as given to optimize")
    sim.add_argument("--params", required=True, metavar="FILE", help="parameters file from 'sagfree optimize'")
    sim.add_argument("--steps", type=int, default=200, help="time steps (default 200)")
    sim.add_argument("--dt", type=float, default=1e-3, help="time step in s (default 1e-3)")
    sim.add_argument("--damping", type=float, default=0.0, help="mass-proportional damping in 1/s (default 0)")
    sim.add_argument("--max-sag", type=float, default=1e-6,
                     help="largest displacement, relative to strand length, that counts as still (default 1e-6)")
    sim.add_argument("--jobs", type=int, default=None, help="worker processes (default: all cores)")
    sim.add_argument("--quiet", action="store_true", help="no progress bar")
    sim.set_defaults(run=_simulate)
    return top


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    try:
        return args.run(args)
    except (FileNotFoundError, ValueError) as exc:  # unreadable or inconsistent input
        print(f"sagfree {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
