"""What would a compiled end-to-end solve save? A measurement for issue 21, item 1.

    python benchmarks/study_compiled_floor.py [--strands 10] [--vertices 100] [--repeats 100]

Most groom strands are held by their root alone and need no stabilization: asc builds the Problem,
takes the least rest change (one square band LU) and the optimum it fixes (solvers.statics_start),
confirms it by the KKT distance (one saddle band LU and solve) and measures the Result's stability
(the stressed Hessian band, its smallest eigenpair, and the unstressed bound of meets_margin).
Here each of those compiled kernels is timed alone on the strand's own inputs (best of 5 batches of
``--repeats`` calls, each through its Python entry point, so their own argument handling counts as
compiled: the floor is if anything lower), and their sum is set against ``solve_strand``'s wall
time on the same strand: the difference is what runs between the kernels (Python, numpy's small
calls, the memos and the Result's packaging), what compiling the whole path into one call removes. The
Problem's construction is shown apart (it would stay: strands cross process boundaries as arrays).
Strands the loop stabilizes (a sixth of a groom) are skipped: they add stability evaluations and a
re-solve on top of the same path.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import sagfree
from sagfree.contract.optimality import working_set
from sagfree.formulation import at_rest
from sagfree.formulation.parameters import REST_BLOCKS
from sagfree.formulation.problem import Problem
from sagfree.frontend.batch import solve_strand
from sagfree.linalg.saddle import SaddleFactor
from sagfree.linalg.square import square_column_solve
from sagfree.solvers.statics_start import statics_start


def best_microseconds(call, repeats: int) -> float:
    """Best over 5 batches of ``repeats`` calls of the mean time per call, us (after one call)."""
    call()
    best = np.inf
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(repeats):
            call()
        best = min(best, (time.perf_counter() - start) / repeats)
    return best * 1e6


def kernel_times(problem: Problem, p: np.ndarray, repeats: int) -> dict[str, float]:
    """us per call of each compiled step of the path in the module docstring, on ``problem`` at the
    start p0 and at its solution ``p`` (the Jacobian and the residual are evaluated at both)."""
    p0 = problem.layout.p0
    forces_arguments, jacobian_arguments = problem.at_rest_kernels[:2]
    J0, c0 = problem.strand_jacobian(p0), problem.residual(p0)
    rest = problem.layout.block_mask(REST_BLOCKS) & (J0.column_norms() > 0)
    change = square_column_solve(J0, rest, -c0)
    J, c, gradient = problem.strand_jacobian(p), problem.residual(p), problem.objective_gradient(p)
    free = working_set(p, problem.layout.lower, problem.layout.upper, 1e-6)
    factor = SaddleFactor(J, problem.layout.weights, free)
    band = problem.hessian_band(p)
    mode = problem.stability(p, vector=True)[1]
    return {
        "dc/dp (x2)": 2 * best_microseconds(lambda: at_rest.jacobian_values(p0, *jacobian_arguments), repeats),
        "c (x2)": 2 * best_microseconds(lambda: at_rest.forces(p0, *forces_arguments), repeats),
        "square LU": best_microseconds(lambda: square_column_solve(J0, rest, -c0), repeats),
        "statics optimum": best_microseconds(lambda: statics_start(problem, change), repeats),
        "saddle LU": best_microseconds(lambda: SaddleFactor(J, problem.layout.weights, free), repeats),
        "saddle solve": best_microseconds(lambda: factor.solve(gradient, c), repeats),
        "Hessian band": best_microseconds(lambda: problem.hessian_band(p), repeats),
        "eigenpair": best_microseconds(lambda: problem._stability_of_band(band, True), repeats),
        "unstressed bound": best_microseconds(lambda: problem._unstressed_form(mode), repeats),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--strands", type=int, default=10)
    parser.add_argument("--vertices", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=100)
    args = parser.parse_args()
    groom = sagfree.scenes.groom(4 * args.strands, args.vertices, seed=0)
    results = sagfree.optimize(groom, jobs=1)
    chosen = [k for k, r in enumerate(results) if r.status == "converged" and r.stable
              and not r.iterations.get("stabilization") and r.iterations.get("gauss_newton", 0) == 0]
    chosen = chosen[:args.strands]
    print(f"groom({4 * args.strands}, {args.vertices}, seed=0): {len(chosen)} strands solved at the statics "
          f"start without stabilization; us per strand, one core")
    rows = []
    for k in chosen:
        strand, p = groom[k], results[k].p
        wall = best_microseconds(lambda: solve_strand(strand), max(1, args.repeats // 4))
        construction = best_microseconds(lambda: Problem(strand), max(1, args.repeats // 4))
        kernels = kernel_times(Problem(strand), p, args.repeats)
        rows.append((wall, construction, kernels))
    if not rows:
        print("no such strand")
        return
    names = list(rows[0][2])
    mean = {name: np.mean([row[2][name] for row in rows]) for name in names}
    wall, construction = np.mean([row[0] for row in rows]), np.mean([row[1] for row in rows])
    compiled = sum(mean.values())
    between = wall - construction - compiled
    print(f"   solve_strand (wall)               {wall:8.0f}")
    print(f"   Problem construction              {construction:8.0f}  {construction / wall:6.1%}")
    print(f"   compiled kernels of the path      {compiled:8.0f}  {compiled / wall:6.1%}")
    for name in names:
        print(f"     {name:31s} {mean[name]:8.0f}")
    print(f"   between them (Python, numpy)      {between:8.0f}  {between / wall:6.1%}")
    print(f"   compiled end to end at best: {construction + compiled:.0f} us, {wall / (construction + compiled):.2f}x "
          "faster on these strands")


if __name__ == "__main__":
    main()
