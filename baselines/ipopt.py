"""The `ipopt` baseline: the same NLP through CasADi's nlpsol('ipopt') (DESIGN section 6).

    minimize R(p) = 1/2 sum w (p - p0)^2   s.t.   c(p) = 0,   lower <= p <= upper,

with c(p) the CasADi expression of the symbolic module (the stencil functions mapped over the strand),
the exact Hessian of the Lagrangian by CasADi's AD, and MUMPS. Options, chosen so that Ipopt stops
where ours does:
- ``nlp_scaling_method none``: c is already unit-free (each row relative to its DOF's weight); with
  Ipopt's gradient scaling it stops at an unscaled |c|_inf of ~5e-9 instead of 1e-8 or below;
- ``constr_viol_tol`` = min(tol, 1e-10) and ``tol`` 1e-10: the |c|_inf target with margin;
- ``acceptable_iter 0``: no "acceptable level" exits;
- ``bound_relax_factor 0``: Ipopt otherwise relaxes each bound by 1e-8 of its size, and a rest length
  1e-9 outside its box moves c by ~1e-2 (a rest-length column of dc/dp is ~1e7). Even so, Ipopt's
  final x can leave the box by a rounding error; it is kept as returned (clipping one ulp of a rest
  length off moves c by 1e-8), and the message reports the excess.
One Ipopt instance per problem structure (strand size and options) is built and reused for every
strand of that structure; the strand's numbers are the NLP's parameter vector.
Model evaluation (``model``): "compiled" (the default) generates C for the NLP's functions (c, its
Jacobian, the Hessian of the Lagrangian, R and its gradient: CasADi's ``nlpsol`` dependencies),
compiles it once per structure with ``-O1`` (about 20 s for a 50-vertex strand, cached on disk like
the stencils, formulation.compiled) and lets Ipopt call the library, as ours calls compiled stencils:
6x faster per strand than CasADi's virtual machine, with the same iterates. "casadi" evaluates in
the virtual machine (no compilation: for one-off solves of many structures; the environment variable
``SAGFREE_IPOPT_MODEL=casadi`` makes it the default, which the test suite does). Building and
compiling is ``Result.setup_time``; CasADi's evaluation times go to ``Result.time_split``'s
``model``, everything else Ipopt does (MUMPS included, which CasADi does not time separately) to
``other``.
Status: ``converged`` needs |c|_inf <= tol and the KKT distance (contract.optimality) <= kkt_tol,
the same test as ours. Ipopt's tol 1e-10 is often below what rounding allows at a feasible optimum,
and it then ends with Search_Direction_Becomes_Too_Small or Restoration_Failed at a point that passes
that test; such a point counts as converged (the message keeps Ipopt's own status).
Iterations: Ipopt's own count, and its function / gradient / Hessian evaluation counts (``stats()``).
"""
from __future__ import annotations

import os
import time
import warnings

import casadi as ca
import numpy as np

from sagfree.contract.feasibility import judged_tolerance, raised_note
from sagfree.contract.optimality import KKT_TOL, TOL, kkt_optimality
from sagfree.contract.result import Result, make_result
from sagfree.formulation.compiled import compile_library, generated_c, start_compiling
from sagfree.formulation.problem import Problem
from sagfree.formulation.symbolic import SymbolicNLP, structure_key
from sagfree.linalg import timing

#: Ipopt return status -> Result status (anything else is "failed")
RETURN_STATUS = {
    "Solve_Succeeded": "converged",
    "Infeasible_Problem_Detected": "infeasible",
    "Maximum_Iterations_Exceeded": "max_iterations",
    "Maximum_CpuTime_Exceeded": "max_iterations",
    "Maximum_WallTime_Exceeded": "max_iterations",
}
_SOLVERS: dict[tuple, ca.Function] = {}
MODELS = ("compiled", "casadi")
#: CasADi's names of the functions Ipopt calls (the generated library must export them all)
_NLP_FUNCTIONS = ("nlp_f", "nlp_g", "nlp_grad", "nlp_grad_f", "nlp_hess_l", "nlp_jac_g")
_warned = False


