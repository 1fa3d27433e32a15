"""The ``sagfree`` command line (DESIGN section 10).

Exit codes: 0 success; 1 a check failed (``check``: a derivative mismatch; ``optimize``: a strand
did not converge; ``simulate``: a strand moved more than ``--max-sag``, fell after a push or was not
checked; ``demo``, ``study``, ``report``: ``asc`` failed or hit a limit on a strand, or a derivative
check failed; an ``infeasible`` strand is an answer; ``view``: 0 once the page is written); 2 bad
usage or unreadable input; 130 interrupted (Ctrl-C; ``optimize`` keeps the finished strands and
prints the ``--resume`` command).
"""
from __future__ import annotations

import argparse
import shlex
import sys
import time
import warnings
from pathlib import Path

from sagfree.frontend.table import SOLVERS

#: exit code after Ctrl-C (128 + SIGINT, what shells report)
INTERRUPTED = 130
#: what ``simulate`` and ``view`` say of an OpenUSD stage that carries no parameters
NO_STAGE_PARAMETERS = ("the stage's curves carry no sagfree parameters (primvars:sagfree:parameters); write "
                       "them with 'sagfree optimize INPUT -o OUT.usda'")


def _solver_list(text: str) -> str:
    unknown = [s for s in (t.strip() for t in text.split(",")) if s and s not in SOLVERS]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown solver(s) {', '.join(unknown)}; choose from "
                                         f"{', '.join(SOLVERS)}")
    return text


def _demo(args) -> int:
    from sagfree.reports.demo import run_demo

    solvers = [s.strip() for s in args.solvers.split(",") if s.strip()]
    run = run_demo(args.out, progress=not args.quiet, jobs=args.jobs, solvers=solvers,
                   baseline_strands=args.baseline_strands)
    return _study_summary(run)


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
    from sagfree.scenes.catalog import SCENE_BODIES

    options = {"stiffness": args.stiffness, "curvature": args.curvature, "stabilize": not args.no_stabilize}
    bodies = args.body if args.body is not None else list(SCENE_BODIES.get(str(args.input), ()))
    bodies = [] if bodies == ["none"] else bodies
    if bodies:
        options["bodies"] = bodies
    if args.contact_distance is not None:
        options["contact_distance"] = args.contact_distance
    if args.friction:
        options["friction"] = args.friction
    if args.bound:
        options["bounds"] = dict(args.bound)
    return options


def _bound(text: str) -> tuple[str, object]:
    """--bound BLOCK=LOWER,UPPER (the box of every entry of a block, in p's normalized units) or
    --bound curvature_budget=VALUE / twist_budget=VALUE: the ``bounds`` of Problem."""
    from sagfree.formulation.parameters import BLOCKS, BUDGETS

    name, equals, raw = (part.strip() for part in text.partition("="))
    if not equals or name not in (*BLOCKS, *BUDGETS):
        raise argparse.ArgumentTypeError(f"--bound {text!r}: expected BLOCK=LOWER,UPPER with BLOCK one of "
                                         f"{', '.join(BLOCKS)}, or {' / '.join(BUDGETS)}=VALUE")
    try:
        values = [float(v) for v in raw.split(",")]
    except ValueError:
        values = []
    if len(values) != (1 if name in BUDGETS else 2):
        raise argparse.ArgumentTypeError(f"--bound {text!r}: {name} takes "
                                         f"{'one value' if name in BUDGETS else 'LOWER,UPPER'}")
    return name, values[0] if name in BUDGETS else values


def _count(minimum: int):
    """argparse type: an integer >= minimum."""
    return _checked(int, lambda v: v >= minimum, f"at least {minimum}")


def _number(positive: bool):
    """argparse type: a finite number, > 0 if ``positive`` else >= 0."""
    return _checked(float, (lambda v: 0 < v < float("inf")) if positive else (lambda v: 0 <= v < float("inf")),
                    "positive and finite" if positive else "non-negative and finite")


