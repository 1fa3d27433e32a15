"""Model evaluation cost: residual + Jacobian for a 1.9K x 100 groom, and its growth with strand size.

    python benchmarks/bench_evaluation.py [--strands 1900] [--vertices 100]

Prints (1) the time to build every strand's Problem and to evaluate residual + Jacobian once per
strand on one core, with the CasADi virtual machine (the uncompiled fallback) measured in the same run
on a subset as the baseline, and (2) time per evaluation against strand size (25 to 400 vertices),
with the time per vertex, which stays flat when the cost is linear.
"""
from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

import sagfree
from sagfree.formulation.compiled import BatchFunction


def evaluate_all(problems) -> float:
    start = time.perf_counter()
    for pb in problems:
        pb.residual(pb.p0)
        pb.jacobian(pb.p0)
    return time.perf_counter() - start


def with_virtual_machine(problem):
    """The same problem evaluated by CasADi's virtual machine instead of compiled C (every stencil
    function: the full stencils and the vertex stencil's fixed-shape functions)."""
    vm = sagfree.Problem(problem.strand)
    for name in ("_edge", "_vertex", "_vertex_fixed"):
        compiled = getattr(vm, name)
        setattr(vm, name, dataclasses.replace(compiled, **{
            field.name: BatchFunction(getattr(compiled, field.name).function)
            for field in dataclasses.fields(compiled)}))
    return vm


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--strands", type=int, default=1900)
    parser.add_argument("--vertices", type=int, default=100)
    parser.add_argument("--baseline-strands", type=int, default=100)
    args = parser.parse_args()

    strands = sagfree.scenes.groom(args.strands, args.vertices, seed=0)
    sagfree.Problem(strands[0])  # compile (or load from cache) before timing
    start = time.perf_counter()
    problems = [sagfree.Problem(s) for s in strands]
    build = time.perf_counter() - start
    compiled = evaluate_all(problems)
    subset = problems[: args.baseline_strands]
    vm_per_strand = evaluate_all([with_virtual_machine(pb) for pb in subset]) / len(subset)
    per_strand = compiled / len(problems)

    print(f"groom: {args.strands} strands x {args.vertices} vertices "
          f"({sum(pb.n_parameters for pb in problems)} parameters), one core")
    print(f"{'step':42} {'total s':>9} {'per strand ms':>14} {'vs VM':>7}")
    print(f"{'build Problems (frames, p0, patterns)':42} {build:9.3f} {build / len(problems) * 1e3:14.3f} {'':>7}")
    print(f"{'residual + Jacobian, compiled C':42} {compiled:9.3f} {per_strand * 1e3:14.3f} "
          f"{per_strand / vm_per_strand:7.3f}")
    print(f"{'residual + Jacobian, CasADi VM (baseline)':42} {vm_per_strand * len(problems):9.3f} "
          f"{vm_per_strand * 1e3:14.3f} {1.0:7.3f}")
    print("  (VM total extrapolated from", len(subset), "strands)")

    print(f"\n{'vertices':>8} {'residual+Jacobian ms':>21} {'us per vertex':>14}")
    for n in (25, 50, 100, 200, 400):
        pb = sagfree.Problem(sagfree.scenes.curly(n=n, length=0.1 * n / 100))
        repeats = max(20, 4000 // n)
        t = evaluate_all([pb] * repeats) / repeats
        print(f"{n:8d} {t * 1e3:21.3f} {t / n * 1e6:14.2f}")


if __name__ == "__main__":
    np.seterr(all="raise")
    main()
