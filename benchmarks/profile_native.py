"""How much of a groom strand's solve is compiled work and how much is Python and numpy around it.

    pip install py-spy
    python benchmarks/profile_native.py [--strands 600] [--vertices 100] [--rate 100]

Samples ``optimize(groom(strands, vertices), jobs=1)`` with py-spy's native stacks and sorts every
sample inside ``solve_strand`` by its innermost frame: compiled work (OpenBLAS/LAPACK, the CasADi
C stencils, numba's JIT code, which py-spy shows as unnamed addresses) or overhead (numpy's C
internals, the interpreter, libc's allocator, Python lines). Prints the split, then the sagfree
functions whose own Python and numpy calls cost the most. This is the measure for issue 21's
"no Python on the per-strand path": the compiled share is what an end-to-end compiled loop keeps.

Native unwinding stops the process for every sample, and on some VMs each stop costs milliseconds:
at 500 samples per second one such VM ran the batch two orders of magnitude slower than
unsampled, and the split then measures the sampler. So the batch runs once unsampled first, and the report gives
both wall times and warns when sampling slowed it more than SLOWDOWN times.
"""
from __future__ import annotations

import argparse
import collections
import os
import shutil
import subprocess
import sys
import tempfile

SCRIPT = """
import sys, time, sagfree
strands = sagfree.scenes.groom(int(sys.argv[1]), int(sys.argv[2]), seed=0)
sagfree.optimize(strands[:2], jobs=1)
start = time.perf_counter()
sagfree.optimize(strands, jobs=1)
print("batch seconds", time.perf_counter() - start)
"""
#: sampled over unsampled wall time of the batch above which the split is reported as unreliable
SLOWDOWN = 2.0


def kind(frame: str) -> str:
    """'compiled' or 'overhead' for py-spy's innermost frame of a sample."""
    if "openblas" in frame or "lapack" in frame or "stencils_" in frame or frame.endswith("(?)"):
        return "compiled"
    return "overhead"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--strands", type=int, default=600)
    parser.add_argument("--vertices", type=int, default=100)
    parser.add_argument("--rate", type=int, default=100, help="samples per second")
    args = parser.parse_args()
    if shutil.which("py-spy") is None:
        sys.exit("py-spy is not installed: pip install py-spy")
    with tempfile.TemporaryDirectory() as where:
        script, raw = os.path.join(where, "run.py"), os.path.join(where, "samples.txt")
        with open(script, "w") as out:
            out.write(SCRIPT)
        command = [sys.executable, script, str(args.strands), str(args.vertices)]
        unsampled = _batch_seconds(command)
        sampled = _batch_seconds(["py-spy", "record", "--native", "-r", str(args.rate), "-f", "raw", "-o", raw,
                                  "--", *command])
        lines = open(raw).read().splitlines()
    total, split, owners = 0, collections.Counter(), collections.Counter()
    for line in lines:
        stack, count = line.rsplit(" ", 1)
        frames = stack.split(";")
        if not any(f.startswith("solve_strand ") for f in frames):
            continue
        total += int(count)
        what = kind(frames[-1])
        split[what] += int(count)
        if what == "overhead":
            ours = [f for f in frames if ".py:" in f and "site-packages" not in f]
            owners[ours[-1].split(" (")[0] if ours else "?"] += int(count)
    print(f"groom({args.strands}, {args.vertices}), one process: {total} samples in solve_strand; the batch "
          f"took {sampled:.2f} s sampled at {args.rate}/s, {unsampled:.2f} s unsampled")
    if sampled > SLOWDOWN * unsampled:
        print(f"  WARNING: sampling slowed the batch {sampled / unsampled:.1f}x; the split below measures the "
              "sampler more than the solver (lower --rate)")
    for what in ("compiled", "overhead"):
        print(f"  {what:9} {100 * split[what] / max(total, 1):5.1f}%")
    print("  overhead by the sagfree function that runs it (its own lines and numpy calls):")
    for name, count in owners.most_common(15):
        print(f"    {100 * count / total:5.1f}%  {name}")


def _batch_seconds(command: list[str]) -> float:
    """Wall time of the timed batch of SCRIPT run by ``command`` (its line 'batch seconds S')."""
    output = subprocess.run(command, check=True, capture_output=True, text=True).stdout
    return next(float(line.split()[-1]) for line in output.splitlines() if line.startswith("batch seconds"))


if __name__ == "__main__":
    main()
