"""The same strand at 50 to 400 vertices: R and the stiffening profile converge (DESIGN section 4).

    python benchmarks/bench_resolution.py [--sizes 50,100,200,400] [--figure docs/resolution.png]

``curly`` and the first strand of ``groom(seed=0)`` (the same physical curves at every resolution),
solved with ``asc`` (element stiffness, default boxes and stabilization): R(p*), the largest bend
multiplier, the stiffened share of the length and the ratio of R to the finest resolution's, printed;
the bend multiplier along arc length of every resolution drawn into the figure.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import sagfree  # noqa: E402

STRANDS = {"curly": lambda n: sagfree.scenes.curly(n=n),
           "groom strand 0": lambda n: sagfree.scenes.groom(1, n, seed=0)[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="50,100,200,400")
    parser.add_argument("--figure", default=str(Path(__file__).resolve().parents[1] / "docs" / "resolution.png"))
    args = parser.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    figure, axes = plt.subplots(1, len(STRANDS), figsize=(10, 3.6))
    print(f"{'strand':16} {'vertices':>8} {'status':>10} {'R':>10} {'R / R_finest':>12} {'bend max':>9} "
          f"{'stiffened / L':>13}")
    for ax, (name, make) in zip(axes, STRANDS.items()):
        rows = []
        for n in sizes:
            problem = sagfree.Problem(make(n))
            result = sagfree.solve(problem)
            bend = result.p[problem.blocks["bend_stiffness"]]
            arc = np.cumsum(problem.edge_lengths)[:-1] / problem.strand.length  # interior vertices
            stiffened = float(np.sum(np.where(bend > 1.01, 0.5 * (problem.edge_lengths[:-1] + problem.edge_lengths[1:]),
                                              0.0)) / problem.strand.length)
            rows.append((n, result.status, result.objective, bend.max(), stiffened))
            ax.plot(arc, bend, label=f"{n} vertices", lw=1.2)
        finest = rows[-1][2]
        for n, status, objective, bend_max, stiffened in rows:
            print(f"{name:16} {n:8d} {status:>10} {objective:10.4g} {objective / finest:12.4f} {bend_max:9.3f} "
                  f"{stiffened:13.3f}")
        ax.set_title(name)
        ax.set_xlabel("arc length / L (interior vertices)")
        ax.set_ylabel("bend stiffness multiplier")
        ax.legend(fontsize=8)
    figure.suptitle("Stiffening profile of the same strand at several resolutions (asc, default boxes)")
    figure.tight_layout()
    Path(args.figure).parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(args.figure, dpi=110)
    print(f"wrote {args.figure}")


if __name__ == "__main__":
    main()