def _checked(kind, accepts, wanted: str):
    """argparse type: ``kind(text)`` where ``accepts`` it, else a usage error saying what is ``wanted``."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
        if not accepts(value):
            raise argparse.ArgumentTypeError(f"must be {wanted}, got {text}")
        return value
    return parse


def _parameters_output(text: str) -> str:
    """argparse type of ``optimize -o``: a parameters file (.npz) or an OpenUSD stage with the
    parameters as primvars, by extension."""
    from sagfree.scenes.usd import EXTENSIONS

    if Path(text).suffix.lower() not in (".npz", *EXTENSIONS):
        raise argparse.ArgumentTypeError(f"{text!r}: the output must end in .npz (a parameters file) or "
                                         f"{', '.join(EXTENSIONS)} (an OpenUSD stage with them as primvars)")
    return text


def _solver_options(args) -> dict:
    """--option NAME=VALUE pairs, checked against the solver's options before any work."""
    from sagfree.frontend.options import check_options, parse_option

    return check_options(args.solver, dict(parse_option(text, args.solver) for text in args.option or ()))


def study_options(option_texts, solvers) -> dict:
    """--option [SOLVER:]NAME=VALUE pairs of a study: with a solver prefix for that solver only,
    without one for every solver of the study (so it must be an option each takes, e.g. tol)."""
    from sagfree.frontend.options import InvalidOption, check_options, parse_option

    options: dict = {solver: {} for solver in solvers}
    for text in option_texts or ():
        prefix, colon, rest = text.partition(":")
        targets, pair = ([prefix], rest) if colon and "=" not in prefix else (list(solvers), text)
        for solver in targets:
            if solver not in options:
                raise InvalidOption(f"--option {text}: {solver!r} is not a solver of this study "
                                    f"({', '.join(solvers)})")
            options[solver].update([parse_option(pair, solver)])
    return {solver: check_options(solver, given) for solver, given in options.items() if given}


def _optimize(args) -> int:
    import time

    from sagfree.contract.result import status_summary
    from sagfree.frontend.batch import optimize
    from sagfree.frontend.checkpoint import Checkpoint
    from sagfree.scenes.npz import save_parameters
    from sagfree.scenes.usd import is_stage, require_pxr, save_stage

    if is_stage(args.output):
        require_pxr()  # before the work, not after it
    solver_options = _solver_options(args)
    strands = _load_input(args)
    options = _problem_options(args)
    checkpoint = Checkpoint(args.output, strands, args.solver, {**options, "solver_options": solver_options},
                            args.resume)
    todo = [k for k in range(len(strands)) if k not in checkpoint.done]
    if checkpoint.done:
        print(f"resuming: {len(checkpoint.done)} of {len(strands)} strands were solved before")
    start = time.perf_counter()
    try:
        optimize([strands[k] for k in todo], solver=args.solver, jobs=args.jobs, progress=not args.quiet,
                 scheduler=args.scheduler, solver_options=solver_options,
                 on_chunk=lambda first, res: checkpoint.save(todo[first: first + len(res)], res), **options)
    except KeyboardInterrupt:
        again = shlex.join(["sagfree", *(args.argv or ["optimize"]), *([] if args.resume else ["--resume"])])
        print(f"\ninterrupted: {len(checkpoint.done)} of {len(strands)} strands are solved and kept in "
              f"{checkpoint.directory}/; continue with\n  {again}", file=sys.stderr)
        return INTERRUPTED
    wall = time.perf_counter() - start
    results = [checkpoint.done[k] for k in range(len(strands))]
    if is_stage(args.output):  # the input stage copied (a new stage for other input), parameters as primvars
        save_stage(args.output, strands, results, args.solver, options,
                   source=args.input if is_stage(args.input) else None)
    else:
        save_parameters(args.output, strands, results, args.solver, options)
    checkpoint.remove()
    print(f"{len(results)} strands with {args.solver} in {wall:.2f} s: {status_summary(results)}")
    eigenvalues = [r.min_eigenvalue for r in results if r.min_eigenvalue == r.min_eigenvalue]
    if eigenvalues:
        print(f"stable rest states {sum(r.stable for r in results)}/{len(results)}; smallest eigenvalue "
              f"{min(eigenvalues):.3g} s^-2 (omega^2 of the slowest mode)")
    for k, r in enumerate(results):
        if r.status != "converged":
            print(f"  strand {k}: {r.status}: {r.message}")
    print(f"wrote {args.output} and {Path(args.output).with_suffix('.json')}")
    return 0 if all(r.status == "converged" for r in results) else 1