def available() -> bool:
    return bool(ca.has_nlpsol("ipopt"))


def ipopt_options(tol: float, max_iterations: int, max_seconds: float) -> dict:
    return {
        "nlp_scaling_method": "none",
        "tol": min(tol, 1e-10),
        "constr_viol_tol": min(tol, 1e-10),
        "compl_inf_tol": 1e-14,
        "acceptable_iter": 0,
        "bound_relax_factor": 0.0,
        "linear_solver": "mumps",
        "hessian_approximation": "exact",
        "max_iter": int(max_iterations),
        "max_wall_time": float(min(max_seconds, 1e20)),
        "print_level": 0,
        "sb": "yes",
    }


def default_model() -> str:
    model = os.environ.get("SAGFREE_IPOPT_MODEL", "compiled")
    if model not in MODELS:
        raise ValueError(f"SAGFREE_IPOPT_MODEL={model!r}; choose from {', '.join(MODELS)}")
    return model


def _solver(problem: Problem, options: dict, model: str) -> tuple[ca.Function, SymbolicNLP]:
    """Ipopt's instance for the problem's structure (cached per process; module docstring)."""
    nlp = SymbolicNLP.for_problem(problem)
    key = _key(problem, options, model)
    if key not in _SOLVERS:
        if len(_SOLVERS) >= 16:
            _SOLVERS.pop(next(iter(_SOLVERS)))
        solver = _interpreted(nlp, options)
        _SOLVERS[key] = _compiled(solver, nlp, options) if model == "compiled" else solver
    return _SOLVERS[key], nlp


def _settings(options: dict) -> dict:
    return {"ipopt": options, "print_time": False, "error_on_fail": False}


def _interpreted(nlp: SymbolicNLP, options: dict) -> ca.Function:
    """Ipopt on the NLP's CasADi expressions (evaluated by CasADi's virtual machine)."""
    return ca.nlpsol("sagfree_ipopt", "ipopt", {"x": nlp.p, "p": nlp.data, "f": nlp.objective,
                                                "g": nlp.constraint}, _settings(options))


def _compiled(solver: ca.Function, nlp: SymbolicNLP, options: dict) -> ca.Function:
    """The same Ipopt instance with its NLP functions compiled to C (or ``solver`` itself, after a
    one-time warning, when no compiler works)."""
    global _warned
    try:
        library = compile_library(_nlp_source(solver, nlp), "ipopt_nlp", "-O1")
        return ca.nlpsol("sagfree_ipopt", "ipopt", str(library), _settings(options))
    except (OSError, RuntimeError) as exc:
        if not _warned:
            _warned = True
            warnings.warn(f"sagfree: compiling Ipopt's NLP failed ({exc}); Ipopt evaluates the model in "
                          "CasADi's virtual machine instead (same iterates, about 6x slower).",
                          RuntimeWarning, stacklevel=3)
        return solver


def _nlp_source(solver: ca.Function, nlp: SymbolicNLP) -> str:
    """C of the functions Ipopt calls (the oracle and its derivatives, as CasADi builds them)."""
    oracle = ca.Function("nlp", [nlp.p, nlp.data], [nlp.objective, nlp.constraint], ["x", "p"], ["f", "g"])
    return generated_c([oracle, *(solver.get_function(name) for name in _NLP_FUNCTIONS)])


def precompile_ipopt(problem: Problem, tol: float = TOL, max_iterations: int = 3000, max_seconds: float = 600.0,
                     model: str | None = None, **_) -> None:
    """Start compiling the problem structure's NLP in the background (a compiler process), so that
    it overlaps other work before Ipopt's turn (a study's other solvers); ``prepare_ipopt`` or the
    first solve then waits for it."""
    options, model = ipopt_options(tol, max_iterations, max_seconds), model or default_model()
    if model != "compiled" or _key(problem, options, model) in _SOLVERS:
        return
    nlp = SymbolicNLP.for_problem(problem)
    start_compiling(_nlp_source(_interpreted(nlp, options), nlp), "ipopt_nlp", "-O1")


