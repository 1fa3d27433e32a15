"""Forward simulation cost against strand size (DESIGN section 7).

    python benchmarks/bench_simulation.py [--strands 4] [--steps 100]

For groom strands of 25 to 400 vertices (the same physical strands at each resolution), one core:
1. implicit-Euler runs of the naive parameters (the strands sag and swing) and of our optimized
   parameters (they stay still; Newton still steps, tol below the round-off floor): time per time
   step, Newton steps per time step, and time per vertex per Newton step (flat = linear cost);
2. the Newton linear solve alone: the banded Cholesky the simulation uses (sagfree.linalg) against
   LAPACK's banded Cholesky and a dense Cholesky of the same matrix (the baselines, measured in this
   run), with their ratios;
3. the forward check of our optimized parameters (sag_check: 200 implicit-Euler steps, the static
   solve, the push) and the naive parameters' static solve, with the Newton solve compiled
   (formulation.newton) against its Python loop (the baseline, measured in this run on the same
   strands), their ratio and the largest difference of the final states; on groom strands and on
   strands lying on the head (the contact penalty compiled too).
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.linalg

import sagfree
from sagfree.formulation.simulation import (
    CHECK_TOLERANCE,
    IncrementalPotential,
    equilibrium,
    generalized_masses,
    sag_check,
)
from sagfree.linalg.cholesky import band_cholesky, band_solve
from sagfree.scenes.head import HEAD, head_groom

SIZES = (25, 50, 100, 200, 400)


def run_table(strands: int, steps: int) -> None:
    print(f"1. implicit Euler, {steps} steps of 1 ms, {strands} groom strands per size, one core")
    print(f"   {'vertices':>8} {'params':>9} {'ms/step':>8} {'Newton/step':>11} {'us/vertex/Newton':>17} "
          f"{'sag / L':>9}")
    for n in SIZES:
        groom = sagfree.scenes.groom(strands, n, seed=0)
        for label in ("naive", "asc"):
            step_time, newton, sag = [], [], []
            for strand in groom:
                problem = sagfree.Problem(strand)
                p = problem.p0 if label == "naive" else sagfree.solve(problem).p
                sagfree.simulate(problem, p, steps=2)  # load the compiled model outside the timing
                run = sagfree.simulate(problem, p, steps=steps, tol=CHECK_TOLERANCE)
                step_time.append(run.time / steps)
                newton.append(run.newton_iterations.mean())
                sag.append(run.relative_sag)
            per_newton = np.sum(step_time) / np.sum(newton)
            print(f"   {n:8d} {label:>9} {1e3 * np.mean(step_time):8.2f} {np.mean(newton):11.2f} "
                  f"{1e6 * per_newton / n:17.2f} {np.max(sag):9.2e}")


def solve_table(repeats: int = 20) -> None:
    print("\n2. one Newton linear solve (K = d2E/dq2 + M/dt^2 on the free DOFs): banded Cholesky (sagfree.linalg), "
          "LAPACK banded, dense")
    print(f"   {'vertices':>8} {'DOFs':>6} {'ours ms':>8} {'LAPACK band ms':>14} {'dense ms':>9} "
          f"{'LAPACK / ours':>13} {'dense / ours':>12}")
    for n in SIZES:
        problem = sagfree.Problem(sagfree.scenes.groom(1, n, seed=0)[0])
        weight = generalized_masses(problem) / 1e-6
        potential = IncrementalPotential(problem, problem.p0, problem.frames, (weight, problem.q_star))
        band = problem.free_band(potential.hessian_band(problem.q_star))
        g = potential.gradient(problem.q_star)[problem.free_index]
        size = band.shape[1]
        dense = np.zeros((size, size))
        for k in range(band.shape[0]):
            i = np.arange(size - k)
            dense[i + k, i] = dense[i, i + k] = band[k, : size - k]

        def our_solve():
            return band_solve(band_cholesky(band), g)

        def lapack_solve():
            return scipy.linalg.cho_solve_banded((scipy.linalg.cholesky_banded(band, lower=True), True), g)

        def dense_solve():
            return scipy.linalg.cho_solve(scipy.linalg.cho_factor(dense, lower=True), g)

        reference = dense_solve()  # the same solution, up to the conditioning of K (~1e10)
        for solve in (our_solve, lapack_solve):
            np.testing.assert_allclose(solve(), reference, rtol=0, atol=1e-6 * np.abs(reference).max())
        times = []
        for solve in (our_solve, lapack_solve, dense_solve):
            start = time.perf_counter()
            for _ in range(repeats):
                solve()
            times.append((time.perf_counter() - start) / repeats)
        print(f"   {n:8d} {size:6d} {1e3 * times[0]:8.3f} {1e3 * times[1]:14.3f} {1e3 * times[2]:9.3f} "
              f"{times[1] / times[0]:13.1f} {times[2] / times[0]:12.1f}")


def compiled_table(strands: int) -> None:
    print(f"\n3. the Newton solve compiled against its Python loop, {strands} groom strands per size (and on the "
          "head: head_groom, 100 vertices, HEAD), one core (ms per strand)")
    print(f"   {'vertices':>8} {'sag_check':>9} {'Python':>8} {'ratio':>6} {'static naive':>12} {'Python':>8} "
          f"{'ratio':>6} {'max |dq| / L':>12}")
    cases = [(str(n), sagfree.scenes.groom(strands, n, seed=0), {}) for n in SIZES]
    cases.append(("100 head", head_groom(strands, 100, seed=0), {"bodies": [HEAD]}))
    for label, groom, options in cases:
        times, difference = np.zeros(4), 0.0
        for strand in groom:
            compiled, python = sagfree.Problem(strand, **options), sagfree.Problem(strand, **options)
            python.__dict__["newton_kernels"] = None  # simulation.newton_solve's Python loop
            p = sagfree.solve(compiled).p
            states = []
            for k, (check, problem) in enumerate([(True, compiled), (True, python), (False, compiled),
                                                  (False, python)]):
                equilibrium(problem, problem.p0, max_steps=2)  # load the compiled model outside the timing
                start = time.perf_counter()
                found = sag_check(problem, p) if check else equilibrium(problem, problem.p0)
                times[k] += time.perf_counter() - start
                if not check:
                    states.append(found.q)
            difference = max(difference, np.abs(states[0] - states[1]).max() / strand.length)
        times *= 1e3 / strands
        print(f"   {label:>8} {times[0]:9.1f} {times[1]:8.1f} {times[1] / times[0]:6.1f} {times[2]:12.2f} "
              f"{times[3]:8.2f} {times[3] / times[2]:6.1f} {difference:12.1e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--strands", type=int, default=4, help="groom strands per size (default 4)")
    parser.add_argument("--steps", type=int, default=100, help="time steps per run (default 100)")
    args = parser.parse_args()
    run_table(args.strands, args.steps)
    solve_table()
    compiled_table(args.strands)


if __name__ == "__main__":
    main()