def _load_parameters(args):
    """The parameters ``--params`` names (a .npz file, or an OpenUSD stage ``optimize`` wrote), else
    those the input carries when it is such a stage (scenes.usd); ValueError if there are none."""
    from sagfree.scenes.usd import is_stage

    params = _given_parameters(args)
    if params is None and is_stage(args.input):
        raise ValueError(f"{args.input}: {NO_STAGE_PARAMETERS}, or give --params FILE")
    if params is None:
        raise ValueError(f"{args.input}: --params FILE is needed (the parameters 'sagfree optimize' wrote); only an "
                         "OpenUSD stage written by 'sagfree optimize' carries its own")
    return params


def _given_parameters(args):
    """The parameters ``--params`` names, else those an input stage carries, else None (each file
    read once)."""
    from sagfree.scenes.npz import load_parameters
    from sagfree.scenes.usd import is_stage, load_stage_parameters

    source = args.params if args.params is not None else args.input
    if not is_stage(source):
        return load_parameters(args.params) if args.params is not None else None
    params = load_stage_parameters(source)
    if params is None and args.params is not None:
        raise ValueError(f"{source}: {NO_STAGE_PARAMETERS}")
    return params


def _simulate(args) -> int:
    from sagfree.frontend.batch import simulate_strands

    params, strands = _checked_parameters(args, _load_input(args), _load_parameters(args))
    from sagfree.formulation.simulation import PUSH, PUSH_DURATION

    push = not args.no_push
    checks = simulate_strands(strands, params.p, args.steps, args.dt, args.damping, jobs=args.jobs,
                              progress=not args.quiet, scheduler=args.scheduler, push=push,
                              **params.problem_options)
    header = (f"{'strand':>6} {'vertices':>8} {'optimized':>10} {'sag (m)':>10} {'sag / L':>9} "
              f"{'static / L':>10} {'push / L':>9} {'newton':>6}  verdict")
    print(f"{len(strands)} strands, {args.steps} implicit-Euler steps of {args.dt:g} s from rest, then the static "
          f"equilibrium" + (f", then {PUSH_DURATION:g} s after a push of {PUSH:g} L along the softest mode"
                            if push else "") + f"; parameters by {params.solver}")
    print(header)
    print("-" * len(header))
    moving = falling = 0
    for k, (strand, status, check) in enumerate(zip(strands, params.status, checks)):
        verdict = ("moves" if check.sags(args.max_sag) else "falls after a push" if push and not check.holds
                   else "holds" if push else "still")
        moving += verdict == "moves"
        falling += verdict == "falls after a push"
        print(f"{k:>6} {strand.n_vertices:>8} {status:>10} {check.sag:>10.3g} {check.relative_sag:>9.2e} "
              f"{check.static_sag:>10.2e} {check.push:>9.2e} {check.newton:>6.1f}  {verdict}"
              + (f" ({check.message})" if check.message else ""))
    print(f"\n{len(strands) - moving}/{len(strands)} strands stay within {args.max_sag:g} of their length"
          + (f"; {sum(c.holds for c in checks)}/{len(strands)} hold after a push" if push else ""))
    return 1 if moving or falling else 0


def _view(args) -> int:
    from sagfree.reports.view import write_view

    strands = _load_input(args)
    params = _given_parameters(args)
    if params is not None:
        params, strands = _checked_parameters(args, strands, params)
        count = len(strands) if args.max_strands is None else min(args.max_strands, len(strands))
        strands = strands[:count]
        parameters, status, messages = params.p[:count], params.status[:count], params.message[:count]
        options, solver = params.problem_options, params.solver
    else:  # optimized here, as `sagfree optimize` would with its default options
        from sagfree.frontend.batch import optimize
        from sagfree.scenes.catalog import SCENE_BODIES

        strands = strands[: args.max_strands]
        options = {"bodies": list(SCENE_BODIES[str(args.input)])} if str(args.input) in SCENE_BODIES else {}
        results = optimize(strands, jobs=args.jobs, progress=not args.quiet, scheduler=args.scheduler, **options)
        parameters, status, messages = ([r.p for r in results], [r.status for r in results],
                                        [r.message for r in results])
        solver = "asc"
    output = Path(args.output) if args.output else Path(f"{Path(str(args.input)).stem}.view.html")
    path = write_view(output, strands, parameters, options, status, messages,
                      title=f"sagfree view: {Path(str(args.input)).name}, parameters by {solver}", jobs=args.jobs,
                      progress=not args.quiet, scheduler=args.scheduler)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB, {len(strands)} strand{'s' if len(strands) != 1 else ''})")
    return 0