def _key(problem: Problem, options: dict, model: str) -> tuple:
    return structure_key(problem), tuple(sorted(options.items())), model


def prepare_ipopt(problem: Problem, announce=None, tol: float = TOL, max_iterations: int = 3000,
                  max_seconds: float = 600.0, model: str | None = None, **_) -> None:
    """Build (and compile, with ``model="compiled"``) Ipopt's instance for the problem's structure
    now, so that a batch's worker processes inherit it instead of each compiling it; calls
    ``announce()`` first when this process does not have it yet."""
    options, model = ipopt_options(tol, max_iterations, max_seconds), model or default_model()
    if _key(problem, options, model) not in _SOLVERS:
        if announce is not None:
            announce()
        _solver(problem, options, model)


def solve_ipopt(problem: Problem, tol: float = TOL, kkt_tol: float = KKT_TOL, max_iterations: int = 3000,
                max_seconds: float = 600.0, p_start=None, model: str | None = None) -> Result:
    """Solve ``problem`` with Ipopt from p0 (or ``p_start``); see the module docstring.

    Common options (contract.options): max_iterations is Ipopt's max_iter, max_seconds its
    max_wall_time. Ipopt's own: model: "compiled" or "casadi", how the NLP's functions are evaluated
    (default: ``$SAGFREE_IPOPT_MODEL``, else "compiled"; module docstring)."""
    model = model or default_model()
    if model not in MODELS:
        raise ValueError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
    setup = time.perf_counter()
    solver, nlp = _solver(problem, ipopt_options(tol, max_iterations, max_seconds), model)
    clock = time.perf_counter()
    setup = clock - setup  # building the instance of a new strand size: Result.setup_time, not time
    start = problem.p0 if p_start is None else np.clip(np.asarray(p_start, dtype=float), problem.lower,
                                                       problem.upper)
    n_constraints = int(problem.free.sum())
    solution = solver(x0=start, p=nlp.data_vector(problem), lbx=problem.lower, ubx=problem.upper,
                      lbg=np.zeros(n_constraints), ubg=np.zeros(n_constraints))
    stats = solver.stats()
    timing.add(timing.MODEL, sum(v for k, v in stats.items() if k.startswith("t_wall_nlp_")))
    # Ipopt's x as returned: it may leave the box by a rounding error, and clipping that off would
    # move c by ~1e-8 (a rest-length column of dc/dp is ~1e7); the message reports the excess
    p = np.asarray(solution["x"]).ravel()
    outside = float(np.max(np.maximum(problem.lower - p, 0.0) + np.maximum(p - problem.upper, 0.0)))
    return_status = stats.get("return_status", "unknown")
    residual = float(np.abs(problem.residual(p)).max(initial=0.0))
    optimality = kkt_optimality(problem, p)
    held = judged_tolerance(problem, p, residual, tol)
    status = RETURN_STATUS.get(return_status, "failed")
    if status in ("converged", "failed"):
        status = "converged" if residual <= held and optimality <= kkt_tol else "failed"
    counts = {
        "ipopt": int(stats.get("iter_count", 0)),
        "constraint_evaluations": int(stats.get("n_call_nlp_g", 0)),
        "jacobian_evaluations": int(stats.get("n_call_nlp_jac_g", 0)),
        "hessian_evaluations": int(stats.get("n_call_nlp_hess_l", 0)),
    }
    message = (f"Ipopt: {return_status} after {counts['ipopt']} iterations; |c|_inf = {residual:.2e} "
               f"(target {held:g}), KKT distance {optimality:.2e} (target {kkt_tol:g})" + raised_note(tol, held)
               + (f"; x leaves the box by up to {outside:.1e} (rounding)" if outside > 0 else ""))
    history = [float(v) for v in stats.get("iterations", {}).get("inf_pr", [])]
    return make_result(problem, p, "ipopt", status, message, counts, time.perf_counter() - clock, history,
                       setup_time=setup)
