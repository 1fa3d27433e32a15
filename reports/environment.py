"""What a report records about where it ran: versions of sagfree and its numerical libraries (Ipopt
included), Python, the CPU and its core count."""
from __future__ import annotations

import os
import platform
import re
import subprocess
import sys
from functools import lru_cache
from importlib import metadata

PACKAGES = ("sagfree", "casadi", "numpy", "scipy", "numba", "osqp", "matplotlib", "typst")

_IPOPT_PROBE = """
import casadi as ca
x = ca.MX.sym("x")
ca.nlpsol("probe", "ipopt", {"x": x, "f": x**2}, {"ipopt.print_level": 5, "print_time": 0})(x0=1)
"""


@lru_cache(maxsize=1)
def ipopt_version() -> str:
    """Version of CasADi's bundled Ipopt, read from its banner (a one-variable NLP in a subprocess,
    since Ipopt prints from C)."""
    try:
        out = subprocess.run([sys.executable, "-c", _IPOPT_PROBE], capture_output=True, text=True,
                             timeout=60).stdout
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"unknown ({exc})"
    found = re.search(r"Ipopt version ([\w.]+)", out)
    return found.group(1) if found else "not available"


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def versions() -> dict[str, str]:
    """Component -> version, then python and the machine (recorded in every report)."""
    found = {}
    for name in PACKAGES:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    found["ipopt (CasADi plugin)"] = ipopt_version()
    found["python"] = sys.version.split()[0]
    found["machine"] = (f"{cpu_model()}, {os.cpu_count()} cores, {platform.system()} {platform.release()} "
                        f"({platform.machine()})")
    return found