def _checked_parameters(args, strands, params):
    """(``params``, ``strands``) checked against each other; the material the input file does not
    store (an OBJ's, a .hair's moduli) and the command line does not give is the material the
    parameters were computed for."""
    from sagfree.scenes.catalog import stored_material
    from sagfree.scenes.npz import MATERIAL_FIELDS

    given = {name for name, value in _material(args).items() if value is not None}
    strands = params.with_material(strands, [f for f in MATERIAL_FIELDS
                                             if f not in stored_material(args.input) and f not in given])
    for note in params.check_matches(strands, args.input):
        print(f"note: {note}", file=sys.stderr)
    return params, strands


def _input_arguments(command) -> None:
    command.add_argument("input", metavar="INPUT", help="strands file (.npz, .hair, .data, .obj, OpenUSD "
                         ".usd/.usda/.usdc) or built-in "
                         "scene name (default-groom, horizontal, flipped, helix, wavy, curly, cable, "
                         "horizontal-tip-pinned, long-hair-on-head)")
    command.add_argument("--units", default=None, choices=("m", "cm", "mm"),
                         help="length unit of a .hair/.data/.obj file (default: cm for .hair, m otherwise; a USD "
                         "stage states its own metersPerUnit)")
    command.add_argument("--root", default=None, choices=("clamped", "pinned"),
                         help="hold every strand's root so (default: the file's, clamped for hair files)")
    command.add_argument("--tip", default=None, choices=("free", "pinned", "clamped"),
                         help="hold every strand's tip so (default: the file's, free for hair files)")
    material = command.add_argument_group(
        "material of a .hair, .data or .obj file's strands (default: human hair, r 50 um, E 1e9 Pa, G 4e8 Pa, "
        "1300 kg/m^3; a .hair file's thickness gives the radius)")
    material.add_argument("--radius", type=_number(positive=True), metavar="M", help="strand radius in m")
    material.add_argument("--youngs-modulus", type=_number(positive=True), metavar="PA", help="Young's modulus E in Pa")
    material.add_argument("--shear-modulus", type=_number(positive=True), metavar="PA", help="shear modulus G in Pa")
    material.add_argument("--density", type=_number(positive=True), metavar="KG_M3", help="density in kg/m^3")
    command.add_argument("--pin", action="append", type=_count(0), default=None, metavar="VERTEX",
                         help="also prescribe this vertex's position on every strand (repeatable)")


def _load_input(args) -> list:
    """The input strands with the command line's attachments; a strand they do not fit (a pin past
    its last vertex) becomes invalid with the reason, and the batch goes on."""
    from sagfree.formulation.strand import InvalidStrand
    from sagfree.scenes import load

    strands = load(args.input, args.units, keep_invalid=True,
                   **{name: value for name, value in _material(args).items() if value is not None})
    if args.root is None and args.tip is None and args.pin is None:
        return strands
    attached = []
    for k, strand in enumerate(strands):
        try:
            attached.append(strand if isinstance(strand, InvalidStrand) else
                            strand.attached(args.root, args.tip, args.pin))
        except ValueError as exc:
            attached.append(InvalidStrand(strand.points, f"{args.input}: strand {k}: {exc}"))
    return attached


def _material(args) -> dict:
    """--radius, --youngs-modulus, --shear-modulus, --density (None where not given)."""
    return {name: getattr(args, name, None) for name in ("radius", "youngs_modulus", "shear_modulus", "density")}


def _simulation_arguments(command) -> None:
    command.add_argument("--steps", type=_count(1), default=200, help="implicit-Euler time steps (default 200)")
    command.add_argument("--dt", type=_number(positive=True), default=1e-3, help="time step in s (default 1e-3)")


def _batch_arguments(command) -> None:
    command.add_argument("--jobs", type=_count(1), default=None, help="worker processes (default: all cores)")
    command.add_argument("--scheduler", default=None, metavar="ADDRESS",
                         help="run on a Dask cluster: a scheduler address (tcp://host:8786) or 'local' for a "
                         "LocalCluster of --jobs workers (needs dask.distributed)")
    command.add_argument("--quiet", action="store_true", help="no progress bars")


