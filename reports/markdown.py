"""Markdown building blocks shared by every report."""
from __future__ import annotations

import platform
import sys
from importlib import metadata


def table(header: list[str], rows: list[list]) -> str:
    """A GitHub-flavoured markdown table; floats in compact scientific form."""
    def cell(value) -> str:
        if isinstance(value, float):
            return f"{value:.3g}" if 1e-3 <= abs(value) < 1e4 or value == 0 else f"{value:.2e}"
        return str(value).replace("|", "\\|")  # a literal pipe would split the cell
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def versions() -> dict[str, str]:
    """Versions of sagfree, its numerical libraries, Python and the machine (recorded in reports)."""
    found = {}
    for name in ("sagfree", "casadi", "numpy", "scipy", "numba", "osqp"):
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    found["python"] = sys.version.split()[0]
    found["machine"] = f"{platform.machine()}, {platform.system()} {platform.release()}"
    return found