def _report(args) -> int:
    from sagfree.reports.report import write_report
    from sagfree.reports.study import run_study
    from sagfree.reports.study_file import StudyRun
    from sagfree.scenes import load
    from sagfree.scenes.catalog import SCENE_BODIES

    start = time.perf_counter()
    scenes = {name: load(name, args.units)[: args.max_strands] for name in
              (n.strip() for n in args.scenes.split(",")) if name}
    solvers = [s.strip() for s in args.solvers.split(",") if s.strip()]
    solver_options = study_options(args.option, solvers)
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    scene_options = {name: {"bodies": list(SCENE_BODIES[name])} for name in scenes if name in SCENE_BODIES}
    study = run_study(scenes, solvers, modes, steps=args.steps, dt=args.dt, jobs=args.jobs,
                      progress=not args.quiet, scheduler=args.scheduler, solver_options=solver_options,
                      scene_options=scene_options)
    files = write_report(study, args.out, "sagfree report", pdf=not args.no_pdf)
    return _study_summary(StudyRun(study, files, seconds=time.perf_counter() - start))


def _study(args) -> int:
    from sagfree.reports.study_file import run_study_file

    run = run_study_file(args.file, args.out, jobs=args.jobs, progress=not args.quiet, pdf=not args.no_pdf)
    return _study_summary(run)


def _study_summary(run) -> int:
    """A line per case (wall time of its batch, statuses, forward checks), the derivative checks and
    the files written; exit code 1 if asc failed or hit its limits on a strand (``infeasible`` is an
    answer) or a derivative check failed."""
    from sagfree.contract.result import status_summary
    from sagfree.reports.report import STILL

    study, files = run.study, run.files
    width = max(12, *(len(case.scene) for case in study.cases))
    for case in study.cases:
        checks = ""
        if case.checks:
            still = sum(not check.sags(STILL) for check in case.checks)
            checks = f"still {still}/{len(case.checks)}"
            if case.pushed:
                checks += f", hold after a push {sum(c.holds for c in case.pushed)}/{len(case.pushed)}"
        print(f"{case.scene:{width}} {case.mode:8} {case.solver:10} {case.wall:7.2f} s   "
              f"{status_summary(case.results):34} {checks}")
    if run.checks_total:
        print(f"derivative checks: {run.checks_passed}/{run.checks_total} passed")
    print(f"took {run.seconds:.0f} s; wrote {files.markdown}" + (f" and {files.pdf}" if files.pdf else ""))
    failed = any(r.status in ("failed", "max_iterations") for c in study.cases if c.solver == "asc"
                 for r in c.results)
    return 1 if failed or run.checks_passed < run.checks_total else 0


def parser() -> argparse.ArgumentParser:
    from sagfree.formulation.curvature import VARIANTS

    top = argparse.ArgumentParser(prog="sagfree", description="Sag-free Discrete Elastic Rods: choose "
                                  "rest shape and stiffness so that a groomed strand is in equilibrium.")
    sub = top.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="the main job on the embedded default groom, with a report",
                          description="Run the shipped study studies/demo.toml (the same as `sagfree "
                          "study` on it): every strand of the embedded default groom with our solver and the "
                          "naive baseline, the other baselines on the first strands, held strands and long "
                          "hair on a head, forward checks, the supplement's experiments, the derivative "
                          "verification; writes report.md and report.pdf.")
    demo.add_argument("--out", default="sagfree-demo", help="output directory (default: sagfree-demo)")
    demo.add_argument("--jobs", type=_count(1), default=None, help="worker processes (default: all cores)")
    demo.add_argument("--quiet", action="store_true", help="no progress bars")
    demo.add_argument("--solvers", default=",".join(SOLVERS), type=_solver_list,
                      help=f"comma-separated solvers (default: all: {','.join(SOLVERS)}); asc always runs")
    demo.add_argument("--baseline-strands", type=_count(0), default=None,
                      help="strands the baselines other than naive solve and check (default: the "
                           "study file's limits)")
    demo.set_defaults(run=_demo)

    check = sub.add_parser("check", help="Jacobian verification table; non-zero exit on any mismatch",
                           description="Compare CasADi AD forces and parameter Jacobians with the "
                           "hand-derived formulas S(7)-(19) and with finite differences, for every energy "
                           "term, parameter block and curvature variant on random strands.")
    check.add_argument("--variant", action="append", choices=VARIANTS,
                       help="curvature variant to check (repeatable; default: all)")
    check.add_argument("--seed", type=int, default=0, help="seed of the random strands (default 0)")
    check.add_argument("--vertices", type=_count(3), default=12, help="vertices per random strand (default 12)")
    check.set_defaults(run=_check)

    opt = sub.add_parser("optimize", help="solve many strands; write their parameters to a .npz file or a USD stage",
                         description="Choose rest shape and stiffness so that every strand of INPUT is "
                         "in static equilibrium; write the parameters (per block, in physical units, and "
                         "each strand's status) to OUT (.npz, or a copy of an OpenUSD input stage with "
                         "them as sagfree: primvars) and a JSON summary next to it. Ctrl-C keeps the "
                         "finished strands for --resume. Exit code 1 if a strand did not converge.")
    _input_arguments(opt)
    opt.add_argument("-o", "--output", required=True, metavar="OUT", type=_parameters_output,
                     help="parameters file to write (.npz), or an OpenUSD stage (.usda, .usdc, .usd)")
    opt.add_argument("--solver", default="asc", choices=SOLVERS, help="solver (default asc)")
    opt.add_argument("--option", action="append", metavar="NAME=VALUE",
                     help="a solver option, e.g. tol=1e-9 or max_iterations=100 (repeatable; the common "
                     "ones: tol, kkt_tol, max_iterations, max_seconds; README, 'Solver options')")
    opt.add_argument("--stiffness", default="element", choices=("element", "strand", "fixed"),
                     help="stiffness per element, one per strand, or fixed (default element)")
    opt.add_argument("--curvature", default="4d", choices=VARIANTS, help="curvature variant (default 4d)")
    opt.add_argument("--body", action="append", default=None, metavar="SPEC",
                     help="a body the strands may rest on (repeatable): sphere:cx,cy,cz,radius, "
                     "capsule:ax,ay,az,bx,by,bz,radius (m) or an .obj mesh in m (default: the built-in "
                     "scene's, e.g. the head of long-hair-on-head; 'none': no bodies)")
    opt.add_argument("--contact-distance", type=_number(positive=True), default=None, metavar="M",
                     help="vertices within this distance (m) of a body rest on it (default 2 strand radii)")
    opt.add_argument("--friction", type=_number(positive=False), default=0.0, metavar="MU",
                     help="Coulomb friction coefficient between strands and bodies (default 0: frictionless)")
    opt.add_argument("--bound", action="append", type=_bound, metavar="BLOCK=LO,HI",
                     help="the box of a parameter block, e.g. bend_stiffness=1,1000 (stiffness "
                     "multipliers), rest_length=-0.1,0.1 (relative), or curvature_budget=VALUE / "
                     "twist_budget=VALUE (rad per strand) for the rest-shape boxes (repeatable; "
                     "what an infeasible strand's message asks to relax)")
    opt.add_argument("--no-stabilize", action="store_true",
                     help="the bare problem: converged strands need not be stable rest states")
    opt.add_argument("--resume", action="store_true",
                     help="continue an interrupted run from OUT.partial/ instead of starting over")
    _batch_arguments(opt)
    opt.set_defaults(run=_optimize)

    sim = sub.add_parser("simulate", help="forward-check optimized parameters: sag per strand",
                         description="Simulate every strand of INPUT with the parameters written by "
                         "'sagfree optimize' (implicit Euler from rest, then the static equilibrium) and "
                         "print its sag. Exit code 1 if a strand moves more than --max-sag of its length.")
    _input_arguments(sim)
    sim.add_argument("--params", default=None, metavar="FILE",
                     help="parameters from 'sagfree optimize': a .npz file or the OpenUSD stage it wrote (default: "
                     "INPUT's own, when INPUT is such a stage)")
    _simulation_arguments(sim)
    sim.add_argument("--damping", type=_number(positive=False), default=0.0,
                     help="mass-proportional damping in 1/s (default 0)")
    sim.add_argument("--no-push", action="store_true",
                     help="skip the push along each strand's softest mode (5 s of simulation per strand)")
    sim.add_argument("--max-sag", type=_number(positive=True), default=1e-6,
                     help="largest displacement, relative to strand length, that counts as still (default 1e-6)")
    _batch_arguments(sim)
    sim.set_defaults(run=_simulate)

    view = sub.add_parser("view", help="an interactive 3D page of a groom: groomed, naive droop, optimized",
                          description="Write one self-contained HTML page (plotly.js inlined: it works offline) "
                          "showing every strand of INPUT groomed, in the static equilibrium it droops into with "
                          "the specified parameters (naive) and in the static state of its optimized parameters, "
                          "coloured by the bend stiffness multiplier, with the bodies the strands rest on; pick a "
                          "strand by typing its index or clicking it. Without --params the strands are "
                          "optimized first with asc and the default options, as 'sagfree optimize' would.")
    _input_arguments(view)
    view.add_argument("--params", default=None, metavar="FILE",
                      help="parameters file from 'sagfree optimize' (default: optimize the strands with asc first)")
    view.add_argument("-o", "--output", default=None, metavar="OUT.html",
                      help="page to write (default: <input stem>.view.html in the current directory)")
    view.add_argument("--max-strands", type=_count(1), default=None, metavar="N", help="show the first N strands only")
    _batch_arguments(view)
    view.set_defaults(run=_view)

    rep = sub.add_parser("report", help="a study (scenes x solvers x modes) written as report.md and report.pdf",
                         description="Solve the chosen scenes with the chosen solvers in the chosen parameter "
                         "modes, forward-check every result by simulation, and write report.md, report.pdf and "
                         "their figures. Exit code 1 if asc did not converge on a strand.")
    rep.add_argument("--out", default="sagfree-report", help="output directory (default: sagfree-report)")
    rep.add_argument("--scenes", default="horizontal,helix,wavy,curly",
                     help="comma-separated built-in scene names or strand files (default: "
                     "horizontal,helix,wavy,curly)")
    rep.add_argument("--units", default=None, help="length unit of hair files: m, cm or mm (default: the format's)")
    rep.add_argument("--solvers", default="asc,ipopt,osqp,penalty-gn,naive", type=_solver_list,
                     help="comma-separated solvers (default: all)")
    rep.add_argument("--modes", default="element,strand", help="comma-separated stiffness modes (default: "
                     "element,strand)")
    rep.add_argument("--max-strands", type=_count(1), default=None, help="solve only the first N strands of each scene")
    rep.add_argument("--option", action="append", metavar="[SOLVER:]NAME=VALUE",
                     help="a solver option, for one solver (osqp:max_seconds=20) or for every solver of the "
                     "study (tol=1e-9); repeatable")
    rep.add_argument("--no-pdf", action="store_true", help="write report.md only")
    _simulation_arguments(rep)
    _batch_arguments(rep)
    rep.set_defaults(run=_report)

    stu = sub.add_parser("study", help="a study declared in a TOML file, written as report.md and report.pdf",
                         description="Run the study a TOML file declares (scenes or strand files, solvers, "
                         "stiffness modes, curvature variants, solver options, strand subsets, simulation "
                         "checks; see sagfree/reports/study_file.py and the examples in studies/) and write "
                         "its report. Exit code 1 if asc failed or hit a limit on a strand or a derivative "
                         "check failed, 2 for a malformed file.")
    stu.add_argument("file", metavar="STUDY.toml", help="the study file")
    stu.add_argument("--out", default=None, help="output directory (default: the file's 'out', else its name)")
    stu.add_argument("--no-pdf", action="store_true", help="write report.md only")
    _batch_arguments(stu)
    stu.set_defaults(run=_study)
    return top


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    # warnings read as the command's own lines, not as a Python source location
    python_format = warnings.formatwarning
    warnings.formatwarning = lambda message, category, *rest, **kw: f"sagfree {args.command}: warning: {message}\n"
    try:
        return args.run(args)
    except KeyboardInterrupt:  # Ctrl-C: a line, not a traceback (optimize says how to resume)
        print(f"\nsagfree {args.command}: interrupted", file=sys.stderr)
        return INTERRUPTED
    except (FileNotFoundError, ValueError, ImportError) as exc:  # unreadable input, a missing optional package
        print(f"sagfree {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into a reader that stopped (| head): not an error of ours
        sys.stderr.close()
        return 0
    finally:
        warnings.formatwarning = python_format


if __name__ == "__main__":
    sys.exit(main())
